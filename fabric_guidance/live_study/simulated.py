"""`fabric-guidance study --simulated`: the study session on the simulated graph, a scene's
wearers as the participants.

Per participant (wearer i of the scene): Algorithm 1 headless with the scene's effects (as the
paper calibrates before the trials, and as `demo --scene` does), then the seven processes of the
simulated graph (process_graph.sim_lab) with wearer_sim as that wearer pressing confirm
(press_confirm) through the headset's uplink as the HoloLens clicker does (press_uplink: the
press stamped on the gaze clock), the study's target in target_selector (found_by_dwell off)
and, for speed, 50 dummies on the display. The study's Session (session_graph.py) runs the
blocks on it; the condition orders and targets are the study plan's (study/plan.py: the
headless experiment's streams on the same seed, or a Latin square),
so the live and the headless study meet the same targets.

A condition is switched within the graph by the live `condition` parameters of
pressure_controller and wearer_sim (no restart).

The controller starts disarmed (start_enabled false, as the lab launch starts it). The
simulated operator arms it once at start, standing for the person at the lab's console who
calls `enable`; the session never does, it only opens and closes its trial gate. Should the arm
drop later (a vent from elsewhere, a restart), the session holds until someone arms it again:
nobody does here unless a test plays that person (live_session.operator_keys).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
import os
from pathlib import Path
import time
from typing import Callable

from ..core import condition as condition_of
from ..graph.process_graph import FILES, Graph, fresh_domain_id, loopback_dds_env, sim_lab, start_nodes, wait_until
from ..sim.population import calibrate_wearer, sample_wearer
from ..study import plan
from ..study.store import StudyError
from ..sim.scene_plan import MAX_SCENE_GAZE_RATE_HZ, NO_REGULATOR_LAG_S
from .operator import STUDY_TARGET, Operator, target_position

PAPER_DUMMIES = 50
#: Graph start-up (seven processes, discovery) on a loaded machine [s].
STARTUP_S = 60.0
#: The nodes whose parameters a session sets (condition, target, repetition).
PARAMETER_NODES = ('pressure_controller', 'target_selector', 'wearer_sim')


@dataclass
class Timing:
    """The condition switches of a participant's graph."""
    switch_s: list[tuple[int, float, str]] = field(default_factory=list)   # (condition, seconds, how)


def graph_overrides(lab, scene, subject: int, cond: int, calibration_file: Path, gaze_rate_hz: float) -> None:
    """The node overrides of a study graph for wearer `subject` (in place on lab.overrides)."""
    ov = lab.overrides
    lag = scene.effect('regulator_lag')
    ov['mock_plc'].update(regulator_tau_s=float(lag.build().tau_s) if lag is not None else NO_REGULATOR_LAG_S)
    # stall_timeout_s 0 (never): the headless engine steps Eq. 5 without the no-progress vent
    # (sim.engine.scene_controller), and these participants are the headless ones, so both play the
    # paper's game. A person's graph keeps guidance.yaml's 10 s (docs/study.md: what it costs).
    ov['pressure_controller'].update(calibration_file=str(calibration_file), wearer=f'sub{subject + 1:02d}',
                                     **dataclasses.asdict(scene.controller), step_on_gaze=False, condition=cond,
                                     stall_timeout_s=0.0, start_enabled=False)
    speed = scene.protocol.kind == 'speed'
    ov['target_selector'].update(target_names=[STUDY_TARGET], target_positions=target_position(0.0, 0.0, 1.2),
                                 found_by_dwell=False, return_to_front=False, auto_advance=False)
    if speed:
        ov['target_selector'].update(acceptance_deg=scene.protocol.acceptance_deg, dwell_s=scene.protocol.dwell_s)
        ov['headset_display'].update(dummies=PAPER_DUMMIES, dummy_seed=scene.seed + subject)
    ov['wearer_sim'].update(scene_file=str(Path(scene.source).resolve()), wearer_index=subject, condition=cond,
                            gaze_rate_hz=gaze_rate_hz, press_confirm=True, press_uplink=True,
                            repetition=0)


def own_domain_id() -> int:
    """A fresh domain of 1-100 that is not the one ROS_DOMAIN_ID names."""
    taken = os.environ.get('ROS_DOMAIN_ID', '').strip()
    while True:
        domain = fresh_domain_id()
        if str(domain) != taken:
            return domain


def fresh_folder(base: Path) -> Path:
    """base, or base-2, base-3 ... the first that does not exist yet."""
    path, n = base, 1
    while path.exists():
        n += 1
        path = base.with_name(f'{base.name}-{n}')
    return path


