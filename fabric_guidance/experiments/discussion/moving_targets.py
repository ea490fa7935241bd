"""Moving targets, in simulation: the second open point of the paper's Discussion.

Moving targets ("the proposed system cannot be directly applied to the directional guidance
of moving targets ... by developing an algorithm that adjusts the air pressure according to
the movement of the target"). A target starts where a speed-protocol target would (within
+-60 deg horizontally, +-30 deg vertically) and moves at a constant angular speed in a random
direction, measured in the paper's horizontal and vertical angles, reflected at the edges of
that range (it stays in the field of the experiment). Three laws, condition 1 (suit,
adjusted, the scene's G):

- paper:  Eq. 5 as the paper built it for static targets: theta_t is taken once, where the
          target was when guidance began, and the law runs on that.
- live:   Eq. 5 fed the moving target every control step without the shift
          (core.feedback follow_target=False): what the pressure_controller node does with
          follow_moving_target false. Here theta_t enters the increment and the sign of de/dt.
- follow: the same plus core.feedback's follow_target: a change of theta_t shifts the
          pressure by f(theta_t new) - f(theta_t old), so the feed-forward part follows the
          target.

The guidance runs for the whole trial (a tracking task, not the speed protocol's
find-and-return). Measured: the time until the tracked gaze has first stayed within the
protocol's acceptance angle of the (moving) target for its dwell, judged on each gaze sample
the controller receives as the target_selector node does (censored at the trial length when
never), and the tracking error, the angle between the true gaze and the target averaged over
every simulation step of the trial (and over its second half). Two scenarios: `seen` (the
target is visible: once in the central field the wearer's eyes catch it, as in the speed
protocol) and `unseen` (no visual capture: the suit alone guides, as in the accuracy
protocol).

The trials, their analyses, plots, summary and report section are in this one module.
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from pathlib import Path

import pandas as pd

from ...core.calibration import Calibration
from ...sim.node_loop import NodeLoop
from ...sim.protocols import draw_target
from ...sim.scene import Scene
from ...sim.wearer import angle_between_deg, hav_limit, haversine
from ..analysis_report import analysis_markdown, image_path, md_table
from ..stats import format_p
from .arms import analyze_arms, pair_p
from .trials import CONDITION, TrialKey

#: The moving-target laws compared (see the module docstring).
LAWS = ('paper', 'live', 'follow')
#: Scenarios of the moving-target study: the target visible (visual capture) or not.
SCENARIOS = ('seen', 'unseen')


def _fold(x: float, half: float) -> float:
    """x reflected into [-half, half] (a point bouncing between the walls)."""
    if half <= 0.0:
        return 0.0
    if -half <= x <= half:
        return x                    # exact inside: a static target stays where it was drawn
    y = math.fmod(x + half, 4.0 * half)
    if y < 0.0:
        y += 4.0 * half
    if y > 2.0 * half:
        y = 4.0 * half - y
    return y - half


@dataclass(frozen=True)
class TargetMotion:
    """A target starting at (yaw0, pitch0) moving at speed_dps in the direction heading_deg
    (0 = to the left, 90 = up) in the horizontal/vertical angles, reflected at +-half_h and
    +-half_v."""

    yaw0: float
    pitch0: float
    speed_dps: float
    heading_deg: float
    half_h: float
    half_v: float

    def at(self, s: float) -> tuple[float, float]:
        """Position s seconds after it appeared."""
        a = math.radians(self.heading_deg)
        d = self.speed_dps * s
        return (_fold(self.yaw0 + d * math.cos(a), self.half_h),
                _fold(self.pitch0 + d * math.sin(a), self.half_v))


def draw_motion(scene: Scene, subject: int, key: TrialKey, speed_dps: float) -> TargetMotion:
    """The moving target of a trial: start as a speed-protocol target, a uniform random
    heading; the same start and heading for every law and speed (common random numbers)."""
    rng = key.targets(scene, subject)
    yaw0, pitch0 = draw_target(rng, scene.protocol)
    heading = float(rng.uniform(0.0, 360.0))
    return TargetMotion(yaw0, pitch0, float(speed_dps), heading, scene.protocol.horizontal_deg,
                        scene.protocol.vertical_deg)


def moving_trial(scene: Scene, wearer, calibration: Calibration, law: str, speed_dps: float,
                 key: TrialKey, duration_s: float = 15.0, seen: bool = True) -> dict:
    """One moving-target trial under `law` (LAWS); the measures as a dict."""
    if law not in LAWS:
        raise ValueError(f'law must be one of {LAWS}, got {law!r}')
    proto = scene.protocol
    motion = draw_motion(scene, wearer.index, key, speed_dps)
    loop = NodeLoop(scene, wearer, key.run, CONDITION, calibration, follow_target=law == 'follow',
                    live_target=law != 'paper')
    loop.warm_up()
    w = loop.wearer
    t0 = loop.t
    loop.present(motion.yaw0, motion.pitch0, visible=seen)
    acc_hav, dwell = hav_limit(proto.acceptance_deg), proto.dwell_s
    n = int(round(duration_s / loop.dt))
    half = n // 2
    inside_since = None
    find_s = None
    errors = []
    for i in range(n):
        loop.step()
        # The world moves: from now on the eyes, the controller and the selector see it here.
        target = motion.at(loop.t - t0)
        loop.move_target(*target)
        errors.append(angle_between_deg(w.gaze_yaw, w.gaze_pitch, target[0], target[1]))
        if find_s is not None or not loop.new_sample:
            continue
        s = loop.last_sample
        if haversine(s[2], s[3], target[0], target[1]) > acc_hav:
            inside_since = None
            continue
        if inside_since is None:
            inside_since = loop.t
        if loop.t - inside_since >= dwell - 1e-9:
            find_s = loop.t - t0
    return dict(start_h_deg=motion.yaw0, start_v_deg=motion.pitch0, heading_deg=motion.heading_deg,
                found=find_s is not None,
                find_s=find_s if find_s is not None else float(duration_s),
                tracking_error_deg=math.fsum(errors) / len(errors),
                late_error_deg=math.fsum(errors[half:]) / len(errors[half:]))


# The analysis (`fabric-guidance beyond`): statistics, plots, summary and report section.

LAW_NAMES = {'paper': 'paper: theta_t at start', 'live': 'live theta_t, no shift', 'follow': 'follow_target'}
MOVING_MEASURES = {'find_s': 'time to find (s)', 'tracking_error_deg': 'tracking error (deg)'}


def analyze_moving(results, out: dict) -> None:
    """The moving-target analyses of a StudyResults, into the parts dict `out`."""
    moving = results.moving_frame()
    out['moving_trials'] = moving
    out['moving'] = {}
    if not moving.empty:
        for scenario in results.settings.scenarios:
            for speed in results.settings.speeds_dps:
                part = moving[(moving['scenario'] == scenario) & (moving['speed_dps'] == float(speed))].copy()
                part['condition'] = part['law'].map(LAW_NAMES)
                for measure in MOVING_MEASURES:
                    out['moving'][(scenario, float(speed), measure)] = analyze_arms(part, measure, False,
                                                                                    LAW_NAMES.values())


def moving_plots(parts: dict, out: Path, plots: dict) -> None:
    from ...core.plot_style import measure_label
    from ..violin_plots import violin_plot
    for (scenario, speed, measure), a in parts['moving'].items():
        if a is None:
            continue
        name = f'moving_{scenario}_{speed:g}dps_{measure}.png'
        plots[(scenario, speed, measure)] = violin_plot(
            a, measure_label(measure, per='mean per wearer'), out / name, significance=a,
            title=f'Target moving {speed:g} deg/s, {scenario}: {MOVING_MEASURES[measure]}',
            point="one wearer's mean")


def moving_summary(results, parts: dict, lines: list[str]) -> None:
    """The moving-target findings as plain sentences with their numbers, appended to `lines`."""
    for scenario in results.settings.scenarios:
        for speed in results.settings.speeds_dps:
            bits = []
            for measure, unit in (('find_s', 's'), ('tracking_error_deg', 'deg')):
                a = parts['moving'].get((scenario, float(speed), measure))
                if a is None:
                    continue
                m = a.summary['mean']
                p = pair_p(a, LAW_NAMES['paper'], LAW_NAMES['follow'])
                p_live = pair_p(a, LAW_NAMES['live'], LAW_NAMES['follow'])
                bits.append(f'{MOVING_MEASURES[measure].split(" (")[0]} paper {m[LAW_NAMES["paper"]]:.2f} / live '
                            f'{m[LAW_NAMES["live"]]:.2f} / follow {m[LAW_NAMES["follow"]]:.2f} {unit} '
                            f'(Friedman p = {format_p(a.p)}; follow vs paper p = {format_p(p)}, '
                            f'vs live p = {format_p(p_live)})')
            if bits:
                lines.append(f'Moving target {speed:g} deg/s, {scenario}: ' + '; '.join(bits) + '.')


def _found_table(moving: pd.DataFrame) -> list[str]:
    rows = []
    for (scenario, speed), part in moving.groupby(['scenario', 'speed_dps'], sort=False):
        row = [scenario, f'{speed:g}']
        for law in LAW_NAMES:
            g = part[part['law'] == law]
            per = g.groupby('subject')
            row.append(f'{100 * g["found"].mean():.0f} % / {per["find_s"].mean().mean():.2f} s / '
                       f'{per["tracking_error_deg"].mean().mean():.1f} / {per["late_error_deg"].mean().mean():.1f}')
        rows.append(row)
    return md_table(['target', 'deg/s'] + [LAW_NAMES[k] for k in LAW_NAMES], rows, 'lr' + 'l' * len(LAW_NAMES))


def moving_report(results, parts: dict, plots: dict, out: Path) -> list[str]:
    """The report's section 2 (markdown lines)."""
    sc, st = results.scene, results.settings
    doc = ['## 2. Moving targets', '',
           f'A target starts as a speed-protocol target (within +-{sc.protocol.horizontal_deg:g} deg horizontally, '
           f'+-{sc.protocol.vertical_deg:g} deg vertically) and moves at {", ".join(f"{s:g}" for s in st.speeds_dps)} '
           'deg/s (in the horizontal and vertical angles) in a random direction, reflected at the edges of that '
           f'range; {st.moving_reps} trials per speed, {st.moving_s:g} s each, guidance throughout (condition 1, the '
           f'scene\'s G = {sc.controller.gain:g}). The same targets and effect streams for the three laws:', '',
           f'- **{LAW_NAMES["paper"]}**: Eq. 5 as the paper built it for static targets: theta_t is taken once, '
           'when guidance begins.',
           f'- **{LAW_NAMES["live"]}**: Eq. 5 fed the moving target every control step, without the shift: what '
           'the pressure_controller node does with `follow_moving_target` false.',
           f'- **{LAW_NAMES["follow"]}**: the same with `follow_target`: a change of theta_t shifts the pressure by '
           'f(new) - f(old).', '',
           'Time to find: until the tracked gaze has first stayed within '
           f'{sc.protocol.acceptance_deg:g} deg of the moving target for {sc.protocol.dwell_s:g} s (censored at '
           f'{st.moving_s:g} s when never). Tracking error: angle between the true gaze and the target, mean over the '
           'trial. *seen*: the target is visible, the eyes catch it once it is in the central field (as in the speed '
           'protocol); *unseen*: no visual capture, the suit alone guides (as in the accuracy protocol).', '',
           'Per cell: found within the trial / mean time to find / mean tracking error (deg) / mean error over '
           'the second half (deg), means over wearers.', '']
    moving = parts.get('moving_trials')
    if moving is not None and not moving.empty:
        doc += _found_table(moving) + ['']
    for (scenario, speed, measure), a in parts['moving'].items():
        if a is None:
            continue
        doc += [f'### {speed:g} deg/s, {scenario}: {MOVING_MEASURES[measure]}', ''] + analysis_markdown(a, level=3)
        doc += ['']
        if (scenario, speed, measure) in plots:
            doc += [f'![{scenario} {speed:g} {measure}]({image_path(plots[(scenario, speed, measure)], out)})', '']
    return doc
