"""Rigid transforms as 4x4 homogeneous matrices, named ``T_a_b``: they map coordinates in frame b to frame a.

``T_world_camera`` maps camera coordinates to world coordinates, so ``p_world = T_world_camera @ p_camera``.
Compose with :func:`concat` (``concat(T_a_b, T_b_c)`` gives ``T_a_c``) and invert with :func:`invert`.
"""

from __future__ import annotations

import math

import numpy as np



def invert(T_a_b: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform: ``T_b_a`` from ``T_a_b``, both (4, 4) float64."""
    R = T_a_b[:3, :3]
    T_b_a = np.eye(4)
    T_b_a[:3, :3] = R.T
    T_b_a[:3, 3] = -R.T @ T_a_b[:3, 3]
    return T_b_a


def concat(T_a_b: np.ndarray, T_b_c: np.ndarray) -> np.ndarray:
    """``T_a_c`` from ``T_a_b`` and ``T_b_c``, all (4, 4) float64."""
    return T_a_b @ T_b_c


def transform_points(T_a_b: np.ndarray, points_b: np.ndarray) -> np.ndarray:
    """Map (n, 3) points from frame b to frame a with the (4, 4) transform ``T_a_b``; returns (n, 3) float64."""
    points_b = np.asarray(points_b, dtype=np.float64)
    return points_b @ T_a_b[:3, :3].T + T_a_b[:3, 3]


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """``T_world_camera`` of an optical frame (x right, y down, z forward) at ``eye`` looking at ``target``.

    ``eye``, ``target``: (3,) metres, world frame. ``up``: (3,) world direction that appears upwards in the image
    (it must not be parallel to the viewing direction).
    """
    eye = np.asarray(eye, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("look_at: 'up' is parallel to the viewing direction")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, eye
    return T


def yaw_pose(position, yaw: float) -> np.ndarray:
    """(4, 4) float64: a pose at ``position`` ((3,) metres) turned by ``yaw`` radians about the z axis."""
    T = np.eye(4)
    c, s = math.cos(yaw), math.sin(yaw)
    T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = position
    return T


def rotation_with_z(axis) -> np.ndarray:
    """(3, 3) rotation whose third column is the unit vector ``axis`` ((3,)); its first column is
    (1, 0, 0) x axis normalised (or (0, 1, 0) x axis when axis is within 26 degrees of the x axis)."""
    a0, a1, a2 = (float(v) for v in axis)
    # the cross products written out: numpy's cross costs 40 us a call, and the loop's ground truth makes thousands
    x0, x1, x2 = (0.0, -a2, a1) if abs(a0) < 0.9 else (a2, 0.0, -a0)
    norm = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
    x0, x1, x2 = x0 / norm, x1 / norm, x2 / norm
    return np.array([[x0, a1 * x2 - a2 * x1, a0],
                     [x1, a2 * x0 - a0 * x2, a1],
                     [x2, a0 * x1 - a1 * x0, a2]])


def quaternion_to_matrix(qx: float, qy: float, qz: float, qw: float) -> np.ndarray:
    """(3, 3) rotation matrix of a unit quaternion given as x, y, z, w (the ROS order)."""
    q = np.array([qw, qx, qy, qz], dtype=np.float64)
    n = np.linalg.norm(q)
    if not np.isfinite(n) or n < 1e-12:
        raise ValueError("quaternion has zero or non-finite norm")
    w, x, y, z = q / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
