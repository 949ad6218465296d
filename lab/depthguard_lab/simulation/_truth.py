"""Ground truth of a simulated frame: exact distances from the robot's control points to every obstacle, and whether
the robot touches anything.

- Control point distances are analytic: each obstacle is a union of :mod:`depthguard.scenes` primitives (capsules,
  spheres, boxes), whose ``distance`` is exact (0 inside).
- Contact is decided on the robot's own collision meshes (the URDF's, as :attr:`RobotModel.collision_meshes`),
  not on capsules around them: ``clearance`` is the smallest distance between any link mesh (a coal BVH of its
  triangles) and any obstacle primitive (coal's exact shapes), computed by coal (``import coal``, installed with
  pinocchio); the robot touches something when it is <= 0. The link capsules (which contain the meshes) give a lower
  bound per pair, so only pairs that can beat the best clearance so far are measured on the meshes. Caveat: the
  meshes are surfaces, so a primitive lying wholly inside a link without crossing its triangles would not count
  (no body part is small enough for that).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import coal
import numpy as np

from depthguard.scenes import Box, Capsule, Sphere
from depthguard.transforms import rotation_with_z


@dataclass(frozen=True, eq=False)
class GroundTruth:
    """Exact geometry of one frame.

    Attributes:
        control_points: (m,) control point names, the robot's order.
        obstacles: (n,) obstacle names (people, carried objects, static obstacles), the workcell's order.
        distances: (m, n) float64 metres: from each control point to each obstacle (the union of its primitives;
            0 inside); inf for an obstacle not in the scene at this time.
        distance: (m,) float64 metres: the smallest of each row (inf when there is no obstacle).
        nearest: (m,) name of the nearest obstacle per control point ("" when there is none).
        nearest_part: (m,) "obstacle/part" of the nearest primitive (a person's body part, e.g. "worker/hand_right";
            an object's own name for single-primitive objects).
        clearance: metres, smallest distance between the robot's link collision meshes and any obstacle primitive
            (coal); negative when they intersect; inf when there is no obstacle.
        clearance_pair: (link, "obstacle/part") of that smallest distance, or None.
        touching: whether the robot touches an obstacle (clearance <= 0).
    """

    control_points: tuple[str, ...]
    obstacles: tuple[str, ...]
    distances: np.ndarray
    distance: np.ndarray
    nearest: tuple[str, ...]
    nearest_part: tuple[str, ...]
    clearance: float
    clearance_pair: tuple[str, str] | None
    touching: bool


def coal_shape(primitive) -> tuple[object, "coal.Transform3s"]:
    """A coal collision shape and its world transform for a :mod:`depthguard.scenes` primitive (metres)."""
    if isinstance(primitive, Sphere):
        return coal.Sphere(float(primitive.radius)), coal.Transform3s(np.eye(3), np.asarray(primitive.center, float))
    if isinstance(primitive, Capsule):
        p0, p1 = np.asarray(primitive.p0, float), np.asarray(primitive.p1, float)
        length = float(np.linalg.norm(p1 - p0))
        if length < 1e-12:
            return coal.Sphere(float(primitive.radius)), coal.Transform3s(np.eye(3), p0)
        return (coal.Capsule(float(primitive.radius), length),
                coal.Transform3s(rotation_with_z((p1 - p0) / length), (p0 + p1) / 2.0))
    if isinstance(primitive, Box):
        size = 2.0 * np.asarray(primitive.half_extents, float)
        return (coal.Box(*size), coal.Transform3s(np.asarray(primitive.R_world_box, float),
                                                  np.asarray(primitive.center, float)))
    raise TypeError(f"not a depthguard.scenes primitive: {type(primitive).__name__}")


class TruthComputer:
    """Computes :class:`GroundTruth` for a robot; holds the coal BVH of each link's collision mesh."""

    def __init__(self, robot):
        self.robot = robot
        self._bvh = {}
        for link, mesh in robot.collision_meshes.items():
            bvh = coal.BVHModelOBBRSS()
            bvh.beginModel(len(mesh.faces), len(mesh.vertices))
            bvh.addVertices(np.asarray(mesh.vertices, dtype=np.float64))
            bvh.addTriangles(np.asarray(mesh.faces, dtype=np.int64))
            bvh.endModel()
            self._bvh[link] = bvh
        self._request = coal.DistanceRequest()

    def __call__(self, q: np.ndarray, obstacles: dict, part_names: dict) -> GroundTruth:
        """Ground truth at joint configuration ``q`` ((n,) radians) for ``obstacles`` (name -> list of primitives,
        world frame; an empty list: not in the scene) whose primitives are named by ``part_names`` (name ->
        tuple of part names)."""
        robot = self.robot
        points = robot.control_point_positions(q)
        names = tuple(obstacles)
        m = len(points)
        distances = np.full((m, len(names)), np.inf)
        best_part = np.full(m, np.inf)
        nearest_part = [""] * m
        flat = []  # (label, primitive)
        for j, name in enumerate(names):
            for part, primitive in zip(part_names[name], obstacles[name]):
                d = primitive.distance(points)
                distances[:, j] = np.minimum(distances[:, j], d)
                label = name if len(part_names[name]) == 1 else f"{name}/{part}"
                better = d < best_part
                best_part[better] = d[better]
                for i in np.flatnonzero(better):
                    nearest_part[i] = label
                flat.append((label, primitive))
        distance = distances.min(axis=1) if names else np.full(m, np.inf)
        nearest = tuple(names[j] if np.isfinite(distance[i]) else ""
                        for i, j in enumerate(distances.argmin(axis=1) if names else np.zeros(m, int)))
        clearance, pair = self._clearance(q, flat)
        return GroundTruth(
            control_points=robot.control_point_names,
            obstacles=names,
            distances=distances,
            distance=distance,
            nearest=nearest,
            nearest_part=tuple(nearest_part),
            clearance=clearance,
            clearance_pair=pair,
            touching=bool(clearance <= 0.0),
        )

    def _clearance(self, q, flat) -> tuple[float, tuple[str, str] | None]:
        if not flat:
            return math.inf, None
        robot = self.robot
        poses = robot.link_poses(q)
        capsules = robot.capsules_world(q)
        shapes = [coal_shape(primitive) for _, primitive in flat]
        candidates = []  # (lower bound, link, index into flat)
        for capsule, link_capsule in zip(capsules, robot.capsules):
            cap_shape, cap_pose = coal_shape(capsule)
            for k, (shape, pose) in enumerate(shapes):
                result = coal.DistanceResult()
                bound = coal.distance(cap_shape, cap_pose, shape, pose, self._request, result)
                candidates.append((bound, link_capsule.link, k))
        candidates.sort(key=lambda c: c[0])
        best, pair = math.inf, None
        for bound, link, k in candidates:
            if bound >= best:
                break
            T = poses[link]
            result = coal.DistanceResult()
            d = coal.distance(self._bvh[link], coal.Transform3s(T[:3, :3], T[:3, 3]), shapes[k][0], shapes[k][1],
                              self._request, result)
            if d < best:
                best, pair = float(d), (link, flat[k][0])
        return best, pair
