"""Numba kernels of the capsule fit (see ``depthguard/robots/_capsules.py`` for the method). They trust their
inputs: contiguous float64 arrays, a unit axis, at least one point. The tests hold them against slow NumPy twins and
run their bodies as plain Python (``.py_func``).

Lengths are in the unit of the points given, metres for the fit (a link's mesh vertices, in the link's frame); every
point, axis and result of one call is in the same frame."""

import math

import numpy as np

from depthguard.kernels.jit import kernel


@kernel(inline=True, error_model="python")
def circumcircle(ax, ay, bx, by, cx, cy):
    """(centre x, centre y, radius) of the circle through three points; for (nearly) collinear points, the circle
    on the farthest pair.

    ax, ay, bx, by, cx, cy: float64, the three points (ax, ay), (bx, by), (cx, cy) in one plane, in one length unit
    (metres in the fit: coordinates in the plane normal to the axis); not a camera's intrinsics."""
    d = 2.0 * (ax * (by - cy) + bx * (cy - ay) + cx * (ay - by))
    if abs(d) < 1e-18:
        dab, dac, dbc = math.hypot(ax - bx, ay - by), math.hypot(ax - cx, ay - cy), math.hypot(bx - cx, by - cy)
        if dab >= dac and dab >= dbc:
            return 0.5 * (ax + bx), 0.5 * (ay + by), 0.5 * dab
        if dac >= dbc:
            return 0.5 * (ax + cx), 0.5 * (ay + cy), 0.5 * dac
        return 0.5 * (bx + cx), 0.5 * (by + cy), 0.5 * dbc
    sa, sb, sc = ax * ax + ay * ay, bx * bx + by * by, cx * cx + cy * cy
    ux = (sa * (by - cy) + sb * (cy - ay) + sc * (ay - by)) / d
    uy = (sa * (cx - bx) + sb * (ax - cx) + sc * (bx - ax)) / d
    return ux, uy, math.hypot(ax - ux, ay - uy)


@kernel(error_model="python")
def enclosing_circle(x, y):
    """Smallest circle enclosing the points (x[i], y[i]), (n,) float64 each (n >= 1, one length unit: metres in the
    fit): (centre x, centre y, radius), in the same unit.

    Welzl's algorithm, iterative; its expected time is linear when the points come in random order (the caller
    shuffles them once). The radius returned is the exact largest distance from the centre to a point.
    """
    n = x.shape[0]
    tol = 1e-12
    cx, cy, rad = x[0], y[0], 0.0
    for i in range(1, n):
        if math.hypot(x[i] - cx, y[i] - cy) <= rad + tol:
            continue
        cx, cy, rad = x[i], y[i], 0.0
        for j in range(i):
            if math.hypot(x[j] - cx, y[j] - cy) <= rad + tol:
                continue
            cx, cy = 0.5 * (x[i] + x[j]), 0.5 * (y[i] + y[j])
            rad = 0.5 * math.hypot(x[i] - x[j], y[i] - y[j])
            for k in range(j):
                if math.hypot(x[k] - cx, y[k] - cy) > rad + tol:
                    cx, cy, rad = circumcircle(x[i], y[i], x[j], y[j], x[k], y[k])
    rad = 0.0
    for i in range(n):
        rad = max(rad, math.hypot(x[i] - cx, y[i] - cy))
    return cx, cy, rad


@kernel(inline=True, error_model="python")
def _scan(t, r2, lo, hi, samples):
    """The radius in ``samples`` evenly spaced values of [lo, hi] whose capsule (shortest segment) has the smallest
    volume: (radius, index).

    t: (n,) float64, metres, each point's coordinate along the axis; r2: (n,) float64, square metres, its squared
    distance from the axis line; lo, hi: float64, metres, the radii to try, lo <= hi, lo at least every
    point's distance from the axis line; samples: int >= 1 (lo alone when 1); index: int in [0, samples), the chosen
    value's."""
    best_volume, best_radius, best_index = np.inf, lo, 0
    for k in range(samples):
        radius = lo + (hi - lo) * k / (samples - 1) if samples > 1 else lo
        t_lo, t_hi = np.inf, -np.inf
        for i in range(t.shape[0]):
            s = math.sqrt(max(radius * radius - r2[i], 0.0))
            t_lo = min(t_lo, t[i] + s)
            t_hi = max(t_hi, t[i] - s)
        volume = math.pi * radius * radius * max(t_hi - t_lo, 0.0) + 4.0 / 3.0 * math.pi * radius**3
        if volume < best_volume:
            best_volume, best_radius, best_index = volume, radius, k
    return best_radius, best_index


