"""Frames and the paper's target angles.

Frames
------
Unity (the HoloLens app) is left-handed with x right, y up, z forward. ROS uses REP 103:
right-handed, x forward, y left, z up. A point or direction (x_u, y_u, z_u) is
(z_u, -x_u, y_u) in REP 103. The basis change M below has determinant -1 (it flips
handedness), so a Unity rotation R becomes M R M^T, which is again a proper rotation.

Angles
------
The paper splits the angle between gaze and target into a horizontal part (projection on the
horizontal plane: left/right twist) and a vertical part (projection on the sagittal plane:
backward/forward bend). Here the horizontal angle is the difference of azimuths (angle of each
vector's projection on the horizontal plane, wrapped to (-180, 180]) and the vertical angle the
difference of elevations (angle of each vector within the vertical plane that contains it).
When the wearer faces forward this is exactly the paper's xz / yz projection in Unity; unlike a
projection on the fixed yz plane it stays defined when the wearer has turned sideways.

Signs follow REP 103: a positive horizontal angle is to the wearer's left, a positive vertical
angle is upward. Direction k of the paper: 1 left twist, 2 right twist, 3 forward bend (down),
4 backward bend (up).
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Sequence

import numpy as np
from transforms3d import quaternions

#: The paper's directions in index order k-1: left twist, right twist, forward bend, backward bend.
DIRECTIONS: tuple[str, ...] = ('left', 'right', 'down', 'up')

#: Below this norm a vector (or its horizontal projection) has no usable direction.
MIN_NORM = 1e-9

# Unity (x right, y up, z forward) to REP 103 (x forward, y left, z up).
_UNITY_TO_ROS = np.array([[0.0, 0.0, 1.0],
                          [-1.0, 0.0, 0.0],
                          [0.0, 1.0, 0.0]])


class GeometryError(ValueError):
    """A vector or quaternion that has no usable direction (zero length, NaN, inf)."""


def _finite_vector(v: Sequence[float], name: str) -> np.ndarray:
    arr = np.asarray(v, dtype=float)
    if arr.shape != (3,):
        raise GeometryError(f'{name} must have 3 components, got shape {arr.shape}')
    if not np.all(np.isfinite(arr)):
        raise GeometryError(f'{name} has a non-finite component: {arr.tolist()}')
    return arr


_isfinite = math.isfinite


def _xyz(v: Sequence[float], name: str) -> tuple[float, float, float]:
    """v as three finite floats. The control loop calls this many times per step, so a plain
    3-sequence of finite numbers takes scalar math; anything else goes through numpy, which
    also raises the error that names what is wrong."""
    t = type(v)
    if (t is np.ndarray and v.shape == (3,)) or ((t is list or t is tuple) and len(v) == 3):
        try:
            x, y, z = float(v[0]), float(v[1]), float(v[2])
        except (TypeError, ValueError):
            pass
        else:
            if _isfinite(x) and _isfinite(y) and _isfinite(z):
                return x, y, z
    arr = _finite_vector(v, name)
    return float(arr[0]), float(arr[1]), float(arr[2])


def _xyzw(q: Sequence[float]) -> tuple[float, float, float, float]:
    """A quaternion (x, y, z, w) as four finite floats (the fast path of _xyz, for 4)."""
    t = type(q)
    if (t is np.ndarray and q.shape == (4,)) or ((t is list or t is tuple) and len(q) == 4):
        try:
            x, y, z, w = float(q[0]), float(q[1]), float(q[2]), float(q[3])
        except (TypeError, ValueError):
            pass
        else:
            if _isfinite(x) and _isfinite(y) and _isfinite(z) and _isfinite(w):
                return x, y, z, w
    arr = np.asarray(q, dtype=float)
    if arr.shape != (4,) or not np.all(np.isfinite(arr)):
        raise GeometryError(f'quaternion must be 4 finite numbers (x, y, z, w), got {arr.tolist()}')
    return float(arr[0]), float(arr[1]), float(arr[2]), float(arr[3])


def _norm3(x: float, y: float, z: float, name: str) -> float:
    n = math.hypot(x, y, z)  # no overflow for large finite components
    if not n > MIN_NORM:
        raise GeometryError(f'{name} has zero length')
    return n


def _unit(arr: np.ndarray, name: str) -> np.ndarray:
    # Scale by the largest component first: |v|**2 would overflow beyond ~1e154.
    scale = float(np.max(np.abs(arr)))
    if not scale > 0.0 or not scale * float(np.linalg.norm(arr / scale)) > MIN_NORM:
        raise GeometryError(f'{name} has zero length')
    scaled = arr / scale
    return scaled / np.linalg.norm(scaled)


def unit_vector(v: Sequence[float], name: str = 'vector') -> np.ndarray:
    """v scaled to length 1; GeometryError for a zero-length or non-finite vector."""
    x, y, z = _xyz(v, name)
    n = _norm3(x, y, z, name)
    return np.array([x / n, y / n, z / n])


def unity_to_ros_point(p: Sequence[float]) -> np.ndarray:
    """A point or direction from Unity's left-handed y-up frame to REP 103 (same units)."""
    return _UNITY_TO_ROS @ _finite_vector(p, 'point')


