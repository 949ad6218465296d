"""Numba kernels of the time-bounded free space (design §8a). They trust their inputs;
``depthguard/freespace/_memory.py`` checks them (``_near.py`` those of the last two kernels).

Two jobs:

- Which voxels of a box some camera sees entirely free now (:func:`seen_free_voxels`), by the depth grid's
  confirmation rule (design §8): all 8 corners of the voxel in front of the camera, every pixel whose footprint
  meets the corners' projected bounding box (grown by ``pad`` pixels) inside the image, and each of them free at
  least up to the voxel's largest corner depth plus ``margin``. A per-row sparse table of each free image (the
  minimum over every run of 2^l pixels of a row) answers "the smallest free value of row r between columns a and b"
  with two reads, so a box costs a few operations per row of its footprint. Blocks of voxels are tested whole
  first, then halved where no camera sees them whole: most voxels of a scene are settled a block at a time.
- The exact squared Euclidean distance transform of Felzenszwalb and Huttenlocher ("Distance transforms of sampled
  functions", Theory of Computing 8, 2012): one pass per axis, the last axis by two sweeps, the others by the lower
  envelope of parabolas, in integers (no rounding anywhere). The box is padded by one layer of "possibly occupied"
  voxels on every side (a person may come from outside), which each 1-D transform sees as two sites of value 0 at
  positions -1 and n. Squared distances are in voxel units: at most 3 * (config.FREESPACE_MAX_SIDE + 1)^2, about
  8e8, within ``int32``.

Voxel arrays are (nx, ny, nz), C order, indexed [i, j, k] along world x, y, z; images are indexed [row, column].

Arguments used throughout:

- ``lo``: (3,) float64, metres, world frame: the voxel box's near corner (voxel (i, j, k) spans lo + (i, j, k) *
  voxel to lo + (i + 1, j + 1, k + 1) * voxel).
- ``voxel``: float, metres: the side of the box's voxels.
- ``sizes``: (n, 2) int64, pixels: each camera's image size (width, height).
- ``floor_log2``: (w_max + 1,) int64, w_max the widest image's width: floor_log2[m] = floor(log2(m)) for m >= 1.
- ``margin``: float, metres: how far beyond a voxel's deepest corner a camera must have seen free (calibration).
- ``pad``: float64, pixels, a whole number: how far a voxel's footprint grows on every side (calibration).
- ``d2``: (nx, ny, nz) int32: the distance transform's squared distances in voxel units (between voxel centres),
  transformed in place pass by pass.
"""

import numpy as np
from numba import prange

from depthguard.kernels.jit import kernel

# ------------------------------------------------------------------------------------------------- seen free voxels


@kernel(parallel=True)
def row_min_tables(free, sizes, table):
    """table[c, l, q, r] = the smallest free[c, r, q : q + 2^l] of camera c's free image (sizes[c] = (width, height)),
    for 2^l <= width and q + 2^l <= width (the rest is not written): a sparse table of each row, stored column-major
    so that the rows of one footprint lie side by side. free: (n, >= h, >= w) float32, metres, each camera's free
    image (how far each pixel saw its ray free, 0 for nothing); table: (n, >= levels, >= w, >= h) float32, metres.
    One task per camera (a single parallel region: on a busy machine each region's barrier costs)."""
    for p in prange(free.shape[0]):
        c = np.int64(p)
        w = sizes[c, 0]
        h = sizes[c, 1]
        for q in range(w):
            for r in range(h):
                table[c, 0, q, r] = free[c, r, q]
        level = 1
        while (np.int64(1) << level) <= w:
            half = np.int64(1) << (level - 1)
            for q in range(w - 2 * half + 1):
                for r in range(h):
                    table[c, level, q, r] = min(table[c, level - 1, q, r], table[c, level - 1, q + half, r])
            level += 1


@kernel(inline=True)
def row_min(table, floor_log2, r, a, b):
    """The smallest value of row r between columns a and b (inclusive, a <= b; int, pixels) of the image ``table``
    holds: table (levels, >= w, >= h) float32, metres, one camera's row-minimum table (:func:`row_min_tables`)."""
    level = floor_log2[b - a + 1]
    return min(table[level, a, r], table[level, b - (np.int64(1) << level) + 1, r])


