"""Frames and target angles, against values worked out by hand."""
import math

import numpy as np
import pytest
from transforms3d import quaternions

from fabric_guidance.core.geometry import (GeometryError, angles_between, split_directions, target_direction,
                                           unity_to_ros_point, unity_to_ros_quaternion, wrap_deg)


def test_unity_point_to_rep103():
    # Unity (x right, y up, z forward) -> REP 103 (x forward, y left, z up) is (z, -x, y).
    assert unity_to_ros_point([1.0, 2.0, 3.0]).tolist() == [3.0, -1.0, 2.0]
    assert unity_to_ros_point([0, 0, 1]).tolist() == [1, 0, 0]     # forward stays forward
    assert unity_to_ros_point([1, 0, 0]).tolist() == [0, -1, 0]    # right is -y
    assert unity_to_ros_point([0, 1, 0]).tolist() == [0, 0, 1]     # up is +z


def test_unity_yaw_right_becomes_negative_ros_yaw():
    # Unity Quaternion.Euler(0, 90, 0) turns forward into right; in REP 103 that is yaw -90 deg.
    s = math.sin(math.pi / 4)
    q = unity_to_ros_quaternion([0.0, s, 0.0, s])
    np.testing.assert_allclose(q, [0.0, 0.0, -s, s], atol=1e-12)


def test_quaternion_conversion_commutes_with_rotating_points():
    """Rotating in Unity then converting equals converting then rotating in REP 103."""
    rng = np.random.default_rng(7)
    for _ in range(50):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        v = rng.normal(size=3)
        rotated_in_unity = quaternions.quat2mat([q[3], q[0], q[1], q[2]]) @ v
        qr = unity_to_ros_quaternion(q)
        rotated_in_ros = quaternions.quat2mat([qr[3], qr[0], qr[1], qr[2]]) @ unity_to_ros_point(v)
        np.testing.assert_allclose(rotated_in_ros, unity_to_ros_point(rotated_in_unity), atol=1e-12)
        assert qr[3] >= 0


def test_horizontal_angle_positive_left():
    a = angles_between([1, 0, 0], [1, 1, 0])
    assert a.horizontal == pytest.approx(45.0)
    assert a.vertical == pytest.approx(0.0)
    assert a.horizontal_defined


def test_unity_target_to_the_right_and_up():
    # Gaze forward in Unity, target forward-right-up at (1, 1, 1)/... in Unity.
    gaze = unity_to_ros_point([0, 0, 1])
    target = unity_to_ros_point([1, 0, 1])          # 45 deg to the right on the horizontal plane
    assert angles_between(gaze, target).horizontal == pytest.approx(-45.0)
    target = unity_to_ros_point([0, 1, 1])          # 45 deg up in the sagittal plane
    assert angles_between(gaze, target).vertical == pytest.approx(45.0)
    # Elevation: target (1, 0, 1) REP 103 is 45 deg above the horizon, gaze level.
    assert angles_between([1, 0, 0], [1, 0, 1]).vertical == pytest.approx(45.0)
    # 36 deg right and 12 deg up, built from yaw/pitch, comes back as (-36, 12).
    y, p = math.radians(-36), math.radians(12)
    t = [math.cos(p) * math.cos(y), math.cos(p) * math.sin(y), math.sin(p)]
    a = angles_between([1, 0, 0], t)
    assert (a.horizontal, a.vertical) == (pytest.approx(-36.0), pytest.approx(12.0))


def test_horizontal_angle_wraps_through_180():
    # Gaze at azimuth 170 deg, target at -170 deg: the short way is 20 deg further left.
    g = [math.cos(math.radians(170)), math.sin(math.radians(170)), 0]
    t = [math.cos(math.radians(-170)), math.sin(math.radians(-170)), 0]
    assert angles_between(g, t).horizontal == pytest.approx(20.0)
    assert angles_between(t, g).horizontal == pytest.approx(-20.0)


def test_wrap_deg():
    assert wrap_deg(180.0) == 180.0
    assert wrap_deg(-180.0) == 180.0
    assert wrap_deg(190.0) == pytest.approx(-170.0)
    assert wrap_deg(-540.0) == 180.0
    assert wrap_deg(725.0) == pytest.approx(5.0)
    with pytest.raises(GeometryError):
        wrap_deg(float('nan'))


def test_split_into_the_four_directions():
    # k = left, right, down, up: 30 deg left and 10 deg down.
    assert split_directions(30.0, -10.0).tolist() == [30.0, -30.0, 10.0, -10.0]


def test_gaze_straight_up_has_no_horizontal_angle():
    a = angles_between([0, 0, 1], [1, 0, 0])
    assert not a.horizontal_defined
    assert a.horizontal == 0.0
    assert a.vertical == pytest.approx(-90.0)


@pytest.mark.parametrize('bad', [[0, 0, 0], [float('nan'), 0, 1], [float('inf'), 0, 0], [1, 2]])
def test_degenerate_vectors_raise_geometry_error(bad):
    with pytest.raises(GeometryError):
        angles_between(bad, [1, 0, 0])


def test_target_direction_from_eye_to_target():
    d = target_direction([0, 0, 1.6], [2, 2, 1.6])
    np.testing.assert_allclose(d, [math.sqrt(0.5), math.sqrt(0.5), 0.0])
    with pytest.raises(GeometryError, match='zero length'):
        target_direction([1, 1, 1], [1, 1, 1])


def test_gaze_ray_as_a_pose_orientation_round_trips():
    from fabric_guidance.core.geometry import ray_direction, ray_orientation
    rng = np.random.default_rng(2)
    for _ in range(100):
        d = rng.normal(size=3)
        q = ray_orientation(d)
        np.testing.assert_allclose(ray_direction(q), d / np.linalg.norm(d), atol=1e-12)
        y_axis = quaternions.quat2mat([q[3], q[0], q[1], q[2]])[:, 1]
        assert abs(y_axis[2]) < 1e-12                    # no roll: the y axis stays horizontal
    # 30 deg up and 90 deg left: yaw +90, pitch -30 in REP 103 (positive pitch looks down).
    q = ray_orientation([0.0, math.cos(math.radians(30)), math.sin(math.radians(30))])
    np.testing.assert_allclose(ray_direction(q), [0.0, math.cos(math.radians(30)), 0.5], atol=1e-12)
    with pytest.raises(GeometryError):
        ray_orientation([0, 0, 0])