def unity_to_ros_quaternion(q_xyzw: Sequence[float]) -> np.ndarray:
    """An orientation (x, y, z, w) from Unity's frame to REP 103, returned as (x, y, z, w).

    Raises GeometryError for a zero or non-finite quaternion; normalises otherwise.
    """
    q = np.asarray(q_xyzw, dtype=float)
    if q.shape != (4,) or not np.all(np.isfinite(q)):
        raise GeometryError(f'quaternion must be 4 finite numbers (x, y, z, w), got {q.tolist()}')
    x, y, z, w = _unit(q, 'quaternion')
    rot_unity = quaternions.quat2mat([w, x, y, z])
    rot_ros = _UNITY_TO_ROS @ rot_unity @ _UNITY_TO_ROS.T
    w2, x2, y2, z2 = quaternions.mat2quat(rot_ros)
    out = np.array([x2, y2, z2, w2])
    # One sign for one orientation, so that equal inputs give equal messages.
    return out if out[3] >= 0 else -out


def wrap_deg(angle: float) -> float:
    """Wrap an angle in degrees to (-180, 180]."""
    if not math.isfinite(angle):
        raise GeometryError(f'angle is not finite: {angle}')
    wrapped = math.fmod(angle, 360.0)
    if wrapped > 180.0:
        wrapped -= 360.0
    elif wrapped <= -180.0:
        wrapped += 360.0
    return wrapped


def azimuth_deg(v: Sequence[float]) -> float | None:
    """Angle of the horizontal projection of v (REP 103), degrees, positive to the left.

    None when the projection vanishes (v points straight up or down).
    """
    x, y, z = _xyz(v, 'vector')
    if math.hypot(x, y) <= 1e-6 * _norm3(x, y, z, 'vector'):
        return None
    return math.degrees(math.atan2(y, x))


def elevation_deg(v: Sequence[float]) -> float:
    """Angle of v above the horizontal plane (REP 103), degrees in [-90, 90]."""
    x, y, z = _xyz(v, 'vector')
    _norm3(x, y, z, 'vector')
    return math.degrees(math.atan2(z, math.hypot(x, y)))


@dataclass(frozen=True)
class GazeAngles:
    """Signed angles from one direction (the gaze) to another (the target), degrees.

    horizontal: positive to the left; vertical: positive upward. horizontal_defined is False
    when either vector points straight up or down, where the horizontal angle is meaningless;
    horizontal is then 0 so that no twist is commanded.
    """

    horizontal: float
    vertical: float
    horizontal_defined: bool = True

    def by_direction(self) -> np.ndarray:
        """The four non-negative direction angles theta_k (left, right, down, up)."""
        return split_directions(self.horizontal, self.vertical)


def split_directions(horizontal: float, vertical: float) -> np.ndarray:
    """Signed horizontal/vertical angles to theta_k for k = left, right, down, up.

    Each theta_k is the component of the angle in direction k, so at most one of a pair is
    positive and the other is its negative (a move in the opposite direction).
    """
    return np.array([horizontal, -horizontal, -vertical, vertical], dtype=float)


def angles_between(gaze: Sequence[float], target: Sequence[float]) -> GazeAngles:
    """The paper's horizontal and vertical angles from a gaze direction to a target direction.

    Both are directions in the same frame (REP 103). Raises GeometryError for a zero-length or
    non-finite vector.
    """
    az_g = azimuth_deg(gaze)
    az_t = azimuth_deg(target)
    vertical = elevation_deg(target) - elevation_deg(gaze)
    if az_g is None or az_t is None:
        return GazeAngles(0.0, vertical, horizontal_defined=False)
    return GazeAngles(wrap_deg(az_t - az_g), vertical)


def target_direction(eye: Sequence[float], target: Sequence[float]) -> np.ndarray:
    """Unit vector from the eye (gaze origin) to a target position, REP 103."""
    ex, ey, ez = _xyz(eye, 'gaze origin')
    tx, ty, tz = _xyz(target, 'target position')
    return unit_vector((tx - ex, ty - ey, tz - ez), 'target relative to the gaze origin')


def ray_orientation(direction: Sequence[float]) -> np.ndarray:
    """Quaternion (x, y, z, w) of a frame whose x axis points along `direction`, with no roll
    (its y axis stays horizontal): how the gaze ray travels as a geometry_msgs/Pose."""
    x, y, z = _xyz(direction, 'gaze direction')
    _norm3(x, y, z, 'gaze direction')
    yaw = math.atan2(y, x)
    pitch = -math.atan2(z, math.hypot(x, y))  # REP 103: positive pitch looks down
    # transforms3d's euler2quat(0, pitch, yaw, 'sxyz') = q_z(yaw) * q_y(pitch), written out
    # (the library call alone costs ~20 us per gaze sample).
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    return np.array([-sy * sp, cy * sp, sy * cp, cy * cp])


def ray_direction(q_xyzw: Sequence[float]) -> np.ndarray:
    """The unit x axis of an orientation (x, y, z, w): the gaze direction of a gaze pose."""
    x, y, z, w = _xyzw(q_xyzw)
    n = math.hypot(x, y, z, w)
    if not n > MIN_NORM:
        raise GeometryError('quaternion has zero length')
    x, y, z, w = x / n, y / n, z / n, w / n
    # The first column of the quaternion's rotation matrix.
    return np.array([1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + z * w), 2.0 * (x * z - y * w)])
