"""Scenes rendered and measured by pybullet, to judge depthguard with code the project did not write.

What decides what is "true" comes from pybullet (Bullet's TinyRenderer through ``getCameraImage``, Bullet's
``getClosestPoints``) and coal (``coal.distance``); the code here builds scenes, converts conventions and checks
the two distance judges against each other. The tolerance of each judged point needs the exact depth of the first
surface on a few pixel-centre rays: :func:`first_hit` casts them analytically against the true boxes, spheres and
capsules (pybullet's ``rayTestBatch`` is not exact enough for that: on a 0.3 m sphere at 2 m it is off by up to
1 cm).

Conventions (checked in ``tests/test_judge_pybullet.py::test_pybullet_camera_convention``):

- Our camera: optical frame x right, y down, z forward; pixel (u, v) is column u, row v, centred at image
  coordinates (u, v); ``u = fx*x/z + cx``.
- pybullet wants a column-major OpenGL view matrix (world -> eye, eye looks down -z with y up) and projection
  matrix. The eye frame is our optical frame turned by pi about x: ``T_eye_camera = diag(1, -1, -1)``.
- TinyRenderer rasterises at integer window coordinates: column i is sampled at window x = i, where window
  x = (x_ndc + 1) * width / 2, and row r of the returned image is window row ``height - 1 - r`` (it flips the image
  vertically). So our pixel centre (u, v) must land on window (u, height - 1 - v):
  ``x_ndc = 2u/width - 1`` and ``y_ndc = 1 - 2(v + 1)/height``. (A renderer that sampled at pixel-square centres
  would need u + 1/2 instead.)
- The depth buffer is OpenGL's non-linear one: the optical z of a pixel is ``far*near / (far - (far-near)*b)``;
  pixels showing nothing read b = 1 (z = far) and have segmentation id -1.

Geometry. Boxes are drawn with pybullet's own box visual (8 corners: exact). pybullet draws its sphere and capsule
visuals as coarse polyhedra *inscribed* in the true shape (a 0.3 m sphere at 2 m renders up to 0.12 m deeper than the
true sphere), so a judge that drew them would accuse the library of a renderer's error. Spheres and capsules are
therefore drawn as meshes that *contain* the true shape (a convex polyhedron of icosphere directions whose every face
plane is at least the radius from the core), at most ``MESH_INFLATION * radius`` bigger. The true shape is what
pybullet and coal measure distances to; the rendered surface lies on or in front of it, so it never hides a piece of
the true obstacle behind a surface that is not there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull

#: Clipping planes of the pybullet projection, metres (optical z). Far enough that the rooms fit, near enough that
#: float32 depth-buffer resolution stays near a micrometre at the depths used (dz = z^2/near * 2^-24).
RENDER_NEAR = 0.2
RENDER_FAR = 20.0

#: Subdivision level of the icosphere used to draw spheres and capsules (642 directions).
ICOSPHERE_LEVEL = 3

#: Radius of the probe sphere used with pybullet's getClosestPoints, metres (added back to its distances).
PROBE_RADIUS = 1e-5


# --------------------------------------------------------------------------------------------- camera conventions

#: Our optical frame (x right, y down, z forward) -> OpenGL eye frame (x right, y up, z backward).
T_EYE_CAMERA = np.diag([1.0, -1.0, -1.0, 1.0])


def view_matrix(camera) -> list[float]:
    """pybullet's viewMatrix (16 floats, column-major) for a depthguard camera: world -> OpenGL eye."""
    V = T_EYE_CAMERA @ camera.T_camera_world
    return V.T.reshape(-1).tolist()


def projection_matrix(camera, near: float = RENDER_NEAR, far: float = RENDER_FAR) -> list[float]:
    """pybullet's projectionMatrix (16 floats, column-major) that puts our pixel (u, v) on TinyRenderer's sample.

    With eye coordinates (X, Y, Z) = (x, -y, -z) and w_clip = -Z = z:
    x_ndc = (2 fx/W) x/z + (2 cx/W - 1) = 2u/W - 1 and y_ndc = (2 fy/H)(-y/z) + (1 - 2(cy + 1)/H) = 1 - 2(v + 1)/H.
    """
    W, H = camera.width, camera.height
    P = np.zeros((4, 4))
    P[0, 0] = 2.0 * camera.fx / W
    P[0, 2] = 1.0 - 2.0 * camera.cx / W
    P[1, 1] = 2.0 * camera.fy / H
    P[1, 2] = 2.0 * (camera.cy + 1.0) / H - 1.0
    P[2, 2] = -(far + near) / (far - near)
    P[2, 3] = -2.0 * far * near / (far - near)
    P[3, 2] = -1.0
    return P.T.reshape(-1).tolist()


