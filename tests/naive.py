"""Slow, obviously-correct NumPy twins of depthguard's kernels. Tests hold the kernels against these.

Nothing here is fast or clever: every pixel is visited, every piece of every function is evaluated.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: Two distances closer than this (metres) tie: ``min`` may then answer with either nearest point.
TIE = 1e-9


def g_of_z(X, Y, Z, a0, a1, b0, b1, z):
    """design §4's g(z) = dx(z)^2 + dy(z)^2 + (Z - z)^2, elementwise."""
    dx = np.maximum(np.maximum(a0 * z - X, 0.0), X - a1 * z)
    dy = np.maximum(np.maximum(b0 * z - Y, 0.0), Y - b1 * z)
    return dx * dx + dy * dy + (Z - z) ** 2


def frustum_distance_pieces(X, Y, Z, a0, a1, b0, b1, z_lo, z_hi):
    """design §4 literally: cut [z_lo, z_hi] at the breakpoints, minimise each piece's quadratic in closed form
    (clamped to the piece), take the smallest. Elementwise over broadcast arrays; returns (D, z*)."""
    X, Y, Z, a0, a1, b0, b1, z_lo, z_hi = np.broadcast_arrays(*(np.asarray(x, np.float64) for x in
                                                                (X, Y, Z, a0, a1, b0, b1, z_lo, z_hi)))
    with np.errstate(divide="ignore", invalid="ignore"):
        breaks = [np.where(a != 0, c / a, z_lo) for a, c in ((a0, X), (a1, X), (b0, Y), (b1, Y))]
    breaks = [np.clip(np.nan_to_num(b, nan=0.0), z_lo, np.where(np.isinf(z_hi), np.maximum(z_lo, b), z_hi))
              for b in breaks]
    edges = np.sort(np.stack([z_lo] + breaks, axis=-1), axis=-1)
    edges = np.concatenate([edges, z_hi[..., None]], axis=-1)
    best_g = np.full(X.shape, np.inf)
    best_z = np.array(z_lo, copy=True)
    for k in range(edges.shape[-1] - 1):
        lo, hi = edges[..., k], edges[..., k + 1]
        mid = np.where(np.isinf(hi), lo + 1.0, 0.5 * (lo + hi))
        left_x, right_x = a0 * mid - X > 0, X - a1 * mid > 0
        left_y, right_y = b0 * mid - Y > 0, Y - b1 * mid > 0
        s2 = 1.0 + np.where(left_x, a0 * a0, 0) + np.where(right_x, a1 * a1, 0) + np.where(left_y, b0 * b0, 0) \
            + np.where(right_y, b1 * b1, 0)
        s1 = Z + np.where(left_x, a0 * X, 0) + np.where(right_x, a1 * X, 0) + np.where(left_y, b0 * Y, 0) \
            + np.where(right_y, b1 * Y, 0)
        z = np.clip(s1 / s2, lo, hi)
        g = g_of_z(X, Y, Z, a0, a1, b0, b1, z)
        better = g < best_g
        best_g = np.where(better, g, best_g)
        best_z = np.where(better, z, best_z)
    return np.sqrt(best_g), best_z


def frustum_point(X, Y, Z, a0, a1, b0, b1, z):
    """The point of the frustum's slice at depth z nearest to (X, Y, Z): (..., 3), elementwise."""
    z = np.asarray(z, np.float64)
    return np.stack(np.broadcast_arrays(np.clip(X, a0 * z, a1 * z), np.clip(Y, b0 * z, b1 * z), z), axis=-1)


def frustum_distance_brute(X, Y, Z, a0, a1, b0, b1, z_lo, z_hi, iterations=200):
    """Golden-section search of the convex g(z) on [z_lo, z_end], z_end = min(z_hi, z0 + sqrt(g(z0))) with
    z0 = clamp(Z, z_lo, z_hi), beyond which g exceeds g(z0). Elementwise; returns D."""
    X, Y, Z, a0, a1, b0, b1, z_lo, z_hi = np.broadcast_arrays(*(np.asarray(x, np.float64) for x in
                                                                (X, Y, Z, a0, a1, b0, b1, z_lo, z_hi)))
    z0 = np.clip(Z, z_lo, z_hi)
    lo = z_lo.copy()
    hi = np.minimum(z_hi, np.maximum(z_lo, z0 + np.sqrt(g_of_z(X, Y, Z, a0, a1, b0, b1, z0))))
    ratio = (np.sqrt(5.0) - 1.0) / 2.0
    for _ in range(iterations):
        m1 = hi - ratio * (hi - lo)
        m2 = lo + ratio * (hi - lo)
        left = g_of_z(X, Y, Z, a0, a1, b0, b1, m1) <= g_of_z(X, Y, Z, a0, a1, b0, b1, m2)
        hi = np.where(left, m2, hi)
        lo = np.where(left, lo, m1)
    candidates = np.stack([lo, hi, z_lo, z0])
    return np.sqrt(np.min(g_of_z(X, Y, Z, a0, a1, b0, b1, candidates), axis=0))


