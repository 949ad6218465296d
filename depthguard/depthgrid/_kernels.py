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
def surface_cell_end(zs, d_min, delta_d):
    """Where the grid cell holding a measured surface at depth zs ends (d_min for a surface before the grid)."""
    if zs < d_min:
        return d_min
    return d_min + (np.floor((zs - d_min) / delta_d) + 1.0) * delta_d


@njit(cache=True, error_model="numpy")
def candidate_start(zs, ze, certain, bf, Z, rho, d_min, delta_d):
    """Where the first candidate piece along one principal pixel starts for a control point at depth Z (inf for
    none before Z + rho)."""
    z_far = Z + rho
    s = np.inf
    if zs <= z_far:
        if certain:
            if zs < Z:
                cell_end = surface_cell_end(zs, d_min, delta_d)
                if cell_end < ze:
                    s = cell_end
        else:
            s = zs
    if bf <= z_far:
        s = min(s, bf)
    return s


@njit(cache=True, error_model="numpy")
def candidate_cells(zs, ze, certain, bf, Z, rho, d_min, delta_d, n_cells):
    """The grid cells (k_a, k_b) that fusion may have to classify along one principal pixel for a control point at
    depth Z: those of the pixel's candidate pieces (see module docstring) that lie within [Z - rho, Z + rho]; a cell
    outside that depth span is farther than rho from the point. k_a > k_b for none."""
    z_far = Z + rho
    lo = max(candidate_start(zs, ze, certain, bf, Z, rho, d_min, delta_d), Z - rho, d_min)
    hi = min(z_far, d_min + n_cells * delta_d)
    if lo > hi:
        return 1, 0
    return min(int((lo - d_min) / delta_d), n_cells - 1), min(int((hi - d_min) / delta_d), n_cells - 1)


@njit(cache=True, error_model="numpy")
def classify_run(u, v, k_a, k_b, d_min, delta_d, corners, offsets, free, sizes, z_near, margin, pad, bits):
    """Classify cells k_a..k_b of principal pixel (u, v) with the secondary cameras: bit k of bits[v, u] set when
    cell k is occupied (no camera clears it), cleared when it is free."""
    for k in range(k_a, k_b + 1):
        word = k >> 6
        bit = np.uint64(1) << np.uint64(k & 63)
        if cell_occupied(u, v, k, d_min, delta_d, corners, offsets, free, sizes, z_near, margin, pad):
            bits[v, u, word] |= bit
        else:
            bits[v, u, word] &= ~bit


@njit(parallel=True, cache=True, error_model="numpy")
def classify_cells(points_camera, rho, z_start, z_end, certain, blind_from, fx, fy, cx, cy, z_min, z_max,
                   unseen_occupied, near_eps, inside_tol, d_min, delta_d, n_cells, corners, offsets, free, sizes,
                   z_near, margin, pad, bits, c_lo, c_hi):
    """Classify, once per frame, every grid cell that the queries of these control points may look at, and extend the
    per-pixel cache: bits[v, u] holds the classes of cells c_lo[v, u]..c_hi[v, u] (none while c_lo > c_hi).

    Rows are shared out among threads, so each pixel's cache has one writer. The queries read the cache and classify
    any cell outside it themselves, so the cache only saves time: it never changes a result.
    """
    n = points_camera.shape[0]
    height, width = z_start.shape
    spans = np.empty((n, height, 2), dtype=np.int64)
    rows = np.empty((n, 2), dtype=np.int64)
    scratch = np.empty(3)
    for i in range(n):
        X, Y, Z = points_camera[i, 0], points_camera[i, 1], points_camera[i, 2]
        _, unseen_here, _, _, _, _, _, _, v_lo, v_hi = surveillance_region(
            X, Y, Z, rho, width, height, fx, fy, cx, cy, z_min, z_max, unseen_occupied, near_eps, inside_tol,
            spans[i], scratch)
        rows[i, 0] = v_lo if not unseen_here else 0
        rows[i, 1] = v_hi if not unseen_here else -1
    first = height
    last = -1
    for i in range(n):
        if rows[i, 0] <= rows[i, 1]:
            first = min(first, rows[i, 0])
            last = max(last, rows[i, 1])
    for v in prange(first, last + 1):
        for i in range(n):
            if v < rows[i, 0] or v > rows[i, 1]:
                continue
            Z = points_camera[i, 2]
            for u in range(spans[i, v, 0], spans[i, v, 1] + 1):
                k_a, k_b = candidate_cells(np.float64(z_start[v, u]), np.float64(z_end[v, u]), certain[v, u],
                                           np.float64(blind_from[v, u]), Z, rho, d_min, delta_d, n_cells)
                if k_a > k_b:
                    continue
                lo = c_lo[v, u]
                hi = c_hi[v, u]
                if lo > hi:
                    classify_run(u, v, k_a, k_b, d_min, delta_d, corners, offsets, free, sizes, z_near, margin, pad,
                                 bits)
                    c_lo[v, u] = k_a
                    c_hi[v, u] = k_b
                    continue
                if k_a < lo:
                    classify_run(u, v, k_a, lo - 1, d_min, delta_d, corners, offsets, free, sizes, z_near, margin,
                                 pad, bits)
                    c_lo[v, u] = k_a
                if k_b > hi:
                    classify_run(u, v, hi + 1, k_b, d_min, delta_d, corners, offsets, free, sizes, z_near, margin,
                                 pad, bits)
                    c_hi[v, u] = k_b