def buffer_to_depth(buffer, near: float = RENDER_NEAR, far: float = RENDER_FAR) -> np.ndarray:
    """OpenGL depth-buffer values (0..1) -> optical z, metres (float64)."""
    b = np.asarray(buffer, dtype=np.float64)
    return far * near / (far - (far - near) * b)


def render_depth(client: int, camera) -> tuple[np.ndarray, np.ndarray]:
    """Render ``camera``'s view with TinyRenderer. Returns (depth, segmentation): (h, w) float64 optical z in metres
    (``inf`` where nothing is drawn) and (h, w) int body ids (-1: nothing)."""
    import pybullet as p

    _, _, _, buffer, segmentation = p.getCameraImage(
        camera.width, camera.height, viewMatrix=view_matrix(camera), projectionMatrix=projection_matrix(camera),
        renderer=p.ER_TINY_RENDERER, physicsClientId=client,
    )
    buffer = np.asarray(buffer, dtype=np.float64).reshape(camera.height, camera.width)
    segmentation = np.asarray(segmentation).reshape(camera.height, camera.width)
    depth = buffer_to_depth(buffer)
    depth[segmentation < 0] = np.inf
    return depth, segmentation


# ----------------------------------------------------------------------------------------------------- primitives

@dataclass(frozen=True, eq=False)
class Primitive:
    """A solid obstacle. ``kind`` is "box" (``size`` = half extents, (3,) metres), "sphere" (``size`` = (radius,))
    or "capsule" (``size`` = (radius, length of the axis segment); axis along the local z). ``T_world_obstacle``:
    (4, 4) pose."""

    kind: str
    size: tuple
    T_world_obstacle: np.ndarray

    @property
    def centre(self) -> np.ndarray:
        return self.T_world_obstacle[:3, 3]


