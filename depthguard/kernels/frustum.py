"""Numba kernels shared by the single-camera depth-space distance (:mod:`depthguard.depthspace`) and the depth grid's
fusion (:mod:`depthguard.depthgrid`): a pixel frustum's exact nearest point (design §4), the surveillance region
(design §5), the aggregation of contributors into one answer (design §6), and the noise margin.

Everything here works in one camera's optical frame (x right, y down, z forward; metres) and trusts its inputs: the
public functions validate them. A pixel (u, v) spans the tangents [a0, a1] x [b0, b1] with
a0 = (u - 1/2 - cx)/fx, a1 = (u + 1/2 - cx)/fx, b0 = (v - 1/2 - cy)/fy, b1 = (v + 1/2 - cy)/fy.

The tests hold these kernels against slow NumPy twins (``tests/naive.py``).

Arguments used throughout:

- ``X, Y, Z``: float64, metres: the point P (a control point) in the camera's optical frame.
- ``a0, a1, b0, b1``: float64, tangents (x/z and y/z, no unit): the frustum {x/z in [a0, a1], y/z in [b0, b1]}; for
  pixel (u, v) the values above, for a block of pixels those of its outer edges (b0, b1 alone: a row's).
- ``z_lo, z_hi``: float64, metres: the frustum's segment between these optical depths, z_lo <= z_hi (z_hi may be
  inf).
- ``rho``: float64, metres: the radius of the surveillance region around P.
- ``fx, fy, cx, cy``: float, pixels: the camera's intrinsics.
- ``width, height``: int, pixels: the image's size.
- ``z_min, z_max``: float, metres: the camera's valid depth range, which with the image's edges bounds the observed
  volume (z_max may be inf).
- ``u_lo, u_hi, v_lo, v_hi``: int, pixels: the window of columns and rows to visit, inclusive (:func:`cube_window`).
- ``spans``: (height, 2) int64: per image row v, the first and last column to visit (first > last: none).
- ``unseen_occupied``: bool: unseen space counts as possibly occupied (``unseen="occupied"``, design §3).
- ``near_eps``: float, metres: a cube corner at or nearer than this optical depth makes the window the whole image
  (``config.NEAR_PLANE_EPSILON``).
- ``inside_tol``: float, metres: a distance at or below it means P is inside (``config.INSIDE_TOLERANCE``).
- ``min_direction``: float, no unit: a sum of unit directions shorter than min_direction times their count gives the
  zero vector (``config.MIN_DIRECTION_NORM``).
- ``aggregate``: int: AGG_MIN, AGG_MEAN or AGG_HYBRID (0, 1, 2: the index in ``config.AGGREGATES``).
- ``out_direction``: (3,) float64, written: the unit direction from the obstacle towards P, optical frame (zero for
  none).
- ``flags``: int: the bits of :class:`depthguard.results.Flag` (the FLAG_* values) set so far.
- ``unseen_d, nx, ny, nz``: float64: the distance (metres) from P to the observed volume's boundary when the boundary
  counts as a contributor (inf when it does not), and the boundary's inward unit normal (optical frame), as
  :func:`surveillance_region` returns them.
- ``best2, best_invalid``: float64, square metres: the nearest contributor's squared distance (inf: none); int, 1 when
  it came from a pixel without a valid measurement, else 0.
"""

import numpy as np
from numba import prange

from depthguard.kernels.jit import kernel

# Aggregation codes (config.AGGREGATES order).
AGG_MIN = 0
AGG_MEAN = 1
AGG_HYBRID = 2

# Flag bits (depthguard.results.Flag holds the same values).
FLAG_INSIDE_OBSTACLE = 1
FLAG_REGION_OUTSIDE_VIEW = 2
FLAG_INVALID_PIXELS_USED = 4
FLAG_ROBOT_BLIND_SPOT = 32

# Tangent units by which the ball's silhouette spans are widened against rounding (about 5e-7 pixel at f = 525).
SILHOUETTE_PAD = 1e-9

# The smallest rho^2 the kernels compare squared distances with (the smallest normal float64): a point inside an
# occupied set (d^2 = 0) is within rho even where rho^2 underflows (rho = 1e-200, which the public functions refuse).
MIN_RHO2 = 2.2250738585072014e-308

# The kernels trust their inputs (the public functions check them: rho in [config.RHO_MIN, config.RHO_MAX], points
# finite and within config.COORDINATE_LIMIT), and are exact within those ranges. Beyond them (check=False) they stay
# memory-safe and finish, and answer conservatively where they cannot compute: every float is clamped before it
# becomes an index, a point that is not finite is "unseen" (distance 0), a NaN rho counts as inf.