class SimulatedParticipant:
    """One participant's graph and its operator: start(), switch(condition), close()."""

    def __init__(self, scene, subject: int, first_condition: int, log_dir: Path, say: Callable[[str], None],
                 design: plan.StudyDesign | None = None):
        self.scene, self.subject, self.say = scene, subject, say
        self.design = design or design_of(scene)
        self.log_dir = log_dir
        wearer = sample_wearer(scene, subject)
        outcome = calibrate_wearer(scene, wearer)
        if not outcome.ok:
            raise ValueError(f'calibration of {wearer.name} refused: {outcome.error}')
        log_dir.mkdir(parents=True, exist_ok=True)
        # The file names the participant the controller guides (wearer `subNN`): one person's
        # calibration never guides another.
        named = dataclasses.replace(outcome.calibration, wearer=f'sub{subject + 1:02d}')
        self.calibration_file = named.save(log_dir / f'sub{subject + 1:02d}.yaml').resolve()
        cond = condition_of(first_condition)
        self.lab = sim_lab(cond.number, cond.layout or 'suit', log_dir / 'calibrations')
        self.gaze_rate_hz = min(scene.sim_rate_hz, MAX_SCENE_GAZE_RATE_HZ)
        graph_overrides(self.lab, scene, subject, cond.number, self.calibration_file, self.gaze_rate_hz)
        # A domain of 1-100 (process_graph.fresh_domain_id; under pytest-xdist, its worker's own):
        # above 101 the DDS ports fall in Linux's ephemeral range (32768-60999), where any UDP
        # socket can hold one, and discovery then fails by chance. Not the domain this shell's
        # ROS_DOMAIN_ID names: a session that met a running graph's target_selector would steer it.
        self.graph = Graph(fresh_folder(log_dir / 'graph'), domain_id=own_domain_id())
        self.op: Operator | None = None
        self.timing = Timing()
        self.condition = cond.number

    def start(self) -> None:
        start_nodes(self.graph, self.lab, FILES)
        os.environ.update(loopback_dds_env())
        self.op = Operator(self.graph.domain_id)
        try:
            # The session's first calls set parameters on these nodes: waited for here, on the
            # start's deadline, not raced by the first call's own (shorter) discovery wait.
            wait_until(lambda: self.op.has_gaze() and self.op.controller_condition is not None
                       and not self.op.parameter_services_missing(*PARAMETER_NODES),
                       STARTUP_S, what='gaze, the controller and the parameter services on the study graph')
        except AssertionError:
            raise StudyError(self.startup_failure()) from None
        self.op.trial_gate(False)     # the session's gate: vented until the first trial
        self.check_nodes()
        # The simulated operator arms the controller once: this call stands for the person at
        # the console (the session itself never calls enable).
        self.op.enable(True)

    def check_nodes(self) -> None:
        """StudyError when a node of the graph has ended on its own. Without plc_output no
        pressure reaches the simulated wearer: its trials would be recorded as guided."""
        ended = self.ended_nodes()
        if ended:
            raise StudyError(f'the study graph of participant {self.subject + 1:02d} lost {ended}: no trial is run '
                             f'without it (the same command resumes); logs in {self.graph.log_dir}')

    def ended_nodes(self) -> str:
        """The graph's nodes that ended on their own, with their exit statuses ('' none)."""
        return ', '.join(f'{node} (exit {code})' for node, code in sorted(self.graph.ended().items()))

    def startup_failure(self) -> str:
        """One line: what of the graph was not heard within STARTUP_S, which nodes ended, where
        their logs are."""
        missing = [what for what, heard in (('gaze from gaze_bridge', self.op.has_gaze()),
                                            ("pressure_controller's status on /diagnostics",
                                             self.op.controller_condition is not None)) if not heard]
        missing += [f'{n}/set_parameters_atomically' for n in self.op.parameter_services_missing(*PARAMETER_NODES)]
        ended = self.ended_nodes()
        return (f'the study graph of participant {self.subject + 1:02d} (ROS_DOMAIN_ID {self.graph.domain_id}) '
                f'did not start within {STARTUP_S:g} s: no {" and no ".join(missing)}; '
                f'{"nodes ended: " + ended if ended else "every node still running"}; logs in {self.graph.log_dir}')

    def switch(self, cond: int) -> None:
        """The condition for the next block, within the running graph: the `condition` parameter
        of pressure_controller (live: it vents and takes the new layout or speech at once) and of
        wearer_sim. A successful atomic call means the node has applied it, so the switch's time
        is the two calls' (OperatorError when a node refuses: nothing is restarted)."""
        t0 = time.monotonic()
        self.op.set_condition(cond, extra_nodes=('wearer_sim',))
        self.condition = cond
        self.timing.switch_s.append((cond, time.monotonic() - t0, 'parameter'))

    def close(self) -> None:
        try:
            if self.op is not None:
                try:
                    self.op.trial_gate(False)
                except Exception:   # noqa: BLE001 - closing anyway; the controller vents on shutdown
                    pass
                self.op.close()
        finally:
            self.graph.stop_all()


def design_of(scene, order: str = 'random', press_sources: tuple[str, ...] = ()) -> plan.StudyDesign:
    """The study design of a scene: its seed, conditions, repetitions and protocol (plan.py
    draws the condition orders and targets as the headless experiment does on that seed), and
    the press sources judged (plan.PRESS_SOURCES; (): all)."""
    proto = scene.protocol
    speed = proto.kind == 'speed'
    extra = dict(trial_s=proto.trial_s, acceptance_deg=proto.acceptance_deg, front_dwell_s=proto.dwell_s) if speed \
        else dict(timeout_s=proto.timeout_s)
    return plan.StudyDesign(proto.kind, seed=scene.seed, conditions=tuple(scene.conditions), order=order,
                            trials=scene.repetitions, horizontal_deg=proto.horizontal_deg,
                            vertical_deg=proto.vertical_deg, press_sources=tuple(press_sources), **extra)


def participant_order(design: plan.StudyDesign, subject: int) -> tuple[int, ...]:
    """The condition order of participant `subject` (random from the seed, or the Latin square's row)."""
    return plan.condition_order(design, subject)


__all__ = ['SimulatedParticipant', 'Timing', 'design_of', 'graph_overrides', 'participant_order']