def pixel_tangents(camera):
    """(h, w) arrays a0, a1, b0, b1 of every pixel's footprint tangents."""
    v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(np.float64)
    return ((u - 0.5 - camera.cx) / camera.fx, (u + 0.5 - camera.cx) / camera.fx,
            (v - 0.5 - camera.cy) / camera.fy, (v + 0.5 - camera.cy) / camera.fy)


def view_boundary(camera, P):
    """Signed distance of optical-frame point P to the observed volume's boundary and the inward normal."""
    tx0 = (-0.5 - camera.cx) / camera.fx
    tx1 = (camera.width - 0.5 - camera.cx) / camera.fx
    ty0 = (-0.5 - camera.cy) / camera.fy
    ty1 = (camera.height - 0.5 - camera.cy) / camera.fy
    X, Y, Z = P
    z_min, z_max = camera.depth_range
    faces = [
        (np.array([1.0, 0.0, -tx0]), 0.0),
        (np.array([-1.0, 0.0, tx1]), 0.0),
        (np.array([0.0, 1.0, -ty0]), 0.0),
        (np.array([0.0, -1.0, ty1]), 0.0),
        (np.array([0.0, 0.0, 1.0]), -z_min),
        (np.array([0.0, 0.0, -1.0]), z_max),
    ]
    best = (np.inf, np.zeros(3))
    for normal, offset in faces:
        length = np.linalg.norm(normal)
        s = (normal @ P + offset) / length
        if s < best[0]:
            best = (s, normal / length)
    return best