def _icosphere(level: int) -> np.ndarray:
    """Unit vectors of a subdivided icosahedron."""
    t = (1.0 + 5.0 ** 0.5) / 2.0
    vertices = [np.array(v, dtype=np.float64) for v in (
        (-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
        (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1))]
    vertices = [v / np.linalg.norm(v) for v in vertices]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2),
             (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11),
             (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    for _ in range(level):
        midpoints: dict = {}

        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in midpoints:
                m = vertices[a] + vertices[b]
                vertices.append(m / np.linalg.norm(m))
                midpoints[key] = len(vertices) - 1
            return midpoints[key]

        new_faces = []
        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new_faces += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new_faces
    return np.array(vertices)


_DIRECTIONS = _icosphere(ICOSPHERE_LEVEL)
_UNIT_HULL = ConvexHull(_DIRECTIONS)
#: A polyhedron with vertices at radius R * _DIRECTIONS contains the ball of radius R * min face-plane distance.
_INSCRIBED = float((-_UNIT_HULL.equations[:, 3]).min())
#: How much bigger than the true radius the drawn sphere/capsule is at its vertices (about 0.45 %).
MESH_INFLATION = 1.0 / _INSCRIBED - 1.0


def containing_mesh(kind: str, size) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n, 3) and outward triangles (m, 3) of a convex polyhedron containing the sphere or capsule.

    The hull of {a + R d_i} and {b + R d_i} (segment ends a, b; icosphere directions d_i) is the Minkowski sum of the
    segment and R * (hull of d_i); it contains segment + ball(r) iff R * (hull of d_i) contains ball(r), i.e.
    R >= r / (smallest face-plane distance of the unit icosphere hull).
    """
    radius = float(size[0])
    R = radius / _INSCRIBED
    if kind == "sphere":
        points = R * _DIRECTIONS
    elif kind == "capsule":
        half = 0.5 * float(size[1])
        points = np.concatenate([R * _DIRECTIONS + [0, 0, half], R * _DIRECTIONS - [0, 0, half]])
    else:
        raise ValueError(kind)
    hull = ConvexHull(points)
    triangles = hull.simplices.copy()
    a, b, c = (points[triangles[:, k]] for k in range(3))
    inward = np.einsum("ij,ij->i", np.cross(b - a, c - a), hull.equations[:, :3]) < 0
    triangles[inward] = triangles[inward][:, [0, 2, 1]]
    used = np.unique(triangles)
    remap = -np.ones(len(points), dtype=np.int64)
    remap[used] = np.arange(len(used))
    return points[used], remap[triangles]


def _matrix_to_quaternion(R: np.ndarray) -> list[float]:
    """(x, y, z, w) of a rotation matrix (Shepperd's method)."""
    trace = np.trace(R)
    if trace > 0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = [(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s]
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + R[i, i] - R[j, j] - R[k, k])
        q = [0.0, 0.0, 0.0, (R[k, j] - R[j, k]) / s]
        q[i] = 0.25 * s
        q[j] = (R[j, i] + R[i, j]) / s
        q[k] = (R[k, i] + R[i, k]) / s
    q = np.array(q)
    return (q / np.linalg.norm(q)).tolist()


class PybulletScene:
    """Primitives loaded into a pybullet DIRECT client: exact collision shapes, drawn as the module says.

    Distances are measured twice, by pybullet's ``getClosestPoints`` (a probe sphere of ``PROBE_RADIUS``) and by
    coal (a point); :meth:`measure` returns the smaller, the stricter truth, and how much the two judges differ.
    """

    def __init__(self, client: int, primitives: list[Primitive]):
        import coal
        import pybullet as p

        self.client = client
        self.primitives = list(primitives)
        self.bodies = []
        self._coal = []
        for prim in self.primitives:
            if prim.kind == "box":
                collision = p.createCollisionShape(p.GEOM_BOX, halfExtents=list(prim.size), physicsClientId=client)
                visual = p.createVisualShape(p.GEOM_BOX, halfExtents=list(prim.size), physicsClientId=client)
                geometry = coal.Box(*(2.0 * np.asarray(prim.size, dtype=np.float64)))
            else:
                if prim.kind == "sphere":
                    collision = p.createCollisionShape(p.GEOM_SPHERE, radius=prim.size[0], physicsClientId=client)
                    geometry = coal.Sphere(float(prim.size[0]))
                elif prim.kind == "capsule":
                    collision = p.createCollisionShape(p.GEOM_CAPSULE, radius=prim.size[0], height=prim.size[1],
                                                       physicsClientId=client)
                    geometry = coal.Capsule(float(prim.size[0]), float(prim.size[1]))
                else:
                    raise ValueError(f"unknown primitive kind {prim.kind!r}")
                vertices, triangles = containing_mesh(prim.kind, prim.size)
                visual = p.createVisualShape(p.GEOM_MESH, vertices=vertices.tolist(),
                                             indices=triangles.reshape(-1).tolist(), physicsClientId=client)
            T = prim.T_world_obstacle
            body = p.createMultiBody(0, collision, visual, basePosition=T[:3, 3].tolist(),
                                     baseOrientation=_matrix_to_quaternion(T[:3, :3]), physicsClientId=client)
            self.bodies.append(body)
            self._coal.append((geometry, coal.Transform3s(T[:3, :3].copy(), T[:3, 3].copy())))
        self._probe = p.createCollisionShape(p.GEOM_SPHERE, radius=PROBE_RADIUS, physicsClientId=client)

    def remove(self) -> None:
        """Take the bodies out of the client."""
        import pybullet as p

        for body in self.bodies:
            p.removeBody(body, physicsClientId=self.client)
        self.bodies = []

    def render(self, camera) -> np.ndarray:
        """(h, w) float64 optical z, metres, of ``camera``'s view (``inf`` where nothing is drawn)."""
        return render_depth(self.client, camera)[0]

    def closest_pybullet(self, points_world, max_distance: float) -> np.ndarray:
        """(n, m) distances from each point to each primitive by pybullet's getClosestPoints, metres
        (0 inside; ``inf`` beyond ``max_distance``)."""
        import pybullet as p

        points = np.asarray(points_world, dtype=np.float64)
        out = np.full((len(points), len(self.bodies)), np.inf)
        for i, point in enumerate(points):
            for j, body in enumerate(self.bodies):
                contacts = p.getClosestPoints(bodyA=-1, bodyB=body, distance=max_distance,
                                              collisionShapeA=self._probe, collisionShapePositionA=point.tolist(),
                                              physicsClientId=self.client)
                if contacts:
                    out[i, j] = max(min(c[8] for c in contacts) + PROBE_RADIUS, 0.0)
        return out

    def closest_coal(self, points_world) -> tuple[np.ndarray, np.ndarray]:
        """(n, m) distances (0 inside) and (n, m, 3) nearest points on each primitive, world frame, by coal."""
        import coal

        points = np.asarray(points_world, dtype=np.float64)
        distance = np.empty((len(points), len(self._coal)))
        nearest = np.empty((len(points), len(self._coal), 3))
        point_shape = coal.Sphere(0.0)
        request = coal.DistanceRequest()
        for i, point in enumerate(points):
            at = coal.Transform3s(np.eye(3), point.copy())
            for j, (geometry, pose) in enumerate(self._coal):
                result = coal.DistanceResult()
                d = coal.distance(geometry, pose, point_shape, at, request, result)
                distance[i, j] = max(d, 0.0)
                nearest[i, j] = result.getNearestPoint1() if d > 0 else point
        return distance, nearest

    def measure(self, points_world, max_distance: float) -> "Truth":
        """The true distance of each point to the obstacles, its nearest obstacle point, and the judges' gap."""
        by_coal, nearest = self.closest_coal(points_world)
        by_pybullet = self.closest_pybullet(points_world, max_distance)
        both = (by_coal <= max_distance) & (by_pybullet <= max_distance)
        gap = float(np.abs(by_coal - by_pybullet)[both].max()) if both.any() else 0.0
        # beyond max_distance pybullet reports nothing; coal's value stands there
        combined = np.where(np.isfinite(by_pybullet), np.minimum(by_coal, by_pybullet), by_coal)
        which = np.argmin(combined, axis=1)
        rows = np.arange(len(combined))
        return Truth(distance=combined[rows, which], nearest_world=nearest[rows, which], primitive=which,
                     judges_gap=gap)


@dataclass(frozen=True)
class Truth:
    """distance: (n,) metres (0 inside an obstacle); nearest_world: (n, 3) the nearest obstacle point Q (coal's);
    primitive: (n,) index of the nearest primitive; judges_gap: largest |coal - pybullet| seen, metres."""

    distance: np.ndarray
    nearest_world: np.ndarray
    primitive: np.ndarray
    judges_gap: float


# ---------------------------------------------------------------------------------------- exact analytic ray casts

def first_hit(primitives, origin_world, directions_world) -> np.ndarray:
    """Parameter t of the first true-shape surface along rays ``origin + t * direction`` (t > 0; ``inf``: no hit).

    ``origin_world``: (3,) metres; ``directions_world``: (n, 3). With directions whose optical z is 1 (a pixel's
    centre ray, ``R @ (x/z, y/z, 1)``), t is the optical depth of the hit. Exact for boxes (slabs), spheres and
    capsules (cylinder plus two end balls); a ray starting inside a solid gets t = 0.
    """
    origin_world = np.asarray(origin_world, dtype=np.float64)
    D_world = np.asarray(directions_world, dtype=np.float64).reshape(-1, 3)
    best = np.full(len(D_world), np.inf)
    for prim in primitives:
        R, c = prim.T_world_obstacle[:3, :3], prim.T_world_obstacle[:3, 3]
        o = R.T @ (origin_world - c)
        D = D_world @ R
        if prim.kind == "box":
            t = _ray_box(o, D, np.asarray(prim.size, dtype=np.float64))
        elif prim.kind == "sphere":
            t = _ray_ball(o, D, float(prim.size[0]))
        else:
            radius, half = float(prim.size[0]), 0.5 * float(prim.size[1])
            t = np.minimum(_ray_ball(o - [0, 0, half], D, radius), _ray_ball(o + [0, 0, half], D, radius))
            t = np.minimum(t, _ray_cylinder(o, D, radius, half))
        best = np.minimum(best, t)
    return best


def _ray_box(o, D, half):
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-half - o) / D
        t2 = (half - o) / D
    inside_slab = np.abs(o) <= half
    t_lo = np.where(D == 0, np.where(inside_slab, -np.inf, np.inf), np.minimum(t1, t2))
    t_hi = np.where(D == 0, np.where(inside_slab, np.inf, -np.inf), np.maximum(t1, t2))
    enter = t_lo.max(axis=1)
    leave = t_hi.min(axis=1)
    return np.where((leave >= np.maximum(enter, 0.0)), np.maximum(enter, 0.0), np.inf)


