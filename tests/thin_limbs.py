"""Thin body parts beside the KUKA iiwa, rendered and measured by code the project did not write (design §11a's
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
  stated to hide (the robot zone, fused answers only: within ``robot_zone`` of the robot's padded capsules,
  ``robot.capsules_world``; a known solid: the box and everything within its band, ``self_filter_tolerance`` +
  2 m(d) of it, as ``StaticSolids`` states it);
- ``tolerance``: 2.5 pixel footprints + 1 mm (``test_judge_self_filter``'s and ``test_judge_fusion``'s pixel
  discretisation and float32 depth buffer), the footprint taken in the answering rig's farthest camera at P's depth
  plus the judged distance (capped at rho): no farther than the obstacle point judged.

The shell S, restated from depthguard's documentation, not computed by its code. The padded geometry the
self-filter renders (``self_filter="hulls"``, the default; ``self_filter.padded_hull``) is, for each link, the
intersection of the half-spaces n . x <= max_v n . v + padding over 64 unit normals n of a Fibonacci lattice (v: the
link's mesh vertices, link frame); the judge builds the same half-spaces from the STL files and pybullet's link
poses. design §7 takes a measurement within the self-filter's tolerance (+ the noise margin: once for the
acceptance, once for the object's own noise) in front of that geometry for the robot, looking one pixel round each
pixel (its 3 x 3 neighbourhood); the depth grid also takes the same depth behind the geometry's far side for the
robot. A point X on camera ray r (optical z = 1) within d = tolerance + 2 m of depth in front of or behind a surface
point B seen by a pixel at most 1.5 pixels off X's is at most d |r| + 2.12 footprints from B. So every point the
self-filter can take for the robot satisfies, for some link,

    max over the 64 planes of (n . X - h)  <=  (self_filter_tolerance + 2 m(z)) |r| + SILHOUETTE_PIXELS footprints

(the left side is a lower bound of X's distance to the padded link, exact on its faces: S is a superset of what the
self-filter can hide, and judging against it is lenient). The parts of the obstacles outside S are sampled on a grid
(:data:`SAMPLE`), so ``outside_*`` may exceed the exact distance by half a sample diagonal: lenient too, never a
false accusation.

The rules, for a :class:`depthguard.DistanceResult` (distance, blind_distance, concession_distance, flags):

1. ``min(distance, blind_distance, concession_distance) <= outside_shell + tolerance``: the answer without
   concessions (design §11a) never hides more than the self-filter's shell;
2. ``min(distance, blind_distance) <= outside_stated + tolerance``: a concession hides an object only inside its
   stated region, flag or not;
3. where ``distance > outside_shell + tolerance``, a flag says why and the distance it names covers the excess:
   ``robot_blind_spot`` with ``blind_distance``, or a concession's flag with ``concession_distance``;
4. (fused answers with a robot zone) where the zone, computed here from ``robot.capsules_world``, is nearer than
   ``distance``, the answer is flagged ``robot_zone`` and ``concession_distance`` is at most the zone's distance.

Distances are compared capped at rho (the library reports inf beyond it).

For SSM's :class:`depthguard.DetectableResult` (:func:`detectable_violations`): ``distance <= core + tolerance``,
where ``core`` is the distance to the balls of diameter ``effective_capability`` that fit inside a body part (for a
capsule of radius r >= e/2: the capsule of radius e/2 on its axis; :func:`core_distance`); and ``detection_opening``
on every distance above 0.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass, field

import numpy as np
import pybullet as p
import pybullet_data
import trimesh

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

#: The cameras: 640 x 480 with a Kinect's focal length (pixels), depth range (metres). Noise-free images.
WIDTH, HEIGHT, FOCAL = 640, 480, 525.0
DEPTH_RANGE = (0.2, 8.0)

#: The shell S (module docstring): the padded geometry's half-spaces (their count, as depthguard's configuration
#: documents it), and the pixels of slack round the robot's silhouette.
HULL_PLANES = 64
SILHOUETTE_PIXELS = 2.2

#: Grid spacing of the samples of the body parts' volumes and the room's surfaces near the robot, metres.
SAMPLE = 0.0025
ROOM_SAMPLE = 0.01

#: Tolerance: pixel footprints at the farthest camera, and metres for the float32 depth buffer.
FOOTPRINTS = 2.5
BUFFER = 1e-3

#: The judge gives the library the benefit of 1 um on ties.
EPS = 1e-6

#: The robot model's padding (metres), the self-filter's default tolerance: restated here, not read from the library
#: (test_judge_thin_limbs checks that the library's defaults are these).
ROBOT_PADDING = 0.02
SELF_FILTER_TOLERANCE = 0.02


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
    judge: the STL meshes placed by pybullet's kinematics (coal BVH models, for placing parts) and the padded links'
    half-spaces (for the shell)."""

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
        self.links = []  # per link: (coal BVH of its mesh, world frame; (64, 3) normals and (64,) offsets, world)
        normals = fibonacci_sphere(HULL_PLANES)
        for j, mesh in enumerate(self.meshes):
            T = self._link_pose(j)
            V = mesh.vertices @ T[:3, :3].T + T[:3, 3]
            bvh = coal.BVHModelOBBRSS()
            bvh.beginModel(len(mesh.faces), len(V))
            bvh.addVertices(np.ascontiguousarray(V, dtype=np.float64))
            bvh.addTriangles(np.asarray(mesh.faces, dtype=np.int64))
            bvh.endModel()
            support = (np.asarray(mesh.vertices) @ normals.T).max(axis=0) + ROBOT_PADDING  # link frame
            world_normals = normals @ T[:3, :3].T
            self.links.append((bvh, world_normals, support + world_normals @ T[:3, 3]))

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
        d = coal.distance(geometry, coal.Transform3s(T[:3, :3].copy(), T[:3, 3].copy()), self.links[link][0],
                          coal.Transform3s(), coal.DistanceRequest(), result)
        return max(float(d), 0.0)

    def place(self, prim: ps.Primitive, direction, links, gap: float = GAP) -> ps.Primitive:
        """``prim``, which starts overlapping a link of ``links``, moved out along ``direction`` until the nearest of
        those links' collision meshes is ``gap`` from it (bisection on coal's exact distance)."""
        direction = np.asarray(direction, float) / np.linalg.norm(direction)
        near = lambda t: min(self.primitive_to_link(moved(prim, t * direction), k) for k in links)  # noqa: E731
        lo, hi = 0.0, 0.5
        assert near(lo) < gap < near(hi), "the part must start on the links and end clear of them"
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            if near(mid) > gap:
                hi = mid
            else:
                lo = mid
        placed = moved(prim, hi * direction)
        assert abs(near(hi) - gap) < 1e-5
        return placed

    def padded_distance(self, points) -> np.ndarray:
        """(n,) metres: a lower bound of each point's distance to the nearest padded link (exact where its nearest
        point lies on a face; <= 0 inside): the largest of n . X - h over the link's half-spaces, least over links."""
        points = np.asarray(points, dtype=np.float64)
        out = np.full(len(points), np.inf)
        for _, normals, offsets in self.links:
            out = np.minimum(out, (points @ normals.T - offsets).max(axis=1))
        return out


