"""Numba kernels of the image-based collision test (design §10): the epipolar bands between two cameras' tile
grids. They trust their inputs; ``depthguard/collision/_epipolar.py`` checks them. Also the tiles the robot's capsules
may cover (``_robot_image.py``) and the per-tile sums of the difference images (``_difference.py``), which check
theirs.

A set of tiles is a bitset: a row of a (K, words) uint64 array, tile index r * cols + c in bit ``index & 63`` of word
``index >> 6``.

Arguments used throughout:

- ``R, t``: (3, 3) float64 and (3,) float64 metres: the rigid transform from the frame the geometry is given in (each
  kernel says which) into the optical frame (x right, y down, z forward) of the camera whose tiles are marked:
  x_camera = R x + t.
- ``fx, fy, cx, cy``: float, pixels: that camera's intrinsics.
- ``col_edges, row_edges``: (cols + 1,) and (rows + 1,) float64, pixels: that camera's tile grid
  (:class:`depthguard.collision.TileGrid`): tile (r, c) spans image columns col_edges[c] to col_edges[c + 1] and
  rows row_edges[r] to row_edges[r + 1], its pixels' footprints (each entry a tile's first pixel minus 1/2, the last
  the image's width or height minus 1/2).
- ``words``: int, the uint64 words of one bitset, (rows * cols + 63) // 64.
- ``k``: int, the row of the bitsets ``out`` that a kernel sets bits in.
- ``ends, radii``: (K, m, 2, 3) float64, metres, world frame: for each of K robot configurations the core segments
  (both end points) of its m capsules; (m,) float64, metres: the capsules' radii (padding included).
- ``first_row, first_col``: (rows + 1,) and (cols + 1,) int64, pixels: each tile row's first image row and each tile
  column's first image column, the last entry the image's height and width.
"""

import numpy as np
from numba import prange

from depthguard.kernels.jit import kernel


@kernel(inline=True)
def _cross(ox, oy, ax, ay, bx, by):
    """(a - o) x (b - o) for the points o = (ox, oy), a = (ax, ay), b = (bx, by) (float64, pixels): > 0 when o, a, b
    turn counter-clockwise (the sense of :func:`convex_hull`), 0 when they are collinear; pixels squared."""
    return (ax - ox) * (by - oy) - (ay - oy) * (bx - ox)


@kernel()
def convex_hull(xs, ys, hull_x, hull_y):
    """Andrew's monotone chain over the points (xs, ys) ((n,) float64 each, 1 <= n <= 16; pixels here): writes the
    hull's vertices counter-clockwise into hull_x, hull_y (float64, length >= 2 n, same unit) and returns their number
    (collinear points dropped)."""
    n = xs.shape[0]
    order = np.arange(n)
    for i in range(1, n):  # insertion sort by x, then y
        j = i
        while j > 0 and (xs[order[j - 1]] > xs[order[j]] or
                         (xs[order[j - 1]] == xs[order[j]] and ys[order[j - 1]] > ys[order[j]])):
            order[j - 1], order[j] = order[j], order[j - 1]
            j -= 1
    k = 0
    for step in range(2):
        start = k
        for idx in range(n):
            i = order[idx] if step == 0 else order[n - 1 - idx]
            while k >= start + 2 and _cross(hull_x[k - 2], hull_y[k - 2], hull_x[k - 1], hull_y[k - 1],
                                            xs[i], ys[i]) <= 0.0:
                k -= 1
            hull_x[k] = xs[i]
            hull_y[k] = ys[i]
            k += 1
        k -= 1  # the last point of each chain is the first of the other
    return max(k, 1)


@kernel(inline=True)
def _rect_meets_hull(x0, x1, y0, y1, hull_x, hull_y, m):
    """Whether the axis-aligned rectangle [x0, x1] x [y0, y1] meets the convex polygon (hull_x, hull_y)[:m]
    (counter-clockwise), by separating axes: the rectangle's two and the polygon's edge normals. x0 <= x1, y0 <= y1:
    float64, pixels; hull_x, hull_y: float64 arrays, pixels, the polygon's m >= 1 vertices first (as
    :func:`convex_hull` writes them)."""
    lo_x = np.inf
    hi_x = -np.inf
    lo_y = np.inf
    hi_y = -np.inf
    for i in range(m):
        lo_x = min(lo_x, hull_x[i])
        hi_x = max(hi_x, hull_x[i])
        lo_y = min(lo_y, hull_y[i])
        hi_y = max(hi_y, hull_y[i])
    if hi_x < x0 or lo_x > x1 or hi_y < y0 or lo_y > y1:
        return False
    for i in range(m):
        j = (i + 1) % m
        ex = hull_x[j] - hull_x[i]
        ey = hull_y[j] - hull_y[i]
        # Outward normal of a counter-clockwise edge: (ey, -ex). The rectangle is separated when all its corners
        # lie beyond the edge's line.
        nx = ey
        ny = -ex
        limit = nx * hull_x[i] + ny * hull_y[i]
        nearest = min(nx * x0, nx * x1) + min(ny * y0, ny * y1)
        if nearest > limit:
            return False
    return True


