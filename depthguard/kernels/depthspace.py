"""Numba kernels of the single-camera depth-space distance (design §4-6).

Everything here works in one camera's optical frame (x right, y down, z forward; metres) and trusts its inputs:
``depthguard/depthspace/_distance.py`` validates them. A pixel (u, v) spans the tangents [a0, a1] x [b0, b1] with
a0 = (u - 1/2 - cx)/fx, a1 = (u + 1/2 - cx)/fx, b0 = (v - 1/2 - cy)/fy, b1 = (v + 1/2 - cy)/fy.

The tests hold every kernel against a slow NumPy twin (``tests/naive.py``).

The frame's arrays are those of a :class:`depthguard.depth.OccupancyImage`, (h, w) and indexed [v, u].

Arguments used throughout:

- ``X, Y, Z``: float64, metres: the control point P in the camera's optical frame.
- ``rho``: float64, metres: the radius of the surveillance region; only what lies nearer than rho to P counts.
- ``z_start, z_end``: (h, w) float32, metres: pixel (u, v) is possibly occupied along its frustum for
  z_start[v, u] <= z <= z_end[v, u]; a z_start of inf: nothing along the pixel, a z_end of inf: no end.
- ``invalid``: (h, w) uint8: 1 where the pixel had no valid measurement, else 0.
- ``block_min``: (ceil(h / block), ceil(w / block)) float32, metres: the minimum of z_start over each block.
- ``blind, blind_block_min``: (h, w) float32, metres: where the space hidden behind the robot starts along each
  pixel (inf: none); and its block minima, shaped as block_min.
- ``has_blind``: bool: whether the frame shows the robot (``blind`` is read only then).
- ``block``: int, pixels: the side of the blocks (``config.BLOCK_SIZE``).
- ``fx, fy, cx, cy``: float, pixels: the camera's intrinsics.
- ``z_min, z_max``: float, metres: the camera's valid depth range, which with the image bounds the observed volume.
- ``aggregate``: int: AGG_MIN, AGG_MEAN or AGG_HYBRID (0, 1, 2: the index in ``config.AGGREGATES``).
- ``unseen_occupied``: bool: unseen space counts as possibly occupied (``unseen="occupied"``, design §3).
- ``near_eps``: float, metres: a cube corner at or nearer than this optical depth makes the window the whole image
  (``config.NEAR_PLANE_EPSILON``).
- ``inside_tol``: float, metres: a distance at or below it means P is inside (``config.INSIDE_TOLERANCE``).
- ``min_direction``: float, no unit: a sum of unit directions shorter than min_direction times their count is
  reported as the zero vector (``config.MIN_DIRECTION_NORM``).
- ``paper``: bool: the 2015 paper's method (:func:`query_point_paper`) instead of the exact one.
- ``points_camera``: (n, 3) float64, metres: the control points in the camera's optical frame.
- ``spans``: (h, 2) int64 work space: per image row v, the first and last column to visit (first > last: none), as
  :func:`depthguard.kernels.frustum.surveillance_region` fills it.
- ``scratch``: (5, w) float64 work space.
- ``distance, direction, count, invalid_count, flags, blind_distance``: the results for the n points, written:
  (n,) float64 metres (inf: nothing nearer than rho); (n, 3) float64, the unit vector from the obstacle towards P in
  the optical frame (zero for none); (n,) int64 contributors; (n,) int64 contributors from pixels without a
  measurement; (n,) int64 bits of :class:`depthguard.results.Flag`; (n,) float64 metres, the distance to the space
  behind the robot (inf beyond rho, or without ``has_blind``).
- ``out_direction``: (3,) float64, written: one point's unit direction from the obstacle towards P, optical frame.
"""

import numpy as np
from numba import prange

from depthguard.kernels.frustum import (
    contribution,
    AGG_MIN,
    FLAG_REGION_OUTSIDE_VIEW,
    FLAG_ROBOT_BLIND_SPOT,
    finish_min,
    finish_min_at_pixel,
    finish_sum,
    guess_piece_row,
    nearest_in_blocks,
    frustum_direction,
    frustum_nearest,
    frustum_nearest_paper,
    index_span,
    rho_squared,
    surveillance_region,
    usable_rho,
    view_boundary,
)
from depthguard.kernels.jit import kernel


