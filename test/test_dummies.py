"""core.dummies: the speed task's distractors around the eye, uniform in solid angle over the
field, apart from each other and from the target, in bounded time whatever the parameters."""
import math

from hypothesis import given, settings, strategies as st
import numpy as np
import pytest
from scipy import stats

from fabric_guidance.core import dummies
from fabric_guidance.live_study.operator import target_position

EYE = np.array([0.0, 0.0, 1.2])


class CountingRng:
    """A numpy Generator that counts the candidates drawn (every uniform() draws one number of each)."""

    def __init__(self, seed):
        self.rng, self.drawn = np.random.default_rng(seed), 0

    def uniform(self, low, high, size):
        self.drawn += size
        return self.rng.uniform(low, high, size)


def angles(a, b) -> np.ndarray:
    """The angles [rad] between the rows of a and of b (unit vectors), from the chord: exact for
    small angles too (an arccos of their dot product is not)."""
    chord = np.linalg.norm(np.asarray(a)[:, None] - np.asarray(b)[None], axis=2)
    return 2.0 * np.arcsin(np.clip(chord / 2.0, 0.0, 1.0))


def cap_area(half_angle: float) -> float:
    return 2.0 * math.pi * (1.0 - math.cos(min(half_angle, math.pi)))


def field_area(azimuth: float, elevation: float) -> float:
    """The solid angle of +-azimuth, +-elevation [rad]."""
    return 2.0 * min(azimuth, math.pi) * 2.0 * math.sin(min(elevation, math.pi / 2))


def grown_field_area(azimuth: float, elevation: float, by: float) -> float:
    """At least the solid angle of the directions within `by` of the field: the field with its
    elevation grown by `by` and its azimuth by the most `by` spans at that elevation."""
    top = elevation + by
    if top >= math.pi / 2 or math.sin(by) >= math.cos(top):
        return field_area(math.pi, min(top, math.pi / 2))
    return field_area(azimuth + math.asin(math.sin(by) / math.cos(top)), top)


FIELD = dict(count=st.integers(0, 200), azimuth=st.floats(0.0, 180.0), elevation=st.floats(0.0, 90.0),
             separation=st.floats(0.0, 1.0), target_az=st.floats(-180.0, 180.0), target_el=st.floats(-90.0, 90.0),
             avoid=st.floats(0.0, 1.0), seed=st.integers(0, 2 ** 32 - 1))


@settings(max_examples=80, deadline=None)
@given(**FIELD)
def test_never_more_than_the_field_holds_always_inside_it_apart_and_in_bounded_time(
        count, azimuth, elevation, separation, target_az, target_el, avoid, seed):
    rng = CountingRng(seed)
    target = np.array([[math.cos(math.radians(target_el)) * math.cos(math.radians(target_az)),
                        math.cos(math.radians(target_el)) * math.sin(math.radians(target_az)),
                        math.sin(math.radians(target_el))]])
    got = dummies.field_directions(rng, count, azimuth, elevation, separation, target, avoid)
    # bounded: never more candidates than ATTEMPTS_PER_DUMMY per dummy asked for, never more dummies
    assert rng.drawn <= 2 * dummies.ATTEMPTS_PER_DUMMY * count and len(got) <= count
    assert got.shape == (len(got), 3) and np.allclose(np.linalg.norm(got, axis=1), 1.0)
    # inside the field (an azimuth at the poles is none: not checked there)
    el = np.degrees(np.arcsin(np.clip(got[:, 2], -1.0, 1.0)))
    assert np.all(np.abs(el) <= elevation + 1e-9)
    off_pole = np.hypot(got[:, 0], got[:, 1]) > 1e-6
    assert np.all(np.abs(np.degrees(np.arctan2(got[off_pole, 1], got[off_pole, 0]))) <= azimuth + 1e-6)
    # apart from each other and from the target
    between = angles(got, got) + np.eye(len(got)) * 10.0
    assert np.all(between >= separation - 1e-9) and np.all(angles(got, target) >= avoid - 1e-9)
    # never more than fit: a cap of half the separation around each is disjoint from the others'
    assert len(got) * cap_area(separation / 2) <= grown_field_area(
        math.radians(azimuth), math.radians(elevation), separation / 2) * (1 + 1e-9) + 1e-12
    # and all of them when the field has room to spare: with every dummy and the target
    # excluding their caps, a candidate is still accepted more than half the time
    room = field_area(math.radians(azimuth), math.radians(elevation))
    if count * cap_area(separation) + cap_area(avoid) <= room / 2:
        assert len(got) == count


