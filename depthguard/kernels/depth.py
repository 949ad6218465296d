"""Numba kernels of the per-frame preparation. They trust their inputs; ``depthguard/depth/_prepare.py`` validates
them.

Each kernel works on one camera's frame: (h, w) arrays indexed [v, u], C order; depths are optical z (the camera's
optical frame), metres.

Arguments used throughout:

- ``raw``: (h, w) uint16 in units of ``scale`` metres, or float32 metres: the camera's depth image; a value that is
  not finite or <= 0 is no measurement (and, for :func:`start_depths`, one outside [z_min, z_max]).
- ``scale``: float, metres per unit of ``raw`` (the frame's depth_scale; 1.0 for float32).
- ``m0, m1, m2``: float, the camera's noise margin m(d) = max(m0 + m1 d + m2 d^2, 0) metres at depth d metres
  (m0 in metres, m1 no unit, m2 per metre; ``NoiseModel.coefficients()``).
- ``z_start``: (h, w) float32, metres: where each pixel's possibly-occupied segment starts (inf: nothing along the
  pixel), :attr:`OccupancyImage.z_start` (:func:`block_minimum` is also given other such images, e.g. ``blind``).
- ``z_end``: (h, w) float32, metres: where that segment ends (inf: it does not end).
- ``blind``: (h, w) float32, metres: where the space hidden behind the robot starts along the pixel (inf: none).
- ``invalid``: (h, w) uint8: 1 where the pixel has no valid measurement (whatever the policy made of it), else 0.
- ``policy_start``: float32, metres: the start depth the invalid-pixel policy gives a pixel without a measurement
  (``invalid_start`` of :func:`start_depths`: the camera's z_min, or inf for ``invalid="free"``).
- ``robot_near``: (h, w) float32, metres: the nearest surface of the robot's padded geometry rendered into the
  camera; 0 where the robot is not rendered.
- ``robot_far``: (h, w) float32, metres: where the rendered robot ends along each pixel (its farthest surface); 0
  where it is not rendered. Read only with ``has_far``.
- ``has_far``: bool: whether ``robot_far`` was given (without it, the caller passes ``robot_near`` again).
- ``tolerance``: float, metres: how far in front of the rendered robot a measurement may lie and still be the robot,
  on top of the noise margin (``prepare_depth``'s ``robot_tolerance``, by default ``config.SELF_FILTER_TOLERANCE``).
"""

import numpy as np
from numba import prange

from depthguard.kernels.frustum import noise_margin
from depthguard.kernels.jit import kernel


@kernel(parallel=True)
def start_depths(raw, scale, z_min, z_max, m0, m1, m2, invalid_start, z_start, invalid, z_end, blind):
    """Per pixel, the depth from which its frustum is possibly occupied.

    raw: (h, w) uint16 units or float32 metres. scale: metres per unit. [z_min, z_max]: float, the camera's valid
    range, metres. m0 + m1*d + m2*d**2: the noise margin at depth d (metres), clamped at 0. invalid_start: float,
    metres, where a pixel without a valid measurement starts (z_min for "occupied" and "neighbors", inf for "free").
    Writes z_start (h, w) float32 metres (inf = nothing) and invalid (h, w) uint8 (1 = no valid measurement), and
    sets z_end and blind (h, w) float32 to inf (no segment end, no robot blind spot).
    """
    h, w = raw.shape
    for v in prange(h):
        for u in range(w):
            z_end[v, u] = np.inf
            blind[v, u] = np.inf
            d = np.float64(raw[v, u]) * scale
            if np.isfinite(d) and d > 0.0 and d >= z_min and d <= z_max:
                margin = noise_margin(d, m0, m1, m2)
                z = d - margin
                if z < 0.0:
                    z = 0.0
                z_start[v, u] = z
                invalid[v, u] = 0
            else:
                z_start[v, u] = invalid_start
                invalid[v, u] = 1


