"""What a scene changes in the simulated ROS graph (`fabric-guidance demo --scene`): its wearer 0,
calibrated by Algorithm 1 headless with the scene's effects (as the paper calibrates before the
trials), the targets wearer 0 meets first in the headless protocol, the node overrides, and
where in the graph each of the scene's effects is realised. No ROS: demo.py runs the graph.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
import time

import numpy as np

from ..core import condition as condition_of
from ..paths import node_parameters

from .population import calibrate_wearer, sample_wearer
from .protocols import draw_target, target_stream
from .effects import effect_class
from .scene_wearer import UNUSED, effect_place, load_scene_file
from .wearer import gaze_from_angles

#: With a scene: targets drawn from its protocol ranges, this many, this far from the eye [m].
SCENE_TARGETS = 4
SCENE_TARGET_DISTANCE_M = 2.0
#: wearer_sim steps at the scene's sim_rate_hz, but not faster than this (real time) [Hz].
MAX_SCENE_GAZE_RATE_HZ = 120.0
#: mock_plc regulator_tau_s when the scene lists no regulator_lag: the mock's "no lag" [s].
NO_REGULATOR_LAG_S = 0.0


@dataclass
class ScenePlan:
    """What a scene changes in the demo: the wearer, their calibration, the node overrides and
    the targets, and where each of the scene's effects is realised."""

    scene: object                         # sim.scene.Scene
    wearer: object                        # sim.population.WearerSpec
    calibration_file: Path
    condition: int
    targets: list[tuple[str, float, float, np.ndarray]]   # name, yaw, pitch (deg), position (m)
    regulator_tau_s: float
    gaze_rate_hz: float
    where: dict[str, list[str]]           # where -> the effects realised there (or unused)

    def effects_line(self) -> str:
        scene = self.scene
        if not scene.effects:
            return (f'scene {scene.name}: no effect listed (the ideal wearer); '
                    f'mock_plc regulator_tau_s {self.regulator_tau_s:g} s (no lag)')
        return (f'scene {scene.name}: effects realised in the graph: ' +
                '; '.join(f'{w}: {", ".join(names)}' for w, names in self.where.items()))


def plan_scene(scene_ref, condition: int | None, log_dir: Path, say) -> ScenePlan:
    """Load the scene, calibrate its wearer 0 headless by Algorithm 1 with the scene's effects
    (population.calibrate_wearer), save the calibration into log_dir and draw the targets.
    Raises ValueError (SceneError, a failed calibration) with the reason."""
    scene = load_scene_file(str(scene_ref))
    cond = condition_of(condition if condition is not None else scene.conditions[0])
    wearer = sample_wearer(scene, 0)
    say(f'scene {scene.name} ({scene.source}): wearer {wearer.name} (index 0) of '
        f'{scene.population.subjects}, '
        f'condition {cond.number}; effects: {", ".join(scene.effect_names) or "none"}')
    t0 = time.monotonic()
    outcome = calibrate_wearer(scene, wearer)
    if not outcome.ok:
        raise ValueError(f'the calibration of wearer {wearer.name} failed: {outcome.error}')
    cal_path = outcome.calibration.save(log_dir / f'{scene.name}-{wearer.name}.yaml')
    worst = max(outcome.angle_error_deg.values())
    say(f'Algorithm 1 on {wearer.name}, headless with the scene\'s effects '
        f'({time.monotonic() - t0:.1f} s): '
        f'fitted laws within {worst:.1f} deg of the true ones over 0-60 deg; saved to {cal_path}')
    lag = scene.effect('regulator_lag')
    tau = float(lag.build().tau_s) if lag is not None else NO_REGULATOR_LAG_S
    # The targets wearer 0 meets first in the headless protocol: the speed trial's first draws
    # of repetition 0, or the accuracy trials' targets of repetitions 0, 1, ... (the same streams).
    eye = np.array([0.0, 0.0, _eye_height()])
    speed = scene.protocol.kind == 'speed'
    rng = target_stream(scene, 0, 0)
    targets = []
    for i in range(SCENE_TARGETS):
        yaw, pitch = draw_target(rng if speed else target_stream(scene, 0, i), scene.protocol)
        targets.append((f'{scene.name.replace("-", "_")}_{i + 1}', yaw, pitch,
                        eye + SCENE_TARGET_DISTANCE_M * gaze_from_angles(yaw, pitch)))
    where = effects_where(scene, cond, tau)
    rate = min(scene.sim_rate_hz, MAX_SCENE_GAZE_RATE_HZ)
    return ScenePlan(scene, wearer, cal_path, cond.number, targets, tau, rate, where)


def _eye_height() -> float:
    params = node_parameters('params/sim.yaml', 'wearer_sim')
    return float(params.get('eye_height_m', 1.2))


def effects_where(scene, cond, regulator_tau_s: float) -> dict[str, list[str]]:
    """Where in the graph each of the scene's effects is realised under condition `cond`:
    {place: effect names}, the places mock_plc, wearer_sim, unused in the condition, or
    headless only."""
    tau = regulator_tau_s
    where: dict[str, list[str]] = {}
    for name in scene.effect_names:
        if name == 'regulator_lag':
            where.setdefault('mock_plc', []).append(f'regulator_lag (regulator_tau_s {tau:g} s)')
            continue
        place = effect_place(name, effect_class(name).stage, cond)
        where.setdefault(f'unused in condition {cond.number}' if place == UNUSED else place, []).append(name)
    if 'mock_plc' not in where:
        none = f'no regulator_lag listed, regulator_tau_s {tau:g} s (no lag)'
        where = {'mock_plc': [none], **where}
    return where