def _ray_ball(o, D, radius):
    a = np.einsum("ij,ij->i", D, D)
    b = 2.0 * D @ o
    c = o @ o - radius * radius
    disc = b * b - 4.0 * a * c
    root = np.sqrt(np.maximum(disc, 0.0))
    near = (-b - root) / (2.0 * a)
    far = (-b + root) / (2.0 * a)
    return np.where((disc >= 0) & (far >= 0), np.maximum(near, 0.0), np.inf)


def _ray_cylinder(o, D, radius, half):
    a = D[:, 0] ** 2 + D[:, 1] ** 2
    b = 2.0 * (o[0] * D[:, 0] + o[1] * D[:, 1])
    c = o[0] ** 2 + o[1] ** 2 - radius * radius
    disc = b * b - 4.0 * a * c
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (-b - np.sqrt(np.maximum(disc, 0.0))) / (2.0 * a)
    z = o[2] + t * D[:, 2]
    return np.where((a > 0) & (disc >= 0) & (t >= 0) & (np.abs(z) <= half), t, np.inf)


def exact_depth_image(primitives, camera) -> np.ndarray:
    """(h, w) float64: optical z of the first true-shape surface on every pixel's centre ray (``inf``: none)."""
    u, v = camera.pixel_grid()
    rays_camera = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], axis=-1)
    rays_world = rays_camera.reshape(-1, 3) @ camera.T_world_camera[:3, :3].T
    return first_hit(primitives, camera.T_world_camera[:3, 3], rays_world).reshape(camera.shape)


