"""The headset's clock against the bridge's: the echo exchange of docs/headset_wire_format.md.

gaze_bridge sends `clock_ping` (t1, its clock) on the downlink; the headset answers
`clock_echo` with t1 copied and t2 / t3 (its clock at receipt and at sending); the bridge
notes t4 on arrival. One exchange gives

    rtt   = (t4 - t1) - (t3 - t2)
    theta = ((t2 - t1) + (t3 - t4)) / 2          (headset minus bridge)

With d_up, d_down >= 0 the path delays, theta = offset + (d_up - d_down) / 2, so the true
offset lies within theta +- rtt / 2 whatever the two delays are: each exchange is an interval,
not only a point. ClockEstimator keeps the exchanges of the last window, keeps in each of
SUB_WINDOWS equal slices the exchange of least round trip (Wi-Fi jitter only ever adds delay),
fits offset = theta0 + drift * t through them, and bounds the error at a time t by the
tightest selected interval carried to t with the fitted drift, widened by how far that drift
can be off: the first and last selected intervals allow the true (constant) drift only within
their own slope +- (rtt_first + rtt_last) / 2 / span.

Numpy only: gaze_bridge imports this and must stay light.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
import json
import math

import numpy as np

from .gaze_wire import (CONFIRM_KIND, Confirm, GazeSample, WireFormatError, _integer, _number, confirm_from_object,
                        decode_object, message_kind, sample_from_object)

#: Downlink and uplink datagrams other than gaze are at most this long [bytes].
MAX_DATAGRAM_BYTES = 1200
PING_KIND = 'clock_ping'
ECHO_KIND = 'clock_echo'
PING_SEQ_MODULUS = 2 ** 32
#: Slices of the window, each contributing its exchange of least round trip to the fit.
SUB_WINDOWS = 8
#: The drift assumed possible while the exchanges do not yet bound it (one selected exchange,
#: or all at one time) [ppm]: quartz clocks stay well inside it.
ASSUMED_MAX_DRIFT_PPM = 500.0
#: A computed round trip down to this far below 0 counts as 0 [s].
NEGATIVE_RTT_TOLERANCE_S = 1e-3
#: Exchanges kept at most, whatever the ping rate (memory stays bounded).
MAX_EXCHANGES = 4096
#: A capture time is believed only while the error the estimate may have gathered since its
#: newest exchange (carried with a drift known within drift_error) is within this [s]. The
#: controller ages gaze from its stamp (gaze_timeout_s, 0.3 s by default): an estimate from its
#: first exchanges (the drift barely seen) carried on after the headset stopped answering pings
#: made fresh gaze stale within seconds. The path's own share of the bound (half the least round
#: trip) is not counted: a slow path is stamped as it was.
MAX_CARRIED_S = 0.1
#: A capture this far beyond the bound after its receipt: the headset's clock jumped ahead [s].
FUTURE_TOLERANCE_S = 0.05


@dataclass(frozen=True)
class ClockEcho:
    """One clock_echo: t1 the bridge's clock, t2 and t3 the headset's (s)."""

    ping_seq: int
    t1: float
    t2: float
    t3: float


def encode_ping(ping_seq: int, t1: float) -> bytes:
    """The clock_ping datagram the bridge sends."""
    if not 0 <= ping_seq < PING_SEQ_MODULUS or not math.isfinite(t1):
        raise ValueError(f'clock_ping needs ping_seq in 0..2**32-1 and a finite t1, got {ping_seq}, {t1}')
    return json.dumps({'version': 1, 'kind': PING_KIND, 'ping_seq': ping_seq, 't1': float(t1)},
                      separators=(',', ':')).encode()


def parse_ping(data: bytes) -> tuple[int, float]:
    """(ping_seq, t1) of a clock_ping; WireFormatError otherwise."""
    msg = decode_object(data, MAX_DATAGRAM_BYTES)
    kind = message_kind(msg)
    if kind != PING_KIND:
        raise WireFormatError('kind', f'kind {kind[:40]!r} is not {PING_KIND}')
    if 't1' not in msg:
        _missing('t1')
    return _ping_seq(msg), _number(msg['t1'], 't1')


def answer_ping(data: bytes, t2: float, t3: float) -> bytes | None:
    """The headset's side: the clock_echo for a valid clock_ping, None for anything else."""
    try:
        ping_seq, t1 = parse_ping(data)
    except WireFormatError:
        return None
    return json.dumps({'version': 1, 'kind': ECHO_KIND, 'ping_seq': ping_seq, 't1': t1,
                       't2': float(t2), 't3': float(t3)}, separators=(',', ':')).encode()