def query_reference(occupancy, points_world, rho, aggregate, unseen, inside_tol=1e-12, min_direction=1e-9):
    """The whole single-camera query, scanning every pixel of the image with the piecewise twin.

    Returns (distance (n,), direction (n, 3) world, count (n,), invalid_count (n,), flag bits (n,),
    blind distance (n,), tied): tied[i] is a (k, 3) array of the world unit directions ``min`` may answer with for
    point i (every nearest point within TIE of the answer), empty for the other aggregates.
    """
    camera = occupancy.camera
    a0, a1, b0, b1 = pixel_tangents(camera)
    z_start = occupancy.z_start.astype(np.float64)
    z_end = occupancy.z_end.astype(np.float64)
    blind = occupancy.blind.astype(np.float64)
    invalid = occupancy.invalid.astype(np.int64)
    R_world_camera = camera.T_world_camera[:3, :3]
    points_camera = camera.world_to_camera(points_world)
    n = len(points_camera)
    out_d = np.empty(n)
    out_dir = np.zeros((n, 3))
    out_count = np.zeros(n, dtype=np.int64)
    out_invalid = np.zeros(n, dtype=np.int64)
    out_flags = np.zeros(n, dtype=np.int64)
    out_blind = np.full(n, np.inf)
    tied = [np.zeros((0, 3)) for _ in range(n)]
    for i, P in enumerate(points_camera):
        X, Y, Z = P
        s_view, normal = view_boundary(camera, P)
        flags = 2 if s_view < rho else 0
        if unseen == "occupied" and s_view <= inside_tol:
            out_d[i], out_count[i], out_flags[i] = 0.0, 1, flags
            continue
        finite = np.isfinite(z_start)
        D = np.full(z_start.shape, np.inf)
        zs = np.zeros(z_start.shape)
        D[finite], zs[finite] = frustum_distance_pieces(X, Y, Z, a0[finite], a1[finite], b0[finite], b1[finite],
                                                        z_start[finite], z_end[finite])
        behind_robot = np.isfinite(blind)
        blind_d = np.inf
        if behind_robot.any():
            D_blind, _ = frustum_distance_pieces(X, Y, Z, a0[behind_robot], a1[behind_robot], b0[behind_robot],
                                                 b1[behind_robot], blind[behind_robot], np.inf)
            blind_d = D_blind.min() if D_blind.min() < rho else np.inf
        out_blind[i] = blind_d
        contributor = D < rho
        vs, us = np.nonzero(contributor)
        d = D[contributor]
        z = zs[contributor]
        nearest = np.stack([np.clip(X, a0[contributor] * z, a1[contributor] * z),
                            np.clip(Y, b0[contributor] * z, b1[contributor] * z), z], axis=1)
        unseen_d = s_view if (unseen == "occupied" and s_view < rho) else np.inf
        inv = invalid[contributor]
        if aggregate == "min":
            if len(d):
                k = np.lexsort((us, vs, d))[0]  # smallest distance, then smallest row, then smallest column
            if len(d) and d[k] <= inside_tol:
                out_d[i], out_count[i], out_invalid[i] = 0.0, 1, inv[k]
                out_flags[i] = flags | 1 | (4 if inv[k] else 0)
            elif unseen_d < np.inf and (not len(d) or unseen_d < d[k]):
                out_d[i], out_count[i], out_dir[i] = unseen_d, 1, R_world_camera @ normal
                out_flags[i] = flags
            elif len(d):
                out_d[i], out_count[i], out_invalid[i] = d[k], 1, inv[k]
                out_dir[i] = R_world_camera @ ((P - nearest[k]) / d[k])
                out_flags[i] = flags | (4 if inv[k] else 0)
            else:
                out_d[i], out_flags[i] = np.inf, flags
            if 0 < out_d[i] < np.inf:
                ties = np.abs(d - out_d[i]) <= TIE
                units = [(P - nearest[ties]) / d[ties, None]]
                if abs(unseen_d - out_d[i]) <= TIE:
                    units.append(normal[None])
                tied[i] = np.concatenate(units) @ R_world_camera.T
            continue
        count = len(d) + (1 if unseen_d < np.inf else 0)
        out_invalid[i] = inv.sum()
        flags |= 4 if inv.sum() else 0
        if len(d) and d.min() <= inside_tol:
            out_d[i], out_count[i], out_flags[i] = 0.0, count, flags | 1
            continue
        out_count[i], out_flags[i] = count, flags
        if count == 0:
            out_d[i] = np.inf
            continue
        units = (P - nearest) / d[:, None]
        total = units.sum(axis=0) + (normal if unseen_d < np.inf else 0.0)
        norm = np.linalg.norm(total)
        if norm > min_direction * count:
            out_dir[i] = R_world_camera @ (total / norm)
        all_d = np.concatenate([d, [unseen_d] if unseen_d < np.inf else []])
        out_d[i] = all_d.mean() if aggregate == "mean" else all_d.min()
    out_flags |= np.where(out_blind < out_d, 32, 0)
    return out_d, out_dir, out_count, out_invalid, out_flags, out_blind, tied


def assert_same_answers(result, distance, direction, count, invalid_count, flags, blind=None, tied=None,
                        distance_tol=1e-10, direction_tol=1e-9):
    """Hold a kernel's :class:`depthguard.DistanceResult` against its twin's answers ((n,) arrays, direction (n, 3)
    world): distances (and blind distances, when given) to ``distance_tol`` metres; counts, invalid counts and flag
    bits exactly; directions: zero where the distance is 0 or inf; where it is positive and finite, both unit vectors
    agreeing to ``direction_tol``, or both zero (the aggregated directions cancelled), or, for ``min``, the kernel's
    is one of ``tied[i]`` (another nearest point at the same distance)."""
    n = len(distance)
    np.testing.assert_allclose(result.distance, distance, rtol=0, atol=distance_tol)
    assert np.array_equal(result.count, count), (result.count, count)
    assert np.array_equal(result.invalid_count, invalid_count), (result.invalid_count, invalid_count)
    assert [int(f) for f in result.flags] == [int(f) for f in flags], ([int(f) for f in result.flags], list(flags))
    if blind is not None:
        np.testing.assert_allclose(result.blind_distance, blind, rtol=0, atol=distance_tol)
    got = np.asarray(result.direction)
    norm = np.linalg.norm(got, axis=1)
    for i in range(n):
        if not 0 < distance[i] < np.inf:
            assert norm[i] == 0 and not np.any(direction[i]), (i, distance[i], got[i], direction[i])
            continue
        assert norm[i] == 0 or abs(norm[i] - 1) <= direction_tol, (i, got[i])
        if np.all(np.abs(got[i] - direction[i]) <= direction_tol):
            continue
        others = np.zeros((0, 3)) if tied is None else tied[i]
        assert np.any(np.all(np.abs(others - got[i]) <= direction_tol, axis=1)), (i, got[i], direction[i], others)