@kernel(inline=True)
def project_point(lo, voxel, i, j, k, pose, intrinsics, out):
    """out[:] = (u, v, z): the lattice point lo + (i, j, k) * voxel (world, metres) in one camera, its image
    coordinates (pixels; garbage where z <= 0) and optical depth (metres).

    i, j, k: int, the lattice point's indices. pose: (12,) float64, the world -> optical rotation row by row, then
    the translation (metres). intrinsics: (4,) float64, fx, fy, cx, cy, pixels. out: (3,) float64, written.
    The point is placed, transformed and projected as written, in this order, as ``seen_free_voxels``' docstring
    says (the tests' judge does the same arithmetic)."""
    x = lo[0] + i * voxel
    y = lo[1] + j * voxel
    z = lo[2] + k * voxel
    pz = pose[6] * x + pose[7] * y + pose[8] * z + pose[11]
    px = pose[0] * x + pose[1] * y + pose[2] * z + pose[9]
    py = pose[3] * x + pose[4] * y + pose[5] * z + pose[10]
    out[0] = intrinsics[0] * px / pz + intrinsics[2]
    out[1] = intrinsics[1] * py / pz + intrinsics[3]
    out[2] = pz


@kernel(inline=True)
def camera_sees_box(corners, z_near, width, height, table, floor_log2, margin, pad):
    """Whether one camera sees a box of voxels entirely free, from its 8 corners in that camera (``corners``: (8, 3)
    float64, u, v, z as :func:`project_point` gives them). The confirmation rule of ``seen_free_voxels``. z_near:
    float, metres, the nearest depth a corner may have; width, height: int, pixels, the camera's image size; table:
    (levels, >= w, >= h) float32, metres, its free image's row-minimum table (:func:`row_min_tables`)."""
    x_lo = np.inf
    x_hi = -np.inf
    y_lo = np.inf
    y_hi = -np.inf
    far = 0.0
    for corner in range(8):
        pz = corners[corner, 2]
        if not pz >= z_near:  # NaN-safe: a NaN depth is not in front
            return False
        u = corners[corner, 0]
        v = corners[corner, 1]
        x_lo = min(x_lo, u)
        x_hi = max(x_hi, u)
        y_lo = min(y_lo, v)
        y_hi = max(y_hi, v)
        far = max(far, pz)
    # The pixels whose footprints [q - 1/2, q + 1/2] meet [x_lo - pad, x_hi + pad]: q_lo..q_hi; likewise rows. Each
    # bound is compared as a float before it becomes an index (a corner near the camera projects very far; NaN fails).
    q_lo = np.ceil(x_lo - 0.5) - pad
    q_hi = np.floor(x_hi + 0.5) + pad
    r_lo = np.ceil(y_lo - 0.5) - pad
    r_hi = np.floor(y_hi + 0.5) + pad
    if not (q_lo >= 0.0 and r_lo >= 0.0 and q_hi <= width - 1.0 and r_hi <= height - 1.0):
        return False
    need = far + margin
    a = np.int64(q_lo)
    b = np.int64(q_hi)
    for r in range(np.int64(r_lo), np.int64(r_hi) + 1):
        if not row_min(table, floor_log2, r, a, b) >= need:
            return False
    return True


@kernel(inline=True)
def _all_true(out, i0, i1, j0, j1, k0, k1):
    """Whether out[i0:i1, j0:j1, k0:k1] (3-D bool) is all True."""
    for i in range(i0, i1):
        for j in range(j0, j1):
            for k in range(k0, k1):
                if not out[i, j, k]:
                    return False
    return True


@kernel(inline=True)
def _push_cube(stack, top, a, b, c, side):
    """Push the box (a, b, c, side) onto ``stack`` ((depth, 4) int64 rows a, b, c, side) at ``top``; returns the new
    top."""
    stack[top, 0] = a
    stack[top, 1] = b
    stack[top, 2] = c
    stack[top, 3] = side
    return top + 1


@kernel(inline=True)
def _push_halves(stack, top, a, b, c, side):
    """Push the 8 halves of the box (a, b, c, side) onto ``stack`` at ``top`` (:func:`_push_cube`); returns the new
    top."""
    half = side // 2
    for child in range(8):
        top = _push_cube(stack, top, a + (half if child & 1 else 0), b + (half if child & 2 else 0),
                         c + (half if child & 4 else 0), half)
    return top


@kernel(inline=True)
def _pop_cube(stack, top):
    """The box on top of ``stack`` (as :func:`_push_halves` writes it): (the new top, a, b, c, side)."""
    top -= 1
    return top, stack[top, 0], stack[top, 1], stack[top, 2], stack[top, 3]


