"""Stage `gaze`: the true gaze to what the controller receives (gaze_noise, datagram_loss,
datagram_latency)."""
from __future__ import annotations

from dataclasses import dataclass
import heapq
import math
from typing import ClassVar

from .base import Draws, Effect, EffectError, RunContext, param

# Gaze stream: true gaze -> what the controller receives. Each takes and returns a sample
# (seq, t_emitted, yaw_deg, pitch_deg) or None (nothing this step), and draws its random
# numbers every step whether or not a sample reaches it.


@dataclass
class GazeNoise(Effect):
    """Angular noise on the gaze the tracker reports (not on the true gaze): independent
    normal noise on yaw and pitch, per sample.

    sd_deg (deg, default 1.0): Microsoft documents the HoloLens 2 eye-tracking accuracy as about
    1.5 deg of visual angle around the target; the sample-to-sample sd is an assumption of that
    order.
    """

    name: ClassVar[str] = 'gaze_noise'
    stage: ClassVar[str] = 'gaze'
    order: ClassVar[int] = 0
    stochastic: ClassVar[bool] = True

    sd_deg: float = param(1.0, 'deg', lo=0.0)

    def start(self, ctx: RunContext) -> None:
        self._draws = Draws(ctx.rng(self.name), 'normal')

    def gaze(self, t: float, sample):
        nxt, sd = self._draws.next, self.sd_deg
        dy, dp = nxt() * sd, nxt() * sd
        if sample is None:
            return None
        seq, te, yaw, pitch = sample
        return (seq, te, yaw + dy, pitch + dp)


@dataclass
class DatagramLoss(Effect):
    """Gaze datagrams lost on the way to the controller. The controller keeps its last sample;
    when none arrived for gaze_timeout_s it vents, as the pressure_controller node does.

    probability (-, default 0.01): long-run fraction lost. burst_len (samples, default null =
    independent losses): mean length of a run of consecutive losses (a two-state Markov
    chain); must be at least 1/(1 - probability), the mean run of independent losses.
    Where from: an assumption for UDP over a lab Wi-Fi link (losses of 0.1-1 %, in bursts when
    the link fades); the gaze_bridge node counts them per reason.
    """

    name: ClassVar[str] = 'datagram_loss'
    stage: ClassVar[str] = 'gaze'
    order: ClassVar[int] = 1
    stochastic: ClassVar[bool] = True

    probability: float = param(0.01, '-', lo=0.0, hi=1.0)
    burst_len: float | None = param(None, 'samples', lo=1.0, optional=True)

    def validate(self) -> None:
        if self.burst_len is not None:
            if self.probability >= 1.0:
                raise EffectError(f'{self.name}.burst_len: cannot be set with probability 1')
            least = 1.0 / (1.0 - self.probability)
            if self.burst_len < least:
                raise EffectError(f'{self.name}.burst_len must be >= 1/(1 - probability) = {least:.3g} samples '
                                  f'(the mean run of independent losses), got {self.burst_len:g}')

    def start(self, ctx: RunContext) -> None:
        self._draws = Draws(ctx.rng(self.name), 'uniform')
        p = self.probability
        if self.burst_len is None:
            self.stay, self.enter = p, p                  # P(loss | loss), P(loss | received)
        else:
            self.stay = 1.0 - 1.0 / self.burst_len
            self.enter = p * (1.0 - self.stay) / (1.0 - p)
        self.lost = False

    def gaze(self, t: float, sample):
        u = self._draws.next()
        self.lost = u < (self.stay if self.lost else self.enter)
        return None if self.lost else sample


@dataclass
class DatagramLatency(Effect):
    """Gaze samples arrive late: delay = mean_s when jitter_s = 0, else lognormal with that
    mean and standard deviation (positive, skewed to late, as network delay is). A sample
    overtaken by a newer one is dropped as stale, as gaze_bridge does; delivery is at the first
    simulation step at or after the arrival time.

    mean_s (s, default 0.03), jitter_s (s, default 0.01): an assumption of the order of the
    HoloLens eye-tracking pipeline plus a Wi-Fi hop (tens of milliseconds).
    """

    name: ClassVar[str] = 'datagram_latency'
    stage: ClassVar[str] = 'gaze'
    order: ClassVar[int] = 2
    stochastic: ClassVar[bool] = True

    mean_s: float = param(0.03, 's', lo=0.0)
    jitter_s: float = param(0.01, 's', lo=0.0)

    def validate(self) -> None:
        if self.jitter_s > 0 and self.mean_s <= 0:
            raise EffectError(f'{self.name}.mean_s must be > 0 when jitter_s > 0')

    def start(self, ctx: RunContext) -> None:
        self._draws = Draws(ctx.rng(self.name), 'normal')
        if self.jitter_s > 0:
            s2 = math.log1p((self.jitter_s / self.mean_s) ** 2)
            self.mu, self.sigma = math.log(self.mean_s) - 0.5 * s2, math.sqrt(s2)
        else:
            self.mu, self.sigma = None, 0.0
        self._queue: list = []
        self._last_seq = -math.inf
        # Arrival times are compared with the step time; a little slack keeps a delay that is a
        # whole number of steps from slipping a step by rounding.
        self._eps = 1e-9

    def gaze(self, t: float, sample):
        z = self._draws.next()
        if sample is not None:
            delay = self.mean_s if self.mu is None else math.exp(self.mu + self.sigma * z)
            heapq.heappush(self._queue, (sample[1] + delay, sample[0], sample))
        queue, out = self._queue, None
        limit = t + self._eps
        while queue and queue[0][0] <= limit:
            s = heapq.heappop(queue)[2]
            if s[0] > self._last_seq:
                self._last_seq, out = s[0], s
        return out