def fibonacci_sphere(n: int) -> np.ndarray:
    """(n, 3) unit vectors of a Fibonacci lattice: z = 1 - (2 i + 1) / n, longitude i times the golden angle."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z * z)
    phi = np.pi * (1.0 + 5.0 ** 0.5) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


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


def box_surface_samples(prim: ps.Primitive, spacing: float) -> np.ndarray:
    """(n, 3) world points on the faces of a box primitive, on grids of at most ``spacing``."""
    h = np.asarray(prim.size, dtype=np.float64)
    out = []
    for axis in range(3):
        a, b = [k for k in range(3) if k != axis]
        ua = np.linspace(-h[a], h[a], max(2, int(np.ceil(2 * h[a] / spacing)) + 1))
        ub = np.linspace(-h[b], h[b], max(2, int(np.ceil(2 * h[b] / spacing)) + 1))
        A, B = np.meshgrid(ua, ub, indexing="ij")
        for sign in (-1.0, 1.0):
            face = np.zeros((A.size, 3))
            face[:, a], face[:, b], face[:, axis] = A.ravel(), B.ravel(), sign * h[axis]
            out.append(face)
    local = np.concatenate(out)
    T = prim.T_world_obstacle
    return local @ T[:3, :3].T + T[:3, 3]


# ------------------------------------------------------------------------------------------------------- cameras

def camera(name: str, eye, target, up=(0.0, 0.0, 1.0)) -> dg.PinholeCamera:
    """A noise-free WIDTH x HEIGHT camera at ``eye`` looking at ``target`` (world, metres), ``up`` upwards."""
    return dg.PinholeCamera(name, WIDTH, HEIGHT, FOCAL, FOCAL, (WIDTH - 1) / 2.0, (HEIGHT - 1) / 2.0,
                            look_at(np.asarray(eye, float), np.asarray(target, float), up=up),
                            depth_range=DEPTH_RANGE, noise=dg.NoiseModel.none())


def with_noise(rig: dg.Rig, noise) -> dg.Rig:
    """The same rig with every camera's noise model replaced (the images stay exact; only the margins change)."""
    cams = {n: dg.PinholeCamera(n, c.width, c.height, c.fx, c.fy, c.cx, c.cy, c.T_world_camera,
                                depth_range=c.depth_range, noise=noise) for n, c in rig.cameras.items()}
    return dg.Rig(cams, principal=rig.principal, workspace=rig.workspace)


