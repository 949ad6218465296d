"""Numba kernels of the depth-grid fusion (design §8). They trust their inputs; ``depthguard/depthgrid/_fusion.py``
checks them.

Along each principal pixel's frustum, what the principal camera says is possibly occupied splits into:

- certain pieces, which no other camera can clear: the measured surface's own cell (case iii), or the whole
  frustum from the surface on when the surface is at or behind the control point (case ii), and anything outside
  the grid's depth span;
- candidate cells, which the other cameras may clear: the gray area behind a surface in front of the control point
  (case iii), the frustum of a pixel without a measurement (design §3), and the space behind the robot from
  where the ray first leaves its body (case iv), the space between two links included: there a cell within the
  self-filter's shell of a later link counts as that link (:func:`shell_cells`).

A candidate cell is occupied only if every secondary camera confirms it. Camera j declares it free only if the
cell's whole footprint (its 8 corners projected into j, grown by ``pad`` pixels) lies inside j's image and every
pixel q of that footprint saw beyond the cell: free[j][q] >= the cell's largest depth in j plus ``margin``, where
free[j][q] is j's measured depth minus its noise margin (0 where j measured nothing).

Cell k of principal pixel (u, v) spans the principal's optical depths d_min + k delta_d to d_min + (k + 1) delta_d
(``grid``'s). A frame's (h, w) arrays are indexed [v, u]; H, W: the principal image's height and width.

Arguments used throughout:

- ``X, Y, Z``: float64, metres: the control point P in the principal camera's optical frame.
- ``rho``: float64, metres: the radius of the surveillance region around P.
- ``u, v``: int, pixels: the column and row of a principal pixel.
- ``a0, a1, b0, b1``: float64, tangents (x/z and y/z, no unit): principal pixel (u, v)'s frustum {x/z in [a0, a1],
  y/z in [b0, b1]}, a0 = (u - 1/2 - cx)/fx, a1 = (u + 1/2 - cx)/fx, b0 = (v - 1/2 - cy)/fy, b1 = (v + 1/2 - cy)/fy.
- ``k_a, k_b``: int: the first and last cell of a run along principal pixel (u, v), k_a <= k_b < k_a + 64.
- ``lo, hi``: float64, metres: the ends of a segment [lo, hi] of principal pixel (u, v)'s frustum (optical depths).
- ``bound2``: float64, square metres: only what comes nearer than sqrt(bound2) to P counts.
- ``grid``: :class:`GridState`: the depth grid and its per-frame state (the fields as documented there).
- ``d_min, delta_d, n_cells``: float64 metres, float64 metres, int: the grid's first depth, its cells' depth and
  their number along each principal pixel (``grid``'s; the helpers called per pixel take them apart).
- ``cells``: (H, W, n_cells) uint8: ``grid``'s classification of every cell (0 not yet, 1 free, 2 occupied, 3 free
  by the memory).
- ``free_run, behind_run``: (H, W) int64: ``grid``'s two runs of known free cells per pixel (``runs`` above).
- ``view``: :class:`PrincipalView`: the principal camera's frame.
- ``runs``: (H, W) int64: per principal pixel, one run of cells known free, (first << 32) | last (NO_FREE_RUN for
  none): ``grid``'s free_run (a gray area, or the frustum of a pixel without a measurement) or behind_run (the space
  behind the robot).
- ``spans``: (H, 2) int64: per principal image row v, the first and last column to visit (first > last: none), as
  :func:`depthguard.kernels.frustum.surveillance_region` fills it.
- ``scale``: float, metres per unit of ``raw`` (the frame's depth_scale; 1.0 for float32).
- ``z_min, z_max``: float, metres: the camera's valid depth range.
- ``m0, m1, m2``: float, the camera's noise margin m(d) = max(m0 + m1 d + m2 d^2, 0) metres at depth d metres
  (m0 in metres, m1 no unit, m2 per metre; ``NoiseModel.coefficients()``).
- ``z_start, invalid, blind``: (h, w) float32 metres, uint8, float32 metres: the camera's prepared frame
  (:class:`depthguard.depth.OccupancyImage`): where each pixel's possibly-occupied segment starts (inf: nothing), 1
  for a pixel without a valid measurement, where the space hidden behind the robot starts (inf: none).
- ``aggregate``: int: AGG_MIN, AGG_MEAN or AGG_HYBRID (0, 1, 2: the index in ``config.AGGREGATES``).
- ``unseen_occupied``: bool: unseen space counts as possibly occupied (``unseen="occupied"``, design §3).
- ``near_eps``: float, metres: a cube corner at or nearer than this optical depth makes the window the whole image
  (``config.NEAR_PLANE_EPSILON``).
- ``inside_tol``: float, metres: a distance at or below it means P is inside (``config.INSIDE_TOLERANCE``).
- ``min_direction``: float, no unit: a sum of unit directions shorter than min_direction times their count gives the
  zero vector (``config.MIN_DIRECTION_NORM``).
- ``out_direction``: (3,) float64, written: the unit direction from the obstacle towards P, principal optical frame
  (zero for none).
"""

from collections import namedtuple

import numpy as np
from numba import prange

from depthguard.kernels.frustum import (
    contribution,
    AGG_MIN,
    finish_min_at_pixel,
    finish_sum,
    guess_piece_row,
    clamped_index,
    frustum_nearest,
    noise_margin,
    rho_squared,
    surveillance_region,
    usable_rho,
)
from depthguard.kernels.jit import kernel

#: What the fused kernels need of the depth grid and its per-frame state, passed as one record (numba compiles a
#: namedtuple of arrays and scalars like separate arguments). d_min, delta_d (metres), n_cells: the grid's cells
#: along each principal pixel; corners (n_sec, H+1, W+1, 3), offsets (n_sec, 3): the map (DepthGridMap); eroded
#: (n_sec, h, w) float32: each secondary's free depths eroded by the footprint pad; sizes (n_sec, 2) int64: their
#: (width, height); z_near (n_sec,): their nearest valid depth; margin: metres a secondary must see beyond a cell;
#: cells (H, W, n_cells) uint8: the cells' classes so far; touched (H, W) uint8: 1 where a pixel's cells or runs were
#: written (:func:`classify_run`, :func:`_walk_out`; what the next set's reuse of the arrays clears); mem_free (free
#: voxels, uint8) and mem_geometry (float64): the free-space memory (:func:`remembered_cells`; zero-sized for none;
#: two fields, not a nested tuple, which numba's parallel loops do not take); free_run, behind_run (H, W) int64:
#: per pixel, one run of cells known free in its gray area (or, without a measurement, its frustum) and one in the
#: space behind the robot (two, so that the two runs of a pixel that shows the robot behind a surface do not replace
#: each other).
#: zone (n_caps, 7) float64 and zone_params (CAPSULE_PARAMS,) float64: the robot zone (:func:`zoned_cells`; zero rows
#: for none). shell (n_caps, 7) float64, shell_params (CAPSULE_PARAMS,) float64 and shell_lo, shell_hi (H, W) float32
#: metres: the self-filter's shell round the links that a principal pixel's ray meets after it first left the robot
#: (:func:`shell_cells`; zero rows for none).
GridState = namedtuple("GridState", "d_min delta_d n_cells corners offsets eroded sizes z_near margin cells touched "
                                    "mem_free mem_geometry free_run behind_run zone zone_params shell shell_params "
                                    "shell_lo shell_hi")

#: What the fused kernels need of the principal camera's frame, one record: its per-pixel arrays ((h, w) each, from
#: :func:`principal_arrays`: z_start float32, z_end float32, certain uint8, blind_from float32), its intrinsics fx,
#: fy, cx, cy (pixels) and its valid depth range z_min, z_max (metres).
PrincipalView = namedtuple("PrincipalView", "z_start z_end certain blind_from fx fy cx cy z_min z_max")

#: A fused query's options: aggregate (AGG_*), unseen_occupied (bool), near_eps, inside_tol, min_direction (the
#: kernels' numerical tolerances, config.NEAR_PLANE_EPSILON, INSIDE_TOLERANCE, MIN_DIRECTION_NORM), row_chunks (each
#: point's rows are split in this many interleaved tasks).
QueryOptions = namedtuple("QueryOptions", "aggregate unseen_occupied near_eps inside_tol min_direction row_chunks")

#: Where a fused query writes, for n points: distance (n,), direction (n, 3), count (n,), invalid_count (n,), flags
#: (n,).
FusedOutput = namedtuple("FusedOutput", "distance direction count invalid_count flags")


