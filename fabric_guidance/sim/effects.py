"""The effects a scene can switch on, one small class each, and the registry of their names.

A scene lists the effects it wants (config/scenes/*.yaml, key `effects:`); the engine builds
exactly those, fresh for every run, and composes them at fixed places of the closed loop:

    controller --(command, per direction = mean of its channels)--> [pressure] regulator_lag,
    suit_hysteresis --(pressure the suit exerts)--> [percept] weber_perception --> [delay]
    reaction_delay --> wearer's goal --> [body] body_dynamics --> true gaze --> [gaze]
    gaze_noise, datagram_loss, datagram_latency --> the controller's last gaze sample
    condition 4: phrase --> [speech] speech_latency --> [delay] reaction_delay --> goal
    [cue] cue_misreading, surface_resistance, relative_perception: how the wearer reads the
    haptic cue (its direction and size) and when they read it again
    [view] hololens_view: when a visible target is seen, found among the dummies, confirmed

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
STAGES = ('pressure', 'percept', 'delay', 'body', 'gaze', 'speech', 'cue', 'view')

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
    (config/params/sim.yaml regulator_tau_s = 0.15), itself an order of magnitude for electro-pneumatic
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
# The wearer's reading of the cue (the wearer who can be wrong). The wearer (wearer.SceneWearer) interprets the
# haptic percept through cue_misreading's current reading; wearer.Senses decides when the cue is
# read again (surface_resistance, relative_perception, a stop without the target in sight).


@dataclass
class CueMisreading(Effect):
    """The wearer can read the haptic cue wrongly (haptic conditions only; speech is words).

    Whenever the wearer reads a cue (the first percept of a guidance, and every re-read), each
    axis's direction (left/right, up/down) is misread with probability direction_p, and the
    size by a factor exp(N(0, magnitude_sd)); the wearer turns toward the goal they read
    (anchor + sign * factor * perceived angle). Without other feedback they re-read the cue
    once their torso has moved slower than still_dps for reread_s while a visible target they
    look for is not seen;
    the pull is still there, so they take it to mean further: the k-th such re-read of a
    guidance multiplies the size read by (1 + still_gain)^min(k, 2). In the accuracy protocol
    the wearer presses the key once they have stood still for the protocol's settle_s (shorter
    than reread_s): a wearer who misread presses where they believe the target is, unless
    resistance or a rise of the pressure corrected them during the move.

    direction_p (-, default 0.15): the paper's Discussion says users may "move differently from
    the directional presentation", and no training was given; no rate is published: an
    assumption, fitted to the paper's speed means by experiments.fit_wearer.
    arm_direction_p (-, default 0): the same on the arm (condition 3), where one muscle per
    side and direction contracts. Assumption: the paper attributes the wrong moves to the
    surface sensation (its hysteresis), so the arm's plain squeeze is read right.
    magnitude_sd (-, log, default 0.2): assumption, of the order of the between-trial spread of
    magnitude estimates (Stevens-type judgements scatter by 20-30 %).
    reread_s (s, default 1.0): assumption, a second of standing still before doubting the cue.
    still_dps (deg/s, default 5): assumption, "nearly stopped".
    still_gain (-, default 0.25): assumption.

    Random numbers: two uniform and two normal draws per read from its own streams, whatever
    the read changes. direction_p = magnitude_sd = 0 leaves every run bit-identical to no
    effect.
    """

    name: ClassVar[str] = 'cue_misreading'
    stage: ClassVar[str] = 'cue'
    stochastic: ClassVar[bool] = True

    direction_p: float = _param(0.15, '-', lo=0.0, hi=0.5)
    arm_direction_p: float = _param(0.0, '-', lo=0.0, hi=0.5)
    magnitude_sd: float = _param(0.2, '-', lo=0.0, hi=2.0)
    reread_s: float = _param(1.0, 's', lo=0.0, lo_open=True)
    still_dps: float = _param(5.0, 'deg/s', lo=0.0)
    still_gain: float = _param(0.25, '-', lo=0.0, hi=10.0)

    def start(self, ctx: RunContext) -> None:
        self.p = self.direction_p      # the layout's; Senses sets arm_direction_p for the arm
        self._u = Draws(ctx.rng(self.name + '.direction'), 'uniform')
        self._n = Draws(ctx.rng(self.name + '.magnitude'), 'normal')
        self.sign_h = self.sign_v = 1.0
        self.factor_h = self.factor_v = 1.0   # sign * size factor per axis
        self.reads = 0
        self.misreads = 0

    def read(self, correct_direction: bool = False, keep_magnitude: bool = False,
             boost: float = 1.0) -> bool:
        """A read of the cue: new signs and size factors. correct_direction: the wearer now
        knows the direction (resistance told them). keep_magnitude: only the direction is read
        again. boost: the size read is multiplied by this. Returns whether a direction
        changed."""
        u_h, u_v, z_h, z_v = self._u.next(), self._u.next(), self._n.next(), self._n.next()
        p, sd = self.p, self.magnitude_sd
        sh = 1.0 if correct_direction or u_h >= p else -1.0
        sv = 1.0 if correct_direction or u_v >= p else -1.0
        changed = sh != self.sign_h or sv != self.sign_v
        self.reads += 1
        self.misreads += (sh < 0.0) + (sv < 0.0)
        if keep_magnitude:
            mh, mv = abs(self.factor_h), abs(self.factor_v)
        else:
            mh = (math.exp(sd * z_h) if sd > 0.0 else 1.0) * boost
            mv = (math.exp(sd * z_v) if sd > 0.0 else 1.0) * boost
        self.sign_h, self.sign_v = sh, sv
        self.factor_h, self.factor_v = sh * mh, sv * mv
        return changed


@dataclass
class SurfaceResistance(Effect):
    """The suit resists a wrong move (layout 'suit' only: the arm band of condition 3 does not
    follow the body, the paper: on the arm "it is difficult to perceive resistance").

    While the wearer's torso moves against the direction the suit pulls, a resistance impulse
    J += net pull of the axis (left - right, up - down exerted pressure) * |angular speed
    against it| * dt builds up (kPa deg);
    when it reaches threshold_kpa_deg the wearer notices the move is wrong and reads the cue
    again with the right direction (cue_misreading; without that effect nothing is misread and
    this effect only counts). J restarts at every read. It grows with the pressure and the
    speed of the wrong move, so Eq. 5's added pressure (condition 1) makes it fire sooner than
    the fixed pressure of condition 2: the mechanism the paper's Discussion gives for
    condition 1 being faster than condition 2.

    threshold_kpa_deg (kPa deg, default 1500): assumption (about 100 kPa over 15 deg),
    fitted to the paper's speed means by experiments.fit_wearer.
    """

    name: ClassVar[str] = 'surface_resistance'
    stage: ClassVar[str] = 'cue'
    order: ClassVar[int] = 1

    threshold_kpa_deg: float = _param(1500.0, 'kPa deg', lo=0.0, hi=1e6, lo_open=True)

    def start(self, ctx: RunContext) -> None:
        self.impulse = 0.0
        self.fired = 0

    def accumulate(self, exerted, v_yaw: float, v_pitch: float, dt: float) -> bool:
        """Add one step's impulse (velocities in deg/s, positive left / up); True when the
        wearer notices (then J restarts)."""
        # Antagonists: the net pull of each axis (left - right, up - down) resists a move
        # against it; a pull the other way's residual pressure (hysteresis) does not.
        jh = -(exerted[0] - exerted[1]) * v_yaw
        jv = -(exerted[3] - exerted[2]) * v_pitch
        j = (jh if jh > 0.0 else 0.0) + (jv if jv > 0.0 else 0.0)
        if j <= 0.0:
            return False
        self.impulse += j * dt
        if self.impulse >= self.threshold_kpa_deg:
            self.impulse = 0.0
            self.fired += 1
            return True
        return False


@dataclass
class RelativePerception(Effect):
    """A change of pressure is noticed more easily than a level (the paper's Discussion, after
    Weber): once settle_s have passed since the cue was last read, the exerted pressure of
    each direction then is the wearer's reference; a rise above (1 + fraction) times the
    reference is noticed (the onset of a cue is its reading, not a change).

    On the suit a noticed rise during a move tells the wearer the move is wrong (the paper's
    Discussion: the adjustment makes the wearer "quickly recognize that the movement was
    different from the guided movement"; condition 1's Eq. 5 raises the pressure exactly when
    the error grows): they read the cue again with the right direction. On the arm (condition 3)
    the rise only makes the percept larger, which the percept already does (the paper: on the
    arm "air pressure adjustment may be less effective"), so nothing more happens there.

    Different from weber_perception, which is a dead band on the percept (changes below the
    fraction are not felt at all); this one acts on the wearer's decisions, not on the percept.

    fraction (-, default 0.14): the Weber fraction for pressure on the skin (textbook table,
    Teghtsoonian 1971, as weber_perception). settle_s (s, default 0.2): assumption, the
    reaction delay plus a regulator time constant after the command began (its pressure has
    nearly settled by then).
    """

    name: ClassVar[str] = 'relative_perception'
    stage: ClassVar[str] = 'cue'
    order: ClassVar[int] = 2

    fraction: float = _param(0.14, '-', lo=0.0, hi=10.0, lo_open=True)
    settle_s: float = _param(0.2, 's', lo=0.0)

    def start(self, ctx: RunContext) -> None:
        self.settle_steps = int(round(self.settle_s / ctx.dt))
        self.noticed = 0
        self.restart()

    def restart(self) -> None:
        """The cue was (re-)read: the comparison starts afresh."""
        self._since = 0
        self._ref: tuple | None = None

    def rise(self, exerted) -> bool:
        """One step of the exerted pressure (per direction); True when a rise is noticed."""
        self._since += 1
        ref = self._ref
        if ref is None:
            if self._since >= self.settle_steps:
                self._ref = (exerted[0], exerted[1], exerted[2], exerted[3])
            return False
        f = 1.0 + self.fraction
        for k in range(4):
            if ref[k] > 0.0 and exerted[k] > ref[k] * f:
                self.noticed += 1
                return True
        return False


#: HoloLens 2 display: 52 deg diagonal at a 3:2 aspect ratio (Microsoft's figure), i.e. about
#: 43 deg horizontal by 29 deg vertical (as worked out by UploadVR and others from it).
HOLOLENS2_FOV_DEG = (43.0, 29.0)


@dataclass
class HololensView(Effect):
    """A virtual target can be seen only on the HoloLens 2 display, found only after a visual
    search among the dummies, and counted only after the key is pressed.

    Seen: inside the display's field of view around the gaze (h_fov_deg x v_fov_deg, default
    43 x 29 deg: Microsoft's 52 deg diagonal at 3:2) and inside body_dynamics' central field.
    Found: after search_base_s + search_per_item_s * (dummies on the display when it came into
    view) of it staying seen (leaving the view restarts the search); only then do head and
    eyes turn to it (visual capture). Confirmed: the key press counts no sooner than
    confirm_s after it was found (in addition to the protocol's dwell_s on the tracked gaze).

    The dummies: `dummies` spheres (the paper: 50, in the same +-60 / +-30 deg region as the
    target) drawn uniformly in the protocol's region per target from its own stream (two
    uniform draws per dummy per target).

    search_base_s (s, default 0.4) and search_per_item_s (s/item, default 0.025): assumption of
    textbook order (Wolfe 1998, "What can 1 million trials tell us about visual search?":
    target-present slopes of about 20-30 ms/item for inefficient (conjunction, similar-colour)
    search, intercepts of about 0.4-0.5 s); red among magenta is a similar-colour search.
    confirm_s (s, default 0.5): assumption (deciding and pressing the key; fitted by
    experiments.fit_wearer); it is separate from the protocol's dwell_s, the tracker's rule.
    scan_deg (deg, default 15) and still_dps (deg/s, default 5): once the torso has stopped
    (slower than still_dps) without the target in sight, the wearer looks around with head
    and eyes: the display's window widens by scan_deg on each side and the central-field
    condition is dropped. Assumption: head movements of that order are what people add to
    their eyes when searching a region (the display is fixed to the head).
    """

    name: ClassVar[str] = 'hololens_view'
    stage: ClassVar[str] = 'view'
    stochastic: ClassVar[bool] = True

    h_fov_deg: float = _param(HOLOLENS2_FOV_DEG[0], 'deg', lo=0.0, hi=180.0, lo_open=True)
    v_fov_deg: float = _param(HOLOLENS2_FOV_DEG[1], 'deg', lo=0.0, hi=180.0, lo_open=True)
    dummies: float = _param(50.0, 'objects', lo=0.0, hi=1000.0)
    search_base_s: float = _param(0.4, 's', lo=0.0)
    search_per_item_s: float = _param(0.025, 's/item', lo=0.0)
    confirm_s: float = _param(0.5, 's', lo=0.0)
    scan_deg: float = _param(15.0, 'deg', lo=0.0, hi=90.0)
    still_dps: float = _param(5.0, 'deg/s', lo=0.0)

    def validate(self) -> None:
        if not float(self.dummies).is_integer():
            raise EffectError(f'{self.name}.dummies must be a whole number, got {self.dummies:g}')

    def start(self, ctx: RunContext) -> None:
        self._u = Draws(ctx.rng(self.name), 'uniform')
        self.half_h, self.half_v = 0.5 * self.h_fov_deg, 0.5 * self.v_fov_deg
        self.region = (60.0, 30.0)
        self.searches: list = []     # (dummies on the display, search time) per search begun
        self.present(None)

    def present(self, target, region: tuple[float, float] | None = None) -> None:
        """A new target (yaw, pitch) or None: new dummies, nothing found yet."""
        if region is not None:
            self.region = region
        self.target = target
        self.found_t: float | None = None
        self.since: float | None = None
        self.need = 0.0
        self.dummy_pos: list = []
        if target is None:
            return
        u, (rh, rv) = self._u.next, self.region
        n = int(self.dummies)
        self.dummy_pos = [((2.0 * u() - 1.0) * rh, (2.0 * u() - 1.0) * rv) for _ in range(n)]

    def in_display(self, gy: float, gp: float, yaw: float, pitch: float,
                   margin: float = 0.0) -> bool:
        dy = yaw - gy
        dy = (dy + 180.0) % 360.0 - 180.0
        hh, hv = self.half_h + margin, self.half_v + margin
        return -hh <= dy <= hh and -hv <= pitch - gp <= hv

    def update(self, t: float, gy: float, gp: float, in_central: bool,
               still: bool = False) -> bool:
        """One step with the gaze at (gy, gp): whether the target has been found. still: the
        torso has stopped, and the head scans around (scan_deg)."""
        if self.found_t is not None:
            return True
        tgt = self.target
        if tgt is None:
            return False
        margin = self.scan_deg if still else 0.0
        if not ((in_central or still) and self.in_display(gy, gp, tgt[0], tgt[1], margin)):
            self.since = None
            return False
        if self.since is None:
            self.since = t
            n = sum(1 for d in self.dummy_pos if self.in_display(gy, gp, d[0], d[1]))
            self.need = self.search_base_s + self.search_per_item_s * n
            self.searches.append((n, self.need))
        if t - self.since >= self.need - 1e-9:
            self.found_t = t
            return True
        return False

    @property
    def key_ready_t(self) -> float:
        """The earliest time the key press counts (inf before the target is found)."""
        return math.inf if self.found_t is None else self.found_t + self.confirm_s


# ---------------------------------------------------------------------------------------------
# Registry

REGISTRY: dict[str, type[Effect]] = {cls.name: cls for cls in (
    GazeNoise, DatagramLoss, DatagramLatency, RegulatorLag, SuitHysteresis, WeberPerception, ReactionDelay,
    BodyDynamics, SpeechLatency, CueMisreading, SurfaceResistance, RelativePerception,
    HololensView)}


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


def start_effects(specs, ctx: RunContext) -> tuple[list[Effect], dict[str, list[Effect]]]:
    """A run's effects built from the scene's specs and started with its context: (the effects
    in the scene's order, by_stage() of them). The engine and the graph's wearer both start
    them so, which keeps their seeding the same."""
    effects = [spec.build() for spec in specs]
    for e in effects:
        e.start(ctx)
    return effects, by_stage(effects)


__all__ = ['HOLOLENS2_FOV_DEG', 'REGISTRY', 'STAGES', 'BodyDynamics', 'CueMisreading',
           'HololensView',
           'RelativePerception', 'SurfaceResistance', 'DatagramLatency', 'DatagramLoss', 'Draws',
           'Effect', 'EffectError',
           'GazeNoise', 'ReactionDelay', 'RegulatorLag', 'RunContext', 'SpeechLatency', 'SuitHysteresis',
           'WeberPerception', 'by_stage', 'effect_class', 'generator', 'make_effect', 'seed_sequence',
           'start_effects', 'stream_key']