# ------------------------------------------------------------------------------------- discretisation tolerance

#: Largest relative error of TinyRenderer's depth against the exact depth on the same pixel-centre ray (float32
#: vertices, transforms and depth buffer). test_pybullet_camera_convention measures it (about 3e-6) and holds it
#: below this bound.
RENDER_DEPTH_REL = 1e-5


def discretisation_bound(primitives, camera, nearest_world, depth_slack: float = 0.0) -> np.ndarray:
    """(n,) metres: how far each true obstacle point Q may lie from what a correct library marks as occupied.

    The library marks pixel k possibly occupied along its frustum F_k from its measured depth d_k on (minus a noise
    margin >= 0); space outside the observed volume counts as occupied (``unseen="occupied"``). For a point Q of
    the obstacle, each of these gives an occupied point, so the distance from Q to the occupied set is at most:

    - 0 if Q itself is unseen (outside the image or the depth range);
    - the distance from Q to the boundary of the observed volume;
    - for each pixel k of the 3 x 3 block around Q's pixel, |Q - B_k| with B_k = z' (x', y', 1): (x', y') the
      tangents of Q clamped into k's footprint and z' = max(z_Q, d_k), where d_k is the exact first-surface depth on
      k's centre ray (:func:`first_hit`) plus the renderer's error ``RENDER_DEPTH_REL * d_k`` plus ``depth_slack``
      (quantisation: half a depth unit).

    The bound is the smallest of these. Its size follows the usual reasoning: on a surface inclined at theta to
    the ray, the centre sample lies up to half a footprint diagonal away, so d_k - z_Q ~ r (sqrt(2)/2) tan(theta)
    / f; at a silhouette the neighbouring pixel's frustum, one footprint (~ sqrt(2) z / f) away, covers Q; at
    grazing angles the own-pixel term grows like tan(theta) but the neighbour terms do not, which caps it.
    """
    Q = camera.world_to_camera(nearest_world)
    X, Y, Z = Q[:, 0], Q[:, 1], Q[:, 2]
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    W, H = camera.width, camera.height
    z_min, z_max = camera.depth_range
    bound = np.full(len(Q), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        tx, ty = X / Z, Y / Z
    tx0, tx1 = (-0.5 - cx) / fx, (W - 0.5 - cx) / fx
    ty0, ty1 = (-0.5 - cy) / fy, (H - 0.5 - cy) / fy
    seen = (Z > z_min) & (Z < z_max) & (tx > tx0) & (tx < tx1) & (ty > ty0) & (ty < ty1)
    bound[~seen] = 0.0
    # distance to the boundary of the observed volume (its side planes pass through the optical centre)
    to_boundary = np.minimum.reduce([
        (X - tx0 * Z) / np.hypot(1.0, tx0), (tx1 * Z - X) / np.hypot(1.0, tx1),
        (Y - ty0 * Z) / np.hypot(1.0, ty0), (ty1 * Z - Y) / np.hypot(1.0, ty1),
        Z - z_min, z_max - Z,
    ])
    bound[seen] = to_boundary[seen]
    idx = np.nonzero(seen)[0]
    if len(idx) == 0:
        return bound
    u0 = np.rint(fx * tx[idx] + cx).astype(np.int64)
    v0 = np.rint(fy * ty[idx] + cy).astype(np.int64)
    R, C = camera.T_world_camera[:3, :3], camera.T_world_camera[:3, 3]
    for du in (-1, 0, 1):
        for dv in (-1, 0, 1):
            u, v = u0 + du, v0 + dv
            ok = (u >= 0) & (u < W) & (v >= 0) & (v < H)
            if not ok.any():
                continue
            i, u, v = idx[ok], u[ok].astype(np.float64), v[ok].astype(np.float64)
            rays = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], axis=-1)
            d = first_hit(primitives, C, rays @ R.T)
            d = d * (1.0 + RENDER_DEPTH_REL) + depth_slack
            x_clamped = np.clip(tx[i], (u - 0.5 - cx) / fx, (u + 0.5 - cx) / fx)
            y_clamped = np.clip(ty[i], (v - 0.5 - cy) / fy, (v + 0.5 - cy) / fy)
            z = np.maximum(Z[i], d)
            B = np.stack([x_clamped * z, y_clamped * z, z], axis=-1)
            bound[i] = np.minimum(bound[i], np.linalg.norm(B - Q[i], axis=1))
    return bound


