"""Kernels of the detectable space (``depthguard.freespace.DetectableSpace``, design §9): erosion by a ball of
diameter d in voxels, distances to what stays, and marking the voxels the robot and known solids fill.

Voxel arrays are (nx, ny, nz) bool, C order, indexed [i, j, k] along world x, y, z; ``lo``: (3,) float64 metres,
the box's near corner in the world frame (a number in :func:`to_interval`); ``voxel``: the side s, metres.

Arguments used throughout:

- ``lo``: (3,) float64, metres, world frame: the box's near corner.
- ``voxel``: float, metres: the side s of the box's voxels.
- ``free``: (nx, ny, nz) bool: the voxels certified free entirely (seen free by some camera, inside the robot's zone,
  inside a known solid).
- ``fits``: (nx, ny, nz) bool: E_vox, the voxels that may hold the centre of a ball of diameter d lying in possibly
  occupied space.
- ``counts``: (bx, by, bz) int32, bx = ceil(nx / block) and so on: how many True voxels of ``fits`` each block holds.
- ``block``: int, voxels: the side of the blocks that ``counts`` counts (``BLOCK`` of
  ``depthguard/freespace/_detectable.py``).
- ``free_b``, ``fits_b``: (bx, by, bz, block, block, block) bool: a watched space's ``free`` and ``fits`` stored
  block-major (below), valid in the blocks whose ``state`` says so.
- ``state``: (bx, by, bz) uint8: per block of a watched space, FREE_DONE once its ``free_b`` is written, FITS_DONE
  once its ``fits_b`` and ``counts`` are.
- ``shape``: (3,) int64, voxels: the box's (nx, ny, nz).
"""

import math

import numpy as np
from numba import prange

from depthguard.kernels.freespace import block_scratch, seen_free_block
from depthguard.kernels.jit import kernel


@kernel(parallel=True)
def erode_fits(free, offsets, block, fits, counts):
    """fits[v] = v is not free and no voxel at one of ``offsets`` ((k, 3) int64, voxels: the offsets o != 0 with
    |o| s <= r) from v is free (beyond the array: not free); counts[block] = how many True voxels of ``fits`` it holds
    (blocks of ``block`` voxels a side). Writes fits and counts."""
    nx, ny, nz = free.shape
    bx, by, bz = counts.shape
    for p in prange(bx * by * bz):
        a0, b0, c0 = unflatten(np.int64(p), by, bz)
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


@kernel(inline=True)
def unflatten(flat, by, bz):
    """Block (a, b, c) of the flat index (a * by + b) * bz + c (int64), blocks (bx, by, bz)."""
    return flat // (bz * by), (flat // bz) % by, flat % bz


@kernel(inline=True)
def box_start(x, y, z, shape, voxel, beyond, limit):
    """Where a nearest-fit search from the point (x, y, z) (metres from the box's near corner) starts: (outside the
    box?, the distance to the box's outside, beyond[f] metres past face f, or ``limit`` if nearer). shape: (nx, ny,
    nz); beyond: (6,) float64, metres."""
    nx, ny, nz = shape[0], shape[1], shape[2]
    if min(x, nx * voxel - x, y, ny * voxel - y, z, nz * voxel - z) <= 0.0:
        return True, 0.0
    return False, min(x + beyond[0], nx * voxel - x + beyond[1], y + beyond[2], ny * voxel - y + beyond[3],
                      z + beyond[4], nz * voxel - z + beyond[5], limit)


