"""Thin body parts beside the KUKA iiwa, rendered and measured by code the project did not write (SPEC section 11a's
judge with thin limbs), and the judge itself.

The scene. pybullet's iiwa (``pybullet_data/kuka_iiwa``, its collision meshes drawn as its visuals, as in
``test_judge_self_filter``) stands with its base at the world origin in the closed room of ``pybullet_scenes``; body
parts are primitives of ``pybullet_scenes`` (boxes drawn exactly, capsules as meshes that contain them):

- a finger: a capsule of radius 7.5 mm (15 mm thick), 80 mm long overall;
- a hand: a flat box 25 x 80 x 100 mm;
- a forearm: a capsule of radius 22.5 mm (45 mm thick), 250 mm long overall.

A part is placed "1 cm from a link" by bisection on coal's exact distance between the part and that link's
collision mesh (the STL file read by trimesh, placed where pybullet's forward kinematics puts the link): the judge's
geometry does not come from depthguard. TinyRenderer draws the depth images (``pybullet_scenes.render_depth``); coal
and pybullet's getClosestPoints give the true distances (``PybulletScene.measure``).

The judge (:func:`violations`). Each query point P gets

- ``truth``: its exact distance to every obstacle (body parts, known solids, the room);
- ``outside_shell``: its distance to the part of the obstacles outside the self-filter's shell S (below);
- ``outside_stated``: its distance to the part outside S and outside every region a concession of the monitor is
  stated to hide (the robot zone: within ``robot_zone`` of the robot's padded capsules; a known solid: within its
  band, ``self_filter_tolerance`` + 2 m(d) of the box);
- ``tolerance``: 2.5 pixel footprints at the depth, in the farthest camera, of the obstacle point nearest P, + 1 mm
  (``test_judge_self_filter``'s and ``test_judge_fusion``'s pixel discretisation and float32 depth buffer).

The shell S, stated independently of depthguard's code. SPEC section 7 takes a measurement within the
self-filter's tolerance (+ the noise margin: once for the acceptance, once for the object's own noise) in front of
the robot's rendered, padded geometry for the robot, with one pixel of slack round its silhouette (the 3 x 3
neighbourhood). depthguard's padded geometry contains every link's convex hull grown by ``robot.padding``; its hull
of 64 planes exceeds that by at most ``HULL_EXCESS``. So every point the self-filter can take for the robot lies
within

    s = padding + HULL_EXCESS + RAY_SLANT * (self_filter_tolerance + 2 m) + SILHOUETTE_PIXELS footprints

of some link's convex hull (RAY_SLANT: a depth difference along a ray of the 320 x 240 cameras below is at most this
factor longer in space). S is that set, computed with scipy's convex hulls of the STL vertices (a plane-distance lower
bound, refined with coal's exact point-to-hull distance where it matters). The part of an obstacle outside S is
sampled on a grid (:data:`SAMPLE`), so ``outside_*`` may be larger than the exact distance by half a sample
diagonal: lenient, never a false accusation.

The rules, for a :class:`depthguard.DistanceResult` (distance, blind_distance, concession_distance, flags):

1. ``min(distance, blind_distance, concession_distance) <= outside_shell + tolerance``: the answer without
   concessions (SPEC 11a) never hides more than the self-filter's shell;
2. ``min(distance, blind_distance) <= outside_stated + tolerance``: a concession hides an object only inside its
   stated region, flag or not;
3. where ``distance > outside_shell + tolerance``, a flag says why and the distance it names covers the excess:
   ``robot_blind_spot`` with ``blind_distance``, or the concession's own flag with ``concession_distance``.

For SSM's :class:`depthguard.DetectableResult`: ``distance <= core + tolerance`` where ``core`` is the distance to
the balls of diameter ``effective_capability`` that fit inside a body part outside every stated region (for a
capsule of radius r >= e/2: the capsule of radius e/2 on the same axis; :func:`core_distance`).
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass, field

import numpy as np
import pybullet as p
import pybullet_data
import trimesh
from scipy.spatial import ConvexHull

import coal
import depthguard as dg
import pybullet_scenes as ps
from depthguard.transforms import look_at

# ----------------------------------------------------------------------------------------------------- the limbs

#: Finger: capsule radius and overall length (metres).
FINGER = (0.0075, 0.080)
#: Hand: half extents of the flat box (thickness along its local z), metres.
HAND = (0.040, 0.050, 0.0125)
#: Forearm: capsule radius and overall length (metres).
FOREARM = (0.0225, 0.250)

#: Gap between a body part and the link it lies along, metres (coal, to the link's collision mesh).
GAP = 0.01

#: The cameras: 320 x 240, focal length (pixels) and depth range (metres). Noise-free images.
WIDTH, HEIGHT, FOCAL = 320, 240, 400.0
DEPTH_RANGE = (0.2, 8.0)

#: Judge's allowances for the shell S (module docstring): the 64-plane hull's excess over the padded convex hull,
#: metres; how much longer than a depth difference along a ray it may be in space (the cameras' widest ray: sqrt(1 +
#: (160^2 + 120^2) / 400^2) = 1.08); pixels of slack round the robot's silhouette.
HULL_EXCESS = 0.004
RAY_SLANT = 1.08
SILHOUETTE_PIXELS = 2.0

#: Grid spacing of the samples of the body parts' volumes and the room's surfaces near the robot, metres.
SAMPLE = 0.0025
ROOM_SAMPLE = 0.01

#: Tolerance: pixel footprints at the farthest camera, and metres for the float32 depth buffer.
FOOTPRINTS = 2.5
BUFFER = 1e-3

#: The judge gives the library the benefit of 1 um on ties.
EPS = 1e-6


def capsule(radius_length, centre, axis) -> ps.Primitive:
    """A capsule primitive of (radius, overall length) along ``axis`` (world, unit), centred at ``centre``."""
    radius, length = radius_length
    return ps.Primitive("capsule", (radius, length - 2.0 * radius), ps.pose(_frame(axis), centre))


def hand(centre, normal, along) -> ps.Primitive:
    """The hand: thickness along ``normal``, its 100 mm length along ``along`` (orthogonalised)."""
    z = np.asarray(normal, float) / np.linalg.norm(normal)
    y = np.asarray(along, float) - z * np.dot(along, z)
    y /= np.linalg.norm(y)
    return ps.Primitive("box", HAND, ps.pose(np.stack([np.cross(y, z), y, z], 1), centre))


def _frame(axis) -> np.ndarray:
    z = np.asarray(axis, float) / np.linalg.norm(axis)
    x = np.cross(z, [0.0, 0.0, 1.0] if abs(z[2]) < 0.9 else [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], 1)


def moved(prim: ps.Primitive, offset) -> ps.Primitive:
    T = prim.T_world_obstacle.copy()
    T[:3, 3] += offset
    return ps.Primitive(prim.kind, prim.size, T)


# ----------------------------------------------------------------------------------------------- the robot world

class IiwaWorld:
    """pybullet's iiwa with its collision meshes as visuals, in one DIRECT client, and its links' geometry for the
    judge: the STL meshes placed by pybullet's kinematics (coal BVH models, for placing parts) and their convex hulls
    (scipy, for the shell)."""

    def __init__(self, folder):
        source = os.path.join(pybullet_data.getDataPath(), "kuka_iiwa")
        shutil.copytree(os.path.join(source, "meshes"), os.path.join(folder, "meshes"))
        with open(os.path.join(source, "model.urdf")) as f:
            text = f.read().replace(".obj", ".stl")
        urdf = os.path.join(folder, "model.urdf")
        with open(urdf, "w") as f:
            f.write(text)
        self.client = p.connect(p.DIRECT)
        self.body = p.loadURDF(urdf, useFixedBase=True, physicsClientId=self.client)
        self.meshes = [trimesh.load(os.path.join(folder, "meshes", f"link_{j}.stl")) for j in range(8)]
        self.q = None

    def close(self):
        p.disconnect(self.client)

    def set_joints(self, q) -> None:
        self.q = np.asarray(q, dtype=np.float64)
        for j in range(7):
            p.resetJointState(self.body, j, float(q[j]), physicsClientId=self.client)
        self.links = []  # per link: (world vertices, coal BVH in world frame, scipy hull equations, coal convex hull)
        for j, mesh in enumerate(self.meshes):
            T = self._link_pose(j)
            V = mesh.vertices @ T[:3, :3].T + T[:3, 3]
            bvh = coal.BVHModelOBBRSS()
            bvh.beginModel(len(mesh.faces), len(V))
            bvh.addVertices(np.ascontiguousarray(V, dtype=np.float64))
            bvh.addTriangles(np.asarray(mesh.faces, dtype=np.int64))
            bvh.endModel()
            hull = ConvexHull(V)
            vec = coal.StdVec_Vec3s()
            for x in V[hull.vertices]:
                vec.append(np.asarray(x, dtype=np.float64))
            self.links.append((V, bvh, hull.equations.copy(), coal.Convex.convexHull(vec, False, "")))

    def _link_pose(self, j) -> np.ndarray:
        """(4, 4) pose of URDF link ``j`` (0: the base) by pybullet's forward kinematics."""
        T = np.eye(4)
        if j == 0:
            com_pos, com_orn = p.getBasePositionAndOrientation(self.body, physicsClientId=self.client)
            local_pos, local_orn = p.getDynamicsInfo(self.body, -1, physicsClientId=self.client)[3:5]
            inv_pos, inv_orn = p.invertTransform(local_pos, local_orn)
            pos, orn = p.multiplyTransforms(com_pos, com_orn, inv_pos, inv_orn)
        else:
            state = p.getLinkState(self.body, j - 1, computeForwardKinematics=True, physicsClientId=self.client)
            pos, orn = state[4], state[5]
        T[:3, :3] = np.array(p.getMatrixFromQuaternion(orn)).reshape(3, 3)
        T[:3, 3] = pos
        return T

    def primitive_to_link(self, prim: ps.Primitive, link: int) -> float:
        """coal's exact distance from a primitive to link ``link``'s collision mesh, metres (0 when they touch)."""
        geometry = (coal.Box(*(2.0 * np.asarray(prim.size))) if prim.kind == "box"
                    else coal.Capsule(float(prim.size[0]), float(prim.size[1])))
        T = prim.T_world_obstacle
        result = coal.DistanceResult()
        d = coal.distance(geometry, coal.Transform3s(T[:3, :3].copy(), T[:3, 3].copy()), self.links[link][1],
                          coal.Transform3s(), coal.DistanceRequest(), result)
        return max(float(d), 0.0)

    def place(self, prim: ps.Primitive, direction, links, gap: float = GAP) -> ps.Primitive:
        """``prim`` moved along ``direction`` (unit) until its nearest link of ``links`` is ``gap`` from it (by
        bisection on coal's distance; the primitive must start clear of them and approach them as it moves back)."""
        direction = np.asarray(direction, float) / np.linalg.norm(direction)
        near = lambda t: min(self.primitive_to_link(moved(prim, t * direction), k) for k in links)  # noqa: E731
        lo, hi = -0.5, 0.5
        assert near(hi) > gap, "the part must start clear of the links"
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            if near(mid) > gap:
                hi = mid
            else:
                lo = mid
        placed = moved(prim, hi * direction)
        assert abs(near(hi) - gap) < 1e-5
        return placed

    def hull_distance(self, points) -> np.ndarray:
        """(n,) metres: each point's distance to the nearest link's convex hull (0 inside), a lower bound by the
        hulls' face planes, made exact (coal) where it is below ``HULL_EXACT_BELOW``."""
        points = np.asarray(points, dtype=np.float64)
        planes = np.full(len(points), np.inf)
        for _, _, equations, _ in self.links:
            planes = np.minimum(planes, (points @ equations[:, :3].T + equations[:, 3]).max(axis=1))
        out = np.maximum(planes, 0.0)
        refine = np.flatnonzero((planes > 0.0) & (planes < HULL_EXACT_BELOW))
        point = coal.Sphere(0.0)
        request = coal.DistanceRequest()
        for i in refine:
            at = coal.Transform3s(np.eye(3), points[i].copy())
            best = np.inf
            for _, _, equations, convex in self.links:
                result = coal.DistanceResult()
                best = min(best, max(coal.distance(convex, coal.Transform3s(), point, at, request, result), 0.0))
            out[i] = max(out[i], best)  # both are lower bounds of nothing less than the exact distance
        return out