def paper_query_reference(occupancy, points_world, rho, aggregate):
    """The 2015 paper's method literally (unseen space free): window of half-width rho*f/(2*(Z - rho)) around P's
    pixel, pixels with depth in [Z - rho, Z + rho], distance at the fixed depth max(Z, z_lo).
    Returns (distance (n,), direction (n, 3) world)."""
    camera = occupancy.camera
    a0, a1, b0, b1 = pixel_tangents(camera)
    zs = occupancy.z_start.astype(np.float64)
    ze = occupancy.z_end.astype(np.float64)
    v_idx, u_idx = np.mgrid[0 : camera.height, 0 : camera.width]
    out_d = np.full(len(points_world), np.inf)
    out_dir = np.zeros((len(points_world), 3))
    for i, P in enumerate(camera.world_to_camera(points_world)):
        X, Y, Z = P
        if Z - rho > 0:
            pu, pv = camera.fx * X / Z + camera.cx, camera.fy * Y / Z + camera.cy
            hu, hv = 0.5 * rho * camera.fx / (Z - rho), 0.5 * rho * camera.fy / (Z - rho)
            window = (np.abs(u_idx - pu) <= hu) & (np.abs(v_idx - pv) <= hv)
        else:
            window = np.ones(zs.shape, bool)
        use = window & (zs <= Z + rho) & (zs >= Z - rho)
        z = np.minimum(np.maximum(Z, zs[use]), ze[use])
        nearest = np.stack([np.clip(X, a0[use] * z, a1[use] * z), np.clip(Y, b0[use] * z, b1[use] * z), z], 1)
        d = np.linalg.norm(P - nearest, axis=1)
        c = d < rho
        if not c.any():
            continue
        d, nearest = d[c], nearest[c]
        if d.min() <= 1e-12:  # inside a possibly-occupied set
            out_d[i] = 0.0
            continue
        units = (P - nearest) / d[:, None]
        R = camera.T_world_camera[:3, :3]
        if aggregate == "min":
            k = np.argmin(d)
            out_d[i], out_dir[i] = d[k], R @ units[k]
        else:
            total = units.sum(axis=0)
            out_dir[i] = R @ (total / np.linalg.norm(total))
            out_d[i] = d.mean() if aggregate == "mean" else d.min()
    return out_d, out_dir


def fill_small_holes_reference(raw, scale, invalid, hole_pixels, margin, z_start, z_end, blind):
    """The ``invalid="neighbors"`` hole filling with scipy.ndimage, whole-image operations only: label the holes,
    find each one's size, thickness (a pixel whose 3x3 neighbourhood is all hole) and the smallest valid depth around
    it, from robot and from other pixels. Edits z_start, z_end, blind in place. ``margin``: depth -> metres."""
    from scipy import ndimage

    holes = invalid.astype(bool)
    labels, n = ndimage.label(holes, structure=np.ones((3, 3), dtype=bool))
    if n == 0:
        return
    index = np.arange(1, n + 1)
    sizes = np.bincount(labels.ravel(), minlength=n + 1)[1:]
    interior = ndimage.binary_erosion(holes, structure=np.ones((3, 3), dtype=bool), border_value=0)
    thick = np.bincount(labels[interior], minlength=n + 1)[1:] > 0
    measured = np.where(holes, np.inf, raw.astype(np.float64) * scale)
    robot = ~holes & np.isfinite(blind)

    def nearest(values):
        around = ndimage.minimum_filter(values, size=3, mode="constant", cval=np.inf)
        return np.asarray(ndimage.minimum(around, labels, index), dtype=np.float64).reshape(-1)

    near_robot = nearest(np.where(robot, measured, np.inf))
    near_other = nearest(np.where(robot, np.inf, measured))
    fillable = (sizes <= hole_pixels) | ~thick
    for k in np.flatnonzero(fillable):
        pixels = labels == k + 1
        if near_robot[k] <= near_other[k] and np.isfinite(near_robot[k]):
            z_start[pixels] = np.inf
            z_end[pixels] = np.inf
            blind[pixels] = np.minimum(blind[pixels], near_robot[k])
        elif np.isfinite(near_other[k]):
            z_start[pixels] = max(near_other[k] - margin(near_other[k]), 0.0)
            z_end[pixels] = np.inf
            blind[pixels] = np.inf


