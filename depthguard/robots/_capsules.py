"""Capsules that contain a link's collision mesh: the robot's simple geometry for self-filtering and distances.

The fit, for a unit axis direction a:

1. the axis line passes through the centre of the smallest circle that encloses the vertices projected on the plane
   normal to a (Welzl's algorithm), so the radial extent r_v of every vertex is as small as this direction allows;
2. for a radius R >= max r_v, vertex v lies in the capsule iff its axial coordinate t_v is within
   s_v = sqrt(R^2 - r_v^2) of the segment's axial interval, so the shortest segment is [t_lo, t_hi] with
   t_lo = min_v (t_v + s_v) and t_hi = max_v (t_v - s_v) (a single point, a sphere, when t_lo > t_hi);
3. R is chosen to minimise the volume pi R^2 L + 4/3 pi R^3 (a scan of the radii, then a finer one around the best).

Steps 1-3 are the numba kernel ``depthguard.kernels.capsules.fit_along`` (about 0.1 ms for a few hundred vertices).

The direction: the three principal axes (PCA) of the vertices and ``config.CAPSULE_AXIS_CANDIDATES`` directions
spread over the half sphere are tried, and the best is refined by Nelder-Mead. On the iiwa and Panda links this gives
capsules 0-30 % smaller in volume than the best principal axis alone (L-shaped links gain most).

The radius finally stored is the exact largest distance of any vertex to the chosen segment, plus the padding, so
containment does not depend on the search: every vertex is within ``radius - padding`` of the segment. The capsule
is convex, so it contains the convex hull of the vertices and therefore the whole mesh.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize
from scipy.spatial import ConvexHull, QhullError

from depthguard import config
from depthguard.errors import RobotError
from depthguard.kernels import capsules as kernels


@dataclass(frozen=True)
class LinkCapsule:
    """A capsule fixed to a link that contains the link's collision mesh plus ``padding``.

    Attributes:
        link: the link's name.
        p0, p1: (3,) float64, metres, link frame: the end points of the capsule's core segment (equal for a sphere).
        radius: metres, including ``padding``: every point of the collision mesh is within ``radius - padding`` of
            the segment.
        padding: metres added to the radius of the smallest capsule this fit found.
    """

    link: str
    p0: np.ndarray
    p1: np.ndarray
    radius: float
    padding: float

    def __post_init__(self):
        for key in ("p0", "p1"):
            value = np.array(getattr(self, key), dtype=np.float64)
            if value.shape != (3,) or not np.all(np.isfinite(value)):
                raise RobotError(f"link {self.link!r}: capsule {key} must be 3 finite numbers, got {value!r}",
                                 field=key)
            value.setflags(write=False)
            object.__setattr__(self, key, value)
        if not (math.isfinite(self.radius) and self.radius >= self.padding >= 0.0):
            raise RobotError(f"link {self.link!r}: capsule needs radius >= padding >= 0, got radius {self.radius}, "
                             f"padding {self.padding}", field="radius")
        object.__setattr__(self, "radius", float(self.radius))
        object.__setattr__(self, "padding", float(self.padding))

    @property
    def length(self) -> float:
        """Length of the core segment, metres."""
        return float(np.linalg.norm(self.p1 - self.p0))

    @property
    def volume(self) -> float:
        """Volume of the capsule (padding included), cubic metres."""
        return capsule_volume(self.radius, self.length)


def capsule_volume(radius: float, length: float) -> float:
    """Volume (m^3) of a capsule of ``radius`` (m) around a segment of ``length`` (m)."""
    return math.pi * radius**2 * length + 4.0 / 3.0 * math.pi * radius**3


def segment_distances(points, p0, p1) -> np.ndarray:
    """Distances (n,) float64, metres, of (n, 3) points to the segment p0-p1 ((3,) each), all in one frame."""
    points = np.asarray(points, dtype=np.float64)
    p0, p1 = np.asarray(p0, dtype=np.float64), np.asarray(p1, dtype=np.float64)
    axis = p1 - p0
    rel = points - p0
    denom = float(axis @ axis)
    s = np.clip(rel @ axis / denom, 0.0, 1.0) if denom > 0.0 else np.zeros(len(points))
    return np.linalg.norm(rel - s[:, None] * axis, axis=1)


def fit_capsule(vertices, *, link: str, padding: float) -> LinkCapsule:
    """The smallest capsule this fit finds around (n, 3) float64 ``vertices`` (metres, link frame), plus ``padding``
    metres on its radius. See the module docstring for the method."""
    points = _hull_vertices(np.asarray(vertices, dtype=np.float64))
    # Welzl's algorithm is fastest on points in random order: shuffle once, the same way every time.
    points = np.ascontiguousarray(points[np.random.default_rng(0).permutation(len(points))])
    samples = config.CAPSULE_RADIUS_SAMPLES

    def volume(axis):
        return kernels.fit_along(points, axis, samples)[3]

    _, _, principal = np.linalg.svd(points - points.mean(axis=0), full_matrices=True)
    candidates = np.concatenate([principal, _half_sphere(config.CAPSULE_AXIS_CANDIDATES)])
    start = candidates[int(np.argmin([volume(axis) for axis in candidates]))]
    # Refine the best direction: Nelder-Mead on two tangent coordinates (the volume is not smooth in the axis).
    helper = np.eye(3)[np.argmin(np.abs(start))]
    t1 = np.cross(start, helper)
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(start, t1)

    def direction(uv):
        axis = start + uv[0] * t1 + uv[1] * t2
        return axis / np.linalg.norm(axis)

    result = minimize(lambda uv: volume(direction(uv)), np.zeros(2), method="Nelder-Mead",
                      options={"initial_simplex": [[0.0, 0.0], [0.05, 0.0], [0.0, 0.05]], "xatol": 1e-4,
                               "fatol": 1e-12, "maxiter": config.CAPSULE_REFINE_ITERATIONS})
    best = result.x if result.fun < volume(start) else np.zeros(2)
    p0, p1, _, _ = kernels.fit_along(points, direction(best), samples)
    core = float(segment_distances(points, p0, p1).max())
    return LinkCapsule(link=link, p0=p0, p1=p1, radius=core + padding, padding=padding)


def enclosing_circle(points) -> tuple[np.ndarray, float]:
    """Smallest circle enclosing (n, 2) points: (centre (2,), radius). Welzl's algorithm on a fixed shuffle."""
    points = np.asarray(points, dtype=np.float64)
    points = points[np.random.default_rng(0).permutation(len(points))]
    cx, cy, radius = kernels.enclosing_circle(np.ascontiguousarray(points[:, 0]), np.ascontiguousarray(points[:, 1]))
    return np.array([cx, cy]), radius


def _half_sphere(count: int) -> np.ndarray:
    """(count, 3) unit vectors spread evenly over the half sphere z >= 0 (a Fibonacci lattice): axis directions."""
    k = np.arange(count) + 0.5
    z = k / count
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    rho = np.sqrt(1.0 - z * z)
    return np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)


def _hull_vertices(points: np.ndarray) -> np.ndarray:
    """The convex hull's vertices (the capsule contains them iff it contains all points); all points if flat."""
    try:
        return points[ConvexHull(points).vertices]
    except (QhullError, ValueError):
        return np.unique(points, axis=0)