@kernel(inline=True)
def noise_margin(d, m0, m1, m2):
    """m(d) = max(m0 + m1 d + m2 d^2, 0), metres: the noise margin of a measurement at depth d (design §3), from
    the camera's NoiseModel.coefficients(). All float64: d and m0 in metres, m1 no unit, m2 per metre."""
    return max(m0 + (m1 + m2 * d) * d, 0.0)


@kernel(inline=True)
def usable_rho(rho):
    """rho as the kernels use it: NaN counts as inf (every pixel is looked at), a negative rho as 0."""
    if rho != rho:
        return np.inf
    return max(rho, 0.0)


@kernel(inline=True)
def rho_squared(rho):
    """rho^2, at least :data:`MIN_RHO2`."""
    return max(rho * rho, MIN_RHO2)


@kernel(inline=True)
def clamped_index(x, lo, hi):
    """int(x) for a float x clamped to the whole numbers [lo, hi] (ints, lo <= hi) first (int() of a huge or NaN
    float is garbage);
    NaN gives lo. (max(a, b) and min(a, b) return a unless b is larger, smaller: never a NaN b.)"""
    return int(min(float(hi), max(float(lo), x)))


@kernel()
def frustum_nearest(X, Y, Z, a0, a1, b0, b1, z_lo, z_hi):
    """Squared distance from P = (X, Y, Z) to the frustum segment {x/z in [a0, a1], y/z in [b0, b1], z in [z_lo,
    z_hi]} (z_hi may be inf), and the depth z* of its nearest point.

    The nearest point itself is (clamp(X, a0*z*, a1*z*), clamp(Y, b0*z*, b1*z*), z*).

    g(z) = dx(z)^2 + dy(z)^2 + (Z - z)^2 with dx(z) = max(a0*z - X, 0, X - a1*z) (dy alike) is convex and, because
    dx and dy vanish at their breakpoints X/a0, X/a1, Y/b0, Y/b1, continuously differentiable; on each piece between
    breakpoints it is one quadratic with a closed-form minimiser. :func:`guessed_piece` tries the piece at
    clamp(Z, z_lo, z_hi), where the minimiser usually lies; where it fails, walk the pieces from z_lo
    (:func:`frustum_nearest_walk`).
    """
    d2, z, ok = guessed_piece(X, Y, Z, a0, a1, b0, b1, z_lo, z_hi)
    if ok:
        return d2, z
    return frustum_nearest_walk(X, Y, Z, a0, a1, b0, b1, _breakpoint(X, a0), _breakpoint(X, a1), _breakpoint(Y, b0),
                                _breakpoint(Y, b1), z_lo, z_hi)


@kernel(inline=True)
def frustum_direction(X, Y, Z, a0, a1, b0, b1, z, d):
    """The unit vector from the nearest point of a pixel frustum's slice at depth z (float64, metres),
    (clamp(X, a0 z, a1 z), clamp(Y, b0 z, b1 z), z), towards P = (X, Y, Z), which lies d > 0 metres (float64) from
    it. Optical frame."""
    inv_d = 1.0 / d
    return ((X - min(max(X, a0 * z), a1 * z)) * inv_d, (Y - min(max(Y, b0 * z), b1 * z)) * inv_d,
            (Z - z) * inv_d)


@kernel(inline=True)
def guessed_piece(X, Y, Z, a0, a1, b0, b1, z_lo, z_hi):
    """The minimiser of g on the piece that holds z_g = clamp(Z, z_lo, z_hi), clamped to [z_lo, z_hi].

    It is the global minimiser if it lies in the closure of that same piece: each lateral state (left of, inside
    or right of the frustum) holds on an interval of z, so checking the states at the minimiser is exact. Branch-free
    apart from the selects, so that loops over pixels vectorise. Returns (g(z), z, ok).
    """
    z_guess = min(max(Z, z_lo), z_hi)
    left_x = a0 * z_guess > X
    right_x = X > a1 * z_guess
    left_y = b0 * z_guess > Y
    right_y = Y > b1 * z_guess
    ax = a0 if left_x else (a1 if right_x else 0.0)
    by = b0 if left_y else (b1 if right_y else 0.0)
    z = min(max((Z + ax * X + by * Y) / (1.0 + ax * ax + by * by), z_lo), z_hi)
    ok_x = (a0 * z >= X) if left_x else ((X >= a1 * z) if right_x else ((a0 * z <= X) & (X <= a1 * z)))
    ok_y = (b0 * z >= Y) if left_y else ((Y >= b1 * z) if right_y else ((b0 * z <= Y) & (Y <= b1 * z)))
    dx = max(max(a0 * z - X, 0.0), X - a1 * z)
    dy = max(max(b0 * z - Y, 0.0), Y - b1 * z)
    return dx * dx + dy * dy + (Z - z) * (Z - z), z, ok_x & ok_y