@kernel(inline=True)
def seen_free_block(lo, voxel, poses, intrinsics, z_near, sizes, tables, floor_log2, margin, pad, block, i0, j0, k0,
                    nx, ny, nz, lattice, corners, stack, skip_covered, last, out, oi, oj, ok):
    """out[oi + a, oj + b, ok + c] = True where some camera sees voxel (i0 + a, j0 + b, k0 + c) entirely free, for
    the block of ``block`` voxels a side at (i0, j0, k0) (cut at the box's size nx, ny, nz); out: 3-D bool holding
    them (the whole box with (oi, oj, ok) = (i0, j0, k0), or one block's array with 0, 0, 0), only set;
    skip_covered: bool, whether a box whose voxels are all True already (free by another source) goes untested (a check
    that costs the whole box's kernel about 4 %, where nothing is marked before). poses, intrinsics, z_near, sizes,
    tables: the cameras, as :func:`seen_free_voxels` takes them. Scratch: lattice (n_cameras, block + 1, block + 1,
    block + 1, 3) float64, corners (8, 3) float64, stack (7 * (log2(block) + 1) + 1, 4) int64. The other
    arguments as :func:`seen_free_voxels`.

    Coarse to fine: a camera that sees a whole block free sees every voxel in it free (the voxel's corners project
    inside the convex hull of the block's, and lie no deeper than its deepest corner), so the block is first tested
    whole, then its 8 halves, and so on down to single voxels. Only a block that is not seen whole has its inner
    lattice points projected (once per camera). Each test asks first the camera that saw the last box (the answer
    is the same; it comes sooner): ``last`` (int) on entry, the camera that saw a box last on return."""
    n_cameras = poses.shape[0]
    ex = min(block, nx - i0)
    ey = min(block, ny - j0)
    ez = min(block, nz - k0)
    projected = False
    top = _push_cube(stack, 0, 0, 0, 0, block)
    while top > 0:
        top, a, b, c, side = _pop_cube(stack, top)
        if a >= ex or b >= ey or c >= ez:
            continue
        a1 = min(a + side, ex)
        b1 = min(b + side, ey)
        c1 = min(c + side, ez)
        if skip_covered and _all_true(out, oi + a, oi + a1, oj + b, oj + b1, ok + c, ok + c1):
            continue
        if side < block and not projected:
            for cam in range(n_cameras):
                for da in range(ex + 1):
                    for db in range(ey + 1):
                        for dc in range(ez + 1):
                            project_point(lo, voxel, i0 + da, j0 + db, k0 + dc, poses[cam], intrinsics[cam],
                                          lattice[cam, da, db, dc])
            projected = True
        seen = False
        for m in range(n_cameras):
            cam = (last + m) % n_cameras
            for corner in range(8):
                da = a1 if corner & 1 else a
                db = b1 if corner & 2 else b
                dc = c1 if corner & 4 else c
                if side < block:
                    for e in range(3):
                        corners[corner, e] = lattice[cam, da, db, dc, e]
                else:
                    project_point(lo, voxel, i0 + da, j0 + db, k0 + dc, poses[cam], intrinsics[cam],
                                  corners[corner])
            if camera_sees_box(corners, z_near[cam], sizes[cam, 0], sizes[cam, 1], tables[cam], floor_log2,
                               margin, pad):
                seen = True
                last = cam
                break
        if seen:
            for da in range(a, a1):
                for db in range(b, b1):
                    for dc in range(c, c1):
                        out[oi + da, oj + db, ok + dc] = True
        elif side > 1:
            top = _push_halves(stack, top, a, b, c, side)
    return last


@kernel(inline=True)
def block_scratch(n_cameras, block):
    """The scratch arrays :func:`seen_free_block` needs: (lattice, corners, stack) for blocks of ``block`` voxels a
    side (a power of 2) seen by ``n_cameras`` cameras."""
    levels = 1
    while (np.int64(1) << (levels - 1)) < block:
        levels += 1
    lattice = np.empty((n_cameras, block + 1, block + 1, block + 1, 3))
    corners = np.empty((8, 3))
    stack = np.empty((7 * levels + 1, 4), dtype=np.int64)  # (a, b, c, side) relative to the block's origin
    return lattice, corners, stack