@njit(cache=True, error_model="numpy")
def cell_is_occupied(u, v, k, d_min, delta_d, corners, offsets, free, sizes, z_near, margin, pad, bits, c_lo, c_hi):
    """Cell k of principal pixel (u, v): from the cache when it holds it, else classified here."""
    if c_lo[v, u] <= k and k <= c_hi[v, u]:
        return (bits[v, u, k >> 6] >> np.uint64(k & 63)) & np.uint64(1) != 0
    return cell_occupied(u, v, k, d_min, delta_d, corners, offsets, free, sizes, z_near, margin, pad)


_ONE = np.uint64(1)
_ALL = np.uint64(0xFFFFFFFFFFFFFFFF)


@njit(cache=True, error_model="numpy")
def _bit_index(word, highest):
    """The index (0-63) of the highest or the lowest set bit of a non-zero uint64, by halving."""
    index = 0
    width = 32
    while width > 0:
        shift = np.uint64(width)
        if highest:
            if word >> shift != np.uint64(0):
                word >>= shift
                index += width
        else:
            if word & ((_ONE << shift) - _ONE) == np.uint64(0):
                word >>= shift
                index += width
        width //= 2
    return index


@njit(cache=True, error_model="numpy")
def set_bit_in(row, k_lo, k_hi, highest):
    """The highest (or lowest) k in [k_lo, k_hi] whose bit is set in row (words of 64 cells), -1 for none."""
    w_lo = k_lo >> 6
    w_hi = k_hi >> 6
    w = w_hi if highest else w_lo
    while w_lo <= w <= w_hi:
        word = row[w]
        if w == w_hi and (k_hi & 63) < 63:
            word &= (_ONE << np.uint64((k_hi & 63) + 1)) - _ONE
        if w == w_lo:
            word &= _ALL << np.uint64(k_lo & 63)
        if word != np.uint64(0):
            return w * 64 + _bit_index(word, highest)
        w += -1 if highest else 1
    return -1


@njit(cache=True, error_model="numpy")
def occupied_in(u, v, k_lo, k_hi, highest, d_min, delta_d, corners, offsets, free, sizes, z_near, margin, pad, bits,
                c_lo, c_hi):
    """The highest (or lowest) occupied cell in k_lo..k_hi of principal pixel (u, v), -1 for none: 64 cells a step
    where the cache holds them, one by one otherwise."""
    if k_lo > k_hi:
        return -1
    if c_lo[v, u] <= k_lo and k_hi <= c_hi[v, u]:
        return set_bit_in(bits[v, u], k_lo, k_hi, highest)
    for i in range(k_hi - k_lo + 1):
        k = k_hi - i if highest else k_lo + i
        if cell_is_occupied(u, v, k, d_min, delta_d, corners, offsets, free, sizes, z_near, margin, pad, bits, c_lo,
                            c_hi):
            return k
    return -1