@kernel(inline=True)
def _breakpoint(c, a):
    """Depth c/a (metres) where a*z - c changes sign; -1 (never, for z > 0) when a == 0. c: float64, metres, X or Y;
    a: float64, the tangent a0, a1, b0 or b1 it is compared with."""
    return c / a if a != 0.0 else -1.0


@kernel(inline=True)
def frustum_nearest_walk(X, Y, Z, a0, a1, b0, b1, t0, t1, t2, t3, z_lo, z_hi):
    """:func:`frustum_nearest` by walking the pieces from z_lo to z_hi, given the breakpoints t0 = X/a0, t1 = X/a1,
    t2 = Y/b0, t3 = Y/b1 (float64 optical depths, metres; any value <= z_lo, or NaN, for "none"). P = (X, Y, Z).

    On each piece the state (left of, inside or right of the frustum, in x and in y) is read at the piece's
    midpoint; the first piece that holds its own minimiser holds the global one, and if a piece's minimiser lies
    before the piece, the derivative changes sign at the piece's start, which can only be z_lo.
    """
    z = z_lo
    z_star = z_lo
    for _ in range(6):
        s2 = 1.0
        s1 = Z
        z_next = z_hi
        if z < t0 < z_next:
            z_next = t0
        if z < t1 < z_next:
            z_next = t1
        if z < t2 < z_next:
            z_next = t2
        if z < t3 < z_next:
            z_next = t3
        z_mid = 0.5 * (z + z_next) if z_next < np.inf else z + 1.0
        if a0 * z_mid > X:
            s2 += a0 * a0
            s1 += a0 * X
        elif X > a1 * z_mid:
            s2 += a1 * a1
            s1 += a1 * X
        if b0 * z_mid > Y:
            s2 += b0 * b0
            s1 += b0 * Y
        elif Y > b1 * z_mid:
            s2 += b1 * b1
            s1 += b1 * Y
        z_c = s1 / s2
        if z_c <= z:
            z_star = z
            break
        if z_c < z_next:
            z_star = z_c
            break
        z = z_next
        z_star = z_next
        if z_next >= z_hi:
            break
    dx = max(a0 * z_star - X, 0.0, X - a1 * z_star)
    dy = max(b0 * z_star - Y, 0.0, Y - b1 * z_star)
    dz = Z - z_star
    return dx * dx + dy * dy + dz * dz, z_star


@kernel(inline=True)
def frustum_nearest_paper(X, Y, Z, a0, a1, b0, b1, z_lo, z_hi):
    """The papers' distance (2015 eqs. 7-8): the point of frustum [a0, a1] x [b0, b1] at the fixed depth
    clamp(Z, z_lo, z_hi) nearest to P = (X, Y, Z).

    It lies on the frustum, so it is an upper bound of the true distance: unsafe, kept for comparison only.
    Returns (squared distance, depth of the point).
    """
    z = min(max(Z, z_lo), z_hi)
    dx = max(a0 * z - X, 0.0, X - a1 * z)
    dy = max(b0 * z - Y, 0.0, Y - b1 * z)
    dz = Z - z
    return dx * dx + dy * dy + dz * dz, z


@kernel(inline=True)
def view_boundary(X, Y, Z, tx0, tx1, ty0, ty1, z_min, z_max):
    """Signed distance from P to the boundary of the observed volume and the boundary's inward unit normal.

    The observed volume {tx0 <= x/z <= tx1, ty0 <= y/z <= ty1, z_min <= z <= z_max} (image edges at tangents tx0..
    tx1, ty0..ty1; z_max may be inf) is convex, so for P inside it the distance to its boundary is the smallest
    distance to a face plane. Returns (s, nx, ny, nz): s >= 0 inside (the distance), s < 0 outside; (nx, ny, nz)
    points from that face into the view. P = (X, Y, Z); tx0 < tx1, ty0 < ty1: float64 tangents (x/z, y/z) of the
    image's outer pixel edges.
    """
    k = 1.0 / np.sqrt(1.0 + tx0 * tx0)
    s = (X - tx0 * Z) * k
    nx, ny, nz = k, 0.0, -tx0 * k
    k = 1.0 / np.sqrt(1.0 + tx1 * tx1)
    t = (tx1 * Z - X) * k
    if t < s:
        s, nx, ny, nz = t, -k, 0.0, tx1 * k
    k = 1.0 / np.sqrt(1.0 + ty0 * ty0)
    t = (Y - ty0 * Z) * k
    if t < s:
        s, nx, ny, nz = t, 0.0, k, -ty0 * k
    k = 1.0 / np.sqrt(1.0 + ty1 * ty1)
    t = (ty1 * Z - Y) * k
    if t < s:
        s, nx, ny, nz = t, 0.0, -k, ty1 * k
    t = Z - z_min
    if t < s:
        s, nx, ny, nz = t, 0.0, 0.0, 1.0
    t = z_max - Z
    if t < s:
        s, nx, ny, nz = t, 0.0, 0.0, -1.0
    return s, nx, ny, nz


