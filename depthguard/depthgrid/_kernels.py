"""Numba kernels of the depth-grid fusion (SPEC section 8). They trust their inputs; ``_fusion.py`` checks them.

Along each principal pixel's frustum, what the principal camera says is possibly occupied splits into:

- certain pieces, which no other camera can clear: the measured surface's own cell (case iii), or the whole
  frustum from the surface on when the surface is at or behind the control point (case ii), and anything outside
  the grid's depth span;
- candidate cells, which the other cameras may clear: the gray area behind a surface in front of the control point
  (case iii), the frustum of a pixel without a measurement (SPEC section 3), and the space behind the robot from
  where its body ends (case iv).

A candidate cell is occupied only if every secondary camera confirms it. Camera j declares it free only if the
cell's whole footprint (its 8 corners projected into j, grown by ``pad`` pixels) lies inside j's image and every
pixel q of that footprint saw beyond the cell: free[j][q] >= the cell's largest depth in j plus ``margin``, where
free[j][q] is j's measured depth minus its noise margin (0 where j measured nothing).
"""

import numpy as np
from numba import njit, prange

from depthguard.depthspace._kernels import (
    AGG_MIN,
    _finish_min_at_pixel,
    _finish_sum,
    frustum_nearest,
    surveillance_region,
)


@njit(parallel=True, cache=True, error_model="numpy")
def free_depths(raw, scale, z_min, z_max, m0, m1, m2, free):
    """Per pixel of a secondary frame, the depth up to which the camera saw the ray free: the measured depth minus
    its noise margin, 0 where it measured nothing (or outside [z_min, z_max]). Writes free (h, w) float32."""
    h, w = raw.shape
    for v in prange(h):
        for u in range(w):
            d = np.float64(raw[v, u]) * scale
            if np.isfinite(d) and d > 0.0 and d >= z_min and d <= z_max:
                free[v, u] = max(d - max(m0 + (m1 + m2 * d) * d, 0.0), 0.0)
            else:
                free[v, u] = 0.0


@njit(cache=True, error_model="numpy")
def camera_clears(corners, offset, free, width, height, z_near, z0, z1, u, v, margin, pad):
    """Whether one secondary camera saw through the whole cell [z0, z1] of principal pixel (u, v) (see module
    docstring). corners: (H+1, W+1, 3) the map's A for that camera; offset: (3,) its B; free: its (h, w) image."""
    x_lo = np.inf
    x_hi = -np.inf
    y_lo = np.inf
    y_hi = -np.inf
    far = 0.0
    for dv in range(2):
        for du in range(2):
            a0 = corners[v + dv, u + du, 0]
            a1 = corners[v + dv, u + du, 1]
            a2 = corners[v + dv, u + du, 2]
            for k in range(2):
                z = z0 if k == 0 else z1
                hz = a2 * z + offset[2]
                if hz <= z_near:  # part of the cell is behind the camera or nearer than it can measure
                    return False
                x = (a0 * z + offset[0]) / hz
                y = (a1 * z + offset[1]) / hz
                x_lo = min(x_lo, x)
                x_hi = max(x_hi, x)
                y_lo = min(y_lo, y)
                y_hi = max(y_hi, y)
                far = max(far, hz)
    # Pixels whose footprint [q - 1/2, q + 1/2] meets the corners' bounding box, grown by pad pixels.
    q_lo = np.ceil(x_lo - 0.5) - pad
    q_hi = np.floor(x_hi + 0.5) + pad
    r_lo = np.ceil(y_lo - 0.5) - pad
    r_hi = np.floor(y_hi + 0.5) + pad
    if q_lo < 0.0 or r_lo < 0.0 or q_hi > width - 1 or r_hi > height - 1:
        return False  # the footprint leaves the image
    need = far + margin
    for r in range(int(r_lo), int(r_hi) + 1):
        for q in range(int(q_lo), int(q_hi) + 1):
            if free[r, q] < need:
                return False
    return True


@njit(cache=True, error_model="numpy")
def cell_occupied(u, v, k, d_min, delta_d, corners, offsets, free, sizes, z_near, margin, pad):
    """Whether cell k of principal pixel (u, v) is occupied: no secondary camera cleared it."""
    z0 = d_min + k * delta_d
    z1 = z0 + delta_d
    for j in range(corners.shape[0]):
        if camera_clears(corners[j], offsets[j], free[j], sizes[j, 0], sizes[j, 1], z_near[j], z0, z1, u, v, margin,
                         pad):
            return False
    return True