@kernel(inline=True)
def measured_free(raw, scale, z_min, z_max, m0, m1, m2):
    """How far one pixel saw its ray free: its measurement (raw * scale metres) minus the noise margin, at least 0;
    -1 where it measured nothing (or outside [z_min, z_max]). raw: the pixel's value, uint16 in units of ``scale``
    metres or float32 metres (not finite or <= 0: no measurement)."""
    d = np.float64(raw) * scale
    if np.isfinite(d) and d > 0.0 and d >= z_min and d <= z_max:
        return max(d - noise_margin(d, m0, m1, m2), 0.0)
    return -1.0


@kernel(parallel=True)
def free_depths(raw, scale, z_min, z_max, m0, m1, m2, free):
    """Per pixel of a secondary frame, the depth up to which the camera saw the ray free: the measured depth minus
    its noise margin, 0 where it measured nothing (or outside [z_min, z_max]). raw: (h, w) uint16 in units of
    ``scale`` metres, or float32 metres. Writes free (h, w) float32, metres."""
    h, w = raw.shape
    for v in prange(h):
        for u in range(w):
            free[v, u] = max(measured_free(raw[v, u], scale, z_min, z_max, m0, m1, m2), 0.0)


@kernel(inline=True)
def surface_cell_end(zs, d_min, delta_d):
    """Where the grid cell holding a measured surface at depth zs ends (d_min for a surface before the grid). zs and
    the answer: float64, metres, principal optical depth."""
    if zs < d_min:
        return d_min
    return d_min + (np.floor((zs - d_min) / delta_d) + 1.0) * delta_d


@kernel(parallel=True)
def seen_free_depths(raw, scale, z_min, z_max, m0, m1, m2, z_start, invalid, invalid_start, blind, free):
    """Per pixel of a secondary camera's frame, how far it saw the ray free: its measurement minus the noise margin
    (:func:`free_depths`; the robot's own surface included: the ray is free up to it); where it measured nothing,
    the depth its prepared frame starts at when the ``neighbors`` policy filled the small hole (the nearest surface
    around it, or the rendered robot when that surface is the robot), else 0. raw: (h, w) measurements (uint16 in
    units of ``scale`` metres, or float32 metres); z_start, invalid, blind: its :class:`OccupancyImage`;
    invalid_start: float32, metres, the start depth its invalid-pixel policy gives a pixel without a measurement
    (z_min, or inf for ``invalid="free"``). Writes free (h, w) float32, metres."""
    h, w = raw.shape
    for v in prange(h):
        for u in range(w):
            seen = measured_free(raw[v, u], scale, z_min, z_max, m0, m1, m2)
            if seen >= 0.0:
                free[v, u] = seen
            elif invalid[v, u] and z_start[v, u] != invalid_start and np.isfinite(z_start[v, u]):
                free[v, u] = z_start[v, u]
            elif invalid[v, u] and z_start[v, u] != invalid_start and np.isfinite(blind[v, u]):
                free[v, u] = blind[v, u]
            else:
                free[v, u] = 0.0


@kernel(parallel=True)
def principal_arrays(z_start, z_end, invalid, invalid_start, blind, robot_near, robot_far, robot_exit, slack, m0, m1,
                     m2, certain, z_end_fused, blind_from, shell_lo, shell_hi):
    """Per pixel of the principal frame, what fusion starts from:

    - certain = 1 where the possibly-occupied segment starts at a measured surface (a valid pixel, or an invalid one
      whose segment starts elsewhere than the invalid start depth);
    - blind_from: where the space behind the robot starts: past the robot's body by the self-filter's slack plus the
      noise margin there, never before ``blind``; inf where no robot is seen. The body ends where the ray first
      leaves the robot (robot_exit) when it is given, else where it last leaves it (robot_far): the space between two
      links along the ray is checked like the rest of the space behind the robot (design §11a: no default
      concession), not taken for the robot;
    - shell_lo, shell_hi: the depths between that first exit's end and where the space behind the last link the ray
      meets starts (robot_far plus the slack and the noise margin), in which a cell that lies wholly within the
      self-filter's shell of a link counts as that link (:func:`shell_cells`): the same shell the self-filter takes
      for the robot in front of a link and the principal behind it. inf, inf for none;
    - z_end_fused: z_end, except that a surface in front of the robot does not hide the robot's own body from
      fusion: its gray area stops where the rendered robot starts (robot_near), and the space behind the body is
      blind space again (blind_from). The body is the robot, whatever hides it; a secondary camera that sees the
      robot's surface could never clear the space inside it.

    Inputs: the principal's prepared frame (:class:`OccupancyImage`), z_start, z_end and blind: (h, w) float32,
    metres, and invalid: (h, w) uint8; invalid_start: float32, metres, the camera's z_min (where the invalid-pixel
    policy starts a pixel without a measurement); robot_near, robot_far, robot_exit: (h, w) float32, metres, the
    rendered robot's nearest surface, where it ends, and where a ray first leaves it (0 where the robot is not
    rendered, all 0 when not given); slack: float, metres, the self-filter's tolerance. Writes certain (h, w) uint8
    and z_end_fused, blind_from, shell_lo, shell_hi (h, w) float32, metres.
    """
    h, w = z_start.shape
    for v in prange(h):
        for u in range(w):
            zs = z_start[v, u]
            certain[v, u] = 1 if (invalid[v, u] == 0 or zs != invalid_start) else 0
            z_end_fused[v, u] = z_end[v, u]
            far = np.float64(robot_far[v, u])
            behind = far + slack + noise_margin(far, m0, m1, m2)
            b = np.float64(blind[v, u])
            if np.isfinite(b):
                blind_from[v, u] = max(b, behind)
            elif far > 0.0 and certain[v, u] and zs < robot_near[v, u]:
                z_end_fused[v, u] = min(z_end[v, u], robot_near[v, u])
                blind_from[v, u] = behind
            else:
                blind_from[v, u] = np.inf
            shell_lo[v, u] = np.inf
            shell_hi[v, u] = np.inf
            exit_ = np.float64(robot_exit[v, u])
            if exit_ > 0.0 and np.isfinite(blind_from[v, u]):
                start = max(exit_ + slack + noise_margin(exit_, m0, m1, m2), np.float64(robot_near[v, u]))
                if np.isfinite(b):
                    start = max(start, b)
                if start < blind_from[v, u]:
                    shell_lo[v, u] = start
                    shell_hi[v, u] = blind_from[v, u]
                    blind_from[v, u] = start


@kernel(parallel=True)
def erode_free(free, sizes, pad, out):
    """out[j, r, q] = the smallest free[j] over the pixels within pad of (r, q) (a (2 pad + 1)^2 square), 0 where
    that square leaves camera j's image: a cell's footprint then needs only its own pixels read, and the grown
    footprint's pixels and its staying inside the image come with them. free, out: (J, h, w) float32, metres (each
    secondary's free image, padded to the largest); sizes: (J, 2) int64, each camera's (width, height) in pixels;
    pad: int, pixels."""
    n_cams, h, w = free.shape
    row_min = np.empty((n_cams, h, w), dtype=np.float32)
    for j in range(n_cams):
        width = sizes[j, 0]
        height = sizes[j, 1]
        for r in prange(h):
            for q in range(w):
                m = np.float32(np.inf)
                if r >= height or q - pad < 0 or q + pad > width - 1:
                    m = np.float32(0.0)
                else:
                    for t in range(q - pad, q + pad + 1):
                        m = min(m, free[j, r, t])
                row_min[j, r, q] = m
        for r in prange(h):
            for q in range(w):
                m = np.float32(np.inf)
                if r - pad < 0 or r + pad > height - 1:
                    m = np.float32(0.0)
                else:
                    for t in range(r - pad, r + pad + 1):
                        m = min(m, row_min[j, t, q])
                out[j, r, q] = m


@kernel(inline=True)
def face_box(corners, offset, u, v, z, z_near):
    """The 4 corners of principal pixel (u, v)'s frustum at depth z, projected into one secondary camera: (ok,
    x_lo, x_hi, y_lo, y_hi, largest depth); not ok when a corner is behind the camera or nearer than it measures,
    or when the map's geometry gives no finite point (NaN in a map: the cell cannot be cleared).

    corners: (H + 1, W + 1, 3) float64 and offset: (3,) float64, that camera's map (``grid``'s corners[j] and
    offsets[j], :class:`depthguard.depthgrid.DepthGridMap`): the footprint corner at (u - 1/2, v - 1/2) and principal
    depth z lands at homogeneous image coordinates h = corners[v, u] z + offset (pixel (h_x / h_z, h_y / h_z), depth
    h_z metres); z: float64, metres; z_near: float, metres, the camera's nearest valid depth. The bounds are in
    pixels, the depth in metres."""
    x_lo = np.inf
    x_hi = -np.inf
    y_lo = np.inf
    y_hi = -np.inf
    far = 0.0
    for dv in range(2):
        for du in range(2):
            hz = corners[v + dv, u + du, 2] * z + offset[2]
            if not (hz > z_near and np.isfinite(hz)):
                return False, x_lo, x_hi, y_lo, y_hi, far
            inv = 1.0 / hz
            x = (corners[v + dv, u + du, 0] * z + offset[0]) * inv
            y = (corners[v + dv, u + du, 1] * z + offset[1]) * inv
            if not (np.isfinite(x) and np.isfinite(y)):
                return False, x_lo, x_hi, y_lo, y_hi, far
            x_lo = min(x_lo, x)
            x_hi = max(x_hi, x)
            y_lo = min(y_lo, y)
            y_hi = max(y_hi, y)
            far = max(far, hz)
    return True, x_lo, x_hi, y_lo, y_hi, far


