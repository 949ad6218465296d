"""The two distance methods the depth-space approach is compared against (never for safety use).

- :func:`cartesian_region_distances`: the 2015 paper's Cartesian approach (its section 4): back-project the pixels of
  each control point's surveillance window and take the nearest point. It ignores pixel size and hidden space.
- :func:`kdtree_distances`: the common practice: back-project the whole image to a point cloud, build a KD-tree
  (scipy ``cKDTree``) on every new frame and query it.

Both return (distance (n,) float64 metres, inf when no point lies within rho; direction (n, 3) float64 world-frame
unit vectors from the nearest point towards the control point, zero when none).
"""

from __future__ import annotations

import numpy as np
from numba import prange
from scipy.spatial import cKDTree

from depthguard import config
from depthguard.kernels.jit import kernel
from depthguard.depth import DepthImage
from depthguard.validation import check_points
from depthguard.kernels.frustum import cube_window


def valid_metres(depth: DepthImage, camera) -> np.ndarray:
    """(h, w) float64 metres, 0 where there is no valid measurement (outside the camera's range too): the form the
    baselines work on, to convert once per frame."""
    d = depth.metres().astype(np.float64)
    z_min, z_max = camera.depth_range
    d[~((d >= z_min) & (d <= z_max))] = 0.0
    return d


@kernel(parallel=True)
def _nearest_points_in_windows(depth_m, points_camera, rho, fx, fy, cx, cy, near_eps, distance, direction):
    height, width = depth_m.shape
    for i in prange(points_camera.shape[0]):
        X = points_camera[i, 0]
        Y = points_camera[i, 1]
        Z = points_camera[i, 2]
        u_lo, u_hi, v_lo, v_hi = cube_window(X, Y, Z, rho, fx, fy, cx, cy, width, height, near_eps)
        best = rho * rho
        bx = 0.0
        by = 0.0
        bz = 0.0
        for v in range(v_lo, v_hi + 1):
            for u in range(u_lo, u_hi + 1):
                d = depth_m[v, u]
                if not (d > 0.0):
                    continue
                ox = X - (u - cx) / fx * d
                oy = Y - (v - cy) / fy * d
                oz = Z - d
                d2 = ox * ox + oy * oy + oz * oz
                if d2 < best:
                    best = d2
                    bx = ox
                    by = oy
                    bz = oz
        if best < rho * rho:
            r = np.sqrt(best)
            distance[i] = r
            if r > 0.0:
                direction[i, 0] = bx / r
                direction[i, 1] = by / r
                direction[i, 2] = bz / r
        else:
            distance[i] = np.inf


def cartesian_region_distances(depth, camera, points_world, rho: float = config.DEFAULT_RHO):
    """The paper's Cartesian baseline: nearest back-projected pixel centre within each control point's window.

    ``depth``: a :class:`DepthImage`, or its :func:`valid_metres` computed once per frame.
    """
    points = check_points(points_world)
    depth_m = valid_metres(depth, camera) if isinstance(depth, DepthImage) else depth
    distance = np.full(len(points), np.inf)
    direction = np.zeros((len(points), 3))
    if len(points):
        _nearest_points_in_windows(depth_m, np.ascontiguousarray(camera.world_to_camera(points)), float(rho),
                                   camera.fx, camera.fy, camera.cx, camera.cy, config.NEAR_PLANE_EPSILON, distance,
                                   direction)
    return distance, direction @ camera.T_world_camera[:3, :3].T


def point_cloud(depth: DepthImage, camera) -> np.ndarray:
    """(m, 3) float64 world-frame points of every valid pixel (pixel centres back-projected at their depth)."""
    depth_m = valid_metres(depth, camera)
    valid = depth_m > 0
    v, u = np.nonzero(valid)
    return camera.camera_to_world(camera.back_project(u, v, depth_m[valid]))


def kdtree_distances(depth: DepthImage, camera, points_world, rho: float = config.DEFAULT_RHO):
    """The practical baseline: KD-tree over the whole back-projected cloud, built for this frame, then queried."""
    points = check_points(points_world)
    cloud = point_cloud(depth, camera)
    distance = np.full(len(points), np.inf)
    direction = np.zeros((len(points), 3))
    if len(cloud) == 0 or len(points) == 0:
        return distance, direction
    tree = cKDTree(cloud)
    d, index = tree.query(points, k=1, distance_upper_bound=rho)
    hit = np.isfinite(d) & (d < rho)
    distance[hit] = d[hit]
    nonzero = hit & (d > 0)
    direction[nonzero] = (points[nonzero] - cloud[index[nonzero]]) / d[nonzero, None]
    return distance, direction