# ------------------------------------------------------------------------------------------------------- a case

@dataclass
class Case:
    """One scene of thin limbs beside the robot, rendered and measured.

    ``limbs``: name -> primitive (the body parts); ``solids``: boxes that are known static solids when a monitor is
    given them (obstacles otherwise, like any other); ``points``: (n, 3) query points, the robot's control points
    first (``n_control`` of them); ``depths``: camera name -> rendered optical z (inf: nothing drawn);
    ``truth``: exact distances to every obstacle (coal and pybullet); ``samples``: (m, 3) points filling the limbs
    and covering the floor near the query points, ``owner`` (m,) which limb ("floor" for the floor), ``padded``
    (m,) their distances to the padded links (:meth:`IiwaWorld.padded_distance`); ``solid_distance``: (n,) exact
    distance to the known solids (inf: none), which lie wholly outside every shell (checked)."""

    label: str
    q: np.ndarray
    limbs: dict
    solids: list
    rig: dg.Rig
    points: np.ndarray
    n_control: int
    depths: dict = field(default_factory=dict)
    segmentation: dict = field(default_factory=dict)
    truth: object = None
    samples: np.ndarray = None
    owner: np.ndarray = None
    padded: np.ndarray = None
    solid_distance: np.ndarray = None
    pixels: dict = field(default_factory=dict)  # (camera, limb) -> pixels showing it

    def frames(self, time: float, rig: dg.Rig | None = None) -> dict:
        """Fresh float32 frames (0: nothing drawn), stamped ``time``, of every camera of ``rig`` (default: the
        case's; its cameras must be the case's, their noise models aside)."""
        rig = self.rig if rig is None else rig
        return {n: dg.depth_image(np.where(np.isfinite(self.depths[n]), self.depths[n], 0.0).astype(np.float32),
                                  cam, timestamp=time) for n, cam in rig.cameras.items()}

    @property
    def boxes(self) -> list:
        """The known solids as depthguard.scenes.Box (for DistanceMonitor(static=...))."""
        from depthguard.scenes import Box

        return [Box(tuple(s.centre), tuple(s.size), s.T_world_obstacle[:3, :3].copy()) for s in self.solids]