@kernel(inline=True)
def _tiles_spanned(edges, lo, hi):
    """(first, last) tile whose span edges[k] .. edges[k + 1] may meet [lo, hi] (clamped to the grid). edges:
    (n + 1,) float64, pixels, ``col_edges`` or ``row_edges``; lo <= hi: float64, pixels."""
    n = edges.shape[0] - 1
    first = 0
    while first < n - 1 and edges[first + 1] < lo:
        first += 1
    last = first
    while last < n - 1 and edges[last + 1] <= hi:
        last += 1
    return first, last


@kernel(inline=True)
def hull_work():
    """The work arrays of :func:`mark_projected_points` / :func:`mark_hull_tiles` for up to 8 points: (xs, ys, hull_x,
    hull_y), float64, (8,), (8,), (16,), (16,)."""
    return np.empty(8), np.empty(8), np.empty(16), np.empty(16)


@kernel(inline=True)
def clear_bits(out, k, words):
    """out[k, :words] = 0: bitset k of out ((K, words) uint64) emptied."""
    for w in range(words):
        out[k, w] = np.uint64(0)


@kernel(inline=True)
def mark_hull_tiles(xs, ys, hull_x, hull_y, col_edges, row_edges, out, k):
    """Set in out[k] (out: (K, words) uint64 bitsets, tile index r * cols + c) every tile whose footprint
    (col_edges[c] .. col_edges[c + 1] x row_edges[r] .. row_edges[r + 1], pixels) meets the convex hull of the points
    (xs, ys) ((n,) float64 each, pixels, 1 <= n <= 8); hull_x, hull_y: float64 work arrays of twice their length."""
    cols = col_edges.shape[0] - 1
    rows = row_edges.shape[0] - 1
    m = convex_hull(xs, ys, hull_x, hull_y)
    lo_x = np.inf
    hi_x = -np.inf
    lo_y = np.inf
    hi_y = -np.inf
    for i in range(xs.shape[0]):
        lo_x = min(lo_x, xs[i])
        hi_x = max(hi_x, xs[i])
        lo_y = min(lo_y, ys[i])
        hi_y = max(hi_y, ys[i])
    if hi_x < col_edges[0] or lo_x > col_edges[cols] or hi_y < row_edges[0] or lo_y > row_edges[rows]:
        return
    c_lo, c_hi = _tiles_spanned(col_edges, lo_x, hi_x)
    r_lo, r_hi = _tiles_spanned(row_edges, lo_y, hi_y)
    for r in range(r_lo, r_hi + 1):
        for c in range(c_lo, c_hi + 1):
            if _rect_meets_hull(col_edges[c], col_edges[c + 1], row_edges[r], row_edges[r + 1], hull_x, hull_y, m):
                tile = r * cols + c
                out[k, tile >> 6] |= np.uint64(1) << np.uint64(tile & 63)


@kernel(inline=True)
def mark_every_tile(n_tiles, out, k):
    """Set in out[k] ((K, words) uint64 bitsets) the bits of tiles 0 .. n_tiles - 1 (something that may be seen
    anywhere); n_tiles: int, rows * cols."""
    for tile in range(n_tiles):
        out[k, tile >> 6] |= np.uint64(1) << np.uint64(tile & 63)


@kernel(inline=True)
def _in_frame(R, t, px, py, pz):
    """(x, y, z) = R (px, py, pz) + t: the point (px, py, pz) (float64, metres, R, t's source frame) in the camera's
    optical frame."""
    return (R[0, 0] * px + R[0, 1] * py + R[0, 2] * pz + t[0], R[1, 0] * px + R[1, 1] * py + R[1, 2] * pz + t[1],
            R[2, 0] * px + R[2, 1] * py + R[2, 2] * pz + t[2])


