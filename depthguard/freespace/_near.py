"""Which control points have marked voxels nearer than a radius (the test behind the ``remembered`` flag), and which
voxels hold a surface a camera measures now."""

from __future__ import annotations

import numpy as np
from numba import prange

from depthguard._jit import kernel


def voxels_within(mask: np.ndarray, box, points_world: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """(n,) bool: whether some True voxel of ``mask`` (box.shape bool) comes nearer than ``radii[i]`` (metres; 0 or
    less: never) to ``points_world[i]`` ((n, 3) float64, metres, world frame): the distance from the point to the
    voxel's cube, not to its centre."""
    points = np.ascontiguousarray(points_world, dtype=np.float64).reshape(-1, 3)
    out = np.zeros(len(points), dtype=np.bool_)
    if len(points) and mask.any():
        _within(np.ascontiguousarray(mask, dtype=np.bool_), np.asarray(box.lo, dtype=np.float64), float(box.voxel),
                points, np.ascontiguousarray(radii, dtype=np.float64), out)
    return out


@kernel(parallel=True)
def _within(mask, lo, voxel, points, radii, out):
    """out[p] = some True voxel of mask lies nearer than radii[p] to points[p] (the voxels of side ``voxel`` from
    corner ``lo``)."""
    nx, ny, nz = mask.shape
    for p in prange(points.shape[0]):
        out[p] = False
        r = radii[p]
        if not r > 0.0:
            continue
        r = min(r, voxel * (nx + ny + nz))  # no farther than the whole box: keeps the index range finite
        x = points[p, 0] - lo[0]
        y = points[p, 1] - lo[1]
        z = points[p, 2] - lo[2]
        i0 = max(int(np.floor((x - r) / voxel)), 0)
        i1 = min(int(np.floor((x + r) / voxel)), nx - 1)
        j0 = max(int(np.floor((y - r) / voxel)), 0)
        j1 = min(int(np.floor((y + r) / voxel)), ny - 1)
        k0 = max(int(np.floor((z - r) / voxel)), 0)
        k1 = min(int(np.floor((z + r) / voxel)), nz - 1)
        r2 = r * r
        found = False
        for i in range(i0, i1 + 1):
            dx = max(i * voxel - x, 0.0, x - (i + 1) * voxel)
            for j in range(j0, j1 + 1):
                dy = max(j * voxel - y, 0.0, y - (j + 1) * voxel)
                if dx * dx + dy * dy >= r2:
                    continue
                for k in range(k0, k1 + 1):
                    dz = max(k * voxel - z, 0.0, z - (k + 1) * voxel)
                    if mask[i, j, k] and dx * dx + dy * dy + dz * dz < r2:
                        found = True
                        break
                if found:
                    break
            if found:
                break
        out[p] = found


def surface_voxels(box, camera, depth, occupancy, out: np.ndarray) -> None:
    """Mark in ``out`` (box.shape bool) the voxels that hold a surface ``camera`` measures in ``depth`` (a
    :class:`~depthguard.DepthImage`): each pixel whose prepared frame (``occupancy``) starts at a measured surface
    (a valid pixel that is not the robot), at its measured depth on the pixel's centre ray."""
    T = camera.T_world_camera
    _mark_surfaces(depth.data, float(depth.depth_scale), occupancy.z_start, occupancy.invalid, camera.fx, camera.fy,
                   camera.cx, camera.cy, np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]),
                   np.asarray(box.lo, dtype=np.float64), float(box.voxel), out)


@kernel(parallel=True)
def _mark_surfaces(raw, scale, z_start, invalid, fx, fy, cx, cy, R, t, lo, voxel, out):
    """out[voxel of (u, v)'s measured point] = True for every pixel with a valid measurement whose z_start is finite
    (a surface, not the robot nor a hole). Rows in parallel: threads may mark the same voxel, and every write is the
    same True."""
    h, w = raw.shape
    nx, ny, nz = out.shape
    inv = 1.0 / voxel
    for v in prange(h):
        for u in range(w):
            if invalid[v, u] or not np.isfinite(z_start[v, u]):
                continue
            d = np.float64(raw[v, u]) * scale
            if not (d > 0.0 and np.isfinite(d)):
                continue
            x = (u - cx) / fx * d
            y = (v - cy) / fy * d
            i = np.floor((R[0, 0] * x + R[0, 1] * y + R[0, 2] * d + t[0] - lo[0]) * inv)
            j = np.floor((R[1, 0] * x + R[1, 1] * y + R[1, 2] * d + t[1] - lo[1]) * inv)
            k = np.floor((R[2, 0] * x + R[2, 1] * y + R[2, 2] * d + t[2] - lo[2]) * inv)
            if 0.0 <= i < nx and 0.0 <= j < ny and 0.0 <= k < nz:
                out[int(i), int(j), int(k)] = True
