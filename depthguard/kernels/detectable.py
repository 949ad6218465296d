"""Kernels of the detectable space (``depthguard.freespace.DetectableSpace``, design §9): erosion by a ball of
diameter d in voxels, distances to what stays, and marking the voxels the robot and known solids fill.

Voxel arrays are (nx, ny, nz) bool, C order, indexed [i, j, k] along world x, y, z; ``lo``: (3,) float64 metres,
the box's near corner in the world frame (a number in :func:`to_interval`); ``voxel``: the side s, metres.

Arguments used throughout:

- ``voxel``: float, metres: the side s of the box's voxels.
- ``free``: (nx, ny, nz) bool: the voxels certified free entirely (seen free by some camera, inside the robot's zone,
  inside a known solid).
- ``fits``: (nx, ny, nz) bool: E_vox, the voxels that may hold the centre of a ball of diameter d lying in possibly
  occupied space.
- ``counts``: (bx, by, bz) int32, bx = ceil(nx / block) and so on: how many True voxels of ``fits`` each block holds.
- ``block``: int, voxels: the side of the blocks that ``counts`` counts (``BLOCK`` of
  ``depthguard/freespace/_detectable.py``).
"""

import math

import numpy as np
from numba import prange

from depthguard.kernels.jit import kernel


@kernel(parallel=True)
def erode_fits(free, offsets, block, fits, counts):
    """fits[v] = v is not free and no voxel at one of ``offsets`` ((k, 3) int64, voxels: the offsets o != 0 with
    |o| s <= r) from v is free (beyond the array: not free); counts[block] = how many True voxels of ``fits`` it holds
    (blocks of ``block`` voxels a side). Writes fits and counts."""
    nx, ny, nz = free.shape
    bx, by, bz = counts.shape
    for p in prange(bx * by * bz):
        c0 = p % bz
        b0 = (p // bz) % by
        a0 = p // (bz * by)
        n = 0
        for i in range(a0 * block, min((a0 + 1) * block, nx)):
            for j in range(b0 * block, min((b0 + 1) * block, ny)):
                for k in range(c0 * block, min((c0 + 1) * block, nz)):
                    keep = not free[i, j, k]
                    if keep:
                        for o in range(offsets.shape[0]):
                            a = i + offsets[o, 0]
                            b = j + offsets[o, 1]
                            c = k + offsets[o, 2]
                            if 0 <= a < nx and 0 <= b < ny and 0 <= c < nz and free[a, b, c]:
                                keep = False
                                break
                    fits[i, j, k] = keep
                    if keep:
                        n += 1
        counts[a0, b0, c0] = n


@kernel(parallel=True)
def or_coarse(free, coarse, ratio):
    """free[i, j, k] |= coarse[i // ratio, j // ratio, k // ratio] (a coarser box of voxels ``ratio`` times as big
    with the same near corner). coarse: (mx, my, mz) bool, the coarser box's voxels certified free
    (mx * ratio >= nx, and so on); ratio: int >= 1."""
    nx, ny, nz = free.shape
    for i in prange(nx):
        for j in range(ny):
            for k in range(nz):
                if coarse[i // ratio, j // ratio, k // ratio]:
                    free[i, j, k] = True


@kernel(inline=True)
def to_interval(x, lo, hi):
    """The distance from x to the interval [lo, hi] along one axis (float64 each, metres, lo <= hi), 0 inside."""
    return max(lo - x, 0.0, x - hi)


@kernel(parallel=True)
def nearest_fit(fits, counts, block, lo, voxel, beyond, points, limit, out):
    """out[p] = min(distance from points[p] to the nearest True voxel's cube, to the outside of the box (beyond[f]
    metres past face f), limit); 0 for a point outside the box.

    points: (n, 3) float64, metres, world frame; lo: (3,) float64, metres, the box's near corner (world frame); beyond:
    (6,) float64, metres, for the faces at lo x, hi x, lo y, hi y, lo z, hi z; limit: float, metres (may be inf); out:
    (n,) float64, metres, written. fits and counts as :func:`erode_fits` wrote them, with its ``block``."""
    nx, ny, nz = fits.shape
    bx, by, bz = counts.shape
    side = block * voxel
    for p in prange(points.shape[0]):
        x = points[p, 0] - lo[0]
        y = points[p, 1] - lo[1]
        z = points[p, 2] - lo[2]
        if min(x, nx * voxel - x, y, ny * voxel - y, z, nz * voxel - z) <= 0.0:
            out[p] = 0.0
            continue
        best = min(x + beyond[0], nx * voxel - x + beyond[1], y + beyond[2], ny * voxel - y + beyond[3],
                   z + beyond[4], nz * voxel - z + beyond[5], limit)
        near = np.empty(bx * by * bz)
        index = np.empty(bx * by * bz, dtype=np.int64)
        m = 0
        for a in range(bx):
            dx = to_interval(x, a * side, (a + 1) * side)
            if dx >= best:
                continue
            for b in range(by):
                dy = to_interval(y, b * side, (b + 1) * side)
                if dx * dx + dy * dy >= best * best:
                    continue
                for c in range(bz):
                    if counts[a, b, c] == 0:
                        continue
                    dz = to_interval(z, c * side, (c + 1) * side)
                    d = math.sqrt(dx * dx + dy * dy + dz * dz)
                    if d < best:
                        near[m] = d
                        index[m] = (a * by + b) * bz + c
                        m += 1
        order = np.argsort(near[:m])
        for n in range(m):
            if near[order[n]] >= best:
                break
            flat = index[order[n]]
            c = flat % bz
            b = (flat // bz) % by
            a = flat // (bz * by)
            for i in range(a * block, min((a + 1) * block, nx)):
                dx = to_interval(x, i * voxel, (i + 1) * voxel)
                if dx >= best:
                    continue
                for j in range(b * block, min((b + 1) * block, ny)):
                    dy = to_interval(y, j * voxel, (j + 1) * voxel)
                    if dx * dx + dy * dy >= best * best:
                        continue
                    for k in range(c * block, min((c + 1) * block, nz)):
                        if fits[i, j, k]:
                            dz = to_interval(z, k * voxel, (k + 1) * voxel)
                            d = math.sqrt(dx * dx + dy * dy + dz * dz)
                            if d < best:
                                best = d
        out[p] = best


@kernel()
def mark_capsule_voxels(lo, voxel, capsules, zone, out):
    """out[v] = True for the voxels whose centre lies within radius + zone - voxel sqrt(3) / 2 of a capsule's
    segment (capsules (n, 7) float64, metres, world frame: p0 (3), p1 (3), radius). zone: float, metres; lo: (3,)
    float64, metres, the box's near corner (world frame); out: (nx, ny, nz) bool, only set (never cleared)."""
    nx, ny, nz = out.shape
    half_diagonal = 0.5 * math.sqrt(3.0) * voxel
    for n in range(capsules.shape[0]):
        p0 = capsules[n, 0:3]
        p1 = capsules[n, 3:6]
        reach = capsules[n, 6] + zone - half_diagonal
        if not reach > 0.0:
            continue
        d = np.empty(3)
        for a in range(3):
            d[a] = p1[a] - p0[a]
        length2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
        i0 = max(int(math.floor((min(p0[0], p1[0]) - reach - lo[0]) / voxel)), 0)
        i1 = min(int(math.ceil((max(p0[0], p1[0]) + reach - lo[0]) / voxel)), nx - 1)
        j0 = max(int(math.floor((min(p0[1], p1[1]) - reach - lo[1]) / voxel)), 0)
        j1 = min(int(math.ceil((max(p0[1], p1[1]) + reach - lo[1]) / voxel)), ny - 1)
        k0 = max(int(math.floor((min(p0[2], p1[2]) - reach - lo[2]) / voxel)), 0)
        k1 = min(int(math.ceil((max(p0[2], p1[2]) + reach - lo[2]) / voxel)), nz - 1)
        for i in range(i0, i1 + 1):
            cx = lo[0] + (i + 0.5) * voxel - p0[0]
            for j in range(j0, j1 + 1):
                cy = lo[1] + (j + 0.5) * voxel - p0[1]
                for k in range(k0, k1 + 1):
                    cz = lo[2] + (k + 0.5) * voxel - p0[2]
                    t = 0.0
                    if length2 > 0.0:
                        t = min(max((cx * d[0] + cy * d[1] + cz * d[2]) / length2, 0.0), 1.0)
                    ex = cx - t * d[0]
                    ey = cy - t * d[1]
                    ez = cz - t * d[2]
                    if ex * ex + ey * ey + ez * ez <= reach * reach:
                        out[i, j, k] = True


@kernel(parallel=True)
def mark_box_voxels(lo, voxel, center, half, R, out):
    """out[v] = True for the voxels whose centre lies at least voxel sqrt(3) / 2 inside every face of the box
    (centre, half extents, R_world_box). center: (3,) float64, metres, world frame; half: (3,) float64, metres, the
    half extents along the box's own axes; R: (3, 3) float64, box frame -> world (its columns are the box's axes);
    lo: (3,) float64, metres, the voxels' near corner (world frame); out: (nx, ny, nz) bool, only set (never
    cleared)."""
    nx, ny, nz = out.shape
    inner = np.empty(3)
    for a in range(3):
        inner[a] = half[a] - 0.5 * math.sqrt(3.0) * voxel
    if inner[0] <= 0.0 or inner[1] <= 0.0 or inner[2] <= 0.0:
        return
    for i in prange(nx):
        x = lo[0] + (i + 0.5) * voxel - center[0]
        for j in range(ny):
            y = lo[1] + (j + 0.5) * voxel - center[1]
            for k in range(nz):
                z = lo[2] + (k + 0.5) * voxel - center[2]
                inside = True
                for a in range(3):
                    if abs(R[0, a] * x + R[1, a] * y + R[2, a] * z) > inner[a]:
                        inside = False
                        break
                if inside:
                    out[i, j, k] = True