def build(world: IiwaWorld, case: Case, rho: float) -> Case:
    """Render ``case`` with ``world``'s robot at ``case.q``, measure its truth, sample its limbs and the floor."""
    world.set_joints(case.q)
    room = ps.room()
    scene = ps.PybulletScene(world.client, room + list(case.solids) + list(case.limbs.values()))
    try:
        for name, cam in case.rig.cameras.items():
            case.depths[name], case.segmentation[name] = ps.render_depth(world.client, cam)
            lo, hi = cam.depth_range
            assert np.all((case.depths[name] > lo) & (case.depths[name] < hi)), f"{case.label}: {name} sees too far"
            for k, limb in enumerate(case.limbs):
                case.pixels[name, limb] = int(np.count_nonzero(
                    case.segmentation[name] == scene.bodies[len(room) + len(case.solids) + k]))
        case.truth = scene.measure(case.points, 1.0)
    finally:
        scene.remove()
    # The walls and the ceiling are farther than rho from every query point: only the floor, the solids and the
    # limbs can matter.
    assert np.all(np.abs(case.points[:, :2]) < ps.ROOM_HALF - rho - 0.05)
    assert np.all(case.points[:, 2] < ps.ROOM_HEIGHT - rho - 0.05)
    chunks, owners = [], []
    for name, limb in case.limbs.items():
        x = volume_samples(limb)
        chunks.append(x)
        owners += [name] * len(x)
    lo = case.points[:, :2].min(axis=0) - rho
    hi = case.points[:, :2].max(axis=0) + rho
    floor = room_samples(lo, hi, ROOM_SAMPLE)
    near = np.min(np.linalg.norm(floor[None] - case.points[:, None], axis=2), axis=0) < rho + 0.02
    chunks.append(floor[near])
    owners += ["floor"] * int(near.sum())
    case.samples = np.concatenate(chunks)
    case.owner = np.array(owners)
    case.padded = world.padded_distance(case.samples)
    case.solid_distance = np.full(len(case.points), np.inf)
    for solid in case.solids:
        h = np.asarray(solid.size)
        local = (case.points - solid.centre) @ solid.T_world_obstacle[:3, :3]
        case.solid_distance = np.minimum(case.solid_distance,
                                         np.linalg.norm(np.maximum(np.abs(local) - h, 0.0), axis=1))
        corners = box_surface_samples(solid, 0.02)
        assert world.padded_distance(corners).min() > 0.15, "a known solid must lie clear of every shell"
    return case


# --------------------------------------------------------------------------------------------- stated regions