def fill_self_filter_reference(robot_near, tolerance, margin, policy_start, invalid, z_start, z_end, blind):
    """After hole filling, a hole's fill is self-filtered as a measurement would be (whole-image numpy): where the
    robot is rendered and the fill lies at or behind the nearest rendered robot surface of the 3x3 neighbourhood
    (border pixels count themselves again) less ``tolerance`` and the noise margin there, the pixel shows the robot:
    free in front, blind from the robot's own depth. Without robot_far (nothing is "seen past" the robot). Only
    filled holes can change: every other pixel was decided by the first self-filtering. Edits in place."""
    h, w = robot_near.shape
    rendered = np.pad(np.where(robot_near > 0, robot_near.astype(np.float64), np.inf), 1, mode="edge")
    d_near = np.min([rendered[1 + dv:1 + dv + h, 1 + du:1 + du + w] for dv in (-1, 0, 1) for du in (-1, 0, 1)],
                    axis=0)
    with np.errstate(invalid="ignore"):
        front = d_near - tolerance - margin(d_near)
        filled = (invalid == 1) & np.isfinite(z_start) & (z_start != policy_start)
        robot = (robot_near > 0) & filled & (z_start.astype(np.float64) >= front)
    z_start[robot] = np.inf
    blind[robot] = robot_near[robot]


def camera_clears_reference(corners_j, offset_j, free_j, z_near_j, z0, z1, u, v, margin, pad):
    """Whether secondary camera j saw through the whole cell [z0, z1] of principal pixel (u, v), written plainly:
    project the cell's 8 corners, take every pixel whose footprint meets their bounding box (grown by pad)."""
    points = []
    for dv in (0, 1):
        for du in (0, 1):
            for z in (z0, z1):
                points.append(corners_j[v + dv, u + du] * z + offset_j)
    points = np.array(points)
    if np.any(points[:, 2] <= z_near_j):
        return False
    x = points[:, 0] / points[:, 2]
    y = points[:, 1] / points[:, 2]
    q = np.arange(int(np.ceil(x.min() - 0.5)) - pad, int(np.floor(x.max() + 0.5)) + pad + 1)
    r = np.arange(int(np.ceil(y.min() - 0.5)) - pad, int(np.floor(y.max() + 0.5)) + pad + 1)
    h, w = free_j.shape
    if q.min() < 0 or r.min() < 0 or q.max() > w - 1 or r.max() > h - 1:
        return False
    return bool(np.all(free_j[np.ix_(r, q)] >= points[:, 2].max() + margin))