@kernel(inline=True)
def mark_projected_points(points, R, t, fx, fy, cx, cy, near, col_edges, row_edges, out, k, xs, ys, hull_x, hull_y):
    """Set in out[k] (out: (K, words) uint64 bitsets) the tiles of the grid col_edges, row_edges whose footprint
    meets the convex hull of ``points`` ((8, 3) float64, metres) as a camera sees them (R, t: the points' frame -> its
    optical frame; fx, fy, cx, cy: its intrinsics); every tile when a point lies at optical depth <= ``near`` (float,
    metres; it may be seen anywhere). xs, ys (8,) and hull_x, hull_y (16,): float64 work arrays."""
    for i in range(points.shape[0]):
        x, y, z = _in_frame(R, t, points[i, 0], points[i, 1], points[i, 2])
        if not z > near:
            mark_every_tile((row_edges.shape[0] - 1) * (col_edges.shape[0] - 1), out, k)
            return
        xs[i] = fx * x / z + cx
        ys[i] = fy * y / z + cy
    mark_hull_tiles(xs, ys, hull_x, hull_y, col_edges, row_edges, out, k)


@kernel(parallel=True)
def tile_bands(rays, depths, R, t, fx, fy, cx, cy, col_edges, row_edges, words, out):
    """For every tile of camera A, the tiles of camera B that its frustum between depths[tile, 0] and depths[tile, 1]
    (A's optical depth, metres) can project onto, as bits in out (n_tiles_A, words) uint64 (tile index r * cols + c
    of B's grid; tile (r, c) spans col_edges[c] to col_edges[c + 1] and row_edges[r] to row_edges[r + 1], pixels).

    rays: (n_tiles_A, 4, 3) float64, the tile's corner rays in A's optical frame (z = 1: metres per metre of depth);
    depths: (n_tiles_A, 2) float64, metres, each tile's near and far optical depth in A; R, t: A's optical frame -> B's;
    fx, fy, cx, cy: B's intrinsics; col_edges, row_edges, words: B's tile grid. The frustum piece is the convex hull of
    its 8 corners; its projection is the convex hull of theirs, and a tile of B is set when its pixel rectangle meets
    that polygon (tiles are sets of pixel footprints: pixel p covers [p - 0.5, p + 0.5]). A piece that reaches behind
    B's image plane (a corner at B's depth <= 1 mm) sets every tile: it may be seen anywhere."""
    for p in prange(rays.shape[0]):  # each tile by a function compiled on its own (a loop body compiles twice)
        _tile_band(rays, depths, np.int64(p), R, t, fx, fy, cx, cy, col_edges, row_edges, words, out)