@kernel(inline=True)
def cube_window(X, Y, Z, rho, fx, fy, cx, cy, width, height, near_eps):
    """Pixels to visit for P = (X, Y, Z): the image bounding box of the cube [P - rho, P + rho] (design §5), in the
    image of width x height pixels with intrinsics fx, fy, cx, cy.

    Returns (u_lo, u_hi, v_lo, v_hi), inclusive, clamped to the image (u_lo > u_hi when it is empty). If a corner
    lies at or behind the near plane z = near_eps, the whole image.
    """
    if Z - rho <= near_eps:
        return 0, width - 1, 0, height - 1
    zn = Z - rho
    zf = Z + rho
    x_lo = min((X - rho) / zn, (X - rho) / zf)
    x_hi = max((X + rho) / zn, (X + rho) / zf)
    y_lo = min((Y - rho) / zn, (Y - rho) / zf)
    y_hi = max((Y + rho) / zn, (Y + rho) / zf)
    u_lo, u_hi = footprint_span(x_lo, x_hi, fx, cx, width)
    v_lo, v_hi = footprint_span(y_lo, y_hi, fy, cy, height)
    return u_lo, u_hi, v_lo, v_hi


@kernel(inline=True)
def footprint_span(t_lo, t_hi, f, c, size):
    """Pixels i in [0, size) whose footprint [i - 1/2, i + 1/2] meets the image coordinates [f*t_lo + c, f*t_hi + c]
    (t: tangents x/z or y/z, float64). f, c: float, pixels (fx, cx or fy, cy); size: int, pixels (width or height).
    Returns (lo, hi), inclusive; lo > hi when there is none."""
    return index_span(np.ceil(f * t_lo + c - 0.5), np.floor(f * t_hi + c + 0.5), size)


@kernel(inline=True)
def index_span(lo, hi, size):
    """The whole numbers lo..hi (float64, pixels) clamped to [0, size) (size: int) before they become integers:
    (first, last), first > last when none. NaN (only from numbers the public functions refuse) gives the whole
    range."""
    return int(min(float(size), max(0.0, lo))), int(max(-1.0, min(float(size - 1), hi)))


