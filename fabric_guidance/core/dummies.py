"""The speed task's dummies (Sec. VI): distractor spheres around the eye, among which the wearer
finds the target.

The field is what the wearer sees from the eye: directions within +-azimuth of the front and
+-elevation of eye level (REP 103: x forward, y left, z up; azimuth positive to the left).
Directions are drawn uniformly in solid angle over it (azimuth uniform, sin(elevation)
uniform), so the spheres are as dense near the field's top and bottom edges as at eye level.

Every dummy is at the target's distance from the eye. Seen from the eye, a sphere of radius r
at distance d covers a cone of half-angle asin(r/d) (its angular radius). Two spheres at the
same distance neither overlap nor hide one another when their directions are at least the sum
of their angular radii apart; for two dummies of radius r that is the least that keeps them
apart, centres 2r apart. So dummies keep that separation from each other and from the target.

They are drawn by rejection with a bounded number of candidates (ATTEMPTS_PER_DUMMY per
dummy asked for, drawn BATCH at a time): time and memory are bounded whatever the field, and a
field too small for that many gets as many as the draw found room for.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

#: Candidates drawn per dummy asked for, at most: far more than a field with room needs.
ATTEMPTS_PER_DUMMY = 100
#: Candidates drawn at once (the memory of a draw).
BATCH = 256


def angular_radius(radius_m: float, distance_m: float) -> float:
    """The half-angle [rad] of the cone a sphere covers seen from a point `distance_m` from its
    centre; pi/2 when the point is inside it (nothing else fits beside it)."""
    if distance_m <= radius_m:
        return math.pi / 2
    return math.asin(radius_m / distance_m)


def field_directions(rng: np.random.Generator, count: int, azimuth_deg: float, elevation_deg: float,
                     separation_rad: float, avoid: Sequence[Sequence[float]] = (),
                     avoid_separation_rad: float = 0.0) -> np.ndarray:
    """Up to `count` unit vectors (rows, REP 103) uniform in solid angle within +-azimuth_deg and
    +-elevation_deg, each at least `separation_rad` from the others and `avoid_separation_rad`
    from every unit vector of `avoid`. Fewer when ATTEMPTS_PER_DUMMY * count candidates found
    no room for more. Deterministic for a given state of `rng`."""
    count = max(0, int(count))
    half_az = math.radians(min(max(azimuth_deg, 0.0), 180.0))
    max_sin = math.sin(math.radians(min(max(elevation_deg, 0.0), 90.0)))
    # Angles compared as cosines: a pair is apart when the cosine of its angle is at most this
    # (no separation: any pair, also one whose rounded cosine exceeds 1).
    cos_sep = math.cos(min(separation_rad, math.pi)) if separation_rad > 0.0 else math.inf
    cos_avoid = math.cos(min(avoid_separation_rad, math.pi)) if avoid_separation_rad > 0.0 else math.inf
    avoid = np.asarray(avoid, dtype=float).reshape(-1, 3)
    placed = np.empty((count, 3))
    n = 0
    budget = ATTEMPTS_PER_DUMMY * count
    while n < count and budget > 0:
        size = min(BATCH, budget)
        budget -= size
        az = rng.uniform(-half_az, half_az, size)
        sin_el = rng.uniform(-max_sin, max_sin, size)
        cos_el = np.sqrt(1.0 - sin_el ** 2)
        candidates = np.stack([cos_el * np.cos(az), cos_el * np.sin(az), sin_el], axis=1)
        # Against the target and what earlier batches placed at once; within this batch one by one.
        ok = np.ones(size, dtype=bool)
        if len(avoid):
            ok &= (candidates @ avoid.T).max(axis=1) <= cos_avoid
        if n:
            ok &= (candidates @ placed[:n].T).max(axis=1) <= cos_sep
        first = n
        for c in candidates[ok]:
            if n > first and (placed[first:n] @ c).max() > cos_sep:
                continue
            placed[n] = c
            n += 1
            if n == count:
                break
    return placed[:n].copy()


def around_eye(rng: np.random.Generator, count: int, eye: Sequence[float], target: Sequence[float],
               radius_m: float, target_radius_m: float, azimuth_deg: float,
               elevation_deg: float) -> np.ndarray:
    """Dummy centres (rows, REP 103) at the target's distance from the eye, within the field seen
    from the eye, apart from each other and from the target by the separation above (a target
    at the eye has no direction to keep apart from)."""
    eye = np.asarray(eye, dtype=float)
    offset = np.asarray(target, dtype=float) - eye
    distance = float(np.linalg.norm(offset))
    dummy = angular_radius(radius_m, distance)
    avoid = [offset / distance] if distance > 1e-9 else []
    directions = field_directions(rng, count, azimuth_deg, elevation_deg, 2.0 * dummy, avoid,
                                  dummy + angular_radius(target_radius_m, distance))
    return eye + distance * directions
