"""`make demo` / `fabric-guidance demo`: the whole simulated graph as separate processes (what
launch/sim.launch.py starts), a short guided session through the targets of
config/params/guidance.yaml, and a report of what happened, read off the graph's own topics and the
mock PLC's registers.

`fabric-guidance demo --scene FILE` (run_demo(scene=...)) runs a scene of the headless simulator
(config/scenes/*.yaml) through the same graph: the scene's wearer 0, calibrated by Algorithm 1
headless with the scene's effects (as the paper calibrates before the trials), guided under the
scene's first condition to four targets drawn from the scene's protocol ranges with its seed
(the targets wearer 0 meets first in the headless protocol); the scene's controller
settings go to pressure_controller, its acceptance rule to target_selector, regulator_lag to
the mock PLC and every wearer-side effect to wearer_sim (sim/scene_wearer.py SceneSide).
The plan (wearer, calibration, targets, where each effect runs) is sim/scene_plan.py's; this
module starts the graph, watches it (SessionWatch) and reports.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
import math
from pathlib import Path
import sys
import tempfile
import threading
import time

import numpy as np

from ..bag.recorder_status import hears, recorded_counts
from ..core import ChannelMap, condition as condition_of, ray_direction, target_direction
from ..core.geometry import DIRECTIONS
from ..core.feedback import PAPER_P_MAX
from ..core.task import angular_error_deg
from ..paths import config_path, node_parameters
from ..plc import PlcClient, PlcLinkError, RegisterMap
from ..graph.process_graph import FILES, NODES, Graph, Probe, sim_lab, start_nodes, start_task, wait_until
from ..sim.scene_plan import ScenePlan, plan_scene

#: Distractor spheres of the paper's speed task (Section VI).
PAPER_DUMMIES = 50
#: The report lists at most this many of the things the simulated headset showed.
VIEW_LINES = 40


@dataclass
class TargetRecord:
    name: str
    activated: float                       # time.monotonic()
    found: float | None = None
    final_error_deg: float | None = None
    peak_kpa: np.ndarray = field(default_factory=lambda: np.zeros(len(DIRECTIONS)))


class SessionWatch:
    """What the demo reads off the graph: targets activated and found, gaze, commands."""

    def __init__(self, probe: Probe, channel_map: ChannelMap, layout: str, sequence: list[str], say):
        from geometry_msgs.msg import PoseStamped
        from std_msgs.msg import Float64MultiArray, String
        from visualization_msgs.msg import MarkerArray

        from .. import interface
        from ..nodes import qos
        self.cmap, self.layout, self.say = channel_map, layout, say
        self.sequence = sequence
        self.lock = threading.Lock()
        self.records: list[TargetRecord] = []
        self.gaze = self.origin = None
        self.positions: dict[str, np.ndarray] = {}   # target name -> position (target_markers)
        self.finished = threading.Event()
        self.start = time.monotonic()
        self.max_command = 0.0
        self.speech: list[str] = []
        self.bridge: dict[str, str] = {}          # gaze_bridge's last diagnostics values
        self.recorder: dict[str, int] | None = None   # bag_recorder's messages per topic, latest
        self.max_written: list[float] = []        # mock_plc/max_written_kpa, latest
        self.view: list[tuple[float, str]] = []   # headset_view: what the simulated headset showed
        probe.subscribe(PoseStamped, interface.GAZE, qos.SENSOR_QOS, self.on_gaze)
        # Every change in turn: a target active and found while this process was late still counts.
        probe.subscribe(String, interface.ACTIVE_TARGET, qos.LATCHED_ALL_QOS, self.on_active)
        probe.subscribe(MarkerArray, interface.TARGET_MARKERS, qos.LATCHED_QOS, self.on_markers)
        probe.subscribe(String, interface.TARGET_FOUND, qos.EVENT_QOS, self.on_found)
        probe.subscribe(Float64MultiArray, interface.PRESSURE_COMMAND, qos.COMMAND_QOS, self.on_command)
        probe.subscribe(Float64MultiArray, interface.MEASURED_PRESSURE, qos.COMMAND_QOS)
        probe.subscribe(String, interface.SPEECH, qos.EVENT_QOS, lambda m: self.speech.append(m.data))
        probe.subscribe(String, interface.HEADSET_VIEW, qos.EVENT_QOS, self.on_view)
        from diagnostic_msgs.msg import DiagnosticArray

        from ..nodes.mock_plc import MAX_WRITTEN
        probe.subscribe(DiagnosticArray, interface.DIAGNOSTICS, 10, self.on_diagnostics)
        probe.subscribe(Float64MultiArray, MAX_WRITTEN, qos.COMMAND_QOS, self.on_max_written)

    def t(self) -> float:
        return time.monotonic() - self.start

    def on_view(self, msg) -> None:
        with self.lock:
            if len(self.view) < 10 * VIEW_LINES:
                self.view.append((self.t(), msg.data))

    def on_gaze(self, msg) -> None:
        q, p = msg.pose.orientation, msg.pose.position
        with self.lock:
            self.gaze, self.origin = ray_direction([q.x, q.y, q.z, q.w]), np.array([p.x, p.y, p.z])

    def on_markers(self, msg) -> None:
        with self.lock:
            for m in msg.markers:
                if m.text:
                    p = m.pose.position
                    self.positions[m.text] = np.array([p.x, p.y, p.z])

    def on_active(self, msg) -> None:
        with self.lock:
            if msg.data and (not self.records or self.records[-1].name != msg.data):
                self.records.append(TargetRecord(msg.data, time.monotonic()))
                self.say(f'[{self.t():5.1f} s] target {msg.data} active')

    def on_found(self, msg) -> None:
        with self.lock:
            rec = next((r for r in reversed(self.records) if r.name == msg.data), None)
            if rec is None or rec.found is not None:
                return
            rec.found = time.monotonic()
            # The found target's own position: `target` may already be the next one's.
            position = self.positions.get(msg.data)
            if self.gaze is not None and position is not None:
                rec.final_error_deg = angular_error_deg(self.gaze, target_direction(self.origin, position))
            self.say(f'[{self.t():5.1f} s] target {msg.data} found after {rec.found - rec.activated:.2f} s')
            if [r.name for r in self.records if r.found is not None] == self.sequence:
                self.finished.set()

    def on_diagnostics(self, msg) -> None:
        for st in msg.status:
            if st.name.startswith('gaze_bridge:'):
                with self.lock:
                    self.bridge = {kv.key: kv.value for kv in st.values}
        counts = recorded_counts(msg)
        if counts is not None:
            with self.lock:
                self.recorder = counts

    def recorder_hears(self, *topics: str) -> bool:
        """bag_recorder has written messages of every one of `topics` (from its /diagnostics)."""
        with self.lock:
            return hears(self.recorder, *topics)

    def on_max_written(self, msg) -> None:
        with self.lock:
            self.max_written = list(msg.data)

    def on_command(self, msg) -> None:
        data = np.asarray(msg.data, dtype=float)
        if data.shape != (len(self.cmap.channels),):
            return
        with self.lock:
            self.max_command = max(self.max_command, float(data.max(initial=0.0)))
            if self.records and self.records[-1].found is None:
                rec = self.records[-1]
                rec.peak_kpa = np.maximum(rec.peak_kpa, self.cmap.to_directions(data, self.layout))


def run_demo(condition: int | None = None, timeout_s: float = 45.0, out_dir: Path | None = None,
             stream=None, scene: str | Path | None = None, record_dir: str | Path | None = None) -> int:
    """Run the demo; 0 when every target was found, nothing exceeded the limit and the suit
    was vented at the end. condition: 1-3 (default 1); with `scene` (a scene file or the name
    of one of config/scenes/) 1-4, default the scene's first condition. With `record_dir`, the
    session is recorded by nodes/bag_recorder.py as a bag <record_dir>/session_<UTC time>_c<n>
    (rosbag2, MCAP) for `fabric-guidance replay`. `stream`: default, sys.stdout as it is now."""
    def say(line: str = '') -> None:
        print(line, file=sys.stdout if stream is None else stream, flush=True)

    if out_dir is not None:
        log_dir = Path(out_dir)
        log_dir.mkdir(parents=True, exist_ok=True)
        return _run_demo(condition, timeout_s, log_dir, say, scene, record_dir, kept=True)
    # A temporary folder goes when the demo ends, a failed one too: what a person needs of its
    # logs is printed first (the tail of each node that logged an error), and --out keeps them.
    with tempfile.TemporaryDirectory(prefix='fabric-guidance-demo-') as tmp:
        code = _run_demo(condition, timeout_s, Path(tmp), say, scene, record_dir, kept=False)
        if code != 0 and say_log_tails(Path(tmp), say):
            say('(the logs above were in a temporary folder, now removed; `--out DIR` keeps them)')
        return code


def say_log_tails(log_dir: Path, say, lines: int = 8) -> int:
    """The last lines of every node log in log_dir that reports an error or a traceback; how
    many logs were shown."""
    shown = 0
    for log in sorted(log_dir.glob('*.log')):
        text = log.read_text(errors='replace')
        if 'Traceback' in text or '[ERROR]' in text:
            say(f'--- {log.name} (last {lines} lines)')
            for line in text.splitlines()[-lines:]:
                say(f'    {line}')
            shown += 1
    return shown


def _run_demo(condition, timeout_s, log_dir: Path, say, scene, record_dir, kept: bool) -> int:
    plan = None
    if scene is not None:
        try:
            plan = plan_scene(scene, condition, log_dir, say)
        except ValueError as exc:     # SceneError, EffectError, a failed calibration
            say(f'fabric_guidance demo: {exc}')
            return 2
        condition = plan.condition
    elif condition is None:
        condition = 1
    cond = condition_of(condition)
    if cond.speech and plan is None:
        say('fabric_guidance demo: condition 4 (speech) needs --scene: the simple wearer does not hear')
        return 2
    layout = cond.layout or 'suit'
    cmap = ChannelMap.load(config_path('hardware/channel_map.yaml'))
    regmap = RegisterMap.load(config_path('hardware/plc_register_map.yaml'), expected_channels=cmap.channels)
    lab = sim_lab(cond.number, layout, log_dir / 'calibrations')
    overrides = lab.overrides
    graph = Graph(log_dir)
    say(f'fabric_guidance demo: condition {cond.number} ({cond.name}), the simulated graph as {len(NODES)} '
        f'processes on ROS_DOMAIN_ID {graph.domain_id} (localhost only); logs in {log_dir}'
        + ('' if kept else ' (removed at the end; --out DIR keeps them)'))
    sequence = task_sequence()
    if plan is not None:
        sc, ctl = plan.scene, plan.scene.controller
        overrides['mock_plc'].update(regulator_tau_s=plan.regulator_tau_s)
        # Every controller setting of the scene, by the parameter table's names (the scene's
        # section holds exactly the table's scene parameters).
        overrides['pressure_controller'].update(
            calibration_file=str(plan.calibration_file.resolve()), wearer=plan.wearer.name,
            **dataclasses.asdict(ctl),
            # Eq. 5 at the scene's control rate, as the headless engine runs it (G acts once per
            # step), not once per gaze sample.
            step_on_gaze=False)
        sequence = [name for name, *_ in plan.targets]
        overrides['target_selector'].update(
            target_names=sequence, target_positions=[float(x) for *_, pos in plan.targets for x in pos])
        if sc.protocol.kind == 'speed':
            overrides['target_selector'].update(acceptance_deg=sc.protocol.acceptance_deg,
                                                dwell_s=sc.protocol.dwell_s)
            overrides['headset_display'].update(dummies=PAPER_DUMMIES)   # the speed task's distractors
        overrides['wearer_sim'].update(scene_file=str(Path(sc.source).resolve()), wearer_index=plan.wearer.index,
                                       condition=cond.number, gaze_rate_hz=plan.gaze_rate_hz)
        say('targets (yaw, pitch from the front, deg): ' +
            ', '.join(f'{name} ({yaw:+.1f}, {pitch:+.1f})' for name, yaw, pitch, _ in plan.targets))
    probe = None
    code = 1
    bag = None
    if record_dir is not None:
        from datetime import datetime, timezone
        stamp = datetime.now(timezone.utc).strftime('%Y%m%d_%H%M%S')
        bag = Path(record_dir).expanduser().resolve() / f'session_{stamp}_c{cond.number}'
        n = 1
        while bag.exists():
            n += 1
            bag = bag.with_name(f'session_{stamp}_c{cond.number}_{n}')
    try:
        if bag is not None:    # first, so that it hears the session from its start
            graph.start('bag_recorder', (), output=str(bag))
        start_nodes(graph, lab, FILES)
        probe = Probe(graph.domain_id, 'demo_watch')
        watch = SessionWatch(probe, cmap, layout, sequence, say)
        deadline = time.monotonic() + timeout_s
        # Start the task, as an operator would, once the whole graph (the watch included) is up:
        # every target's time is then guidance time, not process start-up.
        from .. import interface
        wait_until(lambda: all(probe.messages.get(t) for t in (
            interface.PRESSURE_COMMAND, interface.GAZE, interface.MEASURED_PRESSURE, interface.ACTIVE_TARGET)),
            timeout_s, what='the graph to come up')
        if bag is not None:
            # Discovery is pairwise: the recorder and the controller both being on the graph does
            # not mean the recorder hears the controller yet. Its /diagnostics say what it has written.
            wait_until(lambda: watch.recorder_hears('controller_input', 'pressure_command', 'gaze'),
                       timeout_s, what='the recorder to hear the controller')
        start_task(probe, lambda: watch.records)
        while not watch.finished.is_set() and time.monotonic() < deadline:
            dead = [n for n, p in graph.processes.items() if p.poll() is not None]
            if dead:
                say(f'node(s) {dead} exited early; see their logs in {log_dir}')
                break
            watch.finished.wait(0.1)
        complete = watch.finished.is_set()
        if not complete:
            say(f'the session did not finish within {timeout_s:.0f} s')
        # Shut the lab side down first; the registers must read vented while the mock still runs.
        for node in ('wearer_sim', 'headset_display', 'pressure_controller', 'target_selector', 'gaze_bridge',
                     'plc_output'):
            graph.stop(node)
        if bag is not None:
            graph.stop('bag_recorder')
            say(f'session recorded: {bag}' if (bag / 'metadata.yaml').is_file()
                else f'the recording failed; see {log_dir}/bag_recorder.log')
        try:
            with PlcClient(regmap, '127.0.0.1', lab.plc_port, timeout_s=1.0) as client:
                after = client.read_commands_kpa()
        except PlcLinkError as exc:    # mock_plc itself ended early (killed, or a Ctrl-C it alone saw)
            say(f'the PLC registers could not be read back after shutdown: {exc}; see the logs in {log_dir}')
            return 1
        graph.stop('mock_plc')
        code = report(watch, cond, after, say, plan)
        if not complete:
            code = 1
    finally:
        if probe is not None:
            probe.close()
        graph.stop_all()
    return code


def task_sequence() -> list[str]:
    """The target order target_selector will run, from the same parameter file."""
    params = node_parameters('params/guidance.yaml', 'target_selector')
    return [n for n in params.get('sequence') or [] if n] or list(params['target_names'])


def report_headset(watch: SessionWatch, say) -> None:
    """What the wearer saw on the (simulated) headset, and the headset clock as the bridge
    estimated it."""
    with watch.lock:
        view, bridge = list(watch.view), dict(watch.bridge)
    say()
    if not view:
        say('headset display: nothing arrived at the simulated headset')
    else:
        say(f'headset display (what wearer_sim, as the HoloLens, showed; {len(view)} changes):')
        for t, line in view[:VIEW_LINES]:
            say(f'  [{t:5.1f} s] {line}')
        if len(view) > VIEW_LINES:
            say(f'  ... {len(view) - VIEW_LINES} more')
    if bridge.get('clock_state') == 'synchronised':
        say(f"headset clock: offset {float(bridge['clock_offset_s']) * 1e3:+.2f} ms within "
            f"{bridge['clock_bound_ms']} ms, drift {bridge['clock_drift_ppm']} ppm, least round trip "
            f"{bridge['clock_rtt_min_ms']} ms; gaze stamped at capture, one-way delay p50 "
            f"{bridge.get('delay_p50_ms', '?')} ms, p99 {bridge.get('delay_p99_ms', '?')} ms")
    elif bridge:
        say(f"headset clock: {bridge.get('clock_state', 'unknown')} (gaze stamped on receipt)")


def report(watch: SessionWatch, cond, registers_after: np.ndarray, say, plan: ScenePlan | None = None) -> int:
    say()
    say(f'{"target":<14} {"found":<5} {"time s":>6} {"error deg":>9}   peak kPa ' +
        ' '.join(f'{d:>5}' for d in DIRECTIONS))
    found = 0
    for r in watch.records:
        ok = r.found is not None
        found += ok
        elapsed = (r.found - r.activated) if ok else float('nan')
        err = r.final_error_deg if r.final_error_deg is not None else float('nan')
        say(f'{r.name:<14} {"yes" if ok else "no":<5} {elapsed:6.2f} {err:9.2f}            ' +
            ' '.join(f'{p:5.0f}' for p in r.peak_kpa))
    if watch.speech:
        say(f'speech (condition 4): {"; ".join(watch.speech)}')
    report_headset(watch, say)
    say()
    total = max(len(watch.sequence), len(watch.records))
    presented = f' ({len(watch.records)} presented)' if len(watch.records) < total else ''
    say(f'{found} of {total} targets found{presented}; highest command {watch.max_command:.1f} kPa '
        f'(limit {PAPER_P_MAX:.0f} kPa); after shutdown the PLC registers read {registers_after.max():.1f} kPa '
        'at most.')
    if plan is not None:
        with watch.lock:
            written, bridge = list(watch.max_written), dict(watch.bridge)
        if written:
            say(f'mock PLC: largest value ever written {max(written):.1f} kPa '
                f'(limit {PAPER_P_MAX:.0f} kPa).')
        if bridge:
            why = [name for name in ('datagram_loss', 'datagram_latency') if name in plan.scene.effect_names]
            because = (f' ({" and ".join(why)}; latency, like the engine, passes on only the newest of the samples '
                       'arriving within one step)') if why else ''
            say(f'gaze_bridge: {bridge.get("received", "?")} datagrams received, {bridge.get("lost", "?")} sequence '
                f'gaps{because}.')
        say(plan.effects_line())
        say('(real time over DDS, UDP and Modbus: the same scene, wearer, effect parameters and random '
            'streams as the headless engine, not a bit-identical run)')
    vented = bool(np.all(registers_after == 0.0))
    if not vented:
        say('WARNING: the suit was not vented at shutdown')
    return 0 if found == total and found > 0 and vented and math.isfinite(watch.max_command) else 1