@njit(cache=True, error_model="numpy")
def nearest_confirmed(X, Y, Z, a0, a1, b0, b1, lo, hi, bound2, u, v, d_min, delta_d, n_cells, corners, offsets, free,
                      sizes, z_near, margin, pad):
    """The nearest occupied part of the candidate range [lo, hi] along pixel (u, v)'s frustum, visiting its cells in
    order of distance from P (the distance to consecutive pieces of one convex frustum is unimodal) and stopping at
    the first occupied one or at ``bound2``. Parts outside the grid [d_min, d_max] cannot be checked and count as
    occupied. Returns (squared distance, z*), (inf, 0) if nothing occupied comes nearer than bound2."""
    if lo > hi:
        return np.inf, 0.0
    d_max = d_min + n_cells * delta_d
    best2 = np.inf
    best_z = 0.0
    # Outside the grid: occupied as it stands.
    if lo < d_min:
        d2, z = frustum_nearest(X, Y, Z, a0, a1, b0, b1, lo, min(hi, d_min))
        if d2 < best2:
            best2, best_z = d2, z
    if hi > d_max:
        d2, z = frustum_nearest(X, Y, Z, a0, a1, b0, b1, max(lo, d_max), hi)
        if d2 < best2:
            best2, best_z = d2, z
    g_lo = max(lo, d_min)
    g_hi = min(hi, d_max)
    if g_lo > g_hi:
        return best2, best_z
    bound2 = min(bound2, best2)
    k_lo = min(int((g_lo - d_min) / delta_d), n_cells - 1)
    k_hi = min(int((g_hi - d_min) / delta_d), n_cells - 1)
    _, z_star = frustum_nearest(X, Y, Z, a0, a1, b0, b1, g_lo, g_hi)
    k_star = min(max(int((z_star - d_min) / delta_d), k_lo), k_hi)
    left = k_star
    right = k_star + 1
    left2 = np.inf
    left_z = 0.0
    right2 = np.inf
    right_z = 0.0
    if left >= k_lo:
        left2, left_z = frustum_nearest(X, Y, Z, a0, a1, b0, b1, max(g_lo, d_min + left * delta_d),
                                        min(g_hi, d_min + (left + 1) * delta_d))
    if right <= k_hi:
        right2, right_z = frustum_nearest(X, Y, Z, a0, a1, b0, b1, max(g_lo, d_min + right * delta_d),
                                          min(g_hi, d_min + (right + 1) * delta_d))
    while True:
        if left2 <= right2:
            if left2 >= bound2:
                break
            if cell_occupied(u, v, left, d_min, delta_d, corners, offsets, free, sizes, z_near, margin, pad):
                return left2, left_z
            left -= 1
            left2 = np.inf
            if left >= k_lo:
                left2, left_z = frustum_nearest(X, Y, Z, a0, a1, b0, b1, max(g_lo, d_min + left * delta_d),
                                                min(g_hi, d_min + (left + 1) * delta_d))
        else:
            if right2 >= bound2:
                break
            if cell_occupied(u, v, right, d_min, delta_d, corners, offsets, free, sizes, z_near, margin, pad):
                return right2, right_z
            right += 1
            right2 = np.inf
            if right <= k_hi:
                right2, right_z = frustum_nearest(X, Y, Z, a0, a1, b0, b1, max(g_lo, d_min + right * delta_d),
                                                  min(g_hi, d_min + (right + 1) * delta_d))
    return best2, best_z


@njit(cache=True, error_model="numpy")
def pixel_distance(X, Y, Z, rho, u, v, a0, a1, b0, b1, zs, ze, certain, blind_from, bound2, d_min, delta_d, n_cells,
                   corners, offsets, free, sizes, z_near, margin, pad):
    """Squared distance from P to what is occupied along principal pixel (u, v) after fusion, its depth z*, and
    whether that came from a candidate of a pixel without a measurement. (inf, 0, False) if nothing within
    ``bound2``.

    zs, ze: the principal's possibly-occupied segment; ``certain``: it starts at a measured surface; blind_from:
    where the space behind the robot starts (after its body), inf for none.
    """
    z_far = Z + rho
    best2 = np.inf
    best_z = 0.0
    from_invalid = False
    if zs <= z_far:
        if certain:
            if zs >= Z:  # case (ii): the frustum from the surface on, without other cameras
                best2, best_z = frustum_nearest(X, Y, Z, a0, a1, b0, b1, zs, ze)
            else:  # case (iii): the surface's own cell is certain, the gray area behind it is a candidate
                cell_end = d_min + (np.floor((zs - d_min) / delta_d) + 1.0) * delta_d if zs >= d_min else d_min
                best2, best_z = frustum_nearest(X, Y, Z, a0, a1, b0, b1, zs, min(cell_end, ze))
                if cell_end < ze:
                    d2, z = nearest_confirmed(X, Y, Z, a0, a1, b0, b1, cell_end, min(ze, z_far), min(best2, bound2),
                                              u, v, d_min, delta_d, n_cells, corners, offsets, free, sizes, z_near,
                                              margin, pad)
                    if d2 < best2:
                        best2, best_z = d2, z
        else:  # no measurement: the whole segment is a candidate
            d2, z = nearest_confirmed(X, Y, Z, a0, a1, b0, b1, zs, min(ze, z_far), bound2, u, v, d_min, delta_d,
                                      n_cells, corners, offsets, free, sizes, z_near, margin, pad)
            if d2 < best2:
                best2, best_z = d2, z
                from_invalid = True
    if blind_from <= z_far:  # case (iv): behind the robot
        d2, z = nearest_confirmed(X, Y, Z, a0, a1, b0, b1, blind_from, z_far, min(best2, bound2), u, v, d_min,
                                  delta_d, n_cells, corners, offsets, free, sizes, z_near, margin, pad)
        if d2 < best2:
            best2, best_z = d2, z
            from_invalid = False
    if best2 >= bound2:
        return np.inf, 0.0, False
    return best2, best_z, from_invalid