def test_deterministic_for_a_seed():
    a = dummies.around_eye(np.random.default_rng([3, 7]), 50, EYE, [2.0, 0.5, 1.5], 0.05, 0.05, 60.0, 30.0)
    b = dummies.around_eye(np.random.default_rng([3, 7]), 50, EYE, [2.0, 0.5, 1.5], 0.05, 0.05, 60.0, 30.0)
    c = dummies.around_eye(np.random.default_rng([3, 8]), 50, EYE, [2.0, 0.5, 1.5], 0.05, 0.05, 60.0, 30.0)
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_the_papers_field_around_the_eye_is_uniform_in_solid_angle_and_apart():
    """100 sets of 50 for targets where the study places them (2 m from the eye within the field):
    seen from the eye, at the target's distance, sin(elevation) and azimuth uniform (a
    Kolmogorov-Smirnov test on fixed seeds: deterministic), spheres and target apart."""
    targets = np.random.default_rng(11)
    sin_el, az = [], []
    for k in range(100):
        target = np.array(target_position(targets.uniform(-60, 60), targets.uniform(-30, 30), EYE[2]))
        placed = dummies.around_eye(np.random.default_rng([0, k]), 50, EYE, target, 0.05, 0.05, 60.0, 30.0)
        assert len(placed) == 50
        seen = placed - EYE
        distance = np.linalg.norm(seen, axis=1)
        assert np.allclose(distance, 2.0, atol=1e-12)
        centres = np.linalg.norm(placed[:, None] - placed[None], axis=2) + np.eye(50)
        assert centres.min() >= 2 * 0.05 - 1e-12                        # no two spheres overlap
        assert np.linalg.norm(placed - target, axis=1).min() >= 0.1 - 1e-12   # nor one the target
        sin_el += list(seen[:, 2] / distance)
        az += list(np.arctan2(seen[:, 1], seen[:, 0]))
    # (within +-30 deg uniform in elevation is nearly so too: the next test tells them apart)
    assert stats.kstest(sin_el, 'uniform', args=(-0.5, 1.0)).pvalue > 0.01
    assert stats.kstest(az, 'uniform', args=(-math.pi / 3, 2 * math.pi / 3)).pvalue > 0.01


def test_uniform_in_solid_angle_not_in_elevation():
    """Over +-80 deg of elevation, where the two differ: sin(elevation) is uniform (KS on fixed
    seeds), and the same test refuses elevations drawn uniformly (so it can tell)."""
    sin_el = np.concatenate([dummies.field_directions(np.random.default_rng([1, k]), 50, 60.0, 80.0, 0.01)[:, 2]
                             for k in range(40)])
    bound = math.sin(math.radians(80.0))
    assert len(sin_el) == 2000 and stats.kstest(sin_el, 'uniform', args=(-bound, 2 * bound)).pvalue > 0.01
    by_elevation = np.sin(np.random.default_rng(2).uniform(-math.radians(80.0), math.radians(80.0), 2000))
    assert stats.kstest(by_elevation, 'uniform', args=(-bound, 2 * bound)).pvalue < 1e-6


def test_a_field_too_small_gets_as_many_as_fit_quickly():
    rng = CountingRng(4)
    # 0.3 m spheres 2 m away within +-10 deg: a handful fit, far fewer than 200
    got = dummies.field_directions(rng, 200, 10.0, 10.0, 2 * dummies.angular_radius(0.3, 2.0))
    assert 1 <= len(got) < 20 and rng.drawn <= 2 * dummies.ATTEMPTS_PER_DUMMY * 200
    assert dummies.field_directions(np.random.default_rng(0), 0, 60.0, 30.0, 0.1).shape == (0, 3)


def test_angular_radius_is_the_cone_a_sphere_covers():
    assert dummies.angular_radius(0.05, 2.0) == math.asin(0.025)
    assert dummies.angular_radius(1.0, 0.5) == math.pi / 2                  # the eye inside the sphere
    # two dummies of radius r at distance d apart by twice it have centres exactly 2r apart
    d, r = 2.0, 0.05
    theta = 2 * dummies.angular_radius(r, d)
    assert 2 * d * math.sin(theta / 2) == pytest.approx(2 * r, rel=1e-12)
