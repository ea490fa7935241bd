"""What the core costs per call: one control step, one gaze datagram, one calibration fit.
Each figure times single calls (time.perf_counter_ns around each) after a warm-up."""
from __future__ import annotations

import math
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
    """One calibration fit: 10 points (Algorithm 1's), Levenberg-Marquardt on P = a*theta^b + c."""
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
