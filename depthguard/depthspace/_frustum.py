"""The exact point-to-frustum distance of design §4, for arrays of pairs (public face of the kernel)."""

from __future__ import annotations

import numpy as np

from depthguard.kernels.frustum import frustum_nearest_many


def _run(points_camera, tangents, z_range, paper):
    # Always a writable copy: a read-only array (a broadcast point, or the caller's) would compile the kernel again.
    points = np.array(np.broadcast_to(np.asarray(points_camera, np.float64), (len(tangents), 3))
                      if np.ndim(points_camera) == 1 else points_camera, dtype=np.float64, order="C")
    tangents = np.asarray(tangents, dtype=np.float64).reshape(-1, 4)
    z_range = np.broadcast_to(np.asarray(z_range, dtype=np.float64), (len(tangents), 2))
    if points.shape != (len(tangents), 3):
        raise ValueError(f"points_camera {points.shape} and tangents {tangents.shape} do not pair up")
    bounds = np.ascontiguousarray(np.concatenate([tangents, z_range], axis=1))
    nearest = np.empty((len(points), 3))
    distance = np.empty(len(points))
    frustum_nearest_many(points, bounds, nearest, distance, paper)
    return distance, nearest


def frustum_distance(points_camera, tangents, z_range):
    """Exact distances from points to pixel frustum segments (design §4).

    Args:
        points_camera: (n, 3) float64, metres, optical frame (or (3,) for one point against every segment).
        tangents: (n, 4) float64 ``a0, a1, b0, b1``: the segment's tangents, x/z in [a0, a1], y/z in [b0, b1]
            (for pixel (u, v): a0 = (u - 1/2 - cx)/fx, a1 = (u + 1/2 - cx)/fx, b0, b1 alike with v, cy, fy).
        z_range: (n, 2) or (2,) float64 ``z_lo, z_hi`` metres (z_hi may be inf).

    Returns:
        (distance (n,) float64 metres, nearest (n, 3) float64 optical-frame points of the segments).
    """
    return _run(points_camera, tangents, z_range, False)


def paper_frustum_distance(points_camera, tangents, z_range):
    """The papers' distance at the fixed depth clamp(Z, z_lo, z_hi): an upper bound, for comparison only."""
    return _run(points_camera, tangents, z_range, True)
