"""The gaze-error feedback law of the paper (Eq. 5) for one direction, and for all four.

For direction k with target angle theta_t (from the initial gaze g0 to the target) and current
angle theta (from g0 to the current gaze), the error is e = theta_t - theta and

    P <- P + G * (f(theta_t) - f(theta))   if theta_t > 0 and de/dt > 0  (error grows)
    P <- P                                 if theta_t > 0 and de/dt <= 0 (error shrinks)
    P  = 0                                 if theta_t <= 0

starting from P = f(theta_t). The increment is applied once per control step (the paper
states no rate; the step rate is a parameter of the node). The result is clamped to
[0, P_MAX], and so is the state: the paper's suit "did not change" above 375 kPa, so no
hidden wind-up builds beyond the limit.

The sign of de/dt is all the law needs. It is taken from successive samples with dt > 0
only: a repeated timestamp (dt = 0) holds; a clock that jumps back (a bag replay that loops)
restarts the derivative from that sample and holds, so neither can produce a step.

Mode "adjusted" is conditions 1 and 3; "fixed" (condition 2) keeps P = f(theta_t).

"The error grows" (docs/guidance.md): estimator FILTERED (the default) low-passes the raw
de/dt with a first-order filter of time constant rate_filter_tau_s and counts growth only when
the filtered rate exceeds rate_threshold_dps > 0, a threshold derived from the tracker's noise
(noise_rate_threshold): tracker noise alone rarely crosses it, and no float rounding can
(a rate of 1e-13 deg/s is not above 14 deg/s). Estimator SIGN is the paper's literal test:
the raw rate of successive samples above rate_deadband_dps (0: any growth, however small).

Frame (docs/guidance.md): with frame REST (the default) both angles of Eq. 5 are measured from
the rest gaze that the wearer's calibration recorded (Algorithm 1's g0), the origin f_k was
fitted from; frame TARGET takes g0 from the gaze when guidance to a target begins (the
earlier behaviour, kept as an explicit option).

Beyond the paper (its Discussion: "the proposed system cannot be directly applied to the
directional guidance of moving targets"): with follow_target, a change of theta_t while guiding
shifts the pressure by f(theta_t_new) - f(theta_t_old), so the feed-forward part follows the
target and what Eq. 5 added on top is kept. Without it the law is the paper's: theta_t only
sets the starting pressure.
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Sequence

import numpy as np

from .geometry import DIRECTIONS, angles_between
from .power_law import PowerLaw

ADJUSTED = 'adjusted'
FIXED = 'fixed'
MODES = (ADJUSTED, FIXED)

#: "The error grows" estimators: the filtered rate against a noise threshold, or the paper's sign.
FILTERED = 'filtered'
SIGN = 'sign'
ESTIMATORS = (FILTERED, SIGN)
#: Origins of Eq. 5's angles: the calibration's rest gaze, or the gaze when a target begins.
REST = 'rest'
TARGET = 'target'
FRAMES = (REST, TARGET)
#: The front of the immersive frame (REP 103: x forward): the rest gaze of a calibration
#: that recorded none.
FRONT = (1.0, 0.0, 0.0)

#: The paper's adjustment gain G (conditions 1 and 3).
PAPER_GAIN = 0.05
#: The paper's pressure limit, kPa.
PAPER_P_MAX = 375.0

#: HoloLens 2 eye-tracking accuracy, deg: "approximately within 1.5 degrees in visual angle
#: around the actual target" (Microsoft Learn, "Eye tracking on HoloLens 2", accuracy).
#: Taken as the per-sample noise sd: pessimistic (an accuracy figure includes bias).
TRACKER_NOISE_DEG = 1.5
#: The HoloLens 2 eye-tracking rate, Hz (Microsoft Learn: 30 FPS), the rate Eq. 5 steps at.
TRACKER_RATE_HZ = 30.0
#: Time constant of the rate filter, s: short against a guided turn (the paper's wearers find
#: targets in seconds) and long enough to average about nine samples at 30 Hz.
RATE_FILTER_TAU_S = 0.3
#: Standard deviations of filtered tracker noise the threshold sits above.
RATE_THRESHOLD_SIGMAS = 3.0


def noise_rate_threshold(noise_deg: float = TRACKER_NOISE_DEG, rate_hz: float = TRACKER_RATE_HZ,
                         tau_s: float = RATE_FILTER_TAU_S,
                         sigmas: float = RATE_THRESHOLD_SIGMAS) -> float:
    """The filtered-rate threshold, deg/s, that tracker noise alone crosses rarely.

    For independent angle noise of sd s sampled every dt, the raw rate (e_k - e_k-1)/dt fed to
    the first-order filter r += a (raw - r), a = 1 - exp(-dt/tau), has the stationary sd
    a * s * sqrt(2 / (2 - a)) / dt (the sum of a geometric series of differences). The
    threshold is `sigmas` of those: 14.6 deg/s for the defaults (1.5 deg, 30 Hz, 0.3 s, 3).
    """
    dt = 1.0 / rate_hz
    a = 1.0 - math.exp(-dt / tau_s)
    return sigmas * a * noise_deg * math.sqrt(2.0 / (2.0 - a)) / dt


#: The default threshold of the FILTERED estimator, deg/s.
RATE_THRESHOLD_DPS = noise_rate_threshold()

#: No-progress timeout, s: guidance whose (filtered) gaze-to-target error has not fallen by
#: STALL_PROGRESS_DEG for this long vents. The paper's wearers found targets in seconds (speed
#: experiment: several targets per 40 s trial; the micromanipulation objects here in 1.3-3.6 s),
#: so 10 s without progress is a wearer who cannot or will not follow, not a slow turn.
STALL_TIMEOUT_S = 10.0
#: Progress that restarts the timeout, deg: above the tracker's 1.5 deg so noise cannot fake it.
STALL_PROGRESS_DEG = 2.0
#: Within this of the target (the paper's 5 deg acceptance) the wearer has arrived: no stall.
STALL_NEAR_DEG = 5.0


class StallWatch:
    """Says when guidance has made no progress toward its target for timeout_s seconds.

    Progress is a fall of the error angle (gaze to target, low-passed with RATE_FILTER_TAU_S so
    that one noisy sample is not progress) by progress_deg below the best so far; being within
    near_deg of the target counts as progress. A clock that jumps back restarts the watch. The
    live node feeds it the steady clock (a bound on a safety path must not wait on /clock), and
    an interruption (stale gaze, a blink) does not restart it: the time without progress counts
    across the gap.
    """

    def __init__(self, timeout_s: float | None = STALL_TIMEOUT_S,
                 progress_deg: float = STALL_PROGRESS_DEG,
                 near_deg: float = STALL_NEAR_DEG, tau_s: float = RATE_FILTER_TAU_S):
        if timeout_s is not None and not (math.isfinite(timeout_s) and timeout_s > 0):
            raise ValueError(f'stall timeout must be finite and > 0 s (or None: never), '
                             f'got {timeout_s}')
        for name, v in (('stall progress', progress_deg), ('stall near', near_deg)):
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f'{name} must be finite and >= 0 deg, got {v}')
        self.timeout_s, self.progress_deg = timeout_s, progress_deg
        self.near_deg, self.tau_s = near_deg, tau_s
        self.reset()

    def reset(self) -> None:
        self.error: float | None = None    # filtered error, deg
        self.best = math.inf
        self.since: float | None = None    # time of the last progress, s
        self.last_t: float | None = None

    def update(self, error_deg: float, t: float) -> bool:
        """Feed one sample; True when no progress came for timeout_s."""
        if self.timeout_s is None:
            return False
        if self.last_t is None or t < self.last_t:
            self.reset()
            self.error, self.best, self.since, self.last_t = error_deg, error_deg, t, t
            return False
        dt = t - self.last_t
        self.last_t = t
        self.error += (1.0 - math.exp(-dt / self.tau_s)) * (error_deg - self.error)
        if self.error <= self.near_deg or self.error <= self.best - self.progress_deg:
            self.best, self.since = min(self.best, self.error), t
            return False
        return t - self.since > self.timeout_s


def _finite(value: float, name: str) -> float:
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f'{name} is not finite: {value}')
    return value


@dataclass
class FeedbackLaw:
    """Eq. 5 for one direction k. Pressure in kPa, angles in degrees, time in seconds."""

    law: PowerLaw
    p_max: float = PAPER_P_MAX
    gain: float = PAPER_GAIN
    mode: str = ADJUSTED
    #: SIGN: the raw de/dt must exceed this (deg/s) to count as "the error grows"; 0 is the
    #: paper's literal law.
    rate_deadband_dps: float = 0.0
    #: Shift the pressure with f(theta_t) when the target moves (beyond the paper).
    follow_target: bool = False
    #: How "the error grows" is decided: FILTERED (default) or the paper's literal SIGN.
    estimator: str = FILTERED
    #: FILTERED: time constant of the rate filter, s.
    rate_filter_tau_s: float = RATE_FILTER_TAU_S
    #: FILTERED: the filtered de/dt must exceed this (deg/s, > 0).
    rate_threshold_dps: float = RATE_THRESHOLD_DPS

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f'mode must be one of {MODES}, got {self.mode!r}')
        if not (math.isfinite(self.p_max) and self.p_max > 0):
            raise ValueError(f'p_max must be finite and > 0 kPa, got {self.p_max}')
        if not (math.isfinite(self.gain) and self.gain >= 0):
            raise ValueError(f'gain must be finite and >= 0, got {self.gain}')
        if not (math.isfinite(self.rate_deadband_dps) and self.rate_deadband_dps >= 0):
            raise ValueError(f'rate_deadband_dps must be finite and >= 0 deg/s, got {self.rate_deadband_dps}')
        if self.estimator not in ESTIMATORS:
            raise ValueError(f'estimator must be one of {ESTIMATORS}, got {self.estimator!r}')
        if not (math.isfinite(self.rate_filter_tau_s) and self.rate_filter_tau_s > 0):
            raise ValueError(f'rate_filter_tau_s must be finite and > 0 s, '
                             f'got {self.rate_filter_tau_s}')
        # > 0 strictly: a zero threshold would let a rounding-sized rate count as growth.
        if not (math.isfinite(self.rate_threshold_dps) and self.rate_threshold_dps > 0):
            raise ValueError(f'rate_threshold_dps must be finite and > 0 deg/s, '
                             f'got {self.rate_threshold_dps}')
        self.reset()

    def reset(self) -> None:
        """Vent and forget: the next step starts again from f(theta_t)."""
        self.pressure = 0.0
        self.active = False
        self._last_error: float | None = None
        self._last_time: float | None = None
        self._last_target: float | None = None
        self.rate = 0.0    # the filtered de/dt, deg/s (FILTERED)

    def _clamp(self, p: float) -> float:
        # An increment can overflow to +inf with an absurd gain: that is "above P_MAX", not NaN.
        if math.isnan(p):
            return 0.0
        return min(max(p, 0.0), self.p_max)

    def step(self, theta_target: float, theta: float, t: float) -> float:
        """Advance the law by one sample; return the commanded pressure in [0, p_max].

        Raises ValueError for a non-finite input and leaves the state as it was.
        """
        theta_target = _finite(theta_target, 'target angle')
        theta = _finite(theta, 'gaze angle')
        t = _finite(t, 'time')
        if theta_target <= 0.0:
            self.reset()
            return 0.0
        error = theta_target - theta
        if not self.active:
            self.active = True
            self.pressure = self._clamp(self.law.pressure(theta_target))
            self._last_error, self._last_time, self._last_target = error, t, theta_target
            return self.pressure
        if self.follow_target and theta_target != self._last_target:
            shift = self.law.pressure(theta_target) - self.law.pressure(self._last_target)
            self.pressure = self._clamp(self.pressure + shift)
        self._last_target = theta_target
        if self._last_time is None or t < self._last_time:
            # Clock jumped back: restart the derivative here rather than read a jump.
            self._last_error, self._last_time = error, t
            self.rate = 0.0
            return self.pressure
        dt = t - self._last_time
        if dt == 0.0:
            return self.pressure
        raw = (error - self._last_error) / dt
        self._last_error, self._last_time = error, t
        if self.estimator == SIGN:
            grows = raw > self.rate_deadband_dps
        else:
            self.rate += (1.0 - math.exp(-dt / self.rate_filter_tau_s)) * (raw - self.rate)
            grows = self.rate > self.rate_threshold_dps
        if self.mode == ADJUSTED and grows:
            increment = self.gain * (self.law.pressure(theta_target) - self.law.pressure(theta))
            self.pressure = self._clamp(self.pressure + increment)
        return self.pressure


def step_directions(directions: Sequence[FeedbackLaw], h_target: float, v_target: float, h: float,
                    v: float, t: float) -> tuple[float, float, float, float]:
    """Eq. 5 in each direction (left, right, down, up) from the signed horizontal and vertical
    angles of the target and of the gaze (geometry.split_directions: h, -h, -v, v). Every
    direction is stepped, also one whose theta_t <= 0: its step() resets it and commands 0
    (Eq. 5's third case), so when theta_t turns positive again it starts afresh from
    f(theta_t). The one place the node's controller and the simulator split Eq. 5."""
    left, right, down, up = directions
    return (left.step(h_target, h, t), right.step(-h_target, -h, t), down.step(-v_target, -v, t),
            up.step(v_target, v, t))


class GuidanceController:
    """Eq. 5 in all four directions for one target, from gaze directions (REP 103).

    Target and current angles are measured from the origin g0 that f_k was fitted from: with
    frame REST (default) the calibration's rest gaze `rest_gaze` (Algorithm 1's g0), with frame
    TARGET the gaze at begin() (the per-target origin, an explicit option).
    """

    def __init__(self, laws: Sequence[PowerLaw], p_max: float = PAPER_P_MAX, gain: float | Sequence[float] = PAPER_GAIN,
                 mode: str = ADJUSTED, rate_deadband_dps: float = 0.0, follow_target: bool = False,
                 estimator: str = FILTERED, rate_filter_tau_s: float = RATE_FILTER_TAU_S,
                 rate_threshold_dps: float = RATE_THRESHOLD_DPS, frame: str = REST,
                 rest_gaze: Sequence[float] = FRONT, stall_timeout_s: float | None = None):
        if len(laws) != len(DIRECTIONS):
            raise ValueError(f'need one power law per direction {DIRECTIONS}, got {len(laws)}')
        gains = [gain] * len(DIRECTIONS) if np.ndim(gain) == 0 else list(gain)
        if len(gains) != len(DIRECTIONS):
            raise ValueError(f'need one gain per direction {DIRECTIONS}, got {len(gains)}')
        if frame not in FRAMES:
            raise ValueError(f'frame must be one of {FRAMES}, got {frame!r}')
        angles_between(rest_gaze, rest_gaze)  # validates the vector
        self.directions = [FeedbackLaw(law, p_max, g, mode, rate_deadband_dps, follow_target,
                                       estimator, rate_filter_tau_s, rate_threshold_dps)
                           for law, g in zip(laws, gains)]
        self.p_max = p_max
        self.frame = frame
        self.rest_gaze = np.asarray(rest_gaze, dtype=float)
        self.initial_gaze: np.ndarray | None = None
        self.stall = StallWatch(stall_timeout_s)
        #: Why guidance stopped for lack of progress ('' while it has not): it stays vented
        #: until vent() (a new target, a service call); an interruption keeps it (vent(False)).
        self.stalled = ''

    def begin(self, gaze: Sequence[float], restart_stall: bool = True) -> None:
        """Start guidance toward a new target with the wearer's gaze now (g0 in frame TARGET).
        restart_stall False: resuming after an interruption, the stall watch keeps counting."""
        angles_between(gaze, gaze)  # validates the vector
        self.initial_gaze = self.rest_gaze if self.frame == REST else np.asarray(gaze, dtype=float)
        if restart_stall:
            self.stall.reset()
        for d in self.directions:
            d.reset()

    def vent(self, forget_stall: bool = True) -> np.ndarray:
        """Zero every direction; the next update starts from f(theta_t) again. forget_stall
        False (the gaze went stale, guidance disabled or deactivated for a moment) keeps a stall
        latched and the stall watch counting: a wearer who blinks every second is still one who
        makes no progress."""
        self.initial_gaze = None
        if forget_stall:
            self.stalled = ''
            self.stall.reset()
        for d in self.directions:
            d.reset()
        return np.zeros(len(DIRECTIONS))

    @property
    def pressures(self) -> np.ndarray:
        return np.array([d.pressure for d in self.directions])

    def update(self, gaze: Sequence[float], target: Sequence[float], t: float,
               clock_s: float | None = None) -> np.ndarray:
        """Pressures (left, right, down, up) in kPa for the current gaze and target directions.
        t: Eq. 5's time; clock_s: the stall watch's (the node's steady clock), t when None.

        Raises ValueError (a GeometryError for degenerate vectors) for invalid input, with
        the state unchanged; the caller vents.
        """
        if self.stalled:
            angles_between(gaze, target)   # still refuses invalid input
            return np.zeros(len(DIRECTIONS))
        if self.initial_gaze is None:
            self.begin(gaze, restart_stall=False)   # vent() restarted it if it had to
        at = angles_between(self.initial_gaze, target)
        a = angles_between(self.initial_gaze, gaze)
        _finite(t, 'time')
        out = np.array(step_directions(self.directions, at.horizontal, at.vertical, a.horizontal,
                                       a.vertical, t))
        if self.stall.timeout_s is not None:
            # The full gaze-to-target angle (atan2 form), in scalar math: this runs every step.
            ax, ay, az = (float(c) for c in gaze)
            bx, by, bz = (float(c) for c in target)
            cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
            error = math.degrees(math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz),
                                            ax * bx + ay * by + az * bz))
            if self.stall.update(error, t if clock_s is None else _finite(clock_s, 'clock')):
                self.stalled = (f'no progress toward the target for {self.stall.timeout_s:g} s '
                                f'(error {self.stall.error:.1f} deg, best '
                                f'{self.stall.best:.1f} deg): vented until the next target '
                                'or a service call')
                self.vent(forget_stall=False)
                return np.zeros(len(DIRECTIONS))
        return out
