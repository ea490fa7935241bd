"""What the core costs per call: one control step, one gaze datagram, one calibration fit.
Each figure times single calls (time.perf_counter_ns around each) after a warm-up."""
from __future__ import annotations

import math
from pathlib import Path
import time
from typing import Callable

import numpy as np

from ..core.control_step import ControllerSetup, StepInput, guidance_step, safe_command
from ..core import Calibration, ChannelMap, fit_power_law
from ..core.feedback import PAPER_P_MAX
from ..core.gaze_wire import encode_datagram, parse_datagram
from ..core.geometry import ray_orientation
from ..paths import config_path
from .latency import percentiles_of


def time_calls(call: Callable[[int], object], n: int, warmup: int) -> np.ndarray:
    """Duration of call(k) for k = 0..n-1 [ns], after `warmup` untimed calls."""
    for k in range(warmup):
        call(k)
    now = time.perf_counter_ns
    out = np.empty(n)
    for k in range(n):
        t0 = now()
        call(k)
        out[k] = now() - t0
    return out


def controller_step_us(n: int) -> dict:
    """One Eq. 5 step as pressure_controller runs it (core/control_step.py guidance_step: all four
    directions, onto the channel map, then the P_MAX clip), condition 1, gaze wandering
    around a target 30 deg left and 10 deg up so the error grows and shrinks."""
    cal = Calibration.load(config_path('calibrations/sim-wearer.yaml'))
    # The node's defaults (core/controller_parameters.py): the paper's G and P_MAX.
    setup = ControllerSetup(calibration=cal, channel_map=ChannelMap.load(config_path('hardware/channel_map.yaml')))
    controller = setup.make_controller()
    origin = np.array([0.0, 0.0, 1.2])
    target = origin + 2.0 * np.array([math.cos(math.radians(30)), math.sin(math.radians(30)), 0.35])
    m = 256
    yaw = np.radians(20.0 * np.sin(np.arange(m) * 0.3))
    pitch = np.radians(5.0 * np.cos(np.arange(m) * 0.2))
    gazes = np.stack([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)], axis=1)

    def step(k):
        inp = StepInput(k / 90.0, origin, gazes[k % m], target, True, True, True, False, False, 1, k, k)
        channels, _, _ = guidance_step(setup, controller, inp)
        return safe_command(channels, setup.p_max_kpa)
    return percentiles_of(time_calls(step, n, max(n // 10, 100)) / 1e3)


def gaze_parse_us(n: int) -> dict:
    """One datagram as gaze_bridge handles it before publishing: parse_datagram (validation,
    Unity to REP 103) and the gaze ray's orientation."""
    m = 256
    rng = np.random.default_rng(0)
    datagrams = [encode_datagram(k, k / 90.0, rng.normal(0, 0.1, 3) + [0, 1.2, 0], rng.normal(0, 0.3, 3) + [0, 0, 1],
                                 [0.0, 1.2, 0.0], [0.0, 0.0, 0.0, 1.0], True) for k in range(m)]

    def handle(k):
        sample = parse_datagram(datagrams[k % m])
        return ray_orientation(sample.gaze_direction)
    return percentiles_of(time_calls(handle, n, max(n // 10, 100)) / 1e3)


def fit_ms(n: int) -> dict:
    """One calibration fit: 10 points (Algorithm 1's), the least-squares fit of P = a*theta^b + c."""
    cal = Calibration.load(config_path('calibrations/sim-wearer.yaml'))
    points = []
    rng = np.random.default_rng(1)
    for k in range(16):
        d = cal.directions[('left', 'right', 'down', 'up')[k % 4]]
        # The wearer's own points with the tracker's noise (kept increasing, as a fit needs).
        angles = np.asarray(d.angles, dtype=float) + rng.normal(0, 0.3, len(d.angles))
        points.append((np.maximum.accumulate(np.abs(angles)) + np.arange(len(angles)) * 1e-3,
                       np.asarray(d.pressures, dtype=float)))

    def fit(k):
        theta, pressure = points[k % len(points)]
        return fit_power_law(theta, pressure, PAPER_P_MAX)
    return percentiles_of(time_calls(fit, n, max(n // 20, 10)) / 1e6)


# --- what a hot-path callback does besides the control law ------------------------------------

def _gaze_handling():
    """(call, n_distinct): one datagram as gaze_bridge's _handle turns it into the gaze message,
    without DDS: parse_uplink, the ray's orientation, the PoseStamped filled field by field."""
    from geometry_msgs.msg import PoseStamped
    from rclpy.clock import Clock
    from ..core.clock_sync import parse_uplink
    m = 256
    rng = np.random.default_rng(0)
    datagrams = [encode_datagram(k, k / 90.0, rng.normal(0, 0.1, 3) + [0, 1.2, 0], rng.normal(0, 0.3, 3) + [0, 0, 1],
                                 [0.0, 1.2, 0.0], [0.0, 0.0, 0.0, 1.0], True) for k in range(m)]
    clock = Clock()

    def handle(k):
        now = clock.now()
        sample = parse_uplink(datagrams[k % m], 1024)
        q = ray_orientation(sample.gaze_direction)
        gaze = PoseStamped()
        gaze.header.stamp = now.to_msg()
        gaze.header.frame_id = 'immersive'
        p, o = gaze.pose.position, gaze.pose.orientation
        p.x, p.y, p.z = sample.gaze_origin.tolist()
        o.x, o.y, o.z, o.w = q.tolist()
        return gaze
    return handle


def _controller_handling():
    """One gaze sample as pressure_controller's on_gaze -> step -> publish handles it, without
    DDS: the gaze message read back into arrays, guidance_step, safe_command, and the reused
    Float64MultiArray filled as the node fills it."""
    from array import array
    from geometry_msgs.msg import PoseStamped
    from std_msgs.msg import Float64MultiArray
    from ..core.geometry import ray_direction
    cal = Calibration.load(config_path('calibrations/sim-wearer.yaml'))
    setup = ControllerSetup(calibration=cal, channel_map=ChannelMap.load(config_path('hardware/channel_map.yaml')))
    controller = setup.make_controller()
    target = np.array([1.7, 1.0, 1.9])
    m = 256
    msgs = []
    for k in range(m):
        msg = PoseStamped()
        msg.pose.position.z = 1.2
        o = msg.pose.orientation
        half_yaw = math.radians(10.0 * math.sin(0.3 * k)) / 2   # gaze wandering +-10 deg in yaw
        o.z, o.w = math.sin(half_yaw), math.cos(half_yaw)
        msgs.append(msg)
    command = Float64MultiArray()

    def step(k):
        msg = msgs[k % m]
        p, q = msg.pose.position, msg.pose.orientation
        direction = ray_direction([q.x, q.y, q.z, q.w])
        origin = np.array([p.x, p.y, p.z])
        np.all(np.isfinite(origin))
        inp = StepInput(k / 90.0, origin, direction, target, True, True, True, False, False, 1, k, k)
        channels, _, _ = guidance_step(setup, controller, inp)
        command.data = array('d', safe_command(channels, setup.p_max_kpa).tobytes())
        return command
    return step


def allocations(n: int) -> dict:
    """{'gaze_bridge': ..., 'pressure_controller': ...}: per call of each node's per-sample work
    (above), traced by tracemalloc: the peak of memory allocated during the call above what was
    allocated before it [bytes, p50 and max over the calls], and what stays allocated per call
    after n calls (blocks, bytes; 0 when nothing accumulates)."""
    import gc
    import tracemalloc
    out = {}
    for name, make in (('gaze_bridge', _gaze_handling), ('pressure_controller', _controller_handling)):
        call = make()
        for k in range(max(n // 10, 100)):
            call(k)
        gc.collect()
        tracemalloc.start()
        try:
            peaks = np.empty(n)
            before = tracemalloc.take_snapshot()
            for k in range(n):
                base = tracemalloc.get_traced_memory()[0]
                tracemalloc.reset_peak()
                call(k)
                peaks[k] = tracemalloc.get_traced_memory()[1] - base
            gc.collect()
            after = tracemalloc.take_snapshot()
        finally:
            tracemalloc.stop()
        stats = [s for s in after.compare_to(before, 'filename') if 'tracemalloc' not in s.traceback[0].filename]
        out[name] = {'peak_bytes_p50': float(np.median(peaks)), 'peak_bytes_max': float(peaks.max()),
                     'retained_blocks_per_call': sum(s.count_diff for s in stats) / n,
                     'retained_bytes_per_call': sum(s.size_diff for s in stats) / n}
    return out


def _quiet_stderr():
    """A context that sends fd 2 (rcutils' console output) to /dev/null."""
    import contextlib
    import os

    @contextlib.contextmanager
    def quiet():
        saved = os.dup(2)
        null = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(null, 2)
            yield
        finally:
            os.dup2(saved, 2)
            os.close(null)
            os.close(saved)
    return quiet()


def _bare_node():
    """A bare rclpy node in its own context and ROS domain (for its logger and a publisher)."""
    import rclpy
    from rclpy.context import Context
    from ..graph.process_graph import fresh_domain_id
    context = Context()
    rclpy.init(context=context, domain_id=fresh_domain_id())
    return rclpy.create_node('bench_components', context=context), context


def logging_us(n: int) -> dict:
    """An rclpy logger call on a bare node (its logger also publishes to /rosout): filtered out
    by the level (debug at the default info level), throttled out (the throttle_duration_sec=5
    the nodes use, after one emitted call), throttled by nodes/log_throttle.py before the logger
    is called ('throttled_first'), and emitted (info, console to /dev/null)."""
    node, context = _bare_node()
    try:
        log = node.get_logger()
        text = 'pressure_command above p_max (123 kPa): clamped to 60 kPa'
        out = {'filtered': percentiles_of(time_calls(lambda k: log.debug(text), n, n // 10) / 1e3)}
        with _quiet_stderr():
            out['throttled'] = percentiles_of(time_calls(lambda k: log.info(text, throttle_duration_sec=5.0),
                                                         n, n // 10) / 1e3)
        # What plc_output does for its per-command warnings instead (nodes/log_throttle.py).
        from ..nodes.log_throttle import LogThrottle
        throttle = LogThrottle(5.0)

        def throttled_first(k):
            if throttle.due('warning'):
                log.info(text)
        with _quiet_stderr():
            out['throttled_first'] = percentiles_of(time_calls(throttled_first, n, n // 10) / 1e3)
            m = max(n // 10, 50)
            out['emitted'] = percentiles_of(time_calls(lambda k: log.info(text), m, m // 10) / 1e3)
        return out
    finally:
        node.destroy_node()
        context.try_shutdown()


#: Key/values of each lab node's diagnostics (counted off its publish_diagnostics, idle values)
#: and how often it publishes by default [Hz]: gaze_bridge 12 counters, 16 drop reasons and 7
#: clock values (no headset_address); pressure_controller 9; plc_output 11 and 6 for its one PLC
#: link (two statuses, timed here as one of 17); bag_recorder the bag and 13 topic counts.
DIAGNOSTICS = {'gaze_bridge': (35, 1.0), 'pressure_controller': (9, 1.0), 'plc_output': (17, 1.0),
               'bag_recorder': (14, 2.0)}


def diagnostics_us(n: int) -> dict:
    """One /diagnostics publish as nodes/diagnostics.py builds it (a DiagnosticStatus of K
    key/values made strings, in a DiagnosticArray stamped on the node clock) on a bare node's
    publisher with nobody subscribed, for each lab node's K."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from ..nodes.diagnostics import publish_diagnostics, status
    node, context = _bare_node()
    try:
        pub = node.create_publisher(DiagnosticArray, '/diagnostics', 10)
        out = {}
        for name, (keys, rate_hz) in DIAGNOSTICS.items():
            values = {f'value_{i}': (i * 0.123 if i % 2 else i) for i in range(keys)}

            def publish(k):
                publish_diagnostics(node, pub, [status(node, 'job', DiagnosticStatus.OK, f'{k} Hz', values)])
            out[name] = {**percentiles_of(time_calls(publish, n, n // 10) / 1e3), 'keys': keys, 'rate_hz': rate_hz}
        return out
    finally:
        node.destroy_node()
        context.try_shutdown()


def modbus_write_us(n: int, profile: int = 2000) -> dict:
    """One command write as plc_output makes it (PlcClient.write_pressures: encode, the sequenced
    write-multiple-registers request, its answer) to the in-process mock PLC over loopback TCP,
    and a cProfile of `profile` more writes: the top entries by own time, and the shares of own
    time in pymodbus, in the socket calls and in the mock server's thread (not profiled: the
    client's wait for it shows as socket time)."""
    import cProfile
    import pstats
    from ..plc.mock_server import MockPlcServer
    from ..plc.modbus import PlcClient
    from ..plc.register_map import RegisterMap
    reg_map = RegisterMap.load(config_path('hardware/plc_register_map.yaml'))
    with MockPlcServer(reg_map, watchdog_s=60.0) as server:
        with PlcClient(reg_map, '127.0.0.1', server.port, timeout_s=1.0) as client:
            levels = [np.full(len(reg_map), 5.0 + (k % 7)) for k in range(16)]
            figures = percentiles_of(time_calls(lambda k: client.write_pressures(levels[k % 16]), n, n // 10) / 1e3)
            cpu0 = time.process_time_ns()
            for k in range(n):
                client.write_pressures(levels[k % 16])
            # Both ends run in this process: its CPU time is the client's and the mock's together.
            figures['cpu_us_per_write'] = (time.process_time_ns() - cpu0) / n / 1e3
            prof = cProfile.Profile()
            prof.enable()
            for k in range(profile):
                client.write_pressures(levels[k % 16])
            prof.disable()
    stats = pstats.Stats(prof).stats
    total = sum(v[2] for v in stats.values())
    rows = sorted(((v[2], f'{Path(f).name}:{line}({fn})', v[1]) for (f, line, fn), v in stats.items()), reverse=True)

    def share(pred):
        return sum(v[2] for k, v in stats.items() if pred(*k)) / total if total else None
    socket_calls = ('recv', 'send', 'sendall', 'select', 'poll', 'recv_into')
    return {**figures, 'registers': len(reg_map) + (reg_map.sequenced_block() is not None),
            'profiled_writes': profile,
            'pymodbus_share': share(lambda f, line, fn: 'pymodbus' in f),
            'socket_share': share(lambda f, line, fn: any(s in fn for s in socket_calls) and f == '~'),
            'package_share': share(lambda f, line, fn: 'fabric_guidance' in f),
            'top': [{'entry': name, 'own_us_per_write': own / profile * 1e6, 'calls_per_write': calls / profile}
                    for own, name, calls in rows[:8]]}