@kernel(inline=True)
def box_seen_through(eroded, width, height, x_lo, x_hi, y_lo, y_hi, need):
    """Whether every pixel whose footprint meets [x_lo, x_hi] x [y_lo, y_hi], grown by the erosion's pad, lies in
    the image and saw at least ``need`` metres (not when any of them is NaN). eroded: (>= height, >= width) float32,
    metres, one secondary's eroded free image (``grid``'s eroded[j]); width, height: int, pixels, its image size;
    x_lo, x_hi, y_lo, y_hi: float64, pixels; need: float64, metres."""
    q_lo = np.ceil(x_lo - 0.5)
    q_hi = np.floor(x_hi + 0.5)
    r_lo = np.ceil(y_lo - 0.5)
    r_hi = np.floor(y_hi + 0.5)
    if not (q_lo >= 0.0 and r_lo >= 0.0 and q_lo <= q_hi <= width - 1 and r_lo <= r_hi <= height - 1
            and need == need):
        return False
    for r in range(int(r_lo), int(r_hi) + 1):
        for q in range(int(q_lo), int(q_hi) + 1):
            if eroded[r, q] < need:
                return False
    return True


#: Layout of a capsule set's parameters (``zone_params``, ``shell_params``): the thickness it is grown by (metres),
#: the noise margin's coefficients m0, m1, m2 added to it at each cell's near depth (0, 0, 0 for the robot zone) and
#: the principal's intrinsics fx, fy, cx, cy.
CAPSULE_THICKNESS, CAPSULE_MARGIN, CAPSULE_INTRINSICS, CAPSULE_PARAMS = 0, 1, 4, 8


@kernel(inline=True)
def _to_axis(x, y, z, zone, c):
    """Metres from the point (x, y, z) (float64, metres, the principal's optical frame) to the axis segment of the
    zone's capsule c (``zone`` rows: p0 (3), p1 (3), radius)."""
    ax = zone[c, 3] - zone[c, 0]
    ay = zone[c, 4] - zone[c, 1]
    az = zone[c, 5] - zone[c, 2]
    px = x - zone[c, 0]
    py = y - zone[c, 1]
    pz = z - zone[c, 2]
    length2 = ax * ax + ay * ay + az * az
    t = 0.0 if length2 <= 0.0 else min(max((px * ax + py * ay + pz * az) / length2, 0.0), 1.0)
    dx = px - t * ax
    dy = py - t * ay
    dz = pz - t * az
    return np.sqrt(dx * dx + dy * dy + dz * dz)


@kernel(inline=True)
def capsule_cells(u, v, k_a, k_b, d_min, delta_d, zone, params, z_lo, z_hi, settled):
    """Bit i set when cell k_a + i of principal pixel (u, v) meets the depths (z_lo, z_hi) (float64, metres) and lies
    wholly within one of the capsules ``zone`` ((n, 7) float64 rows: p0 (3), p1 (3) in the principal's optical frame,
    metres, and the radius) grown by params' thickness plus the noise margin at the cell's near depth (``params``:
    (CAPSULE_PARAMS,) float64, laid out as the CAPSULE_* constants say). The test is conservative: the cell's
    bounding sphere (centre on the pixel's central ray at mid-depth, radius reaching its corners) must fit in the
    grown capsule. Cells whose bit is set in ``settled`` (uint64: free by another test) are not tested; their bits
    are 0."""
    if zone.shape[0] == 0 or d_min + (k_b + 1) * delta_d <= z_lo or d_min + k_a * delta_d >= z_hi:
        return np.uint64(0)
    grow = params[CAPSULE_THICKNESS]
    m0 = params[CAPSULE_MARGIN]
    m1 = params[CAPSULE_MARGIN + 1]
    m2 = params[CAPSULE_MARGIN + 2]
    fx = params[CAPSULE_INTRINSICS]
    fy = params[CAPSULE_INTRINSICS + 1]
    tx = (u - params[CAPSULE_INTRINSICS + 2]) / fx
    ty = (v - params[CAPSULE_INTRINSICS + 3]) / fy
    # The capsules that can hold a cell of the run at all (bit c; all of them beyond 64): every cell's centre lies
    # within half the run's length of the run's middle on the ray, so a capsule whose axis is farther than that plus
    # its most grown radius from the middle holds none of them (the cells' own radii only make it less likely).
    near = _ALL
    if zone.shape[0] <= 64:
        near = np.uint64(0)
        z_first = d_min + (k_a + 0.5) * delta_d
        z_last = d_min + (k_b + 0.5) * delta_d
        zm = 0.5 * (z_first + z_last)
        half = 0.5 * (z_last - z_first) * np.sqrt(1.0 + tx * tx + ty * ty)
        grow_most = grow + max(noise_margin(d_min + k_a * delta_d, m0, m1, m2),
                               noise_margin(d_min + k_b * delta_d, m0, m1, m2))
        for c in range(zone.shape[0]):
            if _to_axis(tx * zm, ty * zm, zm, zone, c) - half <= zone[c, 6] + grow_most:
                near |= np.uint64(1) << np.uint64(c)
        if near == np.uint64(0):
            return np.uint64(0)
    bits = np.uint64(0)
    for i in range(k_b - k_a + 1):
        z0 = d_min + (k_a + i) * delta_d
        z1 = z0 + delta_d
        if z1 <= z_lo or z0 >= z_hi or (settled & (np.uint64(1) << np.uint64(i))) != np.uint64(0):
            continue
        zc = 0.5 * (z0 + z1)
        cx = tx * zc
        cy = ty * zc
        # Each corner lies within half a pixel's footprint at z1 of the central ray, plus the ray's slope over half a
        # cell, in x and in y, and within half a cell in depth.
        hx = 0.5 * z1 / fx + abs(tx) * 0.5 * delta_d
        hy = 0.5 * z1 / fy + abs(ty) * 0.5 * delta_d
        radius = np.sqrt(hx * hx + hy * hy + 0.25 * delta_d * delta_d)
        grown = grow + noise_margin(z0, m0, m1, m2)
        for c in range(zone.shape[0]):
            if c < 64 and (near & (np.uint64(1) << np.uint64(c))) == np.uint64(0):
                continue
            if _to_axis(cx, cy, zc, zone, c) + radius <= zone[c, 6] + grown:
                bits |= np.uint64(1) << np.uint64(i)
                break
    return bits


@kernel(inline=True)
def zoned_cells(u, v, k_a, k_b, grid, settled):
    """Bit i set when cell k_a + i of principal pixel (u, v), not set in ``settled`` (uint64), lies wholly in the
    robot zone: within the zone's thickness of one of the robot's padded capsules (``grid``'s zone and zone_params,
    :func:`capsule_cells`). It is
    the self-filter's rule (a measurement up to its tolerance in front of the robot is the robot; the principal takes
    as much behind a link for the robot, ``principal_arrays``), made the same in every direction: the space right
    beside a link lies within every camera's noise margin of the link it sees, and no camera can clear it."""
    return capsule_cells(u, v, k_a, k_b, grid.d_min, grid.delta_d, grid.zone, grid.zone_params, -np.inf, np.inf,
                         settled)


@kernel(inline=True)
def shell_cells(u, v, k_a, k_b, grid, settled):
    """Bit i set when cell k_a + i of principal pixel (u, v), not set in ``settled`` (uint64), lies between the
    links its ray meets (within
    ``grid``'s shell_lo[v, u], shell_hi[v, u]) and wholly within the self-filter's shell of a link: its capsule
    (``grid``'s shell, the rendered geometry's reach beyond the padded capsules included) grown by the self-filter's
    tolerance plus the principal's noise margin at the cell's depth (shell_params), as the principal takes that much
    behind a link for the robot (:func:`principal_arrays`). The space between two links is checked cell by cell; only
    this shell round the second link, a concession stated and flagged with ``robot_shell``, is not."""
    return capsule_cells(u, v, k_a, k_b, grid.d_min, grid.delta_d, grid.shell, grid.shell_params,
                         np.float64(grid.shell_lo[v, u]), np.float64(grid.shell_hi[v, u]), settled)