@kernel(inline=True)
def _all_in_rows(X, Y, Z, rho, z_start, z_end, invalid, fx, fy, cx, cy, v_lo, v_hi, spans, scratch):
    """Every contributing pixel for ``mean`` and ``hybrid``: per row, gather the silhouette span's pixels whose
    start depth is not behind the region, take their exact distances (:func:`guess_piece_row`, walking where the
    guess fails), and sum the contributors' distances and unit directions. ``scratch`` is a (5, width) float64 array;
    v_lo, v_hi (int) the region's first and last row, whose ``spans`` are filled.

    Returns (count, invalid count, inside?, sum of d, sum of unit directions x, y, z, best d^2).
    """
    rho2 = rho_squared(rho)
    z_far = Z + rho
    inv_fx = 1.0 / fx
    inv_fy = 1.0 / fy
    z_in = scratch[0]
    u_in = scratch[1]
    d2_row = scratch[2]
    z_row = scratch[3]
    z_hi_in = scratch[4]
    best2 = np.inf
    sum_d = 0.0
    sx = 0.0
    sy = 0.0
    sz = 0.0
    count = 0
    n_invalid = 0
    inside = False
    for v in range(v_lo, v_hi + 1):
        b0 = (v - 0.5 - cy) * inv_fy
        b1 = (v + 0.5 - cy) * inv_fy
        row = z_start[v]
        row_end = z_end[v]
        m = np.int64(0)  # not a literal 0, for which numba would compile guess_piece_row once more
        for u in range(spans[v, 0], spans[v, 1] + 1):
            zs = row[u]
            if zs <= z_far:  # else it and what it hides lie behind the region (also inf: nothing)
                z_in[m] = zs
                z_hi_in[m] = row_end[u]
                u_in[m] = u
                m += 1
        if m == 0:
            continue
        guess_piece_row(X, Y, Z, b0, b1, z_in, z_hi_in, u_in, m, inv_fx, cx, d2_row, z_row)
        for k in range(m):
            d2 = d2_row[k]
            z_star = z_row[k]
            u = int(u_in[k])
            a0 = (u - 0.5 - cx) * inv_fx
            a1 = (u + 0.5 - cx) * inv_fx
            if d2 < 0.0:
                d2, z_star = frustum_nearest(X, Y, Z, a0, a1, b0, b1, z_in[k], z_hi_in[k])
            if d2 >= rho2:
                continue
            count += 1
            n_invalid += invalid[v, u]
            best2 = min(best2, d2)
            here, d, ex, ey, ez = contribution(X, Y, Z, a0, a1, b0, b1, z_star, d2)
            inside = inside or here
            sum_d += d
            sx += ex
            sy += ey
            sz += ez
    return count, n_invalid, inside, sum_d, sx, sy, sz, best2


@kernel(inline=True)
def query_point(X, Y, Z, rho, z_start, z_end, invalid, block_min, blind, blind_block_min, has_blind, block, fx, fy, cx,
                cy, z_min, z_max, aggregate, unseen_occupied, near_eps, inside_tol, min_direction, spans, scratch,
                out_direction, out_blind):
    """Distance from one control point P = (X, Y, Z) (metres, optical frame) to what one camera says is possibly
    occupied, aggregated as ``aggregate``.

    Visits only the cube window's pixels whose footprint meets the silhouette of the ball B(P, rho) and whose start
    depth is not behind the region; ``min`` also skips blocks that cannot beat the best distance so far. None of
    these skips changes the result: it equals a scan of every pixel.

    Returns (distance, count, invalid_count, flags); writes the unit direction (from the obstacle towards P, optical
    frame) into out_direction (3,). ``spans`` (height, 2) int64 and ``scratch`` (5, width) float64 are scratch space.
    With ``has_blind``, writes into out_blind[0] (out_blind: (1,) float64, metres) the distance to the space hidden
    behind the robot (``blind``: where it starts along each pixel, inf for none; ``blind_block_min``: its block
    minima), inf beyond rho; the caller flags a result that this blind space comes closer than.
    """
    height, width = z_start.shape
    out_blind[0] = np.inf
    flags, unseen_here, unseen_d, nx, ny, nz, u_lo, u_hi, v_lo, v_hi = surveillance_region(
        X, Y, Z, rho, width, height, fx, fy, cx, cy, z_min, z_max, unseen_occupied, near_eps, inside_tol, spans,
        out_direction)
    if unseen_here:
        return 0.0, 1, 0, flags
    if has_blind and v_lo <= v_hi:
        blind2 = nearest_in_blocks(X, Y, Z, rho, blind, blind, np.bool_(False), invalid, blind_block_min, block, fx,
                                    fy, cx, cy, u_lo, u_hi, v_lo, v_hi, near_eps, spans)[0]
        out_blind[0] = np.sqrt(blind2)

    if aggregate == AGG_MIN:
        best2 = np.inf
        best_invalid = 0
        if v_lo <= v_hi:
            best2, best_v, best_u, best_z, best_invalid = nearest_in_blocks(
                X, Y, Z, rho, z_start, z_end, np.bool_(True), invalid, block_min, block, fx, fy, cx, cy, u_lo, u_hi,
                v_lo, v_hi, near_eps, spans)
        return finish_min_at_pixel(X, Y, Z, best2, best_u, best_v, best_z, best_invalid, fx, fy, cx, cy, unseen_d, nx,
                                    ny, nz, flags, inside_tol, out_direction)

    count = 0
    n_invalid = 0
    inside = False
    sum_d = 0.0
    sx = 0.0
    sy = 0.0
    sz = 0.0
    best2 = np.inf
    if v_lo <= v_hi:
        count, n_invalid, inside, sum_d, sx, sy, sz, best2 = _all_in_rows(X, Y, Z, rho, z_start, z_end, invalid, fx,
                                                                          fy, cx, cy, v_lo, v_hi, spans, scratch)
    return finish_sum(aggregate, count, n_invalid, inside, sum_d, sx, sy, sz, best2, unseen_d, nx, ny, nz, flags,
                       inside_tol, min_direction, out_direction)