def echo_from_object(msg: dict) -> ClockEcho:
    """The ClockEcho of a decoded uplink object whose kind is clock_echo."""
    values = []
    for name in ('t1', 't2', 't3'):
        if name not in msg:
            _missing(name)
        values.append(_number(msg[name], name))
    return ClockEcho(_ping_seq(msg), *values)


def parse_uplink(data: bytes, max_size: int) -> GazeSample | ClockEcho | Confirm:
    """Any uplink datagram: a gaze sample (no kind, or kind gaze), a clock_echo or a confirm press.

    Raises WireFormatError and nothing else; an unknown kind is reason 'kind'. Every uplink
    datagram counts against max_size (gaze_bridge's max_datagram_bytes; an echo is ~120 bytes),
    checked first as for a gaze sample.
    """
    msg = decode_object(data, max_size)
    kind = message_kind(msg, 'gaze')
    if kind == ECHO_KIND:
        return echo_from_object(msg)
    if kind == CONFIRM_KIND:
        return confirm_from_object(msg)
    return sample_from_object(msg)


def _ping_seq(msg: dict) -> int:
    seq = _integer(msg, 'ping_seq', ('range', 'ping_seq is too long'))
    if not 0 <= seq < PING_SEQ_MODULUS:
        raise WireFormatError('range', f'ping_seq {seq} is outside 0..2**32-1')
    return seq


def _missing(name: str):
    raise WireFormatError('missing_field', f'field {name!r} is missing')


@dataclass(frozen=True)
class ClockEstimate:
    """The headset clock as seen from the bridge's: headset = bridge + offset_at(t)."""

    theta0: float       # offset at t_ref [s]
    drift: float        # d offset / d t [s/s]
    t_ref: float        # bridge clock of the fit's reference [s]
    rtt_min: float      # least round trip in the window [s]
    exchanges: int      # exchanges in the window
    anchors: tuple      # (t, theta, rtt) of the exchanges the fit went through
    drift_error: float  # how far drift can be from the true drift [s/s]

    def offset_at(self, t: float) -> float:
        return self.theta0 + self.drift * (t - self.t_ref)

    def bound_at(self, t: float) -> float:
        """Error bound of offset_at(t) [s], given path delays >= 0 and a constant drift: the
        tightest anchor interval carried to t with the fitted drift and its error bound."""
        best = math.inf
        for ta, theta, rtt in self.anchors:
            carried = theta + self.drift * (t - ta)
            best = min(best, abs(self.offset_at(t) - carried) + rtt / 2 + self.drift_error * abs(t - ta))
        return best

    def carried_at(self, t: float) -> float:
        """How far the offset may have drifted from the newest exchange by t [s], the drift
        known within drift_error (the bound's growth while no exchange comes)."""
        return self.drift_error * max(0.0, t - max(a[0] for a in self.anchors))

    def to_bridge(self, headset_t: float, now: float) -> float:
        """The bridge-clock time of a headset-clock time (the offset taken at `now`)."""
        return headset_t - self.offset_at(now)