_ALL = np.uint64(0xFFFFFFFFFFFFFFFF)
CLASSIFY_RUN = 8  # cells classified together: neighbours share a face, projected once


@kernel(refcounts=False)
def classify_run(u, v, k_a, k_b, grid):
    """Classify cells k_a..k_b (at most 64) of principal pixel (u, v) into cells[v, u, k]: 3 when the free-space
    memory certifies every voxel the cell touches (:func:`remembered_cells`: the voxels some camera saw wholly free
    this set among them), else 1 when the cell lies in the robot zone (:func:`zoned_cells`) or in the shell of a
    link behind the first (:func:`shell_cells`), else 1 when some secondary camera saw through the whole cell, else
    2 (occupied, or hidden from every camera). Each face between two cells is projected once per camera.

    The memory is asked first because its answer is a lookup in voxels the set has computed already (issue 38's
    one look at what the cameras see free): a cell it certifies needs neither the robot's capsules (a distance to
    each, per cell) nor any camera's footprint. Which cells are free (1 or 3) and which occupied (2) is the same in
    any order; only which of 1 and 3 a free cell gets can differ, and no answer reads that (every reader asks for 0,
    for 2 or for the low bit; the flags ``remembered``, ``robot_zone`` and ``robot_shell`` come from the voxels and
    the capsules, not from the cells).

    A camera is first asked about the whole run at once: the run's footprint lies within the box of its two end
    faces' corners and its largest depth at one of them (depth is linear along each corner ray), so if the camera
    saw beyond that over that box, it saw through every cell, and the per-cell tests would all agree. Behind the
    robot, where a secondary camera sees the room far beyond, that settles a run with one test."""
    d_min, delta_d, corners, offsets = grid.d_min, grid.delta_d, grid.corners, grid.offsets
    eroded, sizes, z_near, margin, cells = grid.eroded, grid.sizes, grid.z_near, grid.margin, grid.cells
    n = k_b - k_a + 1
    everything = _ALL if n == 64 else (np.uint64(1) << np.uint64(n)) - np.uint64(1)
    remembered = remembered_cells(u, v, k_a, k_b, grid)
    cleared = remembered
    if cleared != everything:
        cleared |= zoned_cells(u, v, k_a, k_b, grid, cleared)
    if cleared != everything:
        cleared |= shell_cells(u, v, k_a, k_b, grid, cleared)
    # settled; the cameras are asked about the rest
    for j in range(corners.shape[0]):
        if cleared == everything:
            break
        width = sizes[j, 0]
        height = sizes[j, 1]
        ok0, x_lo0, x_hi0, y_lo0, y_hi0, far0 = face_box(corners[j], offsets[j], u, v, d_min + k_a * delta_d,
                                                         z_near[j])
        if n > 1:
            ok1, x_lo1, x_hi1, y_lo1, y_hi1, far1 = face_box(corners[j], offsets[j], u, v,
                                                             d_min + (k_b + 1) * delta_d, z_near[j])
            if ok0 and ok1 and box_seen_through(eroded[j], width, height, min(x_lo0, x_lo1), max(x_hi0, x_hi1),
                                                min(y_lo0, y_lo1), max(y_hi0, y_hi1), max(far0, far1) + margin):
                cleared = everything
                break
        for i in range(k_b - k_a + 1):
            k = k_a + i
            ok1, x_lo1, x_hi1, y_lo1, y_hi1, far1 = face_box(corners[j], offsets[j], u, v, d_min + (k + 1) * delta_d,
                                                             z_near[j])
            bit = np.uint64(1) << np.uint64(i)
            if ok0 and ok1 and (cleared & bit) == np.uint64(0):
                if box_seen_through(eroded[j], width, height, min(x_lo0, x_lo1), max(x_hi0, x_hi1), min(y_lo0, y_lo1),
                                    max(y_hi0, y_hi1), max(far0, far1) + margin):
                    cleared |= bit
            ok0, x_lo0, x_hi0, y_lo0, y_hi0, far0 = ok1, x_lo1, x_hi1, y_lo1, y_hi1, far1
    grid.touched[v, u] = 1
    for i in range(k_b - k_a + 1):
        bit = np.uint64(1) << np.uint64(i)
        cells[v, u, k_a + i] = 3 if (remembered & bit) != np.uint64(0) else (
            1 if (cleared & bit) != np.uint64(0) else 2)


@kernel(parallel=True)
def clear_touched(cells, runs, touched):
    """cells[v, u, :] = 0, runs[:, v, u] = NO_FREE_RUN and touched[v, u] = 0 wherever touched[v, u] is not 0: a
    set's cell classes and free runs cleared for the next set in time proportional to the pixels it wrote. cells:
    (H, W, n_cells) uint8; runs: (2, H, W) int64, free_run and behind_run; touched: (H, W) uint8, ``grid``'s."""
    for v in prange(touched.shape[0]):
        for u in range(touched.shape[1]):
            if touched[v, u] != 0:
                cells[v, u, :] = 0
                runs[0, v, u] = NO_FREE_RUN
                runs[1, v, u] = NO_FREE_RUN
                touched[v, u] = 0


#: Layout of the free-space memory's geometry, ``memory[1]`` (float64): the voxel box's low corner (world, metres),
#: 1 / voxel side, the principal's rotation and translation (optical frame -> world, row-major), 1/fx, 1/fy, cx, cy.
MEM_LO, MEM_INV_VOXEL, MEM_R, MEM_T, MEM_INTRINSICS, MEM_GEOMETRY_SIZE = 0, 3, 4, 13, 16, 20


@kernel(inline=True)
def _footprint_slopes(u, v, geo):
    """(lo0, hi0, lo1, hi1, lo2, hi2): per world axis, the smallest and largest component of principal pixel (u,
    v)'s 4 frustum edge rays in the world frame, each scaled to optical depth 1 (no unit). A footprint corner at
    optical depth z lies at t + z r (t the principal's position), linear in z > 0, so the footprint at depth z spans
    t_a + z lo_a to t_a + z hi_a along world axis a. geo: (MEM_GEOMETRY_SIZE,) float64, ``grid``'s mem_geometry
    (laid out as the MEM_* constants say)."""
    lo0 = np.inf
    lo1 = np.inf
    lo2 = np.inf
    hi0 = -np.inf
    hi1 = -np.inf
    hi2 = -np.inf
    for dv in range(2):
        for du in range(2):
            x = (u - 0.5 + du - geo[MEM_INTRINSICS + 2]) * geo[MEM_INTRINSICS]
            y = (v - 0.5 + dv - geo[MEM_INTRINSICS + 3]) * geo[MEM_INTRINSICS + 1]
            w0 = geo[MEM_R] * x + geo[MEM_R + 1] * y + geo[MEM_R + 2]
            w1 = geo[MEM_R + 3] * x + geo[MEM_R + 4] * y + geo[MEM_R + 5]
            w2 = geo[MEM_R + 6] * x + geo[MEM_R + 7] * y + geo[MEM_R + 8]
            lo0 = min(lo0, w0)
            lo1 = min(lo1, w1)
            lo2 = min(lo2, w2)
            hi0 = max(hi0, w0)
            hi1 = max(hi1, w1)
            hi2 = max(hi2, w2)
    return lo0, hi0, lo1, hi1, lo2, hi2


@kernel(inline=True)
def _voxel_span(t, lo, hi, z0, z1, origin, inv):
    """(first, last) voxel index (float64, floored) along one world axis that the part of a pixel's frustum between
    optical depths z0 < z1 (float64, metres) can touch: its extent t + z [lo, hi] over z in [z0, z1] (t metres, lo
    and hi the axis's slopes from :func:`_footprint_slopes`), grown by 1e-9 m against rounding, in voxels from
    ``origin`` (metres) of 1 / ``inv`` metres."""
    a = t + (z0 if lo >= 0.0 else z1) * lo
    b = t + (z1 if hi >= 0.0 else z0) * hi
    return np.floor((a - 1e-9 - origin) * inv), np.floor((b + 1e-9 - origin) * inv)


@kernel(inline=True)
def _all_free(free, i0, i1, j0, j1, h0, h1):
    """Whether free[i, j, h] != 0 for every voxel of i0..i1 x j0..j1 x h0..h1 (int, inside ``free``, (nx, ny, nz)
    uint8)."""
    for a in range(i0, i1 + 1):
        for b in range(j0, j1 + 1):
            for c in range(h0, h1 + 1):
                if free[a, b, c] == 0:
                    return False
    return True


