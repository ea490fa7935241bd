"""Stage `view`: when a visible target is seen on the HoloLens 2 display, found among the
dummies and confirmed (hololens_view)."""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import ClassVar

from .base import Draws, Effect, EffectError, RunContext, param

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
    edge_deg (deg, default None: off): a wearer who looks for an object keeps the goals they
    take from the touch within the objects' region (the protocol's +-horizontal_deg /
    +-vertical_deg, the paper's +-60 / +-30, which the participants saw) plus edge_deg, instead
    of the seat's limits; standing still there without the target, they read the cue again
    (cue_misreading.reread_s). Assumption: the paper says nothing of a subject who overshoots;
    without it a misread under a rising pull runs to the seat's 120 deg (sim.wearer.YAW_LIMIT_DEG).
    """

    name: ClassVar[str] = 'hololens_view'
    stage: ClassVar[str] = 'view'
    stochastic: ClassVar[bool] = True

    h_fov_deg: float = param(HOLOLENS2_FOV_DEG[0], 'deg', lo=0.0, hi=180.0, lo_open=True)
    v_fov_deg: float = param(HOLOLENS2_FOV_DEG[1], 'deg', lo=0.0, hi=180.0, lo_open=True)
    dummies: float = param(50.0, 'objects', lo=0.0, hi=1000.0)
    search_base_s: float = param(0.4, 's', lo=0.0)
    search_per_item_s: float = param(0.025, 's/item', lo=0.0)
    confirm_s: float = param(0.5, 's', lo=0.0)
    scan_deg: float = param(15.0, 'deg', lo=0.0, hi=90.0)
    still_dps: float = param(5.0, 'deg/s', lo=0.0)
    edge_deg: float | None = param(None, 'deg', lo=0.0, hi=120.0, optional=True)

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
