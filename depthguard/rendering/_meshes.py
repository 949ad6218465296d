"""Triangle meshes of depthguard's solid primitives (:mod:`depthguard.scenes` Box, Sphere, Capsule).

A box is exact (8 corners, 12 triangles). A sphere or capsule is curved, so its mesh is a convex polyhedron that
*contains* the true solid (circumscribed): a rendered depth is then never behind the true surface, and a robot mask
or an obstacle drawn from it is never smaller than the true one.

Construction: unit directions d_i of a UV sphere (``segments`` around, ``segments // 2`` rings from pole to pole,
axis along the capsule's axis); their convex hull H has every face plane at distance >= h from the centre, so
(r / h) * H contains the ball of radius r. A capsule (segment p0-p1 plus the ball) is the Minkowski sum of the
segment and the ball; the hull of {p0 + (r/h) d_i} and {p1 + (r/h) d_i} is the segment plus (r/h) * H, which
contains it. The mesh exceeds the true surface by at most r (1/h - 1) (at its vertices):
:func:`primitive_mesh_excess` gives it in metres (0.43 % of the radius at 48 segments).
"""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy.spatial import ConvexHull

from depthguard import config
from depthguard.errors import InputError
from depthguard.transforms import rotation_with_z


@functools.lru_cache(maxsize=16)
def _unit_hull(segments: int) -> tuple[np.ndarray, float]:
    """(directions (n, 3) float64 unit vectors about the z axis, h = smallest face-plane distance of their hull)."""
    rings = segments // 2
    polar = np.pi * np.arange(1, rings) / rings  # rings - 1 circles between the poles
    azimuth = 2.0 * np.pi * np.arange(segments) / segments
    s, a = np.meshgrid(polar, azimuth, indexing="ij")
    circle = np.stack([np.sin(s) * np.cos(a), np.sin(s) * np.sin(a), np.cos(s)], axis=-1).reshape(-1, 3)
    directions = np.concatenate([[[0.0, 0.0, 1.0]], circle, [[0.0, 0.0, -1.0]]])
    h = float((-ConvexHull(directions).equations[:, 3]).min())
    directions.setflags(write=False)
    return directions, h


def _outward_hull(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (k, 3) and outward-wound triangles (m, 3) int64 of the convex hull of ``points``."""
    hull = ConvexHull(points)
    faces = hull.simplices.astype(np.int64)
    a, b, c = (points[faces[:, k]] for k in range(3))
    inward = np.einsum("ij,ij->i", np.cross(b - a, c - a), hull.equations[:, :3]) < 0
    faces[inward] = faces[inward][:, [0, 2, 1]]
    used, faces = np.unique(faces, return_inverse=True)
    return points[used], faces.reshape(-1, 3)


def _check_segments(segments) -> int:
    if isinstance(segments, bool) or not isinstance(segments, (int, np.integer)) or segments < 6:
        raise InputError(f"segments must be an integer >= 6, got {segments!r}")
    return int(segments)


def _check_radius(radius) -> float:
    radius = float(radius)
    if not (math.isfinite(radius) and radius > 0):
        raise InputError(f"radius must be a positive number of metres, got {radius!r}")
    return radius


def primitive_mesh(prim, segments: int = config.PRIMITIVE_MESH_SEGMENTS) -> tuple[np.ndarray, np.ndarray]:
    """Triangle mesh of a :mod:`depthguard.scenes` primitive, in the world frame.

    Args:
        prim: a :class:`~depthguard.scenes.Box`, :class:`~depthguard.scenes.Sphere` or
            :class:`~depthguard.scenes.Capsule` (metres, world frame).
        segments: for spheres and capsules, the number of segments around (the mesh has ``segments // 2`` rings
            from pole to pole); ignored for boxes.

    Returns:
        (vertices, faces): (n, 3) float64 metres, world frame, and (m, 3) int64 vertex indices, each triangle wound
        counter-clockwise seen from outside. A box's mesh is exact; a sphere's or capsule's contains the true solid
        and exceeds its surface by at most :func:`primitive_mesh_excess` metres.
    """
    from depthguard.scenes import Box, Capsule, Sphere

    if isinstance(prim, Box):
        R = np.asarray(prim.R_world_box, dtype=np.float64)
        h = np.asarray(prim.half_extents, dtype=np.float64)
        if R.shape != (3, 3) or h.shape != (3,) or not (np.all(np.isfinite(R)) and np.all(h > 0)):
            raise InputError(f"box needs a (3, 3) rotation and three positive half extents, got {prim!r}")
        corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
        return _outward_hull((corners * h) @ R.T + np.asarray(prim.center, dtype=np.float64))
    segments = _check_segments(segments)
    directions, inscribed = _unit_hull(segments)
    if isinstance(prim, Sphere):
        scale = _check_radius(prim.radius) / inscribed
        vertices = directions * scale + np.asarray(prim.center, dtype=np.float64)
        return _outward_hull(vertices)
    if isinstance(prim, Capsule):
        scale = _check_radius(prim.radius) / inscribed
        p0, p1 = np.asarray(prim.p0, dtype=np.float64), np.asarray(prim.p1, dtype=np.float64)
        length = float(np.linalg.norm(p1 - p0))
        if length == 0.0:
            return _outward_hull(directions * scale + p0)
        ball = (directions * scale) @ rotation_with_z((p1 - p0) / length).T
        return _outward_hull(np.concatenate([ball + p0, ball + p1]))
    raise InputError(f"primitive_mesh takes a Box, Sphere or Capsule, got {type(prim).__name__}")


def primitive_mesh_excess(prim, segments: int = config.PRIMITIVE_MESH_SEGMENTS) -> float:
    """Metres by which :func:`primitive_mesh` of ``prim`` may lie outside the true surface: 0 for a box,
    radius * (1/h - 1) for a sphere or capsule (h: smallest face-plane distance of the unit hull; 0.43 % of the
    radius at 48 segments)."""
    from depthguard.scenes import Box, Capsule, Sphere

    if isinstance(prim, Box):
        return 0.0
    if isinstance(prim, (Sphere, Capsule)):
        _, inscribed = _unit_hull(_check_segments(segments))
        return _check_radius(prim.radius) * (1.0 / inscribed - 1.0)
    raise InputError(f"primitive_mesh_excess takes a Box, Sphere or Capsule, got {type(prim).__name__}")