@kernel(inline=True)
def query_point_paper(X, Y, Z, rho, z_start, z_end, invalid, fx, fy, cx, cy, z_min, z_max, aggregate, unseen_occupied,
                      inside_tol, min_direction, out_direction):
    """The 2015 paper's method, for comparison only: window of half-width rho*f/(2*(Z - rho)) (eq. 10-11), pixels
    with depth in [Z - rho, Z + rho], distance at the fixed depth clamp(Z, z_lo, inf) (eqs. 7-8).

    Same outputs as :func:`query_point`. Unseen space and the observed-volume flag are handled as in the exact
    method so that the two differ only in the papers' formulas.
    """
    height, width = z_start.shape
    rho2 = rho_squared(rho)
    out_direction[0] = 0.0
    out_direction[1] = 0.0
    out_direction[2] = 0.0
    if not (np.isfinite(X) and np.isfinite(Y) and np.isfinite(Z)):
        return 0.0, 1, 0, FLAG_REGION_OUTSIDE_VIEW
    flags = 0
    s_view, nx, ny, nz = view_boundary(X, Y, Z, (-0.5 - cx) / fx, (width - 0.5 - cx) / fx, (-0.5 - cy) / fy,
                                       (height - 0.5 - cy) / fy, z_min, z_max)
    if s_view < rho:
        flags |= FLAG_REGION_OUTSIDE_VIEW
    if unseen_occupied and s_view <= inside_tol:
        return 0.0, 1, 0, flags
    if Z - rho > 0.0:
        half_u = 0.5 * rho * fx / (Z - rho)
        half_v = 0.5 * rho * fy / (Z - rho)
        pu = fx * X / Z + cx
        pv = fy * Y / Z + cy
        u_lo, u_hi = index_span(np.ceil(pu - half_u), np.floor(pu + half_u), width)
        v_lo, v_hi = index_span(np.ceil(pv - half_v), np.floor(pv + half_v), height)
    else:
        u_lo, u_hi, v_lo, v_hi = 0, width - 1, 0, height - 1
    best2 = np.inf
    best_dx = 0.0
    best_dy = 0.0
    best_dz = 0.0
    best_invalid = 0
    count = 0
    n_invalid = 0
    sum_d = 0.0
    sx = 0.0
    sy = 0.0
    sz = 0.0
    inside = False
    for v in range(v_lo, v_hi + 1):
        b0 = (v - 0.5 - cy) / fy
        b1 = (v + 0.5 - cy) / fy
        for u in range(u_lo, u_hi + 1):
            zs = np.float64(z_start[v, u])
            if zs > Z + rho or zs < Z - rho:
                continue
            a0 = (u - 0.5 - cx) / fx
            a1 = (u + 0.5 - cx) / fx
            d2, z = frustum_nearest_paper(X, Y, Z, a0, a1, b0, b1, zs, np.float64(z_end[v, u]))
            if d2 >= rho2:
                continue
            count += 1
            n_invalid += invalid[v, u]
            d = np.sqrt(d2)
            if d <= inside_tol:
                inside = True
                continue
            ex, ey, ez = frustum_direction(X, Y, Z, a0, a1, b0, b1, z, d)
            if d2 < best2:
                best2 = d2
                best_dx, best_dy, best_dz = ex, ey, ez
                best_invalid = invalid[v, u]
            sum_d += d
            sx += ex
            sy += ey
            sz += ez
    unseen_d = s_view if (unseen_occupied and s_view < rho) else np.inf
    if aggregate == AGG_MIN:
        return finish_min(0.0 if inside else best2, best_invalid, best_dx, best_dy, best_dz, unseen_d, nx, ny, nz,
                           flags, inside_tol, out_direction)
    return finish_sum(aggregate, count, n_invalid, inside, sum_d, sx, sy, sz, best2, unseen_d, nx, ny, nz, flags,
                       inside_tol, min_direction, out_direction)