@kernel(refcounts=False)
def remembered_cells(u, v, k_a, k_b, grid):
    """Bit i set when cell k_a + i (k_a..k_b, at most 64) of principal pixel (u, v) lies wholly in voxels that the
    free-space memory certifies free (design §8a): the grid's mem_free, (nx, ny, nz) uint8, 1 for a voxel no person
    can have reached yet, of zero size for no memory, and its mem_geometry (MEM_GEOMETRY_SIZE,) float64 as
    MEM_LO.. describe. A cell lies within the box of its 8 corners (it is convex), whose voxels are checked (not when
    the box leaves the voxels' box or holds NaN); a cell whose box touches the same voxels as the cell before it
    takes that cell's answer without reading them again.

    The whole run is asked first: the voxels its part of the frustum touches (from the first cell's near depth to
    the last one's far depth) hold every voxel any of its cells touches (the spans are monotone in depth, in floating
    point too), so when all of them are free every cell is, and the cells' own spans would say the same. Most runs
    the first query classifies lie in certified space (on bench_frame_budget's cell 147,000 of 188,000 cells): one
    read of a few voxels settles the run."""
    free, geo, d_min, delta_d = grid.mem_free, grid.mem_geometry, grid.d_min, grid.delta_d
    if free.size == 0:
        return np.uint64(0)
    nx, ny, nz = free.shape
    inv = geo[MEM_INV_VOXEL]
    s0, e0, s1, e1, s2, e2 = _footprint_slopes(u, v, geo)
    z0 = d_min + k_a * delta_d
    z1 = d_min + (k_b + 1) * delta_d
    i0, i1 = _voxel_span(geo[MEM_T], s0, e0, z0, z1, geo[MEM_LO], inv)
    j0, j1 = _voxel_span(geo[MEM_T + 1], s1, e1, z0, z1, geo[MEM_LO + 1], inv)
    h0, h1 = _voxel_span(geo[MEM_T + 2], s2, e2, z0, z1, geo[MEM_LO + 2], inv)
    if 0.0 <= i0 and i1 < nx and 0.0 <= j0 and j1 < ny and 0.0 <= h0 and h1 < nz and \
            _all_free(free, int(i0), int(i1), int(j0), int(j1), int(h0), int(h1)):
        n = k_b - k_a + 1
        return _ALL if n == 64 else (np.uint64(1) << np.uint64(n)) - np.uint64(1)
    out = np.uint64(0)
    last = (-1.0, -1.0, -1.0, -1.0, -1.0, -1.0)
    last_free = False
    for i in range(k_b - k_a + 1):
        z0 = d_min + (k_a + i) * delta_d
        z1 = d_min + (k_a + i + 1) * delta_d
        i0, i1 = _voxel_span(geo[MEM_T], s0, e0, z0, z1, geo[MEM_LO], inv)
        j0, j1 = _voxel_span(geo[MEM_T + 1], s1, e1, z0, z1, geo[MEM_LO + 1], inv)
        h0, h1 = _voxel_span(geo[MEM_T + 2], s2, e2, z0, z1, geo[MEM_LO + 2], inv)
        if not (0.0 <= i0 and i1 < nx and 0.0 <= j0 and j1 < ny and 0.0 <= h0 and h1 < nz):
            last_free = False
            last = (-1.0, -1.0, -1.0, -1.0, -1.0, -1.0)
            continue
        span = (i0, i1, j0, j1, h0, h1)
        if span != last:
            last = span
            last_free = _all_free(free, int(i0), int(i1), int(j0), int(j1), int(h0), int(h1))
        if last_free:
            out |= np.uint64(1) << np.uint64(i)
    return out


@kernel(inline=True)
def _next_not_free(cells, v, u, k, k_end, step):
    """The first cell from k towards k_end (inclusive, by step +-1) not known to be free, or k_end + step. cells:
    (H, W, n_cells) uint8, ``grid``'s cell classes, read at pixel (u, v); k, k_end, step: int."""
    while k != k_end + step and (cells[v, u, k] & 1) != 0:  # 1: seen free now or the robot's, 3: the memory's
        k += step
    return k


@kernel(refcounts=False)
def occupied_in(u, v, k_lo, k_hi, highest, grid):
    """The highest (with ``highest``, a numpy bool) or lowest occupied cell in k_lo..k_hi (int) of principal pixel
    (u, v), -1 for none.

    cells[v, u, k] caches each cell's class for the frame: 0 unknown, 1 free (the robot's, or seen through by a
    camera), 2 occupied, 3 free (the free-space memory certifies it: seen free this set, or no person can be there
    yet). A cell met unknown is
    classified with the next few in the walk's direction (:func:`classify_run`). Threads that query different
    control points may classify the same cell at once; each writes the same byte, a function of this frame's images
    alone, so whichever write lands, the cache holds the right class.
    """
    cells = grid.cells
    if k_lo > k_hi:
        return -1
    step = -1 if highest else 1
    k_end = k_lo if highest else k_hi
    k = k_hi if highest else k_lo
    while True:
        k = _next_not_free(cells, v, u, k, k_end, step)
        if k == k_end + step:
            return -1
        if cells[v, u, k] == 0:
            if highest:
                classify_run(u, v, max(k - CLASSIFY_RUN + 1, k_end), k, grid)
            else:
                classify_run(u, v, k, min(k + CLASSIFY_RUN - 1, k_end), grid)
        if cells[v, u, k] == 2:
            return k
        k += step


NO_FREE_RUN = 1 << 32  # free_run's value for "no run known": the empty range 1..0


@kernel(inline=True)
def remember_free_run(free_run, v, u, k_lo, k_hi):
    """Record that cells k_lo..k_hi (int) of pixel (u, v) are all free: free_run[v, u] = (first << 32) | last of one run
    of cells known free, grown by this one where they touch, else replaced by the longer. free_run: (H, W) int64, the
    run array to write (``grid``'s free_run or behind_run). One 8-byte store, so a thread never reads half of another's
    run; every run stored is free, whichever store lands."""
    if k_lo > k_hi:
        return
    run = free_run[v, u]
    run_lo = run >> 32
    run_hi = run & 0xFFFFFFFF
    if run_lo <= k_hi + 1 and k_lo <= run_hi + 1:
        k_lo = min(k_lo, run_lo)
        k_hi = max(k_hi, run_hi)
    elif run_hi - run_lo > k_hi - k_lo:
        return
    free_run[v, u] = (np.int64(k_lo) << 32) | np.int64(k_hi)


@kernel(inline=True)
def known_free(lo, hi, u, v, d_min, delta_d, n_cells, runs):
    """Whether every cell of the candidate range [lo, hi] (inside the grid) of pixel (u, v) is known free: inside
    the run ``runs`` holds for it."""
    if not (d_min <= lo <= hi <= d_min + n_cells * delta_d):
        return False
    run = runs[v, u]
    return (run >> 32) <= cell_index(lo, d_min, delta_d, n_cells) and \
        min(cell_index(hi, d_min, delta_d, n_cells), n_cells - 1) <= (run & 0xFFFFFFFF)


@kernel(inline=True)
def cell_index(z, d_min, delta_d, n_cells):
    """int((z - d_min) / delta_d), the grid cell holding depth z (float64, metres), with the quotient clamped to
    [-1, n_cells] first: a depth far beyond the grid (or NaN) gives an end, never an index int() made garbage of.

    The helpers called per pixel (this one, :func:`known_free`, :func:`surface_cell_end`, :func:`nearest_by_run`,
    :func:`distance_by_runs`) take the grid's numbers and arrays apart, not the :data:`GridState`: a record that
    holds arrays, handed to an inlined function, costs a reference count per array per call, and per pixel that
    made later fused queries 1.7 times as slow (1.3 -> 2.2 ms, ``benchmarks/bench_depth_grid.py``)."""
    return clamped_index((z - d_min) / delta_d, -1, n_cells)


@kernel(inline=True)
def _walk_out(u, v, k_lo, k_hi, k_star, in_run, run_lo, run_hi, grid, runs):
    """:func:`nearest_confirmed`'s walk down and up from cell k_star (or from the ends of the known free run holding
    it) to the first occupied cell each way within k_lo..k_hi. Returns (k_left, k_right), -1 for none, or (-2, -2)
    when k_star's own cell is occupied. Records the free run found between them in ``runs``. k_lo, k_hi, k_star:
    int, cells; in_run: bool, whether k_star lies in the pixel's known free run run_lo..run_hi (int64, read from
    ``runs`` before)."""
    # np.bool_, not a literal True or False, for which numba would compile occupied_in twice.
    if not in_run and occupied_in(u, v, k_star, k_star, np.bool_(False), grid) >= 0:
        return -2, -2
    down_from = run_lo - 1 if in_run else k_star - 1
    up_from = run_hi + 1 if in_run else k_star + 1
    k_left = occupied_in(u, v, k_lo, down_from, np.bool_(True), grid)
    k_right = occupied_in(u, v, up_from, k_hi, np.bool_(False), grid)
    # Everything between the two is free now.
    free_lo = k_left + 1 if k_left >= 0 else (min(k_lo, run_lo) if in_run else k_lo)
    free_hi = k_right - 1 if k_right >= 0 else (max(k_hi, run_hi) if in_run else k_hi)
    grid.touched[v, u] = 1
    remember_free_run(runs, v, u, free_lo, free_hi)
    return k_left, k_right