@kernel(error_model="python")
def fit_along(points, axis, samples):
    """The smallest capsule this fit finds around (n, 3) float64 ``points`` (n >= 1; metres, the link's frame) with
    its segment parallel to the unit (3,) float64 ``axis`` (same frame): (p0 (3,), p1 (3,), radius, volume), float64,
    metres, cubic metres, in the points' frame. The radius is the one the volume scan chose; every point lies within
    it of the segment (up to rounding; the caller recomputes the exact largest distance). ``samples``: int >= 1, the
    radii each of the two scans tries (``config.CAPSULE_RADIUS_SAMPLES``): one over the whole range, then one around
    the best.

    Written with scalars rather than NumPy's cross, norm and matrix products, which take seconds to compile."""
    n = points.shape[0]
    ax, ay, az = axis[0], axis[1], axis[2]
    # e1 = axis x (the coordinate axis least aligned with it), normalised; e2 = axis x e1.
    if abs(ax) <= abs(ay) and abs(ax) <= abs(az):
        e1x, e1y, e1z = 0.0, az, -ay
    elif abs(ay) <= abs(az):
        e1x, e1y, e1z = -az, 0.0, ax
    else:
        e1x, e1y, e1z = ay, -ax, 0.0
    norm = math.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
    e1x, e1y, e1z = e1x / norm, e1y / norm, e1z / norm
    e2x, e2y, e2z = ay * e1z - az * e1y, az * e1x - ax * e1z, ax * e1y - ay * e1x
    t = np.empty(n)
    u = np.empty(n)
    v = np.empty(n)
    for i in range(n):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        t[i] = x * ax + y * ay + z * az
        u[i] = x * e1x + y * e1y + z * e1z
        v[i] = x * e2x + y * e2y + z * e2z
    cu, cv, r_min = enclosing_circle(u, v)
    r2 = np.empty(n)
    t_min, t_max = np.inf, -np.inf
    for i in range(n):
        r2[i] = (u[i] - cu) ** 2 + (v[i] - cv) ** 2
        t_min = min(t_min, t[i])
        t_max = max(t_max, t[i])
    # Beyond the radius of the sphere centred mid-way along the axis, the volume only grows.
    t_mid = 0.5 * (t_min + t_max)
    r_max = r_min
    for i in range(n):
        r_max = max(r_max, math.sqrt(r2[i] + (t[i] - t_mid) ** 2))
    radius, k = _scan(t, r2, r_min, r_max, samples)
    step = (r_max - r_min) / (samples - 1) if samples > 1 else 0.0
    radius, _ = _scan(t, r2, max(r_min, r_min + (k - 1) * step), min(r_max, r_min + (k + 1) * step), samples)
    t_lo, t_hi = np.inf, -np.inf
    for i in range(n):
        s = math.sqrt(max(radius * radius - r2[i], 0.0))
        t_lo = min(t_lo, t[i] + s)
        t_hi = max(t_hi, t[i] - s)
    if t_lo > t_hi:  # a sphere: any centre in [t_hi, t_lo] contains every point
        t_lo = t_hi = 0.5 * (t_lo + t_hi)
    ox, oy, oz = cu * e1x + cv * e2x, cu * e1y + cv * e2y, cu * e1z + cv * e2z
    p0 = np.array([ox + t_lo * ax, oy + t_lo * ay, oz + t_lo * az])
    p1 = np.array([ox + t_hi * ax, oy + t_hi * ay, oz + t_hi * az])
    volume = math.pi * radius * radius * (t_hi - t_lo) + 4.0 / 3.0 * math.pi * radius**3
    return p0, p1, radius, volume