def shell_thickness(cam: dg.PinholeCamera, samples, tolerance: float) -> np.ndarray:
    """(m,) metres: how far beyond the padded links camera ``cam``'s self-filter may take a point for the robot
    (module docstring): (tolerance + 2 m(z)) |ray| + SILHOUETTE_PIXELS footprints; -inf for points behind the
    camera."""
    X = cam.world_to_camera(samples)
    z = X[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        ray = np.sqrt(1.0 + (X[:, 0] / z) ** 2 + (X[:, 1] / z) ** 2)
    margin = cam.noise.margin(np.maximum(z, 0.0))
    out = (tolerance + 2.0 * margin) * ray + SILHOUETTE_PIXELS * (z + tolerance + 2.0 * margin) / min(cam.fx, cam.fy)
    return np.where(z > 0, out, -np.inf)


def in_shell(case: Case, cameras, tolerance: float = SELF_FILTER_TOLERANCE) -> np.ndarray:
    """(m,) bool: samples inside the self-filter shell of any of ``cameras`` (PinholeCamera objects: their noise
    models set the margins)."""
    out = np.zeros(len(case.samples), dtype=bool)
    for cam in cameras:
        out |= case.padded <= shell_thickness(cam, case.samples, tolerance)
    return out


def in_zone(case: Case, robot, zone: float) -> np.ndarray:
    """(m,) bool: samples within ``zone`` of the robot's padded capsules at ``case.q`` (0: none)."""
    if zone <= 0.0:
        return np.zeros(len(case.samples), dtype=bool)
    return zone_gap(robot, case.q, case.samples, zone) <= 0.0


def zone_gap(robot, q, points, zone: float) -> np.ndarray:
    """(n,) metres: distance from each point to the robot's padded capsules grown by ``zone`` (0 inside)."""
    best = np.full(len(points), np.inf)
    for c in robot.capsules_world(q):
        a, b = np.asarray(c.p0, dtype=np.float64), np.asarray(c.p1, dtype=np.float64)
        ab = b - a
        t = np.clip(((points - a) @ ab) / max(float(ab @ ab), 1e-300), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(points - (a + t[:, None] * ab), axis=1) - c.radius - zone)
    return np.maximum(best, 0.0)


def in_band(case: Case, band: float) -> np.ndarray:
    """(m,) bool: samples within ``band`` of a known solid (the solid's own inside included)."""
    out = np.zeros(len(case.samples), dtype=bool)
    for solid in case.solids:
        local = (case.samples - solid.centre) @ solid.T_world_obstacle[:3, :3]
        out |= np.linalg.norm(np.maximum(np.abs(local) - np.asarray(solid.size), 0.0), axis=1) <= band
    return out


def stated_band(case: Case, cameras, tolerance: float = SELF_FILTER_TOLERANCE) -> float:
    """Metres: the known solids' band as StaticSolids states it, tolerance + 2 m(d), at the largest depth at which one
    of ``cameras`` sees a solid's corner (m grows with depth). The sliver of a slanted pixel's frustum it also counts
    free lies within a footprint of the surface, inside the band."""
    band = 0.0
    for cam in cameras:
        for solid in case.solids:
            z = cam.world_to_camera(box_surface_samples(solid, 1.0))[:, 2].max()
            band = max(band, tolerance + 2.0 * float(cam.noise.margin(z)))
    return band


def outside(case: Case, hidden: np.ndarray, points=None) -> np.ndarray:
    """(n,) metres: each query point's (default ``case.points``) distance to the nearest sample of the limbs and the
    floor not in ``hidden`` ((m,) bool); inf: none. The known solids are not sampled: :func:`expect` adds them."""
    points = case.points if points is None else points
    keep = case.samples[~hidden]
    out = np.full(len(points), np.inf)
    for start in range(0, len(keep), 20000):
        chunk = keep[start:start + 20000]
        out = np.minimum(out, np.min(np.linalg.norm(points[:, None] - chunk[None], axis=2), axis=1))
    return out


# ----------------------------------------------------------------------------------------------------- the judge

@dataclass
class Expectation:
    """What the judge holds one result to (module docstring): per query point, metres.

    ``outside_shell``: distance to the obstacles outside the self-filter's shell; ``outside_stated``: outside the
    shell and every stated concession region; ``tolerance``; ``zone_gap``: distance to the robot zone (None: the
    zone does not apply to this result)."""

    outside_shell: np.ndarray
    outside_stated: np.ndarray
    tolerance: np.ndarray
    zone_gap: np.ndarray | None = None


def expect(case: Case, robot, rig: dg.Rig, rho: float, zone: float = 0.0, known_solids: bool = False,
           tolerance: float = SELF_FILTER_TOLERANCE) -> Expectation:
    """The judge's expectation for a query on ``case`` by a monitor on ``rig`` (one camera: the single-camera
    method; several: fused, principal ``rig.principal``) with this robot zone (fused answers only) and, if
    ``known_solids``, the case's solids as known static solids; ``tolerance``: the self-filter tolerance the judge
    takes as stated (the library's default)."""
    fused = len(rig.cameras) > 1
    answering = [rig.cameras[rig.principal]] if fused else list(rig.cameras.values())
    shell = in_shell(case, answering, tolerance)
    stated = shell.copy()
    if fused and zone > 0.0:
        stated |= in_zone(case, robot, zone)
    outside_shell = np.minimum(outside(case, shell), case.solid_distance)
    outside_stated = outside(case, stated)
    if known_solids:
        stated_solids = in_band(case, stated_band(case, rig.cameras.values(), tolerance))
        outside_stated = outside(case, stated | stated_solids)  # the solids themselves are inside their band
    else:
        outside_stated = np.minimum(outside_stated, case.solid_distance)
    # the judged obstacle point lies at most min(outside_stated, rho) farther from every camera than the point
    depth = np.max([c.world_to_camera(case.points)[:, 2] for c in rig.cameras.values()], axis=0)
    focal = min(c.fx for c in rig.cameras.values())
    tol = FOOTPRINTS * (depth + np.minimum(outside_stated, rho)) / focal + BUFFER
    gap = zone_gap(robot, case.q, case.points, zone) if (fused and zone > 0.0) else None
    return Expectation(outside_shell, outside_stated, tol, gap)


CONCESSIONS = (dg.Flag.ROBOT_ZONE | dg.Flag.KNOWN_SOLID | dg.Flag.HOLE_FILLED | dg.Flag.REMEMBERED
               | dg.Flag.ROBOT_SHELL)


def _capped(x, rho):
    return np.minimum(np.asarray(x, dtype=np.float64), rho)


def violations(result, e: Expectation, rho: float) -> list[tuple[int, str, float]]:
    """The judged rules (module docstring) broken by a :class:`depthguard.DistanceResult`: (point index, rule,
    by how much, metres). Distances are compared capped at ``rho`` (beyond it the library reports inf)."""
    out = []
    distance = _capped(result.distance, rho)
    blind = _capped(result.blind_distance, rho)
    conceded = _capped(result.concession_distance, rho)
    shell_bound = _capped(e.outside_shell + e.tolerance, rho)
    stated_bound = _capped(e.outside_stated + e.tolerance, rho)
    for i in range(len(distance)):
        conservative = min(distance[i], blind[i], conceded[i])
        if conservative > shell_bound[i] + EPS:
            out.append((i, "1: min(distance, blind, concession) above the truth outside the shell",
                        conservative - shell_bound[i]))
        if min(distance[i], blind[i]) > stated_bound[i] + EPS:
            out.append((i, "2: hidden outside every stated region", min(distance[i], blind[i]) - stated_bound[i]))
        if distance[i] > shell_bound[i] + EPS:
            flags = result.flags[i]
            covered = (dg.Flag.ROBOT_BLIND_SPOT in flags and blind[i] <= shell_bound[i] + EPS) or \
                (bool(flags & CONCESSIONS) and conceded[i] <= shell_bound[i] + EPS)
            if not covered:
                out.append((i, "3: above the truth without a flag that covers it", distance[i] - shell_bound[i]))
        if e.zone_gap is not None and e.zone_gap[i] < distance[i] - EPS:
            if dg.Flag.ROBOT_ZONE not in result.flags[i] or conceded[i] > min(e.zone_gap[i], rho) + EPS:
                out.append((i, "4: the robot zone is nearer than the answer, unflagged",
                            distance[i] - e.zone_gap[i]))
    return out


def core_distance(case: Case, points, capability: float, hidden=None) -> np.ndarray:
    """(n,) metres: distance from each point to the balls of diameter ``capability`` that fit inside a limb (for a
    capsule of radius r >= capability / 2: its axis segment grown by capability / 2; for a box whose half extents
    are all >= capability / 2: the box shrunk by (h - capability / 2) and grown back by a ball); inf: none fits.
    ``hidden``: limb names left out (they lie in a stated region)."""
    r = capability / 2.0
    out = np.full(len(points), np.inf)
    for name, limb in case.limbs.items():
        if hidden and name in hidden:
            continue
        T = limb.T_world_obstacle
        local = (points - T[:3, 3]) @ T[:3, :3]
        if limb.kind == "capsule":
            if limb.size[0] < r:
                continue
            half = 0.5 * limb.size[1]
            axial = np.clip(local[:, 2], -half, half)
            d = np.linalg.norm(local - np.stack([0 * axial, 0 * axial, axial], -1), axis=1) - r
        else:
            h = np.asarray(limb.size) - r
            if np.any(h < 0):
                continue
            d = np.linalg.norm(np.maximum(np.abs(local) - h, 0.0), axis=1) - r
        out = np.minimum(out, np.maximum(d, 0.0))
    return out


def detectable_violations(result, core: np.ndarray, tolerance: np.ndarray) -> list[tuple[int, str, float]]:
    """Broken rules of a :class:`depthguard.DetectableResult`: a part at least ``effective_capability`` thick is
    counted (distance <= core + tolerance), and ``detection_opening`` flags every distance above 0."""
    out = []
    for i, d in enumerate(result.distance):
        if d > core[i] + tolerance[i] + EPS:
            out.append((i, "D1: a part at least the effective capability thick was left out",
                        d - core[i] - tolerance[i]))
        if d > 0.0 and dg.Flag.DETECTION_OPENING not in result.flags[i]:
            out.append((i, "D2: a distance above 0 without detection_opening", d))
    return out


# ------------------------------------------------------------------------------------------------------ the cases

#: The robot's configurations (radians): the arm held out horizontally along +x at z = 0.36 m; upright; the elbow
#: bent to a 65-degree V; reaching down in front of the base.
Q_HORIZONTAL = np.array([0.0, np.pi / 2, 0.0, 0.0, 0.0, 0.0, 0.0])
Q_UPRIGHT = np.zeros(7)
Q_BENT = np.array([0.0, 0.5, 0.0, -2.0, 0.0, 0.0, 0.0])
Q_REACHING = np.array([0.3, 1.2, 0.0, -0.8, 0.0, 1.0, 0.0])

#: The table (case "on a known solid"): a block built down to the floor, top at TABLE_TOP, in front of the upright
#: robot and at least 0.3 m from it.
TABLE_TOP = 0.3


def offsets(centre, outward, faces, steps=(0.02, 0.04, 0.08), lateral=()) -> np.ndarray:
    """Query points ``steps`` metres off a face: ``centre`` of the part, ``outward`` unit normal, ``faces`` the
    distance from the centre to that face, plus each lateral offset (3,) added to every step."""
    outward = np.asarray(outward, float) / np.linalg.norm(outward)
    base = [np.asarray(centre) + outward * (faces + s) for s in steps]
    more = [b + np.asarray(o, float) for b in base for o in lateral]
    return np.array(base + more)


def make_cases(world: IiwaWorld, robot) -> list[Case]:
    """The four cases of design §11a, unrendered (see :func:`build`)."""
    cases = []

    # 1. A hand on top of link 3 and a forearm beside link 5, each 1 cm from the link's mesh.
    world.set_joints(Q_HORIZONTAL)
    palm = world.place(hand([0.34, 0.0, 0.36], [0, 0, 1], [1, 0, 0]), [0, 0, 1], [2, 3, 4])
    arm = world.place(capsule(FOREARM, [0.73, 0.0, 0.36], [1, 0, 0]), [0, -1, 0], [4, 5, 6])
    points = np.concatenate([
        robot.control_point_positions(Q_HORIZONTAL),
        offsets(palm.centre, [0, 0, 1], HAND[2], lateral=[[0.03, 0.03, 0.0], [-0.05, 0.0, 0.0]]),
        offsets(arm.centre, [0, -1, 0], FOREARM[0], lateral=[[0.08, 0.0, 0.0], [-0.08, 0.0, 0.02]]),
    ])
    target = [0.55, 0.0, 0.4]
    rig = dg.Rig({"p": camera("p", [0.3, -1.4, 1.3], target), "s": camera("s", [0.9, 1.3, 1.4], target),
                  # through the forearm onto link 5, along the normal of both
                  "t": camera("t", [0.73, -1.5, 0.45], [0.73, 0.0, 0.36])},
                 principal="p", workspace=WORKSPACE)
    cases.append(Case("along a link", Q_HORIZONTAL, {"hand": palm, "forearm": arm}, [], rig, points,
                      len(robot.control_points)))

    # 2. A hand and a forearm flat on a table (a known static solid when the monitor is told so).
    table = ps.Primitive("box", (0.3, 0.45, TABLE_TOP / 2), ps.pose(np.eye(3), [0.75, 0.0, TABLE_TOP / 2]))
    palm = hand([0.65, 0.2, TABLE_TOP + HAND[2]], [0, 0, 1], [1, 0, 0])
    arm = capsule(FOREARM, [0.8, -0.15, TABLE_TOP + FOREARM[0]], [0, 1, 0])
    points = np.concatenate([
        robot.control_point_positions(Q_UPRIGHT),
        offsets(palm.centre, [0, 0, 1], HAND[2], lateral=[[0.03, 0.03, 0.0], [-0.03, -0.04, 0.0]]),
        offsets(arm.centre, [0, 0, 1], FOREARM[0], lateral=[[0.0, 0.08, 0.0], [0.0, -0.08, 0.0]]),
        np.array([[0.95, 0.3, TABLE_TOP + 0.04], [0.55, -0.3, TABLE_TOP + 0.04], [0.55, -0.3, TABLE_TOP + 0.02]]),
    ])
    target = [0.7, 0.0, 0.32]
    rig = dg.Rig({"p": camera("p", [0.2, -1.3, 1.5], target), "s": camera("s", [1.3, 1.1, 1.5], target),
                  # straight down onto the table
                  "t": camera("t", [0.72, 0.02, 1.6], [0.72, 0.02, TABLE_TOP], up=(1.0, 0.0, 0.0))},
                 principal="p", workspace=WORKSPACE)
    cases.append(Case("on a known solid", Q_UPRIGHT, {"hand": palm, "forearm": arm}, [table], rig, points,
                      len(robot.control_points)))

    # 3. A finger across the crook of the bent elbow, between links 3-4 and 5, 1 cm from the nearest mesh.
    world.set_joints(Q_BENT)
    poses = robot.link_poses(Q_BENT)
    elbow = poses["lbr_iiwa_link_4"][:3, 3]
    up = poses["lbr_iiwa_link_2"][:3, 3] - elbow
    down = poses["lbr_iiwa_link_6"][:3, 3] - elbow
    bisector = up / np.linalg.norm(up) + down / np.linalg.norm(down)
    bisector /= np.linalg.norm(bisector)
    tip = world.place(capsule(FINGER, elbow + 0.05 * bisector, [0, 1, 0]), bisector, [3, 4, 5])
    across = np.cross(bisector, [0, 1, 0])
    points = np.concatenate([
        robot.control_point_positions(Q_BENT),
        offsets(tip.centre, bisector, FINGER[0], lateral=[[0.0, 0.03, 0.0], [0.0, -0.03, 0.0]]),
        tip.centre + np.array([[0.0, 0.06, 0.0], [0.0, -0.06, 0.0], [0.0, 0.1, 0.0]]),
        tip.centre + 0.02 * across[None] * np.array([[1.0], [-1.0]]),
    ])
    target = [0.25, 0.0, 0.55]
    rig = dg.Rig({"p": camera("p", [0.3, -1.5, 0.9], target), "s": camera("s", [0.9, 1.2, 0.2], target),
                  # up into the crook, through the finger
                  "t": camera("t", tip.centre + 0.45 * bisector, tip.centre, up=(1.0, 0.0, 0.0))},
                 principal="p", workspace=WORKSPACE)
    cases.append(Case("between two links", Q_BENT, {"finger": tip}, [], rig, points, len(robot.control_points)))

    # 4. A hand across the flange, 1 cm beyond it, reaching past the end-effector on every side.
    world.set_joints(Q_REACHING)
    flange = robot.link_poses(Q_REACHING)["lbr_iiwa_link_7"]
    axis = flange[:3, 2]
    palm = world.place(hand(flange[:3, 3] + 0.02 * axis, axis, flange[:3, 0]), axis, [5, 6, 7])
    side = np.cross(axis, flange[:3, 0])
    points = np.concatenate([
        robot.control_point_positions(Q_REACHING),
        offsets(palm.centre, axis, HAND[2], lateral=[0.04 * flange[:3, 0], 0.05 * side]),
        palm.centre + np.array([0.06 * flange[:3, 0], -0.06 * flange[:3, 0], 0.07 * side, -0.07 * side]),
    ])
    target = palm.centre
    rig = dg.Rig({"p": camera("p", [0.3, -1.2, 1.1], target), "s": camera("s", [1.6, 0.9, 0.9], target),
                  # down the tool axis: the arm in front of the hand (this camera's blind spot)
                  "t": camera("t", palm.centre - 1.2 * axis, palm.centre, up=(1.0, 0.0, 0.0))},
                 principal="p", workspace=WORKSPACE)
    cases.append(Case("past the end-effector", Q_REACHING, {"hand": palm}, [], rig, points,
                      len(robot.control_points)))
    return cases


#: Every rig's workspace (world, metres): the robot, the parts and the space round them; the depth grid's range, the
#: free-space memory and the detectable space's voxels come from it.
WORKSPACE = ((-0.6, -0.9, 0.0), (1.4, 0.9, 1.4))
