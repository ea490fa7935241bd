"""The effects a scene can switch on, one small class each, and the registry of their names.

A scene lists the effects it wants (config/scenes/*.yaml, key `effects:`); the engine builds
exactly those, fresh for every run, and composes them at fixed places of the closed loop:

    controller --(command, per direction = mean of its channels)--> [pressure] regulator_lag,
    suit_hysteresis --(pressure the suit exerts)--> [percept] weber_perception --> [delay]
    reaction_delay --> wearer's goal --> [body] body_dynamics --> true gaze --> [gaze]
    gaze_noise, datagram_loss, datagram_latency --> the controller's last gaze sample
    condition 4: phrase --> [speech] speech_latency --> [delay] reaction_delay --> goal

With no effect listed the wearer is ideal: the suit exerts the command at once, the wearer
perceives it exactly, at once, and stands at the goal it means; the controller sees the true
gaze every step.

Pressure-side effects act per channel in the real suit. They act identically on every channel,
and all channels of one direction carry the same command (core.channels.ChannelMap), so they
are simulated once per direction: the mean over the direction's channels that the wearer feels
is the same number (test_sim_effects checks it against an 18-channel simulation).

Randomness: each stochastic effect owns numpy Generators derived from the scene seed, its own
name, the wearer index and the run (numpy SeedSequence spawn keys, see `RunContext`), and it
draws a fixed number of values per step or per event whatever the other effects do. So adding,
removing or re-parametrising one effect never changes another effect's random numbers.

Every parameter's default says where it comes from: the paper, the package's own mock
hardware, an order of magnitude from datasheets, or a human-factors figure. Where a value is an
assumption the docstring says so plainly.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields
import heapq
import math
from typing import ClassVar
import zlib

import numpy as np

#: Stages of the loop, in the order the engine applies them within a step.
STAGES = ('pressure', 'percept', 'delay', 'body', 'gaze', 'speech')

#: Random numbers drawn per refill of an effect's buffer (drawing one by one is slow).
_BLOCK = 512


class EffectError(ValueError):
    """An effect name or parameter that cannot be used; the message names the field."""


# ---------------------------------------------------------------------------------------------
# Random streams


def stream_key(name: str) -> int:
    """A stable 32-bit number for a name (crc32: the same in every process and version)."""
    return zlib.crc32(name.encode('utf-8'))


def seed_sequence(seed: int, name: str, wearer: int, run: tuple[int, ...] = ()) -> np.random.SeedSequence:
    """The seed sequence of stream `name` for one wearer (and one run of that wearer).

    run = () keys what is drawn once per wearer (their reaction time, their laws); a run key
    (stage, condition, repetition) keys what is drawn during one run.
    """
    return np.random.SeedSequence(entropy=int(seed), spawn_key=(stream_key(name), int(wearer)) + tuple(run))


def generator(seed: int, name: str, wearer: int, run: tuple[int, ...] = ()) -> np.random.Generator:
    return np.random.Generator(np.random.PCG64(seed_sequence(seed, name, wearer, run)))


class Draws:
    """Values from one generator, one at a time, drawn in blocks (the values are the same as
    drawing them one by one would give for standard_normal / random)."""

    __slots__ = ('_gen', '_kind', '_buf', '_i')

    def __init__(self, gen: np.random.Generator, kind: str = 'normal'):
        if kind not in ('normal', 'uniform'):
            raise ValueError(f'unknown draw kind {kind!r}')
        self._gen, self._kind, self._buf, self._i = gen, kind, [], 0

    def next(self) -> float:
        i = self._i
        if i == len(self._buf):
            arr = self._gen.standard_normal(_BLOCK) if self._kind == 'normal' else self._gen.random(_BLOCK)
            self._buf, i = arr.tolist(), 0
        self._i = i + 1
        return self._buf[i]


@dataclass(frozen=True)
class RunContext:
    """What an effect needs to start a run: the step and its random streams.

    rng(): the effect's Generator for this run; wearer_rng(): its Generator for this wearer,
    the same in every run (for per-wearer traits such as a reaction time).
    """

    dt: float
    seed: int
    wearer: int
    run: tuple[int, ...]

    def rng(self, name: str) -> np.random.Generator:
        return generator(self.seed, name, self.wearer, self.run)

    def wearer_rng(self, name: str) -> np.random.Generator:
        return generator(self.seed, name, self.wearer)


# ---------------------------------------------------------------------------------------------
# Parameter checks


def _param(default, unit: str, lo: float | None = None, hi: float | None = None, lo_open: bool = False,
           optional: bool = False):
    return field(default=default, metadata={'unit': unit, 'lo': lo, 'hi': hi, 'lo_open': lo_open,
                                            'optional': optional})


def _check_fields(effect) -> None:
    for f in fields(effect):
        value = getattr(effect, f.name)
        meta = f.metadata
        where = f'{effect.name}.{f.name}'
        if value is None and meta.get('optional'):
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise EffectError(f'{where} must be a number ({meta.get("unit")}), got {value!r}')
        value = float(value)
        if not math.isfinite(value):
            raise EffectError(f'{where} must be finite, got {value}')
        lo, hi = meta.get('lo'), meta.get('hi')
        if lo is not None and (value <= lo if meta.get('lo_open') else value < lo):
            raise EffectError(f'{where} must be {">" if meta.get("lo_open") else ">="} {lo:g} {meta.get("unit")}, '
                              f'got {value:g}')
        if hi is not None and value > hi:
            raise EffectError(f'{where} must be <= {hi:g} {meta.get("unit")}, got {value:g}')
        object.__setattr__(effect, f.name, value)


class Effect:
    """Base of the effects: a dataclass of parameters; start() makes the per-run state."""

    name: ClassVar[str]
    stage: ClassVar[str]
    #: Order within the stage (physical order: a tracker adds noise before the network loses it).
    order: ClassVar[int] = 0
    stochastic: ClassVar[bool] = False

    def __post_init__(self) -> None:
        _check_fields(self)
        self.validate()

    def validate(self) -> None:
        """Checks across parameters; raise EffectError naming the field."""

    def start(self, ctx: RunContext) -> None:
        """Reset the state for a new run."""

    @classmethod
    def parameters(cls) -> dict[str, tuple[object, str]]:
        """name -> (default, unit)."""
        return {f.name: (f.default, f.metadata.get('unit', '')) for f in fields(cls)}


# ---------------------------------------------------------------------------------------------
# Pressure side: command -> pressure the suit exerts (per direction, see module docstring)


@dataclass
class RegulatorLag(Effect):
    """First-order lag from the commanded pressure to the regulator's output pressure.

    tau_s (s, default 0.15): time constant. Where from: the package's mock PLC regulator
    (config/sim.yaml regulator_tau_s = 0.15), itself an order of magnitude for electro-pneumatic
    proportional regulators (datasheets of the CRCB/ITV class give step responses of about
    0.1-0.2 s without load); the suit's muscle volume would slow it further. Not measured on
    the paper's suit: an assumption of the right order.

    Exact discretisation for a command held over the step: p += (cmd - p) * (1 - exp(-dt/tau)).
    """

    name: ClassVar[str] = 'regulator_lag'
    stage: ClassVar[str] = 'pressure'
    order: ClassVar[int] = 0

    tau_s: float = _param(0.15, 's', lo=0.0, lo_open=True)

    def start(self, ctx: RunContext) -> None:
        self.alpha = 1.0 - math.exp(-ctx.dt / self.tau_s)
        self.out = [0.0, 0.0, 0.0, 0.0]

    def pressure(self, p: list) -> list:
        out, alpha = self.out, self.alpha
        for k in range(4):
            out[k] += (p[k] - out[k]) * alpha
        return out


@dataclass
class SuitHysteresis(Effect):
    """Backlash (play) between the regulator's pressure and the pressure the suit exerts.

    band_kpa (kPa, default 20): total width of the play. The exerted pressure does not move
    while the input moves within +-band/2 of it; beyond, it follows the input at band/2 behind
    (a rising input leads by band/2, a falling one lags by band/2). It never goes below 0.
    Where from: the paper's Discussion names "the hysteresis of surface haptic sensation" of the
    suit without a figure; McKibben muscles are known for pressure-force hysteresis of a few
    per cent of full scale (braid-bladder friction). 20 kPa is about 5 % of P_MAX = 375 kPa:
    an assumption of that order.
    """

    name: ClassVar[str] = 'suit_hysteresis'
    stage: ClassVar[str] = 'pressure'
    order: ClassVar[int] = 1

    band_kpa: float = _param(20.0, 'kPa', lo=0.0)

    def start(self, ctx: RunContext) -> None:
        self.half = 0.5 * self.band_kpa
        self.out = [0.0, 0.0, 0.0, 0.0]

    def pressure(self, p: list) -> list:
        out, h = self.out, self.half
        for k in range(4):
            x, y = p[k], out[k]
            if y < x - h:
                y = x - h
            elif y > x + h:
                y = x + h
            out[k] = y if y > 0.0 else 0.0
        return out


# ---------------------------------------------------------------------------------------------
# Perception


@dataclass
class WeberPerception(Effect):
    """The wearer's percept of each direction's pressure changes only when the pressure has
    changed by more than the Weber fraction of the current percept (perception is relative:
    the paper's Discussion, citing Weber).

    fraction (-, default 0.14): the just-noticeable relative change. Where from: the classic
    textbook table of Weber fractions (Teghtsoonian 1971, as reproduced in Coren, Ward & Enns,
    Sensation and Perception) gives about 0.14 for pressure on the skin; force and pressure
    discrimination studies report 0.07-0.2. A fabric suit pulling the torso was never measured:
    the value is that human-factors figure, not a measurement of this suit.

    From a percept of 0 any non-zero pressure is noticed (the threshold of feeling anything is
    the wearer's own c of their power law).
    """

    name: ClassVar[str] = 'weber_perception'
    stage: ClassVar[str] = 'percept'

    fraction: float = _param(0.14, '-', lo=0.0, hi=10.0)

    def start(self, ctx: RunContext) -> None:
        self.out = [0.0, 0.0, 0.0, 0.0]

    def percept(self, p: list) -> list:
        out, w = self.out, self.fraction
        for k in range(4):
            x, q = p[k], out[k]
            if abs(x - q) > w * q:
                out[k] = x
        return out


@dataclass
class ReactionDelay(Effect):
    """The wearer acts on the percept of `delay` ago: each wearer has their own delay, drawn
    once per wearer from N(mean_s, sd_s) (floored at 0) and rounded to whole simulation steps.

    mean_s (s, default 0.25): simple reaction time to a touch stimulus is about 0.15-0.3 s in
    the human-factors literature; choosing a direction from it (choice reaction) takes longer,
    so a scene may well set more. sd_s (s, default 0.05): between-person spread of that order
    (an assumption). The same delay applies to the spoken phrase of condition 4 (after it has
    been heard: see speech_latency).
    """

    name: ClassVar[str] = 'reaction_delay'
    stage: ClassVar[str] = 'delay'
    stochastic: ClassVar[bool] = True

    mean_s: float = _param(0.25, 's', lo=0.0)
    sd_s: float = _param(0.05, 's', lo=0.0)

    def start(self, ctx: RunContext) -> None:
        draw = float(ctx.wearer_rng(self.name).standard_normal())
        self.delay_s = max(0.0, self.mean_s + self.sd_s * draw)
        self.steps = int(round(self.delay_s / ctx.dt))
        self._buf: list = []
        self._i = 0

    def reset(self, rest) -> None:
        """Fill the history with the percept of rest (what was felt before the run)."""
        self._buf = [rest] * self.steps
        self._i = 0

    def delay(self, percept):
        if not self.steps:
            return percept
        buf, i = self._buf, self._i
        out = buf[i]
        buf[i] = percept
        self._i = i + 1 if i + 1 < self.steps else 0
        return out


# ---------------------------------------------------------------------------------------------
# Body


@dataclass
class BodyDynamics(Effect):
    """The body takes time to move, and the eyes catch a visible target.

    Without this effect the posture jumps to its goal every step. With it the torso follows
    the goal as a first-order lag, and the gaze (head and eyes) rides on the torso; once a
    visible target is inside the central visual field, head and eyes turn to it with a faster
    first-order lag (visual capture: the target is seen).

    torso_tau_s (s, default 0.4): the package's simulated wearer (SimulatedWearer tau_s), an
    assumption of the order of a voluntary trunk rotation of tens of degrees taking about a
    second. head_tau_s (s, default 0.15): head-eye gaze shifts of 20-30 deg take about
    0.1-0.3 s (an order of magnitude from the gaze-shift literature). central_field_deg (deg,
    default 30): the paper's central visual field (30 deg radius, after Sampson and Bhise), in
    which color and shape are identified; 0 disables capture.
    """

    name: ClassVar[str] = 'body_dynamics'
    stage: ClassVar[str] = 'body'

    torso_tau_s: float = _param(0.4, 's', lo=0.0, lo_open=True)
    head_tau_s: float = _param(0.15, 's', lo=0.0, lo_open=True)
    central_field_deg: float = _param(30.0, 'deg', lo=0.0, hi=180.0)

    def start(self, ctx: RunContext) -> None:
        self.torso_alpha = 1.0 - math.exp(-ctx.dt / self.torso_tau_s)
        self.head_alpha = 1.0 - math.exp(-ctx.dt / self.head_tau_s)
        half = math.radians(self.central_field_deg) / 2.0
        self.central_field_hav = math.sin(half) ** 2      # wearer.haversine() at the field's edge


# ---------------------------------------------------------------------------------------------
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

    sd_deg: float = _param(1.0, 'deg', lo=0.0)

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

    probability: float = _param(0.01, '-', lo=0.0, hi=1.0)
    burst_len: float | None = _param(None, 'samples', lo=1.0, optional=True)

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

    mean_s: float = _param(0.03, 's', lo=0.0)
    jitter_s: float = _param(0.01, 's', lo=0.0)

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


# ---------------------------------------------------------------------------------------------
# Speech (condition 4)


@dataclass
class SpeechLatency(Effect):
    """Condition 4's phrase reaches the wearer after synthesis and speaking time: the wearer
    can act once the whole phrase is heard, latency = max(0, N(mean_s, sd_s)) + per_word_s *
    words (one draw per phrase).

    mean_s (s, default 0.4): a cloud text-to-speech service (the paper used Microsoft Azure)
    answers in a few hundred milliseconds: an assumption of that order. sd_s (s, default 0.1):
    assumption. per_word_s (s/word, default 0.35): conversational speech runs at about 150-180
    words per minute (0.33-0.4 s per word); numbers such as "thirty-six" are long words.
    """

    name: ClassVar[str] = 'speech_latency'
    stage: ClassVar[str] = 'speech'
    stochastic: ClassVar[bool] = True

    mean_s: float = _param(0.4, 's', lo=0.0)
    sd_s: float = _param(0.1, 's', lo=0.0)
    per_word_s: float = _param(0.35, 's/word', lo=0.0)

    def start(self, ctx: RunContext) -> None:
        self._draws = Draws(ctx.rng(self.name), 'normal')

    def latency(self, text: str) -> float:
        z = self._draws.next()
        return max(0.0, self.mean_s + self.sd_s * z) + self.per_word_s * len(text.split())


# ---------------------------------------------------------------------------------------------
# Registry

REGISTRY: dict[str, type[Effect]] = {cls.name: cls for cls in (
    GazeNoise, DatagramLoss, DatagramLatency, RegulatorLag, SuitHysteresis, WeberPerception, ReactionDelay,
    BodyDynamics, SpeechLatency)}


def effect_class(name: str) -> type[Effect]:
    """The class registered under `name`; EffectError listing the valid names otherwise."""
    try:
        return REGISTRY[name]
    except (KeyError, TypeError):
        raise EffectError(f'unknown effect {name!r}; valid effects: {", ".join(sorted(REGISTRY))}') from None


def make_effect(name: str, params: dict | None = None) -> Effect:
    """Build an effect from its name and parameters; unknown parameters are errors naming
    the parameter and listing the valid ones."""
    cls = effect_class(name)
    params = dict(params or {})
    valid = cls.parameters()
    unknown = sorted(set(params) - set(valid))
    if unknown:
        raise EffectError(f'{name}: unknown parameter(s) {unknown}; valid: '
                          + ', '.join(f'{k} ({u}, default {d})' for k, (d, u) in valid.items()))
    return cls(**params)


def by_stage(effects) -> dict[str, list[Effect]]:
    """Effects grouped by stage, each stage in the registry's physical order."""
    out: dict[str, list[Effect]] = {s: [] for s in STAGES}
    for e in effects:
        out[e.stage].append(e)
    for s in STAGES:
        out[s].sort(key=lambda e: e.order)
    return out


__all__ = ['REGISTRY', 'STAGES', 'BodyDynamics', 'DatagramLatency', 'DatagramLoss', 'Draws', 'Effect', 'EffectError',
           'GazeNoise', 'ReactionDelay', 'RegulatorLag', 'RunContext', 'SpeechLatency', 'SuitHysteresis',
           'WeberPerception', 'by_stage', 'effect_class', 'generator', 'make_effect', 'seed_sequence', 'stream_key']