# --------------------------------------------------------------------------------------------------- random scenes

#: The room: inner floor [-ROOM_HALF, ROOM_HALF]^2 at z = 0, ceiling at ROOM_HEIGHT, walls WALL metres thick. Small
#: enough that every pixel of every camera below sees a surface within the 6 m depth range, so that the images hold
#: no invalid pixel and no unseen depth.
ROOM_HALF = 2.5
ROOM_HEIGHT = 2.6
WALL = 0.1


def pose(R, t) -> np.ndarray:
    """(4, 4) rigid transform from a (3, 3) rotation and a (3,) translation."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def random_rotation(rng) -> np.ndarray:
    """A uniformly random (3, 3) rotation (normalised Gaussian quaternion)."""
    x, y, z, w = rng.normal(size=4)
    n = np.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def room() -> list[Primitive]:
    """Floor, ceiling and four walls (boxes) enclosing the scene."""
    L, H, t = ROOM_HALF, ROOM_HEIGHT, WALL
    slabs = [((L + t, L + t, t), (0.0, 0.0, -t)), ((L + t, L + t, t), (0.0, 0.0, H + t))]
    for s in (-1.0, 1.0):
        slabs.append(((t, L + t, H / 2 + t), (s * (L + t), 0.0, H / 2)))
        slabs.append(((L + t, t, H / 2 + t), (0.0, s * (L + t), H / 2)))
    return [Primitive("box", half, pose(np.eye(3), centre)) for half, centre in slabs]


def random_scene(rng, width: int, height: int, focal: float, noise=None):
    """A camera and a list of primitives: the room, 6-9 random boxes, spheres and capsules in front of the camera,
    and a large thin plate whose face the camera sees at 60-80 degrees from its normal.

    The camera stands near the x = -ROOM_HALF wall at 0.9-2.0 m height and looks at a point of the floor area, so
    towards the far wall the floor is seen at up to 67-80 degrees from its normal.
    Returns (camera, primitives).
    """
    import depthguard as dg
    from depthguard.transforms import look_at

    eye = np.array([rng.uniform(-2.2, -1.6), rng.uniform(-1.0, 1.0), rng.uniform(0.9, 2.0)])
    target = np.array([rng.uniform(0.0, 1.5), rng.uniform(-0.8, 0.8), rng.uniform(0.0, 0.5)])
    camera = dg.PinholeCamera("cam", width, height, focal, focal, (width - 1) / 2.0, (height - 1) / 2.0,
                              look_at(eye, target), depth_range=(0.3, 6.0),
                              noise=dg.NoiseModel.none() if noise is None else noise)
    primitives = room()
    for _ in range(int(rng.integers(6, 10))):
        kind = str(rng.choice(["box", "sphere", "capsule"]))
        centre = np.array([rng.uniform(-0.6, 2.0), rng.uniform(-1.5, 1.5), rng.uniform(0.1, 1.8)])
        if kind == "box":
            size = tuple(rng.uniform(0.04, 0.35, 3))
        elif kind == "sphere":
            size = (rng.uniform(0.04, 0.3),)
        else:
            size = (rng.uniform(0.03, 0.15), rng.uniform(0.1, 0.6))
        primitives.append(Primitive(kind, size, pose(random_rotation(rng), centre)))
    view = (target - eye) / np.linalg.norm(target - eye)
    centre = eye + view * rng.uniform(2.0, 3.0)
    theta = np.radians(rng.uniform(60.0, 80.0))
    side = np.cross(view, rng.normal(size=3))
    side /= np.linalg.norm(side)
    normal = -np.cos(theta) * view + np.sin(theta) * side
    a = np.cross(normal, [0.0, 0.0, 1.0] if abs(normal[2]) < 0.9 else [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    primitives.append(Primitive("box", (0.6, 0.45, 0.02), pose(np.stack([a, np.cross(normal, a), normal], 1),
                                                                centre)))
    return camera, primitives


def sample_points_near(scene: PybulletScene, rng, per_primitive: int, rho: float, uniform: int = 0,
                       offsets: str = "log") -> np.ndarray:
    """(n, 3) world points: for each primitive, points off its surface (along the outward direction from a random
    nearby point to its nearest surface point) at distances log-uniform in [1 mm, rho] (``offsets="log"``: many
    points very close to surfaces, where discretisation shows) or uniform in (0, rho) (``offsets="uniform"``: a
    control point anywhere in the surveillance shell), plus ``uniform`` points drawn uniformly in the room (some
    farther than rho from everything). Points may lie inside other obstacles; the caller drops those with
    :meth:`PybulletScene.measure`."""
    if offsets not in ("log", "uniform"):
        raise ValueError(f"offsets must be 'log' or 'uniform', got {offsets!r}")
    lo = np.array([-ROOM_HALF, -ROOM_HALF, 0.0])
    hi = np.array([ROOM_HALF, ROOM_HALF, ROOM_HEIGHT])
    chunks = []
    for j, prim in enumerate(scene.primitives):
        extent = min(float(np.linalg.norm(prim.size)) + rho, 2.0)
        X = np.clip(prim.centre + rng.uniform(-extent, extent, (per_primitive, 3)), lo + 1e-3, hi - 1e-3)
        distance, nearest = scene.closest_coal(X)
        Q, d = nearest[:, j], distance[:, j]
        outside = d > 1e-6
        outward = (X[outside] - Q[outside]) / d[outside, None]
        if offsets == "log":
            offset = np.exp(rng.uniform(np.log(1e-3), np.log(rho), outside.sum()))
        else:
            offset = rng.uniform(0.0, rho, outside.sum())
        chunks.append(Q[outside] + offset[:, None] * outward)
    chunks.append(rng.uniform(lo, hi, (uniform, 3)))
    return np.concatenate(chunks)


def random_rigid_transform(rng, spread: float = 5.0) -> np.ndarray:
    """(4, 4) random rigid transform: uniform rotation, translation uniform in [-spread, spread]^3 metres."""
    return pose(random_rotation(rng), rng.uniform(-spread, spread, 3))


def transformed(primitives, T_new_old) -> list[Primitive]:
    """The primitives moved by the rigid transform ``T_new_old``."""
    return [Primitive(p.kind, p.size, T_new_old @ p.T_world_obstacle) for p in primitives]


def surface_inclination(camera, points_world, nearest_world) -> np.ndarray:
    """(n,) degrees: angle between the outward direction P - Q at the nearest point Q (the surface normal on a
    face or a smooth surface) and the direction from Q to the camera. Above 90: Q faces away from the camera."""
    normal = points_world - nearest_world
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    to_camera = camera.T_world_camera[:3, 3] - nearest_world
    to_camera /= np.linalg.norm(to_camera, axis=1, keepdims=True)
    return np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", normal, to_camera), -1.0, 1.0)))