def fused_query_reference(grid, principal, frees, z_nears, points_world, rho, unseen, robot_far=None, margin=0.01,
                          pad=1, inside_tol=1e-12, robot_slack=0.0, robot_near=None, min_direction=1e-9):
    """The fused query of design §8 by brute force: for every principal pixel, every grid cell that comes
    within rho is classified (certain, candidate confirmed by all secondaries, or cleared) and the pixel's distance
    is the smallest over its occupied pieces.

    Returns {aggregate: :class:`FusedAnswer`} for "min", "mean" and "hybrid": distances, counts, unit directions
    (from the nearest obstacle point towards the control point, design §6; world frame), invalid counts (the
    contributing pixels whose nearest point is a candidate of a pixel without a measurement), flag bits and the
    directions ``min`` may answer with on a tie. Flags: INSIDE_OBSTACLE, REGION_OUTSIDE_VIEW, INVALID_PIXELS_USED
    and OUTSIDE_GRID (the region's depths [Z - rho, Z + rho], within the camera's range, leave [d_min, d_max]).
    """
    camera = principal.camera
    a0, a1, b0, b1 = pixel_tangents(camera)
    z_min = camera.depth_range[0]
    d_min, dd, n_cells = grid.d_min, grid.delta_d, grid.n_cells
    d_max = d_min + n_cells * dd
    z_lo, z_hi = camera.depth_range
    R_world_camera = camera.T_world_camera[:3, :3]
    zs_img = principal.z_start.astype(np.float64)
    ze_img = principal.z_end.astype(np.float64)
    certain_img = (principal.invalid == 0) | (principal.z_start != np.float32(z_min))
    if principal.robot_pixels:
        blind_img = np.where(np.isfinite(principal.blind), np.maximum(principal.blind, robot_far + robot_slack),
                             np.inf)
    else:
        blind_img = np.full(camera.shape, np.inf)
    if robot_near is not None:  # a surface in front of the robot: its gray area stops at the robot's body
        hides = np.isinf(principal.blind) & (robot_far > 0) & certain_img & (zs_img < robot_near)
        ze_img = np.where(hides, np.minimum(ze_img, robot_near), ze_img)
        blind_img = np.where(hides, robot_far + robot_slack, blind_img)
    blind_img = blind_img.astype(np.float32).astype(np.float64)  # a start depth, held as float32 like the images
    n = len(points_world)
    out = {a: FusedAnswer(np.full(n, np.inf), np.zeros(n, dtype=np.int64), np.zeros((n, 3)),
                          np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64), [np.zeros((0, 3))] * n)
           for a in ("min", "mean", "hybrid")}
    for i, P in enumerate(camera.world_to_camera(points_world)):
        X, Y, Z = P
        s_view, normal = view_boundary(camera, P)
        flags = (2 if s_view < rho else 0) | \
            (64 if min(Z + rho, z_hi) > grid.d_max or max(Z - rho, z_lo) < d_min else 0)
        for a in out:
            out[a].flags[i] = flags
        if unseen == "occupied" and s_view <= inside_tol:
            for a in out:
                out[a].distance[i], out[a].count[i] = 0.0, 1
            continue
        z_far = Z + rho
        per_pixel = []
        for v in range(camera.height):
            for u in range(camera.width):
                tang = (a0[v, u], a1[v, u], b0[v, u], b1[v, u])

                def dist(lo, hi):
                    """Distances and nearest depths of the pieces [lo, hi] of the pixel's frustum."""
                    lo, hi = np.broadcast_arrays(np.asarray(lo, float), np.asarray(hi, float))
                    d = np.full(lo.shape, np.inf)
                    z = np.zeros(lo.shape)
                    ok = lo <= hi
                    if ok.any():
                        d[ok], z[ok] = frustum_distance_pieces(X, Y, Z, *tang, lo[ok], hi[ok])
                    return d, z

                def nearest(lo, hi):
                    d, z = dist(lo, hi)
                    return float(d), float(z)

                def occupied(k):
                    return not any(camera_clears_reference(grid.corners[j], grid.offsets[j], frees[j], z_nears[j],
                                                           d_min + k * dd, d_min + (k + 1) * dd, u, v, margin, pad)
                                   for j in range(len(frees)))

                def candidates(lo, hi):
                    """The nearest occupied cell's piece of [lo, hi]: (distance, depth)."""
                    best, best_z = np.inf, 0.0
                    if lo > hi:
                        return best, best_z
                    if lo < d_min:
                        best, best_z = min((best, best_z), nearest(lo, min(hi, d_min)), key=lambda t: t[0])
                    if hi > d_max:
                        best, best_z = min((best, best_z), nearest(max(lo, d_max), hi), key=lambda t: t[0])
                    k = np.arange(max(int((max(lo, d_min) - d_min) // dd) - 1, 0),
                                  min(int((min(hi, d_max) - d_min) // dd) + 2, n_cells))
                    d, z = dist(np.maximum(lo, d_min + k * dd), np.minimum(hi, d_min + (k + 1) * dd))
                    for kk, dk, zk in zip(k, d, z):
                        if dk < min(best, rho) and occupied(kk):
                            best, best_z = dk, zk
                    return best, best_z

                zs, ze, bf = zs_img[v, u], ze_img[v, u], blind_img[v, u]
                first = min(zs, bf)
                if first > z_far or nearest(first, np.inf)[0] >= rho:
                    continue
                d, z, from_invalid = np.inf, 0.0, False
                if zs <= z_far:
                    if certain_img[v, u]:
                        if zs >= Z:
                            d, z = nearest(zs, ze)
                        else:
                            cell_end = d_min + (np.floor((zs - d_min) / dd) + 1) * dd if zs >= d_min else d_min
                            d, z = nearest(zs, min(cell_end, ze))
                            if cell_end < ze:
                                d, z = min((d, z), candidates(cell_end, min(ze, z_far)), key=lambda t: t[0])
                    else:  # no measurement: a candidate of a pixel without one
                        d, z = candidates(zs, min(ze, z_far))
                        from_invalid = d < np.inf
                if bf <= z_far:
                    d_blind, z_blind = candidates(bf, z_far)
                    if d_blind < d:
                        d, z, from_invalid = d_blind, z_blind, False
                if d < rho:
                    unit = (P - frustum_point(X, Y, Z, *tang, z)) / d if d > 0 else np.zeros(3)
                    per_pixel.append((d, v, u, unit, from_invalid))
        unseen_d = s_view if (unseen == "occupied" and s_view < rho) else np.inf
        d = np.array([p[0] for p in per_pixel])
        units = np.array([p[3] for p in per_pixel]).reshape(-1, 3)
        invalid = np.array([p[4] for p in per_pixel], dtype=bool)
        if len(d) == 0 and unseen_d == np.inf:
            continue
        # min: the nearest pixel, the first in (v, u) order among equals; the boundary if strictly nearer.
        m = out["min"]
        k = np.lexsort(([p[2] for p in per_pixel], [p[1] for p in per_pixel], d))[0] if len(d) else None
        m.count[i] = 1
        if k is not None and d[k] <= inside_tol:
            m.distance[i], m.invalid_count[i] = 0.0, invalid[k]
            m.flags[i] |= 1 | (4 if invalid[k] else 0)
        elif k is None or unseen_d < d[k]:
            m.distance[i], m.direction[i] = unseen_d, R_world_camera @ normal
        else:
            m.distance[i], m.invalid_count[i], m.direction[i] = d[k], invalid[k], R_world_camera @ units[k]
            m.flags[i] |= 4 if invalid[k] else 0
        if 0 < m.distance[i] < np.inf:
            ties = [units[np.abs(d - m.distance[i]) <= TIE]] + \
                ([normal[None]] if abs(unseen_d - m.distance[i]) <= TIE else [])
            m.tied[i] = np.concatenate(ties) @ R_world_camera.T
        # mean and hybrid: every contributing pixel and the boundary.
        all_d = np.concatenate([d, [unseen_d] if unseen_d < np.inf else []])
        total = units.sum(axis=0) + (normal if unseen_d < np.inf else 0.0)
        for a in ("mean", "hybrid"):
            o = out[a]
            o.count[i], o.invalid_count[i] = len(all_d), invalid.sum()
            o.flags[i] |= 4 if invalid.any() else 0
            if all_d.min() <= inside_tol:
                o.distance[i] = 0.0
                o.flags[i] |= 1
                continue
            o.distance[i] = all_d.mean() if a == "mean" else all_d.min()
            if np.linalg.norm(total) > min_direction * len(all_d):
                o.direction[i] = R_world_camera @ (total / np.linalg.norm(total))
    return out


class FusedAnswer(NamedTuple):
    """One aggregate's answers of :func:`fused_query_reference` for n points."""

    distance: np.ndarray  # (n,) metres, inf: nothing within rho
    count: np.ndarray  # (n,) int
    direction: np.ndarray  # (n, 3) world unit vectors, zero where there is none
    invalid_count: np.ndarray  # (n,) int
    flags: np.ndarray  # (n,) int flag bits
    tied: list  # n (k, 3) arrays: the directions min may answer with (every nearest point within TIE)


def random_rotation(rng) -> np.ndarray:
    """A uniformly random proper rotation (det +1) from the QR decomposition of a Gaussian matrix."""
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def random_pose(rng, spread: float) -> np.ndarray:
    """A random rigid transform (4, 4): random_rotation and a translation uniform in [-spread, spread]^3 metres."""
    T = np.eye(4)
    T[:3, :3] = random_rotation(rng)
    T[:3, 3] = rng.uniform(-spread, spread, size=3)
    return T