#: Points whose hull-plane distance is below this (metres) get coal's exact distance to the hulls.
HULL_EXACT_BELOW = 0.12


# ---------------------------------------------------------------------------------------------------- samples

def volume_samples(prim: ps.Primitive, spacing: float = SAMPLE) -> np.ndarray:
    """(n, 3) world points on a grid of ``spacing`` filling the primitive (its surface included: the grid's outer
    layer is pushed onto the boundary)."""
    if prim.kind == "box":
        h = np.asarray(prim.size, dtype=np.float64)
        axes = [np.linspace(-a, a, max(2, int(np.ceil(2 * a / spacing)) + 1)) for a in h]
        local = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    elif prim.kind == "capsule":
        radius, core = float(prim.size[0]), float(prim.size[1])
        n = max(2, int(np.ceil(2 * (radius + 0.5 * core) / spacing)) + 1)
        m = max(2, int(np.ceil(2 * radius / spacing)) + 1)
        zs = np.linspace(-radius - 0.5 * core, radius + 0.5 * core, n)
        xs = np.linspace(-radius, radius, m)
        X, Y, Z = np.meshgrid(xs, xs, zs, indexing="ij")
        local = np.stack([X, Y, Z], -1).reshape(-1, 3)
        axial = np.clip(local[:, 2], -0.5 * core, 0.5 * core)
        off = local - np.stack([np.zeros_like(axial), np.zeros_like(axial), axial], -1)
        r = np.linalg.norm(off, axis=1)
        outside = r > radius
        local[outside] = np.stack([np.zeros(outside.sum()), np.zeros(outside.sum()), axial[outside]], -1) + \
            off[outside] * (radius / r[outside])[:, None]
    else:
        raise ValueError(prim.kind)
    T = prim.T_world_obstacle
    return local @ T[:3, :3].T + T[:3, 3]


def room_samples(lo, hi, spacing: float = ROOM_SAMPLE) -> np.ndarray:
    """(n, 3) points on the room's floor (z = 0) in the square [lo, hi] (x, y): the floor's part near the robot,
    where the self-filter's shell may reach."""
    xs = np.arange(lo[0], hi[0] + spacing / 2, spacing)
    ys = np.arange(lo[1], hi[1] + spacing / 2, spacing)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    return np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], -1)