@kernel()
def _tile_band(rays, depths, a, R, t, fx, fy, cx, cy, col_edges, row_edges, words, out):
    """Tile a (int) of :func:`tile_bands`: out[a] written. rays (n_tiles_A, 4, 3), depths (n_tiles_A, 2), R, t, fx,
    fy, cx, cy, col_edges, row_edges, words and out as :func:`tile_bands` takes them."""
    corners = np.empty((8, 3))
    xs, ys, hull_x, hull_y = hull_work()
    clear_bits(out, a, words)
    for corner in range(8):
        z = depths[a, corner // 4]
        for axis in range(3):
            corners[corner, axis] = rays[a, corner % 4, axis] * z
    mark_projected_points(corners, R, t, fx, fy, cx, cy, 1e-3, col_edges, row_edges, out, a, xs, ys, hull_x, hull_y)


@kernel(inline=True)
def _ball_slopes(a, z, rho):
    """(lowest, highest) a' / z' over the ball of radius rho around (a, z) in a plane through the camera centre
    (z > rho): the slopes of the two tangents from the centre, exact (tangents x/z or y/z, no unit). a: float64,
    metres, the centre's optical x (or y); z: float64, metres, its optical depth; rho: float64, metres."""
    d = z * z - rho * rho
    root = rho * np.sqrt(a * a + d)
    return (a * z - root) / d, (a * z + root) / d


@kernel(inline=True)
def _capsule_set_bits(ends, k, radii, R, t, fx, fy, cx, cy, col_edges, row_edges, words, out):
    """Set k of :func:`capsule_tile_bits` (the work of one configuration): clears and writes out[k], out (K, words)
    uint64; ends, radii, R, t (world -> optical), fx, fy, cx, cy, col_edges, row_edges, words as there."""
    m = ends.shape[1]
    cols = col_edges.shape[0] - 1
    rows = row_edges.shape[0] - 1
    xs, ys, hull_x, hull_y = hull_work()
    clear_bits(out, k, words)
    for j in range(m):
        rho = radii[j]
        behind = False
        for e in range(2):
            x, y, z = _in_frame(R, t, ends[k, j, e, 0], ends[k, j, e, 1], ends[k, j, e, 2])
            if not z - rho > 1e-3:
                behind = True
                break
            u0, u1 = _ball_slopes(x, z, rho)
            v0, v1 = _ball_slopes(y, z, rho)
            u0 = fx * u0 + cx
            u1 = fx * u1 + cx
            v0 = fy * v0 + cy
            v1 = fy * v1 + cy
            xs[4 * e] = u0
            ys[4 * e] = v0
            xs[4 * e + 1] = u1
            ys[4 * e + 1] = v0
            xs[4 * e + 2] = u0
            ys[4 * e + 2] = v1
            xs[4 * e + 3] = u1
            ys[4 * e + 3] = v1
        if behind:
            mark_every_tile(rows * cols, out, k)
            return
        mark_hull_tiles(xs, ys, hull_x, hull_y, col_edges, row_edges, out, k)


@kernel()
def capsule_tile_bits(ends, radii, R, t, fx, fy, cx, cy, col_edges, row_edges, words, out):
    """For each of K sets of m capsules, the tiles of one camera that any capsule's projection can meet, as bits in
    out (K, words) uint64 (written, tile index r * cols + c; tile footprints as in :func:`tile_bands`). One thread:
    for one or a few sets (a parallel region costs more than the work, and stalls when the other core is busy);
    :func:`capsule_tile_bits_parallel` for many.

    ends: (K, m, 2, 3) float64, the capsules' core segments, world frame, metres; radii: (m,) float64, metres; R, t:
    world -> the camera's optical frame; fx, fy, cx, cy: its intrinsics. A capsule is the convex hull of its two end
    balls, so its projection is the convex hull of theirs; each ball's projection lies in the pixel rectangle bounded by
    its tangent planes through the camera's x and y axes (exact slopes). A tile is set when its footprint meets the
    convex hull of the two rectangles, a superset of the capsule's projection. A capsule that reaches within 1 mm of the
    camera's plane (or behind it) sets every tile."""
    for k in range(ends.shape[0]):
        _capsule_set_bits(ends, k, radii, R, t, fx, fy, cx, cy, col_edges, row_edges, words, out)


@kernel(parallel=True)
def capsule_tile_bits_parallel(ends, radii, R, t, fx, fy, cx, cy, col_edges, row_edges, words, out):
    """:func:`capsule_tile_bits` with the sets spread over the threads: the same arguments (ends (K, m, 2, 3), radii
    (m,), R, t world -> optical), and out (K, words) uint64 written the same."""
    for k in prange(ends.shape[0]):
        _capsule_set_bits(ends, k, radii, R, t, fx, fy, cx, cy, col_edges, row_edges, words, out)


@kernel(parallel=True)
def tile_moments(image, first_row, first_col, row_weight, out):
    """Per tile, the sum of the pixel values and of the values times their row's weight: out (rows, cols, 2) float64
    (written). image: (height, width) numbers (uint8, uint16, float32 or float64 grey values, indexed [v, u]);
    first_row (rows + 1,), first_col (cols + 1,) int64 each tile's first pixel (and the image's size); row_weight:
    (height,) float64, no unit (the caller's: each pixel row's position within its tile, 0 at the first, 1 at the
    last, 0.5 in a tile of one row)."""
    rows = first_row.shape[0] - 1
    cols = first_col.shape[0] - 1
    for r in prange(rows):  # each tile row writes its own row of out
        for c in range(cols):
            out[r, c, 0] = 0.0
            out[r, c, 1] = 0.0
        for v in range(first_row[r], first_row[r + 1]):
            weight = row_weight[v]
            for c in range(cols):
                total = 0.0
                for u in range(first_col[c], first_col[c + 1]):
                    total += image[v, u]
                out[r, c, 0] += total
                out[r, c, 1] += total * weight


@kernel(inline=True)
def _nearest_robot(near, v, u):
    """Metres: the nearest surface of the rendered robot ``near`` ((height, width) float32, 0 where it is not) among
    pixel (v, u) and its 8 neighbours (clamped at the border), inf when the robot is at none of them."""
    height, width = near.shape
    d_r = np.inf
    for dv in range(-1, 2):
        vv = min(max(v + dv, 0), height - 1)
        for du in range(-1, 2):
            x = np.float64(near[vv, min(max(u + du, 0), width - 1)])
            if x > 0.0 and x < d_r:
                d_r = x
    return d_r


@kernel(parallel=True)
def unexplained_changes(now, scale, reference, threshold, k0, k1, k2, near, tolerance, first_row, first_col, wanted,
                        out):
    """Per tile, the number of changed pixels that the current robot cannot explain: out (rows, cols) float64 (written).
    now, scale, reference, threshold, k0, k1, k2, first_row, first_col: as :func:`depth_changes` takes them (the
    image in units of scale metres, the reference in metres, the change threshold in metres, the noise margin's
    coefficients, the tiles' first pixels), and a pixel changed by its rule. near: (height, width) float32 metres,
    the nearest surface of the robot's padded geometry rendered into the camera at the images' joints, 0 where it is
    not (the self-filter's render, design §7); tolerance: float, metres, the self-filter's. A changed pixel is the
    robot's only where the robot is rendered within one pixel of it (d_r: the nearest such surface in its 3 x 3
    neighbourhood) and its measurement lies no nearer than d_r - tolerance - m(d_r), or it has none (the robot may
    drop a pixel); any other changed pixel shows something that is not the robot. wanted: (rows, cols) bool, the
    tiles to count (the others are 0: work only where the answer can matter). One thread per row of tiles."""
    rows = first_row.shape[0] - 1
    cols = first_col.shape[0] - 1
    for r in prange(rows):
        for c in range(cols):
            out[r, c] = 0.0
        for v in range(first_row[r], first_row[r + 1]):
            for c in range(cols):
                if not wanted[r, c]:
                    continue
                count = 0
                for u in range(first_col[c], first_col[c + 1]):
                    d = now[v, u] * scale
                    ref = reference[v, u]
                    seen = d > 0.0 and d < np.inf
                    if seen == (ref > 0.0) and \
                            (not seen or abs(d - ref) <= max(threshold, k0 + k1 * ref + k2 * ref * ref)):
                        continue  # unchanged
                    d_r = _nearest_robot(near, v, u)
                    if d_r < np.inf and (not seen or d >= d_r - tolerance - max(k0 + (k1 + k2 * d_r) * d_r, 0.0)):
                        continue  # the robot may be what changed here
                    count += 1
                out[r, c] += count


@kernel(parallel=True)
def unexplained_grey(image, reference, gain, grey, near, first_row, first_col, wanted, out):
    """Per tile, the number of pixels whose grey value changed where the current robot cannot be: out (rows, cols)
    float64 (written). image: (height, width) uint8 grey values (or float64); reference: (height, width) float64, the
    reference image's grey values; gain: float, the image's brightness relative to the reference (its values are divided by
    it); grey: float, grey levels: a pixel changed when |image / gain - reference| exceeds it; near: (height, width)
    float32 metres, the robot's padded geometry rendered at the image's joints, 0 where it is not: a pixel counts only
    when nothing of the robot is rendered in its 3 x 3 neighbourhood; first_row, first_col: the tiles' first pixels;
    wanted: (rows, cols) bool, the tiles to count (the others are 0). One thread per row of tiles."""
    rows = first_row.shape[0] - 1
    cols = first_col.shape[0] - 1
    for r in prange(rows):
        for c in range(cols):
            out[r, c] = 0.0
        for v in range(first_row[r], first_row[r + 1]):
            for c in range(cols):
                if not wanted[r, c]:
                    continue
                count = 0
                for u in range(first_col[c], first_col[c + 1]):
                    if abs(np.float64(image[v, u]) / gain - reference[v, u]) <= grey:
                        continue
                    if _nearest_robot(near, v, u) == np.inf:
                        count += 1
                out[r, c] += count


@kernel(parallel=True)
def depth_changes(now, scale, reference, threshold, k0, k1, k2, first_row, first_col, out):
    """Per tile, the number of pixels whose depth changed: out (rows, cols) float64 (written). now: (height, width)
    depth in units of ``scale`` metres (uint16 with the camera's depth_scale, or float32 / float64 metres with scale
    1; not finite or <= 0: no measurement); reference: (height, width) float64 metres, 0 = no measurement. A pixel
    changed when exactly one of the two measures, or both do and differ by more than
    max(threshold, k0 + k1 d + k2 d^2) at the reference's depth d (the camera's noise margin). threshold: float,
    metres; k0, k1, k2: float, the camera's NoiseModel.coefficients() (metres, no unit, per metre). first_row,
    first_col: the tiles' first pixels."""
    rows = first_row.shape[0] - 1
    cols = first_col.shape[0] - 1
    for r in prange(rows):  # each tile row writes its own row of out
        for c in range(cols):
            out[r, c] = 0.0
        for v in range(first_row[r], first_row[r + 1]):
            for c in range(cols):
                changed = 0
                for u in range(first_col[c], first_col[c + 1]):
                    d = now[v, u] * scale
                    ref = reference[v, u]
                    seen = d > 0.0 and d < np.inf
                    if seen != (ref > 0.0):
                        changed += 1
                    elif seen:
                        tolerance = max(threshold, k0 + k1 * ref + k2 * ref * ref)
                        if abs(d - ref) > tolerance:
                            changed += 1
                out[r, c] += changed