@kernel()
def _query_one(i, points_camera, rho, z_start, z_end, invalid, block_min, blind, blind_block_min, has_blind, block, fx,
               fy, cx, cy, z_min, z_max, aggregate, unseen_occupied, paper, near_eps, inside_tol, min_direction, spans,
               scratch, distance, direction, count, invalid_count, flags, blind_distance):
    """Point i (int64) of points_camera: :func:`query_point`, or :func:`query_point_paper` with ``paper``, written
    into row i of distance, direction, count, invalid_count, flags and blind_distance; ROBOT_BLIND_SPOT is flagged
    where the space behind the robot comes nearer than the distance. spans (h, 2) and scratch (5, w): this point's
    work space."""
    X = points_camera[i, 0]
    Y = points_camera[i, 1]
    Z = points_camera[i, 2]
    blind_distance[i] = np.inf
    if paper:
        d, c, k, f = query_point_paper(X, Y, Z, rho, z_start, z_end, invalid, fx, fy, cx, cy, z_min, z_max,
                                       aggregate, unseen_occupied, inside_tol, min_direction, direction[i])
    else:
        d, c, k, f = query_point(X, Y, Z, rho, z_start, z_end, invalid, block_min, blind, blind_block_min, has_blind,
                                 block, fx, fy, cx, cy, z_min, z_max, aggregate, unseen_occupied, near_eps, inside_tol,
                                 min_direction, spans, scratch, direction[i], blind_distance[i:i + 1])
        if blind_distance[i] < d:  # something hidden behind the robot could be nearer than the answer
            f |= FLAG_ROBOT_BLIND_SPOT
    distance[i] = d
    count[i] = c
    invalid_count[i] = k
    flags[i] = f


@kernel(parallel=True)
def query_points(points_camera, rho, z_start, z_end, invalid, block_min, blind, blind_block_min, has_blind, block,
                 fx, fy, cx, cy, z_min, z_max, aggregate, unseen_occupied, paper, near_eps, inside_tol, min_direction,
                 distance, direction, count, invalid_count, flags, blind_distance):
    """:func:`query_point` (or the paper's variant) for each of the (n, 3) optical-frame points, in parallel; one
    point on the calling thread, since for one point a parallel region only adds a barrier that a busy machine can
    hold up for milliseconds.

    Writes distance (n,) float64, direction (n, 3) float64 (optical frame), count (n,) int64, invalid_count (n,)
    int64, flags (n,) int64 and blind_distance (n,) float64.
    """
    n = points_camera.shape[0]
    rho = usable_rho(rho)
    spans = np.empty((n, z_start.shape[0], 2), dtype=np.int64)
    scratch = np.empty((n, 5, z_start.shape[1]), dtype=np.float64)
    if n == 1:
        _query_one(np.int64(0), points_camera, rho, z_start, z_end, invalid, block_min, blind, blind_block_min,
                   has_blind, block, fx, fy, cx, cy, z_min, z_max, aggregate, unseen_occupied, paper, near_eps,
                   inside_tol, min_direction, spans[0], scratch[0], distance, direction, count, invalid_count, flags,
                   blind_distance)
        return
    for i in prange(n):
        # An int64 index, as above: prange's is unsigned, and a second index type would compile _query_one twice.
        _query_one(np.int64(i), points_camera, rho, z_start, z_end, invalid, block_min, blind, blind_block_min,
                   has_blind, block, fx, fy, cx, cy, z_min, z_max, aggregate, unseen_occupied, paper, near_eps,
                   inside_tol, min_direction, spans[i], scratch[i], distance, direction, count, invalid_count, flags,
                   blind_distance)


# One kernel serves one point and many (one compile less); the name stays for its callers.
query_points_serial = query_points
