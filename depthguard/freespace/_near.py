"""Which control points have marked voxels nearer than a radius (the test behind the ``remembered`` flag), and which
voxels hold a surface a camera measures now."""

from __future__ import annotations

import numpy as np

from depthguard.kernels.freespace import mark_surface_voxels, voxels_within_radii


def voxels_within(mask: np.ndarray, box, points_world: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """(n,) bool: whether some True voxel of ``mask`` (box.shape bool) comes nearer than ``radii[i]`` (metres; 0 or
    less: never) to ``points_world[i]`` ((n, 3) float64, metres, world frame): the distance from the point to the
    voxel's cube, not to its centre."""
    points = np.ascontiguousarray(points_world, dtype=np.float64).reshape(-1, 3)
    out = np.zeros(len(points), dtype=np.bool_)
    if len(points) and mask.any():
        voxels_within_radii(np.ascontiguousarray(mask, dtype=np.bool_), np.asarray(box.lo, dtype=np.float64),
                            float(box.voxel), points, np.ascontiguousarray(radii, dtype=np.float64), out)
    return out


def surface_voxels(box, camera, depth, occupancy, out: np.ndarray) -> None:
    """Mark in ``out`` (box.shape bool) the voxels that hold a surface ``camera`` measures in ``depth`` (a
    :class:`~depthguard.DepthImage`): each pixel whose prepared frame (``occupancy``) starts at a measured surface
    (a valid pixel that is not the robot), at its measured depth on the pixel's centre ray."""
    T = camera.T_world_camera
    mark_surface_voxels(depth.data, float(depth.depth_scale), occupancy.z_start, occupancy.invalid, camera.fx, camera.fy,
                   camera.cx, camera.cy, np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]),
                   np.asarray(box.lo, dtype=np.float64), float(box.voxel), out)