class ClockEstimator:
    """Offset and drift of the headset's clock from clock_echo exchanges.

    add() takes an echo and t4 (bridge clock at arrival) and returns None when it was used or
    the reason it was not ('invalid', 'rtt', 'restart' when the headset's clock ran backwards:
    the window is cleared and this exchange starts the new one). estimate() is None until
    min_exchanges are in the window.
    """

    def __init__(self, window_s: float = 30.0, max_rtt_s: float = 0.5, min_exchanges: int = 3):
        if not (window_s > 0 and max_rtt_s > 0 and min_exchanges >= 1):
            raise ValueError('window_s and max_rtt_s must be > 0 and min_exchanges >= 1')
        self.window_s = float(window_s)
        self.max_rtt_s = float(max_rtt_s)
        self.min_exchanges = int(min_exchanges)
        self._exchanges: deque = deque(maxlen=MAX_EXCHANGES)  # (t_mid, theta, rtt, t2)
        self._estimate: ClockEstimate | None = None
        self.restarts = 0
        self.rejected = {'invalid': 0, 'rtt': 0}

    def reset(self) -> None:
        """Forget every exchange (the headset app restarted)."""
        self._exchanges.clear()
        self._estimate = None

    def restart(self) -> None:
        """A restart seen elsewhere (the gaze seq or stamp): counted, then reset."""
        self.restarts += 1
        self.reset()

    def add(self, echo: ClockEcho, t4: float) -> str | None:
        t1, t2, t3 = echo.t1, echo.t2, echo.t3
        if not all(math.isfinite(v) for v in (t1, t2, t3, t4)) or t4 < t1 or t3 < t2:
            self.rejected['invalid'] += 1
            return 'invalid'
        # A round trip a little below 0 is drift and rounding over a near-zero path; more is not.
        rtt = max((t4 - t1) - (t3 - t2), 0.0) if (t4 - t1) - (t3 - t2) > -NEGATIVE_RTT_TOLERANCE_S else -1.0
        if rtt < 0.0 or rtt > self.max_rtt_s:
            self.rejected['rtt'] += 1
            return 'rtt'
        outcome = None
        if self._exchanges and t2 < self._exchanges[-1][3] - self.max_rtt_s:
            self.restart()  # the headset's clock ran backwards: a new app, a new clock
            outcome = 'restart'
        theta = ((t2 - t1) + (t3 - t4)) / 2.0
        t_mid = (t1 + t4) / 2.0
        self._exchanges.append((t_mid, theta, rtt, t2))
        while self._exchanges and self._exchanges[0][0] < t_mid - self.window_s:
            self._exchanges.popleft()
        self._estimate = self._fit()
        return outcome

    def estimate(self) -> ClockEstimate | None:
        return self._estimate

    @property
    def exchanges(self) -> int:
        return len(self._exchanges)

    def _fit(self) -> ClockEstimate | None:
        n = len(self._exchanges)
        if n < self.min_exchanges:
            return None
        data = np.array(self._exchanges)
        t, theta, rtt = data[:, 0], data[:, 1], data[:, 2]
        t0, span = t[0], t[-1] - t[0]
        # The least round trip of each slice of the window: the truest offsets it holds.
        slices = np.minimum((SUB_WINDOWS * (t - t0) / span).astype(int), SUB_WINDOWS - 1) if span > 0 \
            else np.zeros(n, dtype=int)
        picks = [int(np.flatnonzero(slices == k)[np.argmin(rtt[slices == k])])
                 for k in np.unique(slices)]
        tp, thp, rp = t[picks], theta[picks], rtt[picks]
        t_ref = float(t[-1])
        reach = tp[-1] - tp[0]
        if len(picks) >= 3 and reach > 0:
            # Weighted by the inverse interval width: a tight exchange counts more.
            drift, theta0 = np.polyfit(tp - t_ref, thp, 1, w=1.0 / np.maximum(rp, 1e-6))
            # The true drift lies within the slope between the first and last anchors, give or
            # take their half round trips over the reach.
            slope = (thp[-1] - thp[0]) / reach
            drift_error = abs(drift - slope) + (rp[0] + rp[-1]) / 2 / reach
        else:
            # Too few slices to see a drift: the tightest exchange, no drift, the assumed one.
            best = int(np.argmin(rp))
            tp, thp, rp = tp[best:best + 1], thp[best:best + 1], rp[best:best + 1]
            drift, theta0, t_ref = 0.0, float(thp[0]), float(tp[0])
            drift_error = ASSUMED_MAX_DRIFT_PPM * 1e-6
        anchors = tuple((float(a), float(b), float(c)) for a, b, c in zip(tp, thp, rp))
        if picks[-1] != n - 1 and len(anchors) > 1:
            # The newest exchange bounds the offset now with the least drift carried.
            anchors += ((float(t[-1]), float(theta[-1]), float(rtt[-1])),)
        return ClockEstimate(float(theta0), float(drift), t_ref, float(rtt.min()), n, anchors,
                             float(drift_error))


def capture_delay(estimate: ClockEstimate, capture: float, received: float,
                  max_delay_s: float) -> tuple[float | None, str]:
    """(the one-way delay from a capture, on the headset's clock, to its receipt at `received`,
    on the bridge's [s], '') when the estimate can stand by it, else (None, why): 'future' (it
    was captured after it arrived, beyond the bound: the headset's clock jumped ahead),
    'carried' (the estimate has gone too long without an exchange for how well it knows the
    drift: MAX_CARRIED_S), 'old' (above max_delay_s)."""
    delay = received - estimate.to_bridge(capture, received)
    if delay < -estimate.bound_at(received) - FUTURE_TOLERANCE_S:
        return None, 'future'
    if estimate.carried_at(received) > MAX_CARRIED_S:
        return None, 'carried'
    if delay > max_delay_s:
        return None, 'old'
    return max(delay, 0.0), ''   # within the bound of zero: no stamp in the future
