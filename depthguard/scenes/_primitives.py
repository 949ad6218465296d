"""Solid primitives with exact ray casting and exact point distances.

Used to synthesise depth images by exact ray casting (one ray through each pixel centre) and to compute ground-truth
distances. All coordinates are metres in the world frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Box:
    """A solid oriented box: centre (3,), half extents (3,) along its own axes, rotation R_world_box (3, 3)."""

    center: tuple
    half_extents: tuple
    R_world_box: np.ndarray = field(default_factory=lambda: np.eye(3))

    @classmethod
    def from_bounds(cls, lower, upper) -> "Box":
        """An axis-aligned box spanning lower (3,) to upper (3,)."""
        lower, upper = np.asarray(lower, float), np.asarray(upper, float)
        return cls(tuple((lower + upper) / 2), tuple((upper - lower) / 2))

    def _local(self, points):
        return (np.asarray(points, float) - np.asarray(self.center, float)) @ np.asarray(self.R_world_box)

    def intersect(self, origins, directions) -> np.ndarray:
        """Ray parameter t >= 0 of the first hit of rays origins + t*directions ((n, 3) each); inf on a miss."""
        R = np.asarray(self.R_world_box)
        o = (np.asarray(origins, float) - np.asarray(self.center, float)) @ R
        d = np.asarray(directions, float) @ R
        h = np.asarray(self.half_extents, float)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            t1 = (-h - o) * inv
            t2 = (h - o) * inv
        t1 = np.where(np.isnan(t1), -np.inf, t1)
        t2 = np.where(np.isnan(t2), np.inf, t2)
        t_near = np.max(np.minimum(t1, t2), axis=1)
        t_far = np.min(np.maximum(t1, t2), axis=1)
        hit = (t_near <= t_far) & (t_far >= 0)
        return np.where(hit, np.where(t_near >= 0, t_near, 0.0), np.inf)

    def distance(self, points) -> np.ndarray:
        """Distance from (n, 3) points to the solid box (0 inside)."""
        q = np.abs(self._local(points)) - np.asarray(self.half_extents, float)
        return np.linalg.norm(np.maximum(q, 0.0), axis=-1)


@dataclass(frozen=True)
class Sphere:
    """A solid sphere: centre (3,), radius."""

    center: tuple
    radius: float

    def intersect(self, origins, directions) -> np.ndarray:
        o = np.asarray(origins, float) - np.asarray(self.center, float)
        d = np.asarray(directions, float)
        a = np.einsum("ij,ij->i", d, d)
        b = np.einsum("ij,ij->i", o, d)
        c = np.einsum("ij,ij->i", o, o) - self.radius**2
        disc = b * b - a * c
        root = np.sqrt(np.maximum(disc, 0.0))
        t0 = (-b - root) / a
        t1 = (-b + root) / a
        t = np.where(t0 >= 0, t0, np.where(t1 >= 0, 0.0, np.inf))
        return np.where(disc >= 0, t, np.inf)

    def distance(self, points) -> np.ndarray:
        return np.maximum(np.linalg.norm(np.asarray(points, float) - np.asarray(self.center, float), axis=-1)
                          - self.radius, 0.0)


@dataclass(frozen=True)
class Capsule:
    """A solid capsule: the points within ``radius`` of the segment p0-p1 ((3,) each)."""

    p0: tuple
    p1: tuple
    radius: float

    def intersect(self, origins, directions) -> np.ndarray:
        p0, p1 = np.asarray(self.p0, float), np.asarray(self.p1, float)
        axis = p1 - p0
        length = np.linalg.norm(axis)
        t = np.minimum(Sphere(tuple(p0), self.radius).intersect(origins, directions),
                       Sphere(tuple(p1), self.radius).intersect(origins, directions))
        if length == 0:
            return t
        k = axis / length
        o = np.asarray(origins, float) - p0
        d = np.asarray(directions, float)
        # Infinite cylinder: |(o + t d) - ((o + t d).k) k|^2 = r^2.
        dp = d - np.outer(d @ k, k)
        op = o - np.outer(o @ k, k)
        a = np.einsum("ij,ij->i", dp, dp)
        b = np.einsum("ij,ij->i", op, dp)
        c = np.einsum("ij,ij->i", op, op) - self.radius**2
        disc = b * b - a * c
        with np.errstate(divide="ignore", invalid="ignore"):
            root = np.sqrt(np.maximum(disc, 0.0))
            tc0 = (-b - root) / a
            tc1 = (-b + root) / a
        inside = c <= 0  # origin inside the infinite cylinder
        tc = np.where(inside, 0.0, tc0)
        s = (o @ k) + tc * (d @ k)
        ok = (disc >= 0) & (a > 0) & (tc1 >= 0) & (s >= 0) & (s <= length)
        return np.minimum(t, np.where(ok, np.maximum(tc, 0.0), np.inf))

    def distance(self, points) -> np.ndarray:
        p0, p1 = np.asarray(self.p0, float), np.asarray(self.p1, float)
        axis = p1 - p0
        rel = np.asarray(points, float) - p0
        denom = float(axis @ axis)
        s = np.clip(rel @ axis / denom, 0.0, 1.0) if denom > 0 else np.zeros(len(rel))
        return np.maximum(np.linalg.norm(rel - np.outer(s, axis), axis=-1) - self.radius, 0.0)


def scene_distance(primitives, points_world) -> np.ndarray:
    """Exact distance from (n, 3) points to the union of solid primitives (0 inside any); inf for no primitive."""
    points = np.atleast_2d(np.asarray(points_world, float))
    best = np.full(len(points), np.inf)
    for primitive in primitives:
        best = np.minimum(best, primitive.distance(points))
    return best


def render_depth(camera, primitives) -> np.ndarray:
    """Exact ray-cast depth image of ``primitives`` seen by ``camera``: (h, w) float32 metres (optical-frame z of
    the first surface hit by the ray through each pixel centre); 0 where no primitive is hit."""
    u, v = camera.pixel_grid()
    rays_camera = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], axis=-1)
    rays_camera = rays_camera.reshape(-1, 3)
    R = camera.T_world_camera[:3, :3]
    directions = rays_camera @ R.T  # unit z in the optical frame, so the ray parameter is the depth
    origins = np.broadcast_to(camera.T_world_camera[:3, 3], directions.shape)
    t = np.full(len(directions), np.inf)
    for primitive in primitives:
        t = np.minimum(t, primitive.intersect(origins, directions))
    depth = np.where(np.isfinite(t), t, 0.0).reshape(camera.height, camera.width)
    return depth.astype(np.float32)