@kernel(inline=True)
def ball_silhouette_rows(X, Y, Z, rho, fx, fy, cx, cy, width, v_lo, v_hi, u_lo, u_hi, pad, spans):
    """For each row v in [v_lo, v_hi], the columns whose pixel frustum can come closer than rho to P: those whose
    footprint meets the ball's silhouette (the cone from the optical centre around the ball of radius rho).

    Needs Z > rho (the ball in front of the camera, so the silhouette is an ellipse in the plane z = 1). The
    silhouette is {(x, y): (x*X + y*Y + Z)^2 >= c*(x^2 + y^2 + 1)}, c = |P|^2 - rho^2; its part inside the row's band
    of tangents [b0, b1] is convex, so its x-extent runs from the left boundary at the clamped y of the leftmost
    point to the right boundary at the clamped y of the rightmost point. ``pad`` (float64, tangent units) widens
    every span against rounding. Writes spans[v, 0] = first column, spans[v, 1] = last column (first > last when
    none), within [u_lo, u_hi], for the image of ``width`` columns and intrinsics fx, fy, cx, cy.

    The cone is the same for (X, Y, Z, rho) scaled by any factor, so they are first divided by max(|X|, |Y|, |Z|):
    the squares below then never overflow, whatever the point's distance. A row whose span is not a number (only
    from numbers no kernel should get) keeps [u_lo, u_hi] whole.
    """
    scale = max(abs(X), abs(Y), abs(Z))
    X = X / scale
    Y = Y / scale
    Z = Z / scale
    rho = rho / scale
    c = X * X + Y * Y + Z * Z - rho * rho
    q = Z * Z - rho * rho
    root_x = rho * np.sqrt(max(X * X + Z * Z - rho * rho, 0.0))
    root_y = rho * np.sqrt(max(Y * Y + Z * Z - rho * rho, 0.0))
    x_left = (X * Z - root_x) / q  # the planes x = t*z that touch the ball
    x_right = (X * Z + root_x) / q
    y_top = (Y * Z - root_y) / q  # the planes y = t*z that touch the ball
    y_bottom = (Y * Z + root_y) / q
    w = X * X + Z * Z - rho * rho  # c - Y^2 > 0
    y_of_left = Y * (x_left * X + Z) / w  # the row of the silhouette's leftmost point
    y_of_right = Y * (x_right * X + Z) / w
    A = rho * rho - Y * Y - Z * Z  # < 0: the x^2 coefficient
    for v in range(v_lo, v_hi + 1):
        b0 = (v - 0.5 - cy) / fy
        b1 = (v + 0.5 - cy) / fy
        y0 = max(b0, y_top - pad)
        y1 = min(b1, y_bottom + pad)
        if y0 > y1:
            spans[v, 0] = 1
            spans[v, 1] = 0
            continue
        yl = min(max(y_of_left, y0), y1)
        B = X * (yl * Y + Z)
        C = (yl * Y + Z) ** 2 - c * (yl * yl + 1.0)
        x_lo = (-B + np.sqrt(max(B * B - A * C, 0.0))) / A
        yr = min(max(y_of_right, y0), y1)
        B = X * (yr * Y + Z)
        C = (yr * Y + Z) ** 2 - c * (yr * yr + 1.0)
        x_hi = (-B - np.sqrt(max(B * B - A * C, 0.0))) / A
        lo, hi = footprint_span(x_lo - pad, x_hi + pad, fx, cx, width)
        if x_lo != x_lo or x_hi != x_hi:
            lo, hi = u_lo, u_hi
        spans[v, 0] = max(lo, u_lo)
        spans[v, 1] = min(hi, u_hi)


@kernel()
def nearest_in_blocks(X, Y, Z, rho, z_start, z_end, bounded, invalid, block_min, block, fx, fy, cx, cy, u_lo, u_hi,
                       v_lo, v_hi, near_eps, spans):
    """The nearest contributing pixel for ``min``: visit blocks of pixels in rings around P's pixel, skipping a block
    whose minimum start depth lies behind the region or whose bounding frustum is farther than the best distance so far.
    Ties go to the smallest (v, u), as in a full scan. Pixel segments are [z_start, z_end] if ``bounded`` (bool), else
    [z_start, inf). (Callers pass ``np.bool_(True)``, not ``True``: numba would compile the kernel once for each
    literal.)

    P = (X, Y, Z); z_start, z_end: (height, width) float32, metres, the pixels' segments (the start depths and their
    ends, or ``blind``, or the depth grid's ``unchecked_from`` and ``blind_from``); invalid: (height, width) uint8, 1
    for a pixel without a valid measurement, read for the nearest pixel only (fusion passes its ``certain``, whose
    answer it does not use); block_min: (ceil(height / block), ceil(width / block)) float32, metres, z_start's minima
    over blocks of ``block`` (int) pixels a side. Only the window u_lo..u_hi, v_lo..v_hi and, in each row, its ``spans``
    are visited; the camera's intrinsics fx, fy, cx, cy and ``near_eps`` find P's pixel.

    Returns (best d^2 (inf if none below rho^2), v, u, z*, invalid flag of that pixel).
    """
    height, width = z_start.shape
    rho2 = rho_squared(rho)
    z_far = Z + rho
    inv_fx = 1.0 / fx
    inv_fy = 1.0 / fy
    best2 = np.inf
    best_v = height
    best_u = width
    best_z = 0.0
    best_invalid = 0
    bu_lo = u_lo // block
    bu_hi = u_hi // block
    bv_lo = v_lo // block
    bv_hi = v_hi // block
    if Z > near_eps:
        pu = fx * X / Z + cx
        pv = fy * Y / Z + cy
    else:
        pu = 0.5 * (u_lo + u_hi)
        pv = 0.5 * (v_lo + v_hi)
    cbu = clamped_index(pu, u_lo, u_hi) // block
    cbv = clamped_index(pv, v_lo, v_hi) // block
    rings = max(cbu - bu_lo, bu_hi - cbu, cbv - bv_lo, bv_hi - cbv)
    for r in range(rings + 1):
        for bv in range(cbv - r, cbv + r + 1):
            if bv < bv_lo or bv > bv_hi:
                continue
            step = 1 if (r == 0 or bv == cbv - r or bv == cbv + r) else 2 * r
            for bu in range(cbu - r, cbu + r + 1, step):
                if bu < bu_lo or bu > bu_hi:
                    continue
                z_block = np.float64(block_min[bv, bu])
                if z_block > z_far:
                    continue
                v0 = max(bv * block, v_lo)
                v1 = min(bv * block + block - 1, v_hi)
                u0 = bu * block
                u1 = bu * block + block - 1
                c0 = u1 + 1  # the block's columns that some row's silhouette span reaches
                c1 = u0 - 1
                for v in range(v0, v1 + 1):
                    c0 = min(c0, max(spans[v, 0], u0))
                    c1 = max(c1, min(spans[v, 1], u1))
                if c0 > c1:
                    continue
                lb2, _ = frustum_nearest(X, Y, Z, (c0 - 0.5 - cx) * inv_fx, (c1 + 0.5 - cx) * inv_fx,
                                         (v0 - 0.5 - cy) * inv_fy, (v1 + 0.5 - cy) * inv_fy, z_block, np.inf)
                if lb2 >= rho2 or lb2 > best2:
                    continue
                for v in range(v0, v1 + 1):
                    b0 = (v - 0.5 - cy) * inv_fy
                    b1 = (v + 0.5 - cy) * inv_fy
                    for u in range(max(spans[v, 0], u0), min(spans[v, 1], u1) + 1):
                        zs = z_start[v, u]
                        if zs > z_far:
                            continue
                        d2, z_star = frustum_nearest(X, Y, Z, (u - 0.5 - cx) * inv_fx, (u + 0.5 - cx) * inv_fx, b0,
                                                     b1, np.float64(zs),
                                                     np.float64(z_end[v, u]) if bounded else np.inf)
                        if d2 < rho2 and (d2 < best2 or (d2 == best2 and (v < best_v or (v == best_v
                                                                                         and u < best_u)))):
                            best2 = d2
                            best_v = v
                            best_u = u
                            best_z = z_star
                            best_invalid = invalid[v, u]
    return best2, best_v, best_u, best_z, best_invalid