@kernel(parallel=True)
def block_minimum(z_start, block, out):
    """out[i, j] = min of z_start over the block of pixels [i*block, (i+1)*block) x [j*block, (j+1)*block).

    z_start: (h, w) float32, metres (the start depths, or any image of depths: the callers pass ``blind`` and
    ``unchecked_from`` too); block: int, the blocks' side in pixels (``config.BLOCK_SIZE``); out: (ceil(h / block),
    ceil(w / block)) float32, metres (written).

    One thread per row of blocks: the minimum over its image rows column by column (a loop that vectorises), then
    over each block's columns."""
    h, w = z_start.shape
    hb, wb = out.shape
    for bi in prange(hb):
        columns = np.full(w, np.inf, dtype=np.float32)
        for v in range(bi * block, min(h, (bi + 1) * block)):
            row = z_start[v]
            for u in range(w):
                columns[u] = min(columns[u], row[u])
        for bj in range(wb):
            m = np.float32(np.inf)
            for u in range(bj * block, min(w, (bj + 1) * block)):
                m = min(m, columns[u])
            out[bi, bj] = m


@kernel(parallel=True)
def robot_filter(z_start, invalid, policy_start, robot_near, robot_far, has_far, tolerance, m0, m1, m2, z_end, blind):
    """Self-filtering (design §7): remove the robot from what a frame says is possibly occupied.

    robot_near: (h, w) float32 metres, the nearest rendered robot surface per pixel (0 where the robot is not
    rendered). A pixel whose start depth could be the robot shows the robot: z_start >= d_r' - tolerance - m(d_r'),
    with d_r' the nearest rendered robot surface in the pixel's 3x3 neighbourhood (one pixel of slack for
    calibration and for silhouettes, where the rendered depth changes fast). Its ray is free up to the robot
    (z_start = inf) and unknown from the robot on (blind = d_r). A pixel clearly in
    front of the robot keeps its obstacle, which hides everything behind it anyway. With ``has_far``, robot_far
    (h, w) float32 is where the rendered robot ends along each pixel: a measurement beyond the farthest end in the
    3x3 neighbourhood (plus the tolerance and the noise margin) saw past the robot's padded geometry, through
    space the real robot does not fill, and stays what it is: a surface, with nothing hidden in front of it. A
    pixel whose occupied set the invalid-pixel policy made (z_start == policy_start, invalid) is occupied only up to
    the robot: z_end = d_r - tolerance - m(d_r), with the blind spot from the robot on.
    Edits z_start, and z_end and blind (h, w) float32 metres (inf = none), in place on the robot's pixels.
    """
    h, w = z_start.shape
    for v in prange(h):
        row = robot_near[v]
        for u in range(w):
            if row[u] > 0.0:
                _filter_robot_pixel(v, u, z_start, invalid, policy_start, robot_near, robot_far, has_far, tolerance,
                                    m0, m1, m2, z_end, blind)


@kernel(parallel=True)
def robot_filter_fills(z_start, invalid, policy_start, robot_near, robot_far, has_far, tolerance, m0, m1, m2, z_end,
                       blind):
    """After ``invalid="neighbors"`` filled the small holes: each fill stands for the measurement its pixel lost, and
    is self-filtered as one (:func:`robot_filter`'s rule) where the robot is rendered. Only filled pixels (no
    measurement, a finite start other than the policy's) are touched; every other pixel was decided before."""
    h, w = z_start.shape
    for v in prange(h):
        for u in range(w):
            if robot_near[v, u] > 0.0 and invalid[v, u] and np.isfinite(z_start[v, u]) and \
                    z_start[v, u] != policy_start:
                _filter_robot_pixel(v, u, z_start, invalid, policy_start, robot_near, robot_far, has_far, tolerance,
                                    m0, m1, m2, z_end, blind)


