"""Which control points have marked voxels nearer than a radius: the test behind the ``remembered`` flag."""

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