@njit(cache=True, error_model="numpy")
def fused_query_point(X, Y, Z, rho, z_start, z_end, certain, blind_from, fx, fy, cx, cy, z_min, z_max, aggregate,
                      unseen_occupied, near_eps, inside_tol, min_direction, d_min, delta_d, n_cells, corners, offsets,
                      free, sizes, z_near, margin, pad, spans, out_direction):
    """Distance from one control point P = (X, Y, Z) (metres, principal optical frame) to what the principal camera
    says is possibly occupied and the secondary cameras do not clear, aggregated as ``aggregate``; the fused
    counterpart of :func:`depthguard.depthspace._kernels.query_point`. Returns (distance, count, invalid_count,
    flags); writes the unit direction (from the obstacle towards P, principal optical frame) into out_direction."""
    height, width = z_start.shape
    rho2 = rho * rho
    flags, unseen_here, unseen_d, nx, ny, nz, u_lo, u_hi, v_lo, v_hi = surveillance_region(
        X, Y, Z, rho, width, height, fx, fy, cx, cy, z_min, z_max, unseen_occupied, near_eps, inside_tol, spans,
        out_direction)
    if unseen_here:
        return 0.0, 1, 0, flags
    prune_min = aggregate == AGG_MIN
    z_far = Z + rho
    best2 = np.inf
    best_u = 0
    best_v = 0
    best_z = 0.0
    best_invalid = 0
    count = 0
    n_invalid = 0
    inside = False
    sum_d = 0.0
    sx = 0.0
    sy = 0.0
    sz = 0.0
    for v in range(v_lo, v_hi + 1):
        b0 = (v - 0.5 - cy) / fy
        b1 = (v + 0.5 - cy) / fy
        for u in range(spans[v, 0], spans[v, 1] + 1):
            zs = np.float64(z_start[v, u])
            bf = np.float64(blind_from[v, u])
            first = min(zs, bf)
            if first > z_far:
                continue
            a0 = (u - 0.5 - cx) / fx
            a1 = (u + 0.5 - cx) / fx
            bound2 = min(rho2, best2) if prune_min else rho2
            lb2, _ = frustum_nearest(X, Y, Z, a0, a1, b0, b1, first, np.inf)  # a lower bound
            if lb2 >= bound2 and not (prune_min and lb2 == best2):
                continue
            d2, z, from_invalid = pixel_distance(X, Y, Z, rho, u, v, a0, a1, b0, b1, zs, np.float64(z_end[v, u]),
                                                 certain[v, u], bf, rho2, d_min, delta_d, n_cells, corners, offsets,
                                                 free, sizes, z_near, margin, pad)
            if d2 >= rho2:
                continue
            if d2 < best2 or (d2 == best2 and (v < best_v or (v == best_v and u < best_u))):
                best2 = d2
                best_u = u
                best_v = v
                best_z = z
                best_invalid = 1 if from_invalid else 0
            if prune_min:
                continue
            count += 1
            n_invalid += 1 if from_invalid else 0
            if d2 <= 0.0:
                inside = True
                continue
            d = np.sqrt(d2)
            sum_d += d
            sx += (X - min(max(X, a0 * z), a1 * z)) / d
            sy += (Y - min(max(Y, b0 * z), b1 * z)) / d
            sz += (Z - z) / d
    if prune_min:
        return _finish_min_at_pixel(X, Y, Z, best2, best_u, best_v, best_z, best_invalid, fx, fy, cx, cy, unseen_d, nx,
                                    ny, nz, flags, inside_tol, out_direction)
    return _finish_sum(aggregate, count, n_invalid, inside, sum_d, sx, sy, sz, best2, unseen_d, nx, ny, nz, flags,
                       inside_tol, min_direction, out_direction)


@njit(parallel=True, cache=True, error_model="numpy")
def fused_query_points(points_camera, rho, z_start, z_end, certain, blind_from, fx, fy, cx, cy, z_min, z_max,
                       aggregate, unseen_occupied, near_eps, inside_tol, min_direction, d_min, delta_d, n_cells, corners,
                       offsets, free, sizes, z_near, margin, pad, distance, direction, count, invalid_count, flags):
    """:func:`fused_query_point` for each of the (n, 3) principal-frame points, in parallel."""
    n = points_camera.shape[0]
    spans = np.empty((n, z_start.shape[0], 2), dtype=np.int64)
    for i in prange(n):
        d, c, k, f = fused_query_point(points_camera[i, 0], points_camera[i, 1], points_camera[i, 2], rho, z_start,
                                       z_end, certain, blind_from, fx, fy, cx, cy, z_min, z_max, aggregate,
                                       unseen_occupied, near_eps, inside_tol, min_direction, d_min, delta_d, n_cells,
                                       corners, offsets, free, sizes, z_near, margin, pad, spans[i], direction[i])
        distance[i] = d
        count[i] = c
        invalid_count[i] = k
        flags[i] = f