@njit(cache=True, error_model="numpy")
def nearest_confirmed(X, Y, Z, rho, a0, a1, b0, b1, lo, certain_to, hi, bound2, u, v, d_min, delta_d, n_cells,
                      corners, offsets, free, sizes, z_near, margin, pad, bits, c_lo, c_hi):
    """The nearest occupied part of [lo, hi] along principal pixel (u, v)'s frustum, nearer than ``bound2``: the
    part [lo, certain_to] is occupied as it stands (a measured surface's own cell; certain_to <= lo for none), and so
    are the parts outside the grid [d_min, d_max], which no camera can check; the rest is candidate cells.

    The distance from P along one convex frustum is unimodal in depth, so the nearest occupied part is the one
    holding the nearest point z* of [lo, hi] if that part is occupied, else the first occupied part met walking
    down from z*, or the first walking up. Cells shallower than Z - rho or deeper than Z + rho are farther than rho
    and are never looked at. Returns (squared distance, z*), (inf, 0) if nothing occupied comes nearer than bound2.
    """
    if lo > hi:
        return np.inf, 0.0
    d2, z = frustum_nearest(X, Y, Z, a0, a1, b0, b1, lo, hi)
    if d2 >= bound2:
        return np.inf, 0.0
    d_max = d_min + n_cells * delta_d
    # Occupied as they stand: [lo, below] when below > lo, and [above, hi] (beyond the grid) when hi > above.
    below = max(certain_to, min(d_min, hi)) if lo < d_min else certain_to
    above = max(d_max, below)
    if (below > lo and z <= below) or (hi > above and z >= above):
        return d2, z
    k_lo = max(int((max(below, lo) - d_min) / delta_d), int((max(Z - rho, d_min) - d_min) / delta_d))
    k_hi = min(int((min(hi, d_max) - d_min) / delta_d), n_cells - 1)
    k_star = min(max(int((z - d_min) / delta_d), k_lo), k_hi)
    if cell_is_occupied(u, v, k_star, d_min, delta_d, corners, offsets, free, sizes, z_near, margin, pad, bits, c_lo,
                        c_hi):
        return d2, z
    best2 = np.inf
    best_z = 0.0
    k = occupied_in(u, v, k_lo, k_star - 1, True, d_min, delta_d, corners, offsets, free, sizes, z_near, margin, pad,
                    bits, c_lo, c_hi)
    if k >= 0:
        best2, best_z = frustum_nearest(X, Y, Z, a0, a1, b0, b1, max(below, lo, d_min + k * delta_d),
                                        min(hi, d_min + (k + 1) * delta_d))
    elif below > lo:
        best2, best_z = frustum_nearest(X, Y, Z, a0, a1, b0, b1, lo, below)
    k = occupied_in(u, v, k_star + 1, k_hi, False, d_min, delta_d, corners, offsets, free, sizes, z_near, margin, pad,
                    bits, c_lo, c_hi)
    if k >= 0:
        d2, z = frustum_nearest(X, Y, Z, a0, a1, b0, b1, max(below, lo, d_min + k * delta_d),
                                min(hi, d_min + (k + 1) * delta_d))
    elif hi > above:
        d2, z = frustum_nearest(X, Y, Z, a0, a1, b0, b1, above, hi)
    else:
        d2 = np.inf
    if d2 < best2:
        best2, best_z = d2, z
    if best2 >= bound2:
        return np.inf, 0.0
    return best2, best_z