@kernel(inline=True)
def scan_block(cube, i0, j0, k0, voxel, x, y, z, best):
    """The smallest distance below ``best`` from (x, y, z) (metres from the box's near corner) to the cube of a True
    voxel of ``cube`` (a 3-D bool array: the voxels from (i0, j0, k0) on, as many as it holds); ``best`` if none is
    nearer."""
    for da in range(cube.shape[0]):
        i = i0 + da
        dx = to_interval(x, i * voxel, (i + 1) * voxel)
        if dx >= best:
            continue
        for db in range(cube.shape[1]):
            j = j0 + db
            dy = to_interval(y, j * voxel, (j + 1) * voxel)
            if dx * dx + dy * dy >= best * best:
                continue
            for dc in range(cube.shape[2]):
                if cube[da, db, dc]:
                    k = k0 + dc
                    dz = to_interval(z, k * voxel, (k + 1) * voxel)
                    d = math.sqrt(dx * dx + dy * dy + dz * dz)
                    if d < best:
                        best = d
    return best


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
        outside, best = box_start(x, y, z, fits.shape, voxel, beyond, limit)
        if outside:
            out[p] = 0.0
            continue
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
            a, b, c = unflatten(index[order[n]], by, bz)
            best = scan_block(fits[a * block:(a + 1) * block, b * block:(b + 1) * block, c * block:(c + 1) * block],
                              a * block, b * block, c * block, voxel, x, y, z, best)
        out[p] = best


@kernel(inline=True)
def within_segment(cx, cy, cz, d, length2, reach):
    """Whether the point (cx, cy, cz) (metres, relative to a segment's start p0) lies within ``reach`` metres of the
    segment p0 + t d, t in [0, 1] (d (3,) metres, length2 = |d|^2), in the arithmetic every voxel test of a capsule
    uses (:func:`mark_capsule_voxels`, :func:`fill_free_blocks`)."""
    t = 0.0
    if length2 > 0.0:
        t = min(max((cx * d[0] + cy * d[1] + cz * d[2]) / length2, 0.0), 1.0)
    ex = cx - t * d[0]
    ey = cy - t * d[1]
    ez = cz - t * d[2]
    return ex * ex + ey * ey + ez * ez <= reach * reach


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
                    if within_segment(cx, cy, cz, d, length2, reach):
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


# ------------------------------------------------------------------------- the same space, block by block on demand
#
# A watched detectable space (``DetectableSpace.watch``) computes the voxels certified free, and E_vox, only in the
# blocks a distance query reaches. Its arrays are block-major: ``free_b`` and ``fits_b`` (bx, by, bz, block, block,
# block) bool, voxel (i, j, k) at [i // block, j // block, k // block, i % block, j % block, k % block]; ``state``
# (bx, by, bz) uint8, bit 1 set once a block's ``free_b`` is written, bit 2 once its ``fits_b`` and ``counts`` are.
# Each voxel is decided by the same predicates, in the same arithmetic, as the whole-box kernels (seen_free_voxels,
# mark_capsule_voxels, or_coarse, the solids' mask, erode_fits), so a block holds what the whole box would.

FREE_DONE = 1
FITS_DONE = 2