@kernel(inline=True)
def _filter_robot_pixel(v, u, z_start, invalid, policy_start, robot_near, robot_far, has_far, tolerance, m0, m1, m2,
                        z_end, blind):
    """:func:`robot_filter` on one pixel where the robot is rendered: v, u (int), its row and column. The other
    arguments as there."""
    h, w = z_start.shape
    d_r = np.float64(robot_near[v, u])
    d_near = d_r
    for dv in range(-1, 2):
        vv = min(max(v + dv, 0), h - 1)  # clamped: a border pixel counts itself again
        for du in range(-1, 2):
            d = np.float64(robot_near[vv, min(max(u + du, 0), w - 1)])
            if d > 0.0:
                d_near = min(d_near, d)
    margin = noise_margin(d_near, m0, m1, m2)
    front = d_near - tolerance - margin  # nearest depth at which a measurement could still be the robot
    zs = np.float64(z_start[v, u])
    if invalid[v, u] and zs == policy_start:
        if front > zs:
            z_end[v, u] = front
        else:
            z_start[v, u] = np.inf
        blind[v, u] = d_r
    elif zs >= front:
        if has_far:
            d_far = 0.0
            for dv in range(-1, 2):
                vv = min(max(v + dv, 0), h - 1)
                for du in range(-1, 2):
                    d_far = max(d_far, np.float64(robot_far[vv, min(max(u + du, 0), w - 1)]))
            if zs > d_far + tolerance + noise_margin(d_far, m0, m1, m2):
                return  # seen past the robot
        z_start[v, u] = np.inf
        blind[v, u] = d_r


@kernel()
def fill_small_holes(raw, scale, invalid, hole_pixels, m0, m1, m2, z_start, z_end, blind, visited, stack):
    """``invalid="neighbors"``: fill holes (8-connected pixels without a measurement) that are small — at most
    ``hole_pixels`` pixels, or nowhere more than 2 pixels thick (no pixel of the hole has all 8 neighbours in it:
    the thin lines depth cameras drop along depth edges) — from the smallest valid depth around them.

    If that nearest surface around the hole is the robot (a valid pixel that self-filtering marked: ``blind``
    finite), the hole shows the robot: free in front (z_start = inf) and blind from that depth on. Otherwise it
    takes that depth minus its noise margin. Work is proportional to the pixels without a measurement.

    raw: (h, w) uint16 or float32 measurements, ``scale`` metres per unit. invalid: (h, w) uint8. hole_pixels: int,
    pixels, the largest hole filled whatever its thickness. m0, m1, m2: the noise margin. Edits z_start, z_end, blind
    in place. visited: (h, w) uint8 scratch; stack: (h*w,) int64 scratch.
    """
    h, w = invalid.shape
    for v0 in range(h):
        for u0 in range(w):
            visited[v0, u0] = 0
    for v0 in range(h):
        for u0 in range(w):
            if invalid[v0, u0] == 0 or visited[v0, u0]:
                continue
            visited[v0, u0] = 1
            stack[0] = v0 * w + u0
            n = 1
            head = 0
            thick = False
            near_robot = np.inf
            near_other = np.inf
            while head < n:
                v = stack[head] // w
                u = stack[head] % w
                head += 1
                interior = True
                for dv in range(-1, 2):
                    for du in range(-1, 2):
                        if dv == 0 and du == 0:
                            continue
                        vv = v + dv
                        uu = u + du
                        if vv < 0 or vv >= h or uu < 0 or uu >= w:
                            interior = False
                            continue
                        if invalid[vv, uu]:
                            if not visited[vv, uu]:
                                visited[vv, uu] = 1
                                stack[n] = vv * w + uu
                                n += 1
                        else:
                            interior = False
                            d = np.float64(raw[vv, uu]) * scale
                            if np.isfinite(blind[vv, uu]):
                                near_robot = min(near_robot, d)
                            else:
                                near_other = min(near_other, d)
                if interior:
                    thick = True
            if n > hole_pixels and thick:
                continue
            if near_robot <= near_other and near_robot < np.inf:
                for k in range(n):
                    v = stack[k] // w
                    u = stack[k] % w
                    z_start[v, u] = np.inf
                    z_end[v, u] = np.inf
                    blind[v, u] = min(np.float64(blind[v, u]), near_robot)
            elif near_other < np.inf:
                margin = noise_margin(near_other, m0, m1, m2)
                start = max(near_other - margin, 0.0)
                for k in range(n):
                    v = stack[k] // w
                    u = stack[k] % w
                    z_start[v, u] = start
                    z_end[v, u] = np.inf
                    blind[v, u] = np.inf