@kernel(refcounts=False)
def nearest_confirmed(X, Y, Z, rho, a0, a1, b0, b1, lo, certain_to, hi, bound2, u, v, grid, runs):
    """The nearest occupied part of [lo, hi] along principal pixel (u, v)'s frustum, nearer than ``bound2``: the
    part [lo, certain_to] is occupied as it stands (a measured surface's own cell; certain_to <= lo for none), and so
    are the parts outside the grid [d_min, d_max], which no camera can check; the rest is candidate cells.

    The distance from P along one convex frustum is unimodal in depth, so the nearest occupied part is the one
    holding the nearest point z* of [lo, hi] if that part is occupied, else the first occupied part met walking
    down from z*, or the first walking up.

    A range of candidate cells alone (no certain part) is walked whole, and the run of cells found free is kept in
    ``runs`` (the grid's free_run for a gray area, behind_run for the space behind the robot), so that the next
    control point whose range that run covers skips the pixel at once: the space behind the robot, which every point
    on the robot looks at, is mostly such a range. Elsewhere only cells close enough to z* to come nearer than bound2
    are looked at. Returns (squared distance, z*), (inf, 0) if nothing occupied comes nearer than bound2.

    P = (X, Y, Z); certain_to: float64, metres; the segment [lo, hi] and the frustum a0..b1 are pixel (u, v)'s. rho
    is not used.
    """
    d_min, delta_d, n_cells = grid.d_min, grid.delta_d, grid.n_cells
    if lo > hi:
        return np.inf, 0.0
    d_max = d_min + n_cells * delta_d
    # Occupied as they stand: [lo, below] when below > lo, and [above, hi] (beyond the grid) when hi > above.
    below = max(certain_to, min(d_min, hi)) if lo < d_min else certain_to
    above = max(d_max, below)
    candidates_only = below <= lo and hi <= above
    if candidates_only:
        if known_free(lo, hi, u, v, d_min, delta_d, n_cells, runs):
            return np.inf, 0.0
        k_lo = cell_index(lo, d_min, delta_d, n_cells)
        k_hi = min(cell_index(hi, d_min, delta_d, n_cells), n_cells - 1)
    run = runs[v, u]
    run_lo = run >> 32
    run_hi = run & 0xFFFFFFFF
    d2, z = frustum_nearest(X, Y, Z, a0, a1, b0, b1, lo, hi)
    if d2 >= bound2:
        return np.inf, 0.0
    if (below > lo and z <= below) or (hi > above and z >= above):
        return d2, z
    if not candidates_only:
        # g(z), the squared distance from P to the frustum's slice at depth z, is convex with g'' >= 2, so
        # g(z) >= d2 + (z - z*)^2 and only cells within reach of z* can come nearer than bound2.
        reach = np.sqrt(bound2 - d2)
        k_lo = max(cell_index(max(below, lo), d_min, delta_d, n_cells),
                   cell_index(max(z - reach, d_min), d_min, delta_d, n_cells))
        k_hi = min(cell_index(min(hi, d_max, z + reach), d_min, delta_d, n_cells), n_cells - 1)
    k_lo = max(k_lo, 0)
    k_star = min(max(cell_index(z, d_min, delta_d, n_cells), k_lo), k_hi)
    # Skip the run of cells already known free around z*, if there is one; else start at z*'s own cell. (No cell
    # in reach, k_lo > k_hi, happens only with numbers the public functions refuse.)
    in_run = run_lo <= k_star <= run_hi
    if (run_lo <= k_lo and k_hi <= run_hi) or k_lo > k_hi:
        k_left = -1
        k_right = -1
    else:
        k_left, k_right = _walk_out(u, v, k_lo, k_hi, k_star, in_run, run_lo, run_hi, grid, runs)
        if k_left == -2:  # z*'s own cell is occupied
            return d2, z
    # Down: the occupied cell found, else the part occupied as it stands below; up alike.
    best2, best_z = np.inf, 0.0
    if k_left >= 0:
        best2, best_z = frustum_nearest(X, Y, Z, a0, a1, b0, b1, max(below, lo, d_min + k_left * delta_d),
                                        min(hi, d_min + (k_left + 1) * delta_d))
    elif below > lo:
        best2, best_z = frustum_nearest(X, Y, Z, a0, a1, b0, b1, lo, below)
    d2, z = np.inf, 0.0
    if k_right >= 0:
        d2, z = frustum_nearest(X, Y, Z, a0, a1, b0, b1, max(below, lo, d_min + k_right * delta_d),
                                min(hi, d_min + (k_right + 1) * delta_d))
    elif hi > above:
        d2, z = frustum_nearest(X, Y, Z, a0, a1, b0, b1, above, hi)
    if d2 < best2:
        best2, best_z = d2, z
    if best2 >= bound2:
        return np.inf, 0.0
    return best2, best_z


@kernel(inline=True)
def _slice_distance2(X, Y, Z, a0, a1, b0, b1, z):
    """g(z): the squared distance (square metres) from P = (X, Y, Z) to the slice of pixel frustum [a0, a1] x
    [b0, b1] at depth z (float64, metres)."""
    dx = max(a0 * z - X, 0.0, X - a1 * z)
    dy = max(b0 * z - Y, 0.0, Y - b1 * z)
    return dx * dx + dy * dy + (Z - z) * (Z - z)


@kernel(inline=True)
def nearest_by_run(X, Y, Z, a0, a1, b0, b1, d2, z, lo, certain_to, hi, bound2, u, v, d_min, delta_d, n_cells, cells,
                   runs):
    """:func:`nearest_confirmed` on [lo, hi] (certain part [lo, certain_to]) when the pixel's known free run in
    ``runs`` holds the cell of the segment's nearest point z (d2 = g(z) < bound2): the first occupied part each way
    is then the cell just past each end of the run, or the part occupied as it stands past the cells in reach. g is
    convex with its minimum at z, so each such part's nearest point is its end towards z: one evaluation of g each.
    A z outside the run whose own cell is known occupied is the answer itself. Returns (squared distance, depth,
    True), (inf, 0, True) for nothing nearer than bound2, or (.., False) when the run does not decide it (a cell past
    its end not yet classified, or z outside it in a cell not known occupied): the caller asks the grid.

    P = (X, Y, Z); pixel (u, v) with frustum a0..b1; d2: float64, square metres; z, certain_to: float64, metres.
    The grid's numbers and cells come apart (:data:`GridState`'s d_min, delta_d, n_cells, cells), as for every helper
    called per pixel (see :func:`cell_index`)."""
    d_max = d_min + n_cells * delta_d
    below = max(certain_to, min(d_min, hi)) if lo < d_min else certain_to
    above = max(d_max, below)
    if (below > lo and z <= below) or (hi > above and z >= above):
        return d2, z, True
    reach = np.sqrt(bound2 - d2)
    k_lo = max(cell_index(max(below, lo), d_min, delta_d, n_cells),
               cell_index(max(z - reach, d_min), d_min, delta_d, n_cells), 0)
    k_hi = min(cell_index(min(hi, d_max, z + reach), d_min, delta_d, n_cells), n_cells - 1)
    if k_lo > k_hi:
        return d2, z, False
    k_star = min(max(cell_index(z, d_min, delta_d, n_cells), k_lo), k_hi)
    run = runs[v, u]
    run_lo = run >> 32
    run_hi = run & 0xFFFFFFFF
    if not (run_lo <= k_star <= run_hi):
        return d2, z, cells[v, u, k_star] == 2  # z's own cell occupied: the answer, as nearest_confirmed finds it
    best2, best_z = np.inf, 0.0
    if run_lo - 1 >= k_lo:
        if cells[v, u, run_lo - 1] != 2:
            return d2, z, False
        best_z = min(hi, d_min + run_lo * delta_d)
        best2 = _slice_distance2(X, Y, Z, a0, a1, b0, b1, best_z)
    elif below > lo:
        best_z = below
        best2 = _slice_distance2(X, Y, Z, a0, a1, b0, b1, below)
    if run_hi + 1 <= k_hi:
        if cells[v, u, run_hi + 1] != 2:
            return d2, z, False
        z_up = max(below, lo, d_min + (run_hi + 1) * delta_d)
        d2_up = _slice_distance2(X, Y, Z, a0, a1, b0, b1, z_up)
        if d2_up < best2:
            best2, best_z = d2_up, z_up
    elif hi > above:
        d2_up = _slice_distance2(X, Y, Z, a0, a1, b0, b1, above)
        if d2_up < best2:
            best2, best_z = d2_up, above
    if best2 >= bound2:
        return np.inf, 0.0, True
    return best2, best_z, True