@kernel(parallel=True)
def fill_free_blocks(blocks, lo, voxel, poses, intrinsics, z_near, sizes, tables, floor_log2, margin, pad, static,
                     coarse, ratio, capsules, zone, shape, free_b, state):
    """For each block of ``blocks`` ((m,) int64, flat indices (a * by + b) * bz + c, each once) whose ``free_b`` is
    not written yet: write it, the voxels certified free, and set its FREE_DONE bit.

    A voxel is free when some camera sees it entirely free (``seen_free_block``; poses, intrinsics, z_near,
    sizes, tables, floor_log2, margin and pad as :func:`seen_free_voxels` of ``depthguard.kernels.freespace`` takes
    them; no camera when poses has no row), when static[i, j, k] ((nx, ny, nz)
    bool, the known solids' inside; a (0, 0, 0) array for none), when coarse[i // ratio, j // ratio, k // ratio]
    ((mx, my, mz) bool, the memory's voxels free now, ``ratio`` times as big, same near corner; (0, 0, 0) for none),
    or when, for every joint set s of ``capsules`` ((s, n, 7) float64, metres, world: p0, p1, radius; s = 0 for
    none), its centre lies within radius + zone - voxel sqrt(3) / 2 of one of that set's capsules
    (:func:`mark_capsule_voxels`'s test). shape: (3,) int64, (nx, ny, nz); zone: metres."""
    nx = shape[0]
    ny = shape[1]
    nz = shape[2]
    bx, by, bz = state.shape
    block = free_b.shape[3]
    half_diagonal = 0.5 * math.sqrt(3.0) * voxel
    block_half = 0.5 * math.sqrt(3.0) * block * voxel
    for n in prange(blocks.shape[0]):
        a0, b0, c0 = unflatten(blocks[n], by, bz)
        if state[a0, b0, c0] & FREE_DONE:
            continue
        out = free_b[a0, b0, c0]
        out[:] = False
        i0 = a0 * block
        j0 = b0 * block
        k0 = c0 * block
        ex = min(block, nx - i0)
        ey = min(block, ny - j0)
        ez = min(block, nz - k0)
        if static.shape[0] > 0:
            for da in range(ex):
                for db in range(ey):
                    for dc in range(ez):
                        if static[i0 + da, j0 + db, k0 + dc]:
                            out[da, db, dc] = True
        if coarse.shape[0] > 0:
            for da in range(ex):
                for db in range(ey):
                    for dc in range(ez):
                        if coarse[(i0 + da) // ratio, (j0 + db) // ratio, (k0 + dc) // ratio]:
                            out[da, db, dc] = True
        if capsules.shape[0] > 0:
            robot = np.ones((block, block, block), dtype=np.bool_)
            mark = np.empty((block, block, block), dtype=np.bool_)
            centre = np.empty(3)
            centre[0] = lo[0] + (i0 + 0.5 * block) * voxel
            centre[1] = lo[1] + (j0 + 0.5 * block) * voxel
            centre[2] = lo[2] + (k0 + 0.5 * block) * voxel
            d = np.empty(3)
            for s in range(capsules.shape[0]):
                mark[:] = False
                for m in range(capsules.shape[1]):
                    p0 = capsules[s, m, 0:3]
                    p1 = capsules[s, m, 3:6]
                    reach = capsules[s, m, 6] + zone - half_diagonal
                    if not reach > 0.0:
                        continue
                    for e in range(3):
                        d[e] = p1[e] - p0[e]
                    length2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
                    # no voxel centre of the block within reach: its bounding ball is farther (1 um to spare)
                    if not within_segment(centre[0] - p0[0], centre[1] - p0[1], centre[2] - p0[2], d, length2,
                                          reach + block_half + 1e-6):
                        continue
                    for da in range(ex):
                        cx = lo[0] + (i0 + da + 0.5) * voxel - p0[0]
                        for db in range(ey):
                            cy = lo[1] + (j0 + db + 0.5) * voxel - p0[1]
                            for dc in range(ez):
                                cz = lo[2] + (k0 + dc + 0.5) * voxel - p0[2]
                                if within_segment(cx, cy, cz, d, length2, reach):
                                    mark[da, db, dc] = True
                for da in range(block):
                    for db in range(block):
                        for dc in range(block):
                            robot[da, db, dc] = robot[da, db, dc] and mark[da, db, dc]
            for da in range(ex):
                for db in range(ey):
                    for dc in range(ez):
                        if robot[da, db, dc]:
                            out[da, db, dc] = True
        if poses.shape[0] > 0:  # last: the cheaper sources spare it the boxes they cover
            lattice, corners, stack = block_scratch(poses.shape[0], block)
            seen_free_block(lo, voxel, poses, intrinsics, z_near, sizes, tables, floor_log2, margin, pad, block,
                            i0, j0, k0, nx, ny, nz, lattice, corners, stack, True, 0, out, 0, 0, 0)
        state[a0, b0, c0] |= FREE_DONE


@kernel()
def blocks_to_free(blocks, state, mark):
    """The blocks whose ``free_b`` E_vox needs for ``blocks`` ((m,) int64 flat indices): each of them and their 26
    neighbours (in the box) without FREE_DONE, each once: (k,) int64. mark: (bx * by * bz,) uint8 scratch, all 0 on
    entry and on return."""
    bx, by, bz = state.shape
    out = np.empty(27 * blocks.shape[0], dtype=np.int64)
    m = 0
    for n in range(blocks.shape[0]):
        a0, b0, c0 = unflatten(blocks[n], by, bz)
        for a in range(max(a0 - 1, 0), min(a0 + 2, bx)):
            for b in range(max(b0 - 1, 0), min(b0 + 2, by)):
                for c in range(max(c0 - 1, 0), min(c0 + 2, bz)):
                    f = (a * by + b) * bz + c
                    if mark[f] == 0 and not state[a, b, c] & FREE_DONE:
                        mark[f] = 1
                        out[m] = f
                        m += 1
    for n in range(m):
        mark[out[n]] = 0
    return out[:m].copy()


@kernel(parallel=True)
def fill_fit_blocks(blocks, offsets, shape, free_b, state, fits_b, counts):
    """For each block of ``blocks`` ((m,) int64 flat indices, each once) without FITS_DONE: fits_b (E_vox) as
    :func:`erode_fits` decides it, its count of True voxels in ``counts`` ((bx, by, bz) int32), and the FITS_DONE
    bit. Every block of ``blocks`` and its 26 neighbours in the box must have FREE_DONE. offsets: (k, 3) int64, as
    :func:`erode_fits`, none longer than a block along an axis; shape: (3,) int64, (nx, ny, nz).

    Each block first gathers the free voxels round it (out to the longest offset; beyond the box: not free) into a
    small array of its own, so that each voxel's offsets are read at fixed strides."""
    nx = shape[0]
    ny = shape[1]
    nz = shape[2]
    bx, by, bz = state.shape
    block = free_b.shape[3]
    reach = 0
    for o in range(offsets.shape[0]):
        for e in range(3):
            reach = max(reach, abs(offsets[o, e]))
    side = block + 2 * reach
    delta = np.empty(offsets.shape[0], dtype=np.int64)  # each offset as a step in the gathered array
    for o in range(offsets.shape[0]):
        delta[o] = (offsets[o, 0] * side + offsets[o, 1]) * side + offsets[o, 2]
    for n in prange(blocks.shape[0]):
        a0, b0, c0 = unflatten(blocks[n], by, bz)
        if state[a0, b0, c0] & FITS_DONE:
            continue
        near = np.zeros(side * side * side, dtype=np.bool_)
        for ga in range(side):
            a = a0 * block + ga - reach
            if a < 0 or a >= nx:
                continue
            for gb in range(side):
                b = b0 * block + gb - reach
                if b < 0 or b >= ny:
                    continue
                row = (ga * side + gb) * side
                for gc in range(side):
                    c = c0 * block + gc - reach
                    if 0 <= c < nz:
                        near[row + gc] = free_b[a // block, b // block, c // block, a % block, b % block, c % block]
        fits = fits_b[a0, b0, c0]
        fits[:] = False
        total = 0
        for da in range(min(block, nx - a0 * block)):
            for db in range(min(block, ny - b0 * block)):
                for dc in range(min(block, nz - c0 * block)):
                    here = ((da + reach) * side + db + reach) * side + dc + reach
                    keep = not near[here]
                    if keep:
                        for o in range(delta.shape[0]):
                            if near[here + delta[o]]:
                                keep = False
                                break
                    fits[da, db, dc] = keep
                    if keep:
                        total += 1
        counts[a0, b0, c0] = total
        state[a0, b0, c0] |= FITS_DONE


@kernel()
def search_start(points, lo, voxel, shape, beyond, limit, best, pending):
    """Where the watched search starts for each point (:func:`box_start`, as :func:`nearest_fit` starts): best[p],
    and pending[p] False for a point outside the box (its answer 0). points: (n, 3) float64, metres, world frame;
    beyond: (6,) float64, metres, as :func:`nearest_fit` takes it; limit: float, metres; best: (n,) float64 and
    pending: (n,) bool, written."""
    for p in range(points.shape[0]):
        outside, best[p] = box_start(points[p, 0] - lo[0], points[p, 1] - lo[1], points[p, 2] - lo[2], shape, voxel,
                                     beyond, limit)
        pending[p] = not outside


@kernel(parallel=True)
def search_fits(fits_b, counts, state, shape, lo, voxel, points, pending, ring, best, lookahead, need, need_count):
    """One round of the nearest-fit search over a watched space: for each point p with pending[p], walk the rings of
    blocks round the point's block (Chebyshev distance ring[p], ring[p] + 1, ...) and lower best[p] to the distance
    from points[p] to the nearest True voxel's cube of a block with FITS_DONE, while some block of the ring may lie
    nearer than best[p]. At a block without FITS_DONE that may lie nearer, the point stalls: its ring is kept in
    ring[p] (the next round starts there again), and that block and the next ones without FITS_DONE that may lie
    nearer, up to need.shape[1] of them in this ring and the next ``lookahead`` (int >= 0), go into
    need[p, :need_count[p]]. A point
    whose rings reach past best[p] (or past the box) has pending[p] = False and its answer in best[p].

    points: (n, 3) float64, metres, world frame; lo: (3,) float64, the box's near corner; shape: (3,) int64;
    pending: (n,) bool; ring: (n,) int64; best: (n,) float64, metres (the first round: :func:`search_start`'s,
    the box's faces and the limit, as :func:`nearest_fit` starts); need: (n, cap) int64 flat block indices;
    need_count: (n,) int64."""
    bx, by, bz = state.shape
    block = fits_b.shape[3]
    side = block * voxel
    for p in prange(points.shape[0]):
        need_count[p] = 0
        if not pending[p]:
            continue
        x = points[p, 0] - lo[0]
        y = points[p, 1] - lo[1]
        z = points[p, 2] - lo[2]
        pa = min(max(np.int64(math.floor(x / side)), 0), bx - 1)
        pb = min(max(np.int64(math.floor(y / side)), 0), by - 1)
        pc = min(max(np.int64(math.floor(z / side)), 0), bz - 1)
        r = ring[p]
        stalled = -1
        while True:
            if r > 0 and (r - 1) * side >= best[p] + 1e-9:  # no block of ring r lies nearer (rounding to spare)
                break
            if pa - r < 0 and pb - r < 0 and pc - r < 0 and pa + r >= bx and pb + r >= by and pc + r >= bz:
                break
            if stalled >= 0 and (r > stalled + lookahead or need_count[p] >= need.shape[1]):
                break
            for a in range(max(pa - r, 0), min(pa + r, bx - 1) + 1):
                dx = to_interval(x, a * side, (a + 1) * side)
                if dx >= best[p]:
                    continue
                edge_a = abs(a - pa) == r
                for b in range(max(pb - r, 0), min(pb + r, by - 1) + 1):
                    dy = to_interval(y, b * side, (b + 1) * side)
                    if dx * dx + dy * dy >= best[p] * best[p]:
                        continue
                    step = 1 if edge_a or abs(b - pb) == r else 2 * r
                    c = pc - r
                    while c <= pc + r:
                        if 0 <= c < bz:
                            dz = to_interval(z, c * side, (c + 1) * side)
                            if math.sqrt(dx * dx + dy * dy + dz * dz) < best[p]:
                                if state[a, b, c] & FITS_DONE:
                                    if stalled < 0 and counts[a, b, c] > 0:
                                        best[p] = scan_block(fits_b[a, b, c, :min(block, shape[0] - a * block),
                                                                    :min(block, shape[1] - b * block),
                                                                    :min(block, shape[2] - c * block)],
                                                             a * block, b * block, c * block, voxel, x, y, z,
                                                             best[p])
                                elif need_count[p] < need.shape[1]:
                                    if stalled < 0:
                                        stalled = r
                                    need[p, need_count[p]] = (a * by + b) * bz + c
                                    need_count[p] += 1
                        c += max(step, 1)
            r += 1
        if stalled >= 0:
            ring[p] = stalled
        else:
            pending[p] = False