@kernel()
def guess_piece_row(X, Y, Z, b0, b1, z_in, z_hi_in, u_in, m, inv_fx, cx, d2_out, z_out):
    """:func:`guessed_piece` for m pixels of one row (tangents b0, b1): pixel k has column u_in[k] and segment
    [z_in[k], z_hi_in[k]]. Writes d2_out[k] = g(z*) and z_out[k] = z*, or d2_out[k] = -1 where the guessed piece does
    not hold the minimiser and the caller must walk. A loop of its own, so that it vectorises.

    P = (X, Y, Z); z_in, z_hi_in, u_in, d2_out, z_out: float64 arrays of at least m (int) entries (rows of the
    callers' scratch): metres, metres, columns (whole numbers, pixels), square metres, metres; inv_fx: float, 1 / fx,
    per pixel; cx: float, pixels."""
    for k in range(m):
        d2, z, ok = guessed_piece(X, Y, Z, (u_in[k] - 0.5 - cx) * inv_fx, (u_in[k] + 0.5 - cx) * inv_fx, b0, b1,
                                  z_in[k], z_hi_in[k])
        d2_out[k] = d2 if ok else -1.0
        z_out[k] = z


@kernel()
def surveillance_region(X, Y, Z, rho, width, height, fx, fy, cx, cy, z_min, z_max, unseen_occupied, near_eps,
                        inside_tol, spans, out_direction):
    """What every query of one point P = (X, Y, Z) starts with (single camera and fused): the observed volume's
    boundary and the pixels to visit, in the image of width x height pixels (intrinsics fx, fy, cx, cy, valid depths
    z_min..z_max).

    Clears out_direction (3,). Returns (flags, P unseen?, unseen_d, nx, ny, nz, u_lo, u_hi, v_lo, v_hi): the
    REGION_OUTSIDE_VIEW flag; whether P itself lies in unseen space under ``unseen_occupied`` (the answer is then
    0); the observed volume's boundary as a contributor (distance unseen_d, inf when it does not count, and inward
    normal); the cube window, v_lo > v_hi when it is empty. Fills spans[v] for the window's rows with the columns
    that meet the silhouette of the ball B(P, rho), and P's own pixel.

    A point that is not finite (which the public functions refuse) is unseen: nothing can be computed for it.
    """
    out_direction[0] = 0.0
    out_direction[1] = 0.0
    out_direction[2] = 0.0
    if not (np.isfinite(X) and np.isfinite(Y) and np.isfinite(Z)):
        return FLAG_REGION_OUTSIDE_VIEW, True, np.inf, 0.0, 0.0, 0.0, 0, -1, 0, -1
    flags = 0
    s_view, nx, ny, nz = view_boundary(X, Y, Z, (-0.5 - cx) / fx, (width - 0.5 - cx) / fx, (-0.5 - cy) / fy,
                                       (height - 0.5 - cy) / fy, z_min, z_max)
    if s_view < rho:
        flags |= FLAG_REGION_OUTSIDE_VIEW
    unseen_here = unseen_occupied and s_view <= inside_tol
    # The boundary of the observed volume is one more contributor when unseen space counts as occupied.
    unseen_d = s_view if (unseen_occupied and s_view < rho) else np.inf
    u_lo, u_hi, v_lo, v_hi = cube_window(X, Y, Z, rho, fx, fy, cx, cy, width, height, near_eps)
    if unseen_here:
        return flags, unseen_here, unseen_d, nx, ny, nz, u_lo, u_hi, 0, -1
    if Z - rho <= near_eps:  # the whole image
        for v in range(v_lo, v_hi + 1):
            spans[v, 0] = u_lo
            spans[v, 1] = u_hi
        return flags, unseen_here, unseen_d, nx, ny, nz, u_lo, u_hi, v_lo, v_hi
    if u_lo <= u_hi and v_lo <= v_hi:
        ball_silhouette_rows(X, Y, Z, rho, fx, fy, cx, cy, width, v_lo, v_hi, u_lo, u_hi, SILHOUETTE_PAD, spans)
    else:
        v_lo = 0
        v_hi = -1
    # P's own pixel (two or four where P projects onto their border) is always visited: rounding in the window or
    # the silhouette (a tiny rho, a far point) must never leave out the pixel whose frustum holds P.
    pu_lo, pu_hi = footprint_span(X / Z, X / Z, fx, cx, width)
    pv_lo, pv_hi = footprint_span(Y / Z, Y / Z, fy, cy, height)
    if pu_lo <= pu_hi and pv_lo <= pv_hi:
        if v_lo > v_hi:
            u_lo, u_hi, v_lo, v_hi = pu_lo, pu_hi, pv_lo, pv_hi
        for v in range(pv_lo, pv_hi + 1):
            if v < v_lo or v > v_hi or spans[v, 0] > spans[v, 1]:
                spans[v, 0] = pu_lo
                spans[v, 1] = pu_hi
            else:
                spans[v, 0] = min(spans[v, 0], pu_lo)
                spans[v, 1] = max(spans[v, 1], pu_hi)
        for v in range(pv_hi + 1, v_lo):  # rows between the own pixel's and the window's see nothing more
            spans[v, 0] = 1
            spans[v, 1] = 0
        for v in range(v_hi + 1, pv_lo):
            spans[v, 0] = 1
            spans[v, 1] = 0
        u_lo = min(u_lo, pu_lo)
        u_hi = max(u_hi, pu_hi)
        v_lo = min(v_lo, pv_lo)
        v_hi = max(v_hi, pv_hi)
    return flags, unseen_here, unseen_d, nx, ny, nz, u_lo, u_hi, v_lo, v_hi


