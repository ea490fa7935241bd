"""Stage `cue`: how the wearer reads the haptic cue and when they read it again (cue_misreading,
surface_resistance, relative_perception)."""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import ClassVar

from .base import Draws, Effect, RunContext, logit_shifted, param

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
    arm_read_s (s, default 0): at every read of the arm band's cue (condition 3) the wearer
    stands still for this long before acting on it, turning a squeeze on the arm into a
    direction of the torso (a less direct mapping of stimulus to response than the suit's
    pull on the torso itself). Assumption, no time is published: 0 reads the arm at once,
    as the suit; fitted with the pace trait by experiments.fit_wearer (the same person
    searches, confirms and reads the arm slowly or fast), so that condition 3's spread of people is
    the one conditions 1 and 4 share, as in the paper's table.
    trial_sd (-, logit, default 0) and arm_read_trial_sd (-, log, default 0): how much a wearer
    varies from trial to trial: every run (a trial of the protocols) moves both misreading rates
    by trial_sd * z1 on the logit scale (at most to 0.5) and multiplies arm_read_s by
    exp(arm_read_trial_sd * z2 - arm_read_trial_sd^2 / 2) (mean 1: arm_read_s stays the wearer's
    mean read time), z1, z2 ~ N(0, 1). The paper's text gives each condition's SD over
    all trials (3.0, 3.3, 4.0, 1.4), larger than its table's spread of people: each subject's own
    trials varied, condition 3's most (the paper: on the arm a large error is not felt). A trait
    over them gives each wearer their own consistency. Fitted so, trial_sd went to its floor and
    arm_read_trial_sd cost the paper's consistency across conditions, so the fitted scenes keep
    both 0 (docs/simulation.md, "Within-person variation").

    Random numbers: two uniform and two normal draws per read from its own streams, whatever
    the read changes (arm_read_s draws none); two normal draws per run from a third when
    trial_sd or arm_read_trial_sd is above 0. direction_p = magnitude_sd = arm_read_s =
    trial_sd = arm_read_trial_sd = 0 leaves every run bit-identical to no effect.
    """

    name: ClassVar[str] = 'cue_misreading'
    stage: ClassVar[str] = 'cue'
    stochastic: ClassVar[bool] = True

    direction_p: float = param(0.15, '-', lo=0.0, hi=0.5)
    arm_direction_p: float = param(0.0, '-', lo=0.0, hi=0.5)
    magnitude_sd: float = param(0.2, '-', lo=0.0, hi=2.0)
    reread_s: float = param(1.0, 's', lo=0.0, lo_open=True)
    still_dps: float = param(5.0, 'deg/s', lo=0.0)
    still_gain: float = param(0.25, '-', lo=0.0, hi=10.0)
    arm_read_s: float = param(0.0, 's', lo=0.0, hi=10.0)
    trial_sd: float = param(0.0, '-', lo=0.0, hi=5.0)
    arm_read_trial_sd: float = param(0.0, '-', lo=0.0, hi=3.0)

    def start(self, ctx: RunContext) -> None:
        if self.trial_sd > 0.0 or self.arm_read_trial_sd > 0.0:
            # This run's own values; the draws come from a stream of their own, so every other
            # draw of the run stays where it was.
            z1, z2 = ctx.rng(self.name + '.trial').standard_normal(2)
            shift = self.trial_sd * float(z1)
            self.direction_p = _logit_shifted(self.direction_p, shift)
            self.arm_direction_p = _logit_shifted(self.arm_direction_p, shift)
            # exp(sd z - sd^2 / 2) has mean 1: arm_read_s stays the wearer's mean read time.
            sd = self.arm_read_trial_sd
            self.arm_read_s *= math.exp(sd * float(z2) - 0.5 * sd * sd)
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


def _logit_shifted(p: float, shift: float) -> float:
    """p moved by `shift` on the logit scale, at most 0.5 (more often wrong than right is reading
    the other way); 0 stays 0 (a wearer who never misreads)."""
    return min(logit_shifted(p, shift), 0.5) if p > 0.0 else p


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

    threshold_kpa_deg: float = param(1500.0, 'kPa deg', lo=0.0, hi=1e6, lo_open=True)

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

    fraction: float = param(0.14, '-', lo=0.0, hi=10.0, lo_open=True)
    settle_s: float = param(0.2, 's', lo=0.0)

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