@kernel(inline=True)
def distance_by_runs(X, Y, Z, a0, a1, b0, b1, d2, z, one_piece, zs, ze, certain, bf, z_far, bound2, u, v, d_min,
                     delta_d, n_cells, cells, free_run, behind_run):
    """:func:`pixel_distance` from the pixel's known free runs alone (:func:`nearest_by_run` on each of its
    candidate segments: the surface's gray area, or the frustum of a pixel without a measurement, with free_run; the
    space behind the robot with behind_run), when they decide it. (d2, z): the nearest point of the span fused_rows
    gathered, which is the segment itself for a ``one_piece`` pixel (a surface and its gray area) and for one whose
    only segment is behind the robot. Returns (squared distance, depth, from a pixel without a measurement?,
    decided?); (inf, 0, False, True) for nothing nearer than bound2. A surface at or behind P (case ii) is left to
    pixel_distance.

    P = (X, Y, Z); pixel (u, v) with frustum a0..b1; d2 (square metres), z (metres): float64; one_piece: bool; zs,
    ze: float64, metres, the principal's possibly-occupied segment; certain: it starts at a measured surface (uint8
    0 or 1); bf: float64, metres, where the space behind the robot starts (inf: none); z_far: float64, metres,
    Z + rho. The grid's numbers, cells and runs come apart (:data:`GridState`'s fields), as for every helper called
    per pixel (see :func:`cell_index`)."""
    best2, best_z, from_invalid = np.inf, 0.0, False
    if zs <= z_far:
        if certain and zs >= Z:
            return d2, z, False, False
        hi = min(ze, z_far)
        if zs <= hi:
            if not one_piece:
                d2, z = frustum_nearest(X, Y, Z, a0, a1, b0, b1, zs, hi)
            if d2 < bound2:
                certain_to = surface_cell_end(zs, d_min, delta_d) if certain else zs
                best2, best_z, decided = nearest_by_run(X, Y, Z, a0, a1, b0, b1, d2, z, zs, certain_to, hi, bound2, u,
                                                        v, d_min, delta_d, n_cells, cells, free_run)
                if not decided:
                    return best2, best_z, False, False
                from_invalid = not certain and best2 < np.inf
    if bf <= z_far:
        if zs <= z_far:
            d2, z = frustum_nearest(X, Y, Z, a0, a1, b0, b1, bf, z_far)
        bound_behind = min(best2, bound2)  # as pixel_distance asks it: only to beat the gray area's answer
        if d2 < bound_behind:
            d2, z, decided = nearest_by_run(X, Y, Z, a0, a1, b0, b1, d2, z, bf, bf, z_far, bound_behind, u, v, d_min,
                                            delta_d, n_cells, cells, behind_run)
            if not decided:
                return d2, z, False, False
            if d2 < best2:
                best2, best_z, from_invalid = d2, z, False
    if best2 >= bound2:
        return np.inf, 0.0, False, True
    return best2, best_z, from_invalid, True


@kernel(inline=True)
def pixel_distance(X, Y, Z, rho, u, v, a0, a1, b0, b1, zs, ze, certain, blind_from, bound2, grid):
    """Squared distance from P to what is occupied along principal pixel (u, v) after fusion, its depth z*, and
    whether that came from a candidate of a pixel without a measurement. (inf, 0, False) if nothing nearer than
    ``bound2``.

    P = (X, Y, Z), frustum a0..b1. zs, ze: float64, metres, the principal's possibly-occupied segment; ``certain``
    (uint8 0 or 1): it starts at a measured surface; blind_from: float64, metres, where the space behind the robot
    starts (after its body), inf for none. rho: for z_far = Z + rho.
    """
    free_run, behind_run = grid.free_run, grid.behind_run
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
                best2, best_z = nearest_confirmed(X, Y, Z, rho, a0, a1, b0, b1, zs,
                                                  surface_cell_end(zs, grid.d_min, grid.delta_d),
                                                  min(ze, z_far), bound2, u, v, grid, free_run)
        else:  # no measurement: the whole segment is a candidate
            best2, best_z = nearest_confirmed(X, Y, Z, rho, a0, a1, b0, b1, zs, zs, min(ze, z_far), bound2, u, v,
                                              grid, free_run)
            from_invalid = best2 < np.inf
    if blind_from <= z_far:  # case (iv): behind the robot
        d2, z = nearest_confirmed(X, Y, Z, rho, a0, a1, b0, b1, blind_from, blind_from, z_far, min(best2, bound2), u,
                                  v, grid, behind_run)
        if d2 < best2:
            best2, best_z = d2, z
            from_invalid = False
    if best2 >= bound2:
        return np.inf, 0.0, False
    return best2, best_z, from_invalid


# The sums over one control point's contributing pixels (:func:`fused_rows`), in a float64 array of this length.
ACC_COUNT, ACC_INVALID, ACC_INSIDE, ACC_SUM_D, ACC_SX, ACC_SY, ACC_SZ, ACC_BEST2, ACC_BEST_U, ACC_BEST_V, ACC_BEST_Z, \
    ACC_BEST_INVALID = range(12)
N_ACC = 12


@kernel(refcounts=False)
def fused_rows(X, Y, Z, rho, v_first, v_last, v_step, spans, view, prune_min, grid, scratch, acc):
    """One control point P = (X, Y, Z) (metres, principal optical frame) against the rows v_first, v_first + v_step,
    ... <= v_last of its surveillance region (``spans``): what the principal camera says is possibly occupied and
    the secondary cameras do not clear. Writes into acc (N_ACC,) the count of contributing pixels, those from pixels
    without a measurement, whether P is inside, the sums of their distances and unit directions, and the nearest
    one (squared distance, pixel, depth, from a pixel without a measurement?). ``scratch`` (5, width) float64.

    rho: metres; v_first, v_last, v_step: int, rows; ``view``, ``grid``: the principal's frame and the grid; with
    ``prune_min`` (bool: the aggregate is ``min``) only pixels that can beat the nearest so far are followed and no
    sums are kept. acc: (N_ACC,) float64, written, laid out as the ACC_* constants say."""
    d_min, delta_d, n_cells, cells = grid.d_min, grid.delta_d, grid.n_cells, grid.cells
    free_run, behind_run = grid.free_run, grid.behind_run
    z_start, z_end, certain, blind_from = view.z_start, view.z_end, view.certain, view.blind_from
    fx, fy, cx, cy = view.fx, view.fy, view.cx, view.cy
    rho2 = rho_squared(rho)
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
    inv_fx = 1.0 / fx
    z_in = scratch[0]
    u_in = scratch[1]
    d2_row = scratch[2]
    z_row = scratch[3]
    z_hi_in = scratch[4]
    for v in range(v_first, v_last + 1, v_step):
        b0 = (v - 0.5 - cy) / fy
        b1 = (v + 0.5 - cy) / fy
        # Gather the row's pixels with something possibly occupied in reach, and the depth span that holds it.
        m = np.int64(0)  # not a literal 0, for which numba would compile guess_piece_row once more
        for u in range(spans[v, 0], spans[v, 1] + 1):
            zs = np.float64(z_start[v, u])
            bf = np.float64(blind_from[v, u])
            if min(zs, bf) > z_far:
                continue
            if zs > z_far and known_free(bf, z_far, u, v, d_min, delta_d, n_cells, behind_run):
                continue  # the space behind the robot, every cell in reach known free
            z_in[m] = min(zs, bf)
            z_hi_in[m] = min(np.float64(z_end[v, u]), z_far) if (certain[v, u] and bf > z_far) else z_far
            u_in[m] = u
            m += 1
        if m == 0:
            continue
        # The nearest point of that span, a lower bound of the pixel's distance (vectorised).
        guess_piece_row(X, Y, Z, b0, b1, z_in, z_hi_in, u_in, m, inv_fx, cx, d2_row, z_row)
        for i in range(m):
            u = int(u_in[i])
            a0 = (u - 0.5 - cx) * inv_fx
            a1 = (u + 0.5 - cx) * inv_fx
            d2 = d2_row[i]
            z = z_row[i]
            if d2 < 0.0:
                d2, z = frustum_nearest(X, Y, Z, a0, a1, b0, b1, z_in[i], z_hi_in[i])
            # With min, a pixel that only ties the best so far cannot win: pixels come in (v, u) order.
            bound2 = min(rho2, best2) if prune_min else rho2
            if d2 >= bound2:
                continue
            zs = np.float64(z_start[v, u])
            bf = np.float64(blind_from[v, u])
            from_invalid = False
            # The span's nearest point is the answer when it lies on something occupied for sure: a measured surface
            # behind P (case ii, no other camera asked), the surface's own cell, or a grid cell already known to be
            # occupied (a pixel with one piece of candidates only: a surface's gray area, or the space behind the
            # robot). Otherwise ask the grid.
            one_piece = certain[v, u] and bf > z_far  # a measured surface and its gray area, the span gathered
            answered = False
            if certain[v, u] and zs <= z_far:  # the surface's certain part: the frustum on (case ii), or its cell
                ze = np.float64(z_end[v, u])
                answered = z <= (ze if zs >= Z else min(surface_cell_end(zs, d_min, delta_d), ze))
            if not answered and (one_piece or zs > z_far) and d_min <= z < d_max:
                answered = cells[v, u, min(int((z - d_min) / delta_d), n_cells - 1)] == 2
            # Earlier queries' runs of free cells decide it, without a walk: the nearest occupied cell is the one
            # just past a run's end, or nothing is in reach.
            if not answered:
                d2, z, from_invalid, answered = distance_by_runs(
                    X, Y, Z, a0, a1, b0, b1, d2, z, one_piece, zs, np.float64(z_end[v, u]), certain[v, u], bf, z_far,
                    bound2, u, v, d_min, delta_d, n_cells, cells, free_run, behind_run)
            if not answered:
                d2, z, from_invalid = pixel_distance(X, Y, Z, rho, u, v, a0, a1, b0, b1, zs, np.float64(z_end[v, u]),
                                                     certain[v, u], bf, bound2, grid)
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
            here, d, ex, ey, ez = contribution(X, Y, Z, a0, a1, b0, b1, z, d2)
            inside = inside or here
            sum_d += d
            sx += ex
            sy += ey
            sz += ez
    acc[ACC_COUNT] = count
    acc[ACC_INVALID] = n_invalid
    acc[ACC_INSIDE] = 1.0 if inside else 0.0
    acc[ACC_SUM_D] = sum_d
    acc[ACC_SX] = sx
    acc[ACC_SY] = sy
    acc[ACC_SZ] = sz
    acc[ACC_BEST2] = best2
    acc[ACC_BEST_U] = best_u
    acc[ACC_BEST_V] = best_v
    acc[ACC_BEST_Z] = best_z
    acc[ACC_BEST_INVALID] = best_invalid