@kernel(inline=True)
def finish_min(best2, best_invalid, ex, ey, ez, unseen_d, nx, ny, nz, flags, inside_tol, out_direction):
    """``min``'s answer from the nearest pixel (squared distance best2, its unit direction (ex, ey, ez), float64,
    optical frame; whether it had no measurement, best_invalid) and the observed volume's boundary (distance
    unseen_d, inward normal nx, ny, nz). Returns (distance, count, invalid_count, flags) and writes the direction into
    out_direction."""
    if best_invalid:
        flags |= FLAG_INVALID_PIXELS_USED
    if best2 <= inside_tol * inside_tol:
        return 0.0, 1, best_invalid, flags | FLAG_INSIDE_OBSTACLE
    if unseen_d * unseen_d < best2:
        out_direction[0] = nx
        out_direction[1] = ny
        out_direction[2] = nz
        return unseen_d, 1, 0, flags & ~FLAG_INVALID_PIXELS_USED
    if best2 == np.inf:
        return np.inf, 0, 0, flags
    out_direction[0] = ex
    out_direction[1] = ey
    out_direction[2] = ez
    return np.sqrt(best2), 1, best_invalid, flags


@kernel(inline=True)
def contribution(X, Y, Z, a0, a1, b0, b1, z, d2):
    """One contributing pixel's share of the ``mean`` and ``hybrid`` aggregations (design §6), from the nearest point
    of its frustum [a0, a1] x [b0, b1] to P = (X, Y, Z), at depth z (metres), squared distance d2 > 0 (square
    metres) or 0 inside: (P inside its frustum?, distance d, unit direction (x, y, z)
    from that point towards P; 0 inside). Both walks that sum contributors, the single camera's
    (:mod:`depthguard.kernels.depthspace`) and the depth grid's (:mod:`depthguard.kernels.depthgrid`), add these;
    :func:`finish_sum` turns the sums into the answer."""
    if d2 <= 0.0:
        return True, 0.0, 0.0, 0.0, 0.0
    d = np.sqrt(d2)
    ex, ey, ez = frustum_direction(X, Y, Z, a0, a1, b0, b1, z, d)
    return False, d, ex, ey, ez