@kernel(parallel=True)
def seen_free_voxels(lo, voxel, poses, intrinsics, z_near, sizes, tables, floor_log2, margin, pad, block, out):
    """out[i, j, k] = True where some camera sees voxel (i, j, k) of the box with corner ``lo`` ((3,) metres, world)
    and side ``voxel`` entirely free; out (nx, ny, nz) bool comes all False.

    Per camera c: poses[c] (12,) world -> optical (rotation rows, translation in metres), poses (n, 12) float64;
    intrinsics[c] (fx, fy, cx, cy), intrinsics (n, 4) float64, pixels; z_near[c] the nearest depth a corner may have
    (metres), z_near (n,) float64; sizes[c] (width, height); tables[c] its free image's row-minimum table
    (:func:`row_min_tables`), tables (n, levels, >= w, >= h) float32, metres. floor_log2[n] = floor(log2(n)) for
    n >= 1. margin: metres; pad: pixels (float64, a whole number). block: int, voxels, a power of 2
    (``config.FREESPACE_BLOCK``).

    Block by block (:func:`seen_free_block`, coarse to fine inside each), one column of blocks per task."""
    nx, ny, nz = out.shape
    nbx = (nx + block - 1) // block
    nby = (ny + block - 1) // block
    for p in prange(nbx * nby):
        column = np.int64(p)
        i0 = (column // nby) * block
        j0 = (column % nby) * block
        lattice, corners, stack = block_scratch(poses.shape[0], block)
        last = 0
        for k0 in range(0, nz, block):
            last = seen_free_block(lo, voxel, poses, intrinsics, z_near, sizes, tables, floor_log2, margin, pad,
                                   block, i0, j0, k0, nx, ny, nz, lattice, corners, stack, False, last, out, i0, j0,
                                   k0)


@kernel(inline=True)
def _segment_distance2(x, y, z, capsules, c):
    """Squared distance (metres^2) from the point (x, y, z) to the segment of capsule c of ``capsules`` ((k, 7): p0,
    p1, radius; world, metres)."""
    ax = capsules[c, 3] - capsules[c, 0]
    ay = capsules[c, 4] - capsules[c, 1]
    az = capsules[c, 5] - capsules[c, 2]
    length2 = ax * ax + ay * ay + az * az
    dx = x - capsules[c, 0]
    dy = y - capsules[c, 1]
    dz = z - capsules[c, 2]
    s = 0.0
    if length2 > 0.0:
        s = min(max((dx * ax + dy * ay + dz * az) / length2, 0.0), 1.0)
    ex = dx - s * ax
    ey = dy - s * ay
    ez = dz - s * az
    return ex * ex + ey * ey + ez * ez


@kernel(inline=True)
def _piece_inside(world, capsules, near, n_near):
    """Whether the box with corners ``world`` ((8, 3) float64, metres) lies wholly inside one of the capsules
    ``capsules[near[:n_near]]`` ((k, 7): p0, p1, radius): all 8 corners within its radius of its segment (a capsule
    is convex, so then the whole box is)."""
    for q in range(n_near):
        c = near[q]
        r2 = capsules[c, 6] * capsules[c, 6]
        inside = True
        for corner in range(8):
            if not _segment_distance2(world[corner, 0], world[corner, 1], world[corner, 2], capsules, c) < r2:
                inside = False
                break
        if inside:
            return True
    return False


@kernel(parallel=True)
def certify_mixed_voxels(lo, voxel, candidates, poses, intrinsics, z_near, sizes, tables, floor_log2, margin, pad,
                         capsules, levels, out):
    """out[m] = every point of voxel candidates[m] is seen free by some camera or lies inside the robot (design §8a:
    the two combine within one voxel). The voxel is cut into 8^levels pieces, coarse to fine as needed: a piece
    passes when one camera sees it entirely free (the rule of :func:`seen_free_voxels`, ``camera_sees_box``) or it
    lies wholly inside one of ``capsules`` (all 8 corners within one); the voxel passes when every piece does.
    Different pieces may pass by different cameras or by the robot.

    candidates: (m, 3) int64 voxel indices; capsules: (k, 7) float64, metres, world frame: p0, p1, radius (the robot's
    inner capsules at the frames' joints; (0, 7) for none); levels: int >= 0 (pieces of voxel / 2^levels a side);
    out: (m,) bool, written. The cameras, as :func:`seen_free_voxels` takes them: poses (n, 12) float64, world ->
    optical (rotation rows, translation in metres); intrinsics (n, 4) float64, fx, fy, cx, cy, pixels; z_near (n,)
    float64, metres, the nearest depth a corner may have; sizes (n, 2) width, height; tables (n, levels, >= w, >= h)
    float32, metres, each free image's row-minimum table (:func:`row_min_tables`). A voxel's capsules are those whose
    segment passes within their radius plus half the voxel's diagonal of its centre (at most 256 are looked at: a
    voxel with more is judged by its first 256, which can only pass fewer pieces)."""
    n_cameras = poses.shape[0]
    n = np.int64(1) << levels
    half_diagonal = 0.5 * np.sqrt(3.0) * voxel
    for p in prange(candidates.shape[0]):
        i = candidates[p, 0]
        j = candidates[p, 1]
        k = candidates[p, 2]
        cx = lo[0] + (i + 0.5) * voxel
        cy = lo[1] + (j + 0.5) * voxel
        cz = lo[2] + (k + 0.5) * voxel
        near = np.empty(256, dtype=np.int64)
        n_near = 0
        for c in range(capsules.shape[0]):
            reach = capsules[c, 6] + half_diagonal
            if _segment_distance2(cx, cy, cz, capsules, c) < reach * reach and n_near < 256:
                near[n_near] = c
                n_near += 1
        world = np.empty((8, 3))
        corners = np.empty((8, 3))
        stack = np.empty((7 * levels + 1, 4), dtype=np.int64)  # (a, b, c, side) in pieces
        top = _push_cube(stack, 0, 0, 0, 0, n)
        passed = True
        while top > 0:
            top, a, b, c, side = _pop_cube(stack, top)
            for corner in range(8):
                world[corner, 0] = lo[0] + (i + (a + (side if corner & 1 else 0)) / n) * voxel
                world[corner, 1] = lo[1] + (j + (b + (side if corner & 2 else 0)) / n) * voxel
                world[corner, 2] = lo[2] + (k + (c + (side if corner & 4 else 0)) / n) * voxel
            ok = _piece_inside(world, capsules, near, n_near)
            m = 0
            while not ok and m < n_cameras:
                pose = poses[m]
                for corner in range(8):
                    x = world[corner, 0]
                    y = world[corner, 1]
                    z = world[corner, 2]
                    pz = pose[6] * x + pose[7] * y + pose[8] * z + pose[11]
                    px = pose[0] * x + pose[1] * y + pose[2] * z + pose[9]
                    py = pose[3] * x + pose[4] * y + pose[5] * z + pose[10]
                    corners[corner, 0] = intrinsics[m, 0] * px / pz + intrinsics[m, 2]
                    corners[corner, 1] = intrinsics[m, 1] * py / pz + intrinsics[m, 3]
                    corners[corner, 2] = pz
                ok = camera_sees_box(corners, z_near[m], sizes[m, 0], sizes[m, 1], tables[m], floor_log2, margin,
                                     pad)
                m += 1
            if ok:
                continue
            if side == 1:
                passed = False
                break
            top = _push_halves(stack, top, a, b, c, side)
        out[p] = passed


# ----------------------------------------------------------------------------------------- the distance transform


@kernel(inline=True)
def _sweep_back(d2, i, j, nz):
    """The last axis' second sweep: d2[i, j, k] holds the distance (in voxels) to the nearest site at or before k
    (0 on a site); make it the squared distance to the nearest site either side, position nz counting as one. d2:
    (nx, ny, nz) int32; i, j: int, the line's first two indices; nz: int, its length (d2's last axis)."""
    last = nz
    for k in range(nz - 1, -1, -1):
        d = d2[i, j, k]
        if d == 0:
            last = k
        d = min(d, last - k)
        d2[i, j, k] = d * d


@kernel(parallel=True)
def last_axis_of_mask(mask, d2):
    """Pass 1 for a mask: d2[i, j, k] = squared distance (voxels) along the last axis to the nearest True voxel or
    to the padding (positions -1 and nz). mask: (nx, ny, nz) bool; d2: (nx, ny, nz) int32."""
    nx, ny, nz = mask.shape
    for p in prange(nx * ny):
        ij = np.int64(p)
        i = ij // ny
        j = ij - i * ny
        last = -1
        for k in range(nz):
            if mask[i, j, k]:
                last = k
            d2[i, j, k] = k - last
        _sweep_back(d2, i, j, nz)


@kernel(parallel=True)
def grown_possibly_occupied(arrival, seen, robot, use_robot, t, grown, scratch):
    """grown = U grown by one voxel in every direction (the 26 neighbours), the layer outside the box counting as U;
    U = (arrival <= t) & ~seen & ~robot (robot only when use_robot), the voxels where a person may be now. The
    distance between voxel centres from a voxel to the nearest voxel of ``grown`` is exactly its cube's distance to
    the nearest cube of U (or to the outside): along each axis max(|d| - 1, 0) voxels. arrival: (nx, ny, nz) float64
    seconds; seen, robot: bool (robot may be any shape when not use_robot); use_robot: bool; t: float, seconds, the
    frames' clock; grown, scratch: (nx, ny, nz) bool, written (scratch: work space)."""
    nx, ny, nz = arrival.shape
    for p in prange(nx * ny):  # U, grown along the last axis, into scratch
        ij = np.int64(p)
        i = ij // ny
        j = ij - i * ny
        before = True  # the layer outside the box
        here = arrival[i, j, 0] <= t and not seen[i, j, 0] and not (use_robot and robot[i, j, 0])
        for k in range(nz):
            after = True
            if k + 1 < nz:
                after = arrival[i, j, k + 1] <= t and not seen[i, j, k + 1] and not (use_robot and robot[i, j, k + 1])
            scratch[i, j, k] = before or here or after
            before = here
            here = after
    for p in prange(nx):  # along the middle axis, into grown
        i = np.int64(p)
        for j in range(ny):
            for k in range(nz):
                grown[i, j, k] = j == 0 or j == ny - 1 or scratch[i, j - 1, k] or scratch[i, j, k] or scratch[i, j + 1, k]
    for p in prange(nx):  # along the first axis, into scratch, then back
        i = np.int64(p)
        for j in range(ny):
            for k in range(nz):
                scratch[i, j, k] = i == 0 or i == nx - 1 or grown[i - 1, j, k] or grown[i, j, k] or grown[i + 1, j, k]
    for p in prange(nx):
        i = np.int64(p)
        for j in range(ny):
            for k in range(nz):
                grown[i, j, k] = scratch[i, j, k]


@kernel(inline=True)
def _lower_envelope(f, n, v, fv, zn, zd, out):
    """out[q] = min over sites p of (q - p)^2 + f(p), for q in 0..n-1 (Felzenszwalb-Huttenlocher). Sites: p in
    0..n-1 with f(p) = f[p] (whole numbers), and the padding p = -1 and p = n with f = 0. Work space, (n + 2,) int64
    each: v, fv the envelope's parabolas and their values; zn / zd where each starts, as a fraction (zd > 0), so that
    every comparison is exact in integers (|zn * den| stays below 2^63 for sides up to config.FREESPACE_MAX_SIDE).
    f, out: (n,) int64, squared distances in voxel units; n: int, the line's length."""
    top = 0
    v[0] = -1
    fv[0] = 0
    zn[0] = -1  # the padding's parabola starts at -inf: it is never popped (top > 0 below)
    zd[0] = 0
    for q in range(n + 1):
        fq = np.int64(0) if q == n else np.int64(f[q])
        while True:  # pop the parabolas the new one hides: where it starts, s = num / den, is at or before theirs
            p = v[top]
            num = (fq + q * q) - (fv[top] + p * p)
            den = 2 * (q - p)
            if top > 0 and num * zd[top] <= zn[top] * den:
                top -= 1
            else:
                break
        top += 1
        v[top] = q
        fv[top] = fq
        zn[top] = num
        zd[top] = den
    last = top
    top = 0
    for q in range(n):
        while top < last and zn[top + 1] < q * zd[top + 1]:
            top += 1
        d = q - v[top]
        out[q] = d * d + fv[top]


@kernel(inline=True)
def _envelope_slab(slab, lines, f, v, fv, zn, zd, out):
    """Transform every line along the first axis of ``slab`` ((m, nz) int32 view) in place, through ``lines`` ((nz,
    m) int64 work space: the slab transposed so each line is contiguous). f, v, fv, zn, zd, out: int64 work space
    for :func:`_lower_envelope`, (m,), (m + 2,) each and (m,), as :func:`_slab_scratch` makes them."""
    m, nz = slab.shape
    for q in range(m):
        for k in range(nz):
            lines[k, q] = slab[q, k]
    for k in range(nz):
        for q in range(m):
            f[q] = lines[k, q]
        _lower_envelope(f, m, v, fv, zn, zd, out)
        for q in range(m):
            lines[k, q] = out[q]
    for q in range(m):
        for k in range(nz):
            slab[q, k] = lines[k, q]


@kernel(inline=True)
def _slab_scratch(n, nz):
    """The work arrays of one slab's envelopes along an axis of n voxels (int64): its nz lines (nz, n), one line f
    (n,), the envelope's v, fv, zn, zd (n + 2,) and the result out (n,), in :func:`_envelope_slab`'s order."""
    return (np.empty((nz, n), dtype=np.int64), np.empty(n, dtype=np.int64), np.empty(n + 2, dtype=np.int64),
            np.empty(n + 2, dtype=np.int64), np.empty(n + 2, dtype=np.int64), np.empty(n + 2, dtype=np.int64),
            np.empty(n, dtype=np.int64))


@kernel(parallel=True)
def middle_axis(d2):
    """Pass 2: the lower envelope along the second axis, in place, one (ny, nz) slab per task. d2: (nx, ny, nz)
    int32."""
    nx, ny, nz = d2.shape
    for p in prange(nx):
        i = np.int64(p)
        lines, f, v, fv, zn, zd, out = _slab_scratch(ny, nz)
        _envelope_slab(d2[i], lines, f, v, fv, zn, zd, out)


@kernel(parallel=True)
def first_axis(d2):
    """Pass 3: the lower envelope along the first axis, in place, one (nx, nz) slab per task. d2: (nx, ny, nz)
    int32."""
    nx, ny, nz = d2.shape
    for p in prange(ny):
        j = np.int64(p)
        lines, f, v, fv, zn, zd, out = _slab_scratch(nx, nz)
        _envelope_slab(d2[:, j, :], lines, f, v, fv, zn, zd, out)


@kernel(parallel=True)
def advance_arrival(d2, t, voxel, clearance, v_max, rounding, arrival):
    """arrival = max(arrival, t + max(0, D - clearance) / v_max), D = voxel * sqrt(d2) metres between voxel centres,
    lowered by ``rounding`` * D metres and one unit in the last place of the sum so that float rounding never makes
    it later than the exact value. d2: (nx, ny, nz) int32 squared distances (voxels); arrival: (nx, ny, nz) float64
    seconds, edited in place. t: float, seconds; voxel, clearance: float, metres (clearance: voxel sqrt(3)); v_max:
    float, metres per second; rounding: float, no unit (``config.FREESPACE_ROUNDING``)."""
    nx, ny, nz = arrival.shape
    for p in prange(nx):
        i = np.int64(p)
        for j in range(ny):
            for k in range(nz):
                distance = voxel * np.sqrt(np.float64(d2[i, j, k]))
                reach = distance - clearance - rounding * distance
                a = t
                if reach > 0.0:
                    a = np.nextafter(t + reach / v_max, -np.inf)
                arrival[i, j, k] = max(arrival[i, j, k], a)


@kernel(parallel=True)
def voxels_within_radii(mask, lo, voxel, points, radii, out):
    """out[p] = some True voxel of mask lies nearer than radii[p] to points[p] (the voxels of side ``voxel`` from
    corner ``lo``), the distance being to the voxel's cube. mask: (nx, ny, nz) bool; points: (n, 3) float64, metres,
    world frame; radii: (n,) float64, metres (0 or less, or NaN: never); out: (n,) bool, written."""
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


@kernel(parallel=True)
def mark_surface_voxels(raw, scale, z_start, invalid, fx, fy, cx, cy, R, t, lo, voxel, out):
    """out[voxel of (u, v)'s measured point] = True for every pixel with a valid measurement whose z_start is finite
    (a surface, not the robot nor a hole). Rows in parallel: threads may mark the same voxel, and every write is the
    same True.

    raw: (h, w) uint16 in units of ``scale`` metres, or float32 metres (scale 1.0); z_start, invalid: (h, w) float32
    metres and uint8, the frame's :class:`depthguard.depth.OccupancyImage`; fx, fy, cx, cy: float, pixels, the
    camera's intrinsics; R (3, 3), t (3,): float64, the camera's optical frame -> world (t in metres). The measured
    point lies on the pixel's centre ray at optical depth raw * scale. out: (nx, ny, nz) bool, only set (never
    cleared)."""
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