@kernel(refcounts=False)
def fused_region(X, Y, Z, rho, view, unseen_occupied, near_eps, inside_tol, spans, region, out_direction):
    """The first step of one control point P = (X, Y, Z)'s fused query: its surveillance region (``spans``, (height,
    2) int64, as :func:`surveillance_region` fills it) in the principal camera's ``view``, written into region (8,)
    float64: flags, P unseen?, unseen_d, nx, ny, nz, v_lo, v_hi (v_hi < v_lo: no rows to visit). Clears
    out_direction (3,)."""
    height, width = view.z_start.shape
    fx, fy, cx, cy, z_min, z_max = view.fx, view.fy, view.cx, view.cy, view.z_min, view.z_max
    f, unseen_here, unseen_d, nx, ny, nz, _, _, v_lo, v_hi = surveillance_region(
        X, Y, Z, rho, width, height, fx, fy, cx, cy, z_min, z_max, unseen_occupied, near_eps, inside_tol, spans,
        out_direction)
    region[0] = f
    region[1] = 1.0 if unseen_here else 0.0
    region[2] = unseen_d
    region[3] = nx
    region[4] = ny
    region[5] = nz
    region[6] = v_lo
    region[7] = v_hi if not unseen_here else v_lo - 1


@kernel()
def fused_finish(X, Y, Z, aggregate, region, acc, view, inside_tol, min_direction, out_direction):
    """The last step of one control point P = (X, Y, Z)'s fused query: the sums of its row tasks (acc, (row_chunks,
    N_ACC) float64), added in a fixed order, so that the answer does not depend on the threads' timing, and
    aggregated as ``aggregate``. region (8,) float64: from :func:`fused_region`. ``view``: for the intrinsics.
    Returns (distance, count, invalid_count, flags) and writes the direction into out_direction."""
    fx, fy, cx, cy = view.fx, view.fy, view.cx, view.cy
    f = int(region[0])
    if region[1] != 0.0:
        return 0.0, 1, 0, f
    total = acc[0].copy()
    for c in range(1, acc.shape[0]):
        part = acc[c]
        for a in (ACC_COUNT, ACC_INVALID, ACC_SUM_D, ACC_SX, ACC_SY, ACC_SZ):
            total[a] += part[a]
        total[ACC_INSIDE] = max(total[ACC_INSIDE], part[ACC_INSIDE])
        # The nearest pixel; among equals, the first in (v, u) order, as one scan of the rows would find.
        if part[ACC_BEST2] < total[ACC_BEST2] or (part[ACC_BEST2] == total[ACC_BEST2] and (
                part[ACC_BEST_V] < total[ACC_BEST_V] or (part[ACC_BEST_V] == total[ACC_BEST_V]
                                                         and part[ACC_BEST_U] < total[ACC_BEST_U]))):
            for a in (ACC_BEST2, ACC_BEST_U, ACC_BEST_V, ACC_BEST_Z, ACC_BEST_INVALID):
                total[a] = part[a]
    if aggregate == AGG_MIN:
        return finish_min_at_pixel(X, Y, Z, total[ACC_BEST2], int(total[ACC_BEST_U]), int(total[ACC_BEST_V]),
                                    total[ACC_BEST_Z], int(total[ACC_BEST_INVALID]), fx, fy, cx, cy, region[2],
                                    region[3], region[4], region[5], f, inside_tol, out_direction)
    return finish_sum(aggregate, int(total[ACC_COUNT]), int(total[ACC_INVALID]), total[ACC_INSIDE] != 0.0,
                       total[ACC_SUM_D], total[ACC_SX], total[ACC_SY], total[ACC_SZ], total[ACC_BEST2], region[2],
                       region[3], region[4], region[5], f, inside_tol, min_direction, out_direction)


@kernel(parallel=True)
def fused_query_points(points_camera, rho, view, options, grid, out):
    """Distances from the (n, 3) float64 control points ``points_camera`` (metres, principal optical frame) to what
    the principal camera says is possibly occupied and the secondary cameras do not clear, aggregated as
    ``aggregate``; the fused counterpart of :func:`depthguard.kernels.depthspace.query_points`. ``view``:
    :class:`PrincipalView`; ``options``: :class:`QueryOptions`; ``grid``: :class:`GridState`. Writes into ``out``
    (:class:`FusedOutput`) distance (n,) float64 metres, the unit direction (n, 3) float64 (from the obstacle towards
    P, principal optical frame), count, invalid_count and flags ((n,) int64 each).

    Each point's region is split into ``row_chunks`` interleaved sets of rows, and the n * row_chunks tasks run in
    parallel: a point near much clutter does not leave the other threads idle. Their sums are then added in a fixed
    order (:func:`fused_finish`). The parallel loops only call functions compiled on their own: numba compiles a
    parallel loop's body twice.
    """
    n = points_camera.shape[0]
    height, width = view.z_start.shape
    aggregate, unseen_occupied, near_eps, inside_tol, min_direction, row_chunks = options
    distance, direction, count, invalid_count, flags = out
    rho = usable_rho(rho)
    spans = np.empty((n, height, 2), dtype=np.int64)
    region = np.empty((n, 8))
    for i in prange(n):
        fused_region(points_camera[i, 0], points_camera[i, 1], points_camera[i, 2], rho, view, unseen_occupied,
                     near_eps, inside_tol, spans[i], region[i], direction[i])
    acc = np.empty((n, row_chunks, N_ACC))
    scratch = np.empty((n * row_chunks, 5, width))
    for t in prange(n * row_chunks):
        i = t // row_chunks
        c = t % row_chunks
        fused_rows(points_camera[i, 0], points_camera[i, 1], points_camera[i, 2], rho, int(region[i, 6]) + c,
                   int(region[i, 7]), row_chunks, spans[i], view, aggregate == AGG_MIN, grid, scratch[t], acc[i, c])
    for i in range(n):
        d, k, m, g = fused_finish(points_camera[i, 0], points_camera[i, 1], points_camera[i, 2], aggregate, region[i],
                                  acc[i], view, inside_tol, min_direction, direction[i])
        distance[i] = d
        count[i] = k
        invalid_count[i] = m
        flags[i] = g