@njit(cache=True, error_model="numpy")
def pixel_distance(X, Y, Z, rho, u, v, a0, a1, b0, b1, zs, ze, certain, blind_from, bound2, d_min, delta_d, n_cells,
                   corners, offsets, free, sizes, z_near, margin, pad, bits, c_lo, c_hi):
    """Squared distance from P to what is occupied along principal pixel (u, v) after fusion, its depth z*, and
    whether that came from a candidate of a pixel without a measurement. (inf, 0, False) if nothing nearer than
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
                if best2 >= bound2:
                    best2 = np.inf
            else:  # case (iii): the surface's own cell is certain, the gray area behind it is a candidate
                best2, best_z = nearest_confirmed(X, Y, Z, rho, a0, a1, b0, b1, zs, surface_cell_end(zs, d_min, delta_d),
                                                  min(ze, z_far), bound2, u, v, d_min, delta_d, n_cells, corners,
                                                  offsets, free, sizes, z_near, margin, pad, bits, c_lo, c_hi)
        else:  # no measurement: the whole segment is a candidate
            best2, best_z = nearest_confirmed(X, Y, Z, rho, a0, a1, b0, b1, zs, zs, min(ze, z_far), bound2, u, v,
                                              d_min, delta_d, n_cells, corners, offsets, free, sizes, z_near, margin,
                                              pad, bits, c_lo, c_hi)
            from_invalid = best2 < np.inf
    if blind_from <= z_far:  # case (iv): behind the robot
        d2, z = nearest_confirmed(X, Y, Z, rho, a0, a1, b0, b1, blind_from, blind_from, z_far, min(best2, bound2), u,
                                  v, d_min, delta_d, n_cells, corners, offsets, free, sizes, z_near, margin, pad, bits,
                                  c_lo, c_hi)
        if d2 < best2:
            best2, best_z = d2, z
            from_invalid = False
    if best2 >= bound2:
        return np.inf, 0.0, False
    return best2, best_z, from_invalid


@njit(cache=True, error_model="numpy")
def fused_query_point(X, Y, Z, rho, z_start, z_end, certain, blind_from, fx, fy, cx, cy, z_min, z_max, aggregate,
                      unseen_occupied, near_eps, inside_tol, min_direction, d_min, delta_d, n_cells, corners, offsets,
                      free, sizes, z_near, margin, pad, bits, c_lo, c_hi, spans, out_direction):
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
    d_max = d_min + n_cells * delta_d
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
            if not certain[v, u] or zs > z_far:
                # Only candidates: skip the pixel when the other cameras cleared every cell of them in reach.
                s = candidate_start(zs, np.float64(z_end[v, u]), certain[v, u], bf, Z, rho, d_min, delta_d)
                if s >= d_min and z_far <= d_max:
                    k_a, k_b = candidate_cells(zs, np.float64(z_end[v, u]), certain[v, u], bf, Z, rho, d_min, delta_d,
                                               n_cells)
                    if k_a > k_b or (c_lo[v, u] <= k_a and k_b <= c_hi[v, u] and set_bit_in(bits[v, u], k_a, k_b,
                                                                                               False) < 0):
                        continue
            a0 = (u - 0.5 - cx) / fx
            a1 = (u + 0.5 - cx) / fx
            # With min, a pixel that only ties the best so far cannot win: pixels come in (v, u) order.
            bound2 = min(rho2, best2) if prune_min else rho2
            d2, z, from_invalid = pixel_distance(X, Y, Z, rho, u, v, a0, a1, b0, b1, zs, np.float64(z_end[v, u]),
                                                 certain[v, u], bf, bound2, d_min, delta_d, n_cells, corners, offsets,
                                                 free, sizes, z_near, margin, pad, bits, c_lo, c_hi)
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
                       offsets, free, sizes, z_near, margin, pad, bits, c_lo, c_hi, distance, direction, count,
                       invalid_count, flags):
    """:func:`fused_query_point` for each of the (n, 3) principal-frame points, in parallel."""
    n = points_camera.shape[0]
    spans = np.empty((n, z_start.shape[0], 2), dtype=np.int64)
    for i in prange(n):
        d, c, k, f = fused_query_point(points_camera[i, 0], points_camera[i, 1], points_camera[i, 2], rho, z_start,
                                       z_end, certain, blind_from, fx, fy, cx, cy, z_min, z_max, aggregate,
                                       unseen_occupied, near_eps, inside_tol, min_direction, d_min, delta_d, n_cells,
                                       corners, offsets, free, sizes, z_near, margin, pad, bits, c_lo, c_hi, spans[i],
                                       direction[i])
        distance[i] = d
        count[i] = c
        invalid_count[i] = k
        flags[i] = f