@kernel(inline=True)
def finish_min_at_pixel(X, Y, Z, best2, best_u, best_v, best_z, best_invalid, fx, fy, cx, cy, unseen_d, nx, ny, nz,
                         flags, inside_tol, out_direction):
    """:func:`finish_min` when the nearest point lies on pixel (best_u, best_v)'s frustum (int, pixels) at depth
    best_z (float64, metres): its unit direction towards P = (X, Y, Z) is derived here, with the intrinsics fx, fy,
    cx, cy."""
    ex = ey = ez = 0.0
    if inside_tol * inside_tol < best2 < np.inf:
        ex, ey, ez = frustum_direction(X, Y, Z, (best_u - 0.5 - cx) / fx, (best_u + 0.5 - cx) / fx,
                                       (best_v - 0.5 - cy) / fy, (best_v + 0.5 - cy) / fy, best_z, np.sqrt(best2))
    return finish_min(best2, best_invalid, ex, ey, ez, unseen_d, nx, ny, nz, flags, inside_tol, out_direction)


@kernel(inline=True)
def finish_sum(aggregate, count, n_invalid, inside, sum_d, sx, sy, sz, best2, unseen_d, nx, ny, nz, flags, inside_tol,
                min_direction, out_direction):
    """``mean``'s and ``hybrid``'s answer from the sums over the contributing pixels and the observed volume's
    boundary (distance unseen_d, inward normal, one more contributor when finite). Returns (distance, count,
    invalid_count, flags) and writes the normalised mean direction.

    The sums: count (int) contributing pixels, n_invalid (int) of them without a measurement, inside (bool) whether
    P lies in one, sum_d (float64, metres) their distances, sx, sy, sz (float64) their unit directions (optical
    frame), best2 the smallest squared distance."""
    if n_invalid:
        flags |= FLAG_INVALID_PIXELS_USED
    if unseen_d < np.inf:
        count += 1
    if inside or best2 <= inside_tol * inside_tol:
        return 0.0, count, n_invalid, flags | FLAG_INSIDE_OBSTACLE
    d_min = np.sqrt(best2)
    if unseen_d < np.inf:
        sum_d += unseen_d
        sx += nx
        sy += ny
        sz += nz
        d_min = min(d_min, unseen_d)
    if count == 0:
        return np.inf, 0, 0, flags
    norm = np.sqrt(sx * sx + sy * sy + sz * sz)
    if norm > min_direction * count:
        out_direction[0] = sx / norm
        out_direction[1] = sy / norm
        out_direction[2] = sz / norm
    if aggregate == AGG_MEAN:
        return sum_d / count, count, n_invalid, flags
    return d_min, count, n_invalid, flags


@kernel(parallel=True)
def frustum_nearest_many(points, bounds, nearest_out, distance_out, paper):
    """For each i: distance_out[i] (metres) from points[i] ((n, 3) float64, metres, optical frame) to the frustum
    segment bounds[i] ((n, 6) float64: a0, a1, b0, b1 tangents, z_lo, z_hi metres) and nearest_out[i] its nearest
    point (optical frame, metres); nearest_out (n, 3) and distance_out (n,), float64, written. ``paper`` (bool): the
    papers' fixed-depth formula instead of the exact one (design §4)."""
    for i in prange(points.shape[0]):
        X, Y, Z = points[i, 0], points[i, 1], points[i, 2]
        a0, a1, b0, b1, z_lo, z_hi = bounds[i, 0], bounds[i, 1], bounds[i, 2], bounds[i, 3], bounds[i, 4], bounds[i, 5]
        if paper:
            d2, z = frustum_nearest_paper(X, Y, Z, a0, a1, b0, b1, z_lo, z_hi)
        else:
            d2, z = frustum_nearest(X, Y, Z, a0, a1, b0, b1, z_lo, z_hi)
        distance_out[i] = np.sqrt(d2)
        nearest_out[i, 0] = min(max(X, a0 * z), a1 * z)
        nearest_out[i, 1] = min(max(Y, b0 * z), b1 * z)
        nearest_out[i, 2] = z
