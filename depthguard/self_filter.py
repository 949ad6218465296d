"""Robot self-filtering (design §7): render the robot's padded collision geometry into each camera, so that
frame preparation can tell the robot's pixels from obstacles.

The geometry rendered must contain the robot wherever it really is (a pixel of the robot left unfiltered makes the
robot its own obstacle) and should not be much larger (a pixel wrongly taken for the robot hides what is there).
Three choices, all containing every link's collision mesh grown by ``padding``:

- ``"hulls"`` (default): each link's convex hull grown by ``padding``, bounded by a fixed number of planes
  (:func:`padded_hull`). Closed meshes of a few hundred triangles, so the renderer culls back faces: fast.
- ``"capsules"``: the robot's link capsules (:attr:`RobotModel.capsules`, already padded), as circumscribed meshes.
  Looser.
- ``"meshes"``: the collision meshes themselves, unpadded and uncullable (open STL files): exact but slowest.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import HalfspaceIntersection

from depthguard import config
from depthguard.cameras import PinholeCamera
from depthguard.errors import InputError
from depthguard.validation import check_real, short_repr
from depthguard.rendering import MeshInstance, Renderer, primitive_mesh
from depthguard.robots import RobotModel
from depthguard.scenes import Capsule

GEOMETRIES = config.SELF_FILTER_GEOMETRIES


def padded_hull(vertices, padding: float, directions: int = config.SELF_FILTER_HULL_PLANES) -> tuple[np.ndarray,
                                                                                                  np.ndarray]:
    """A closed convex mesh, wound outward, that contains every point within ``padding`` metres of ``vertices``
    (n, 3): the intersection of the half-spaces n . x <= max_v(n . v) + padding over ``directions`` unit normals n
    spread evenly over the sphere (a Fibonacci lattice).

    Containment is exact whatever the normals: a point within ``padding`` of the vertices' hull exceeds no support
    plane of the hull by more than ``padding``. The normals' count bounds the faces (a few hundred triangles) and the
    excess over the padded hull (64 planes: about 250 triangles per link of the iiwa, 6 % more volume than 128 planes).
    Returns (vertices (k, 3) float64, faces (m, 3) int64).
    """
    points = np.asarray(vertices, dtype=np.float64)
    normals = _fibonacci_sphere(directions)
    support = (points @ normals.T).max(axis=0) + padding
    halfspaces = np.concatenate([normals, -support[:, None]], axis=1)  # n . x - h <= 0
    corners = HalfspaceIntersection(halfspaces, points.mean(axis=0)).intersections
    # Three or more planes meet at each corner: merge the copies (to 1e-9 m) before taking the hull of the corners.
    mesh = trimesh.convex.convex_hull(np.unique(np.round(corners, 9), axis=0))
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


def _beyond(vertices: np.ndarray, capsule) -> float:
    """Metres by which the convex hull of ``vertices`` ((n, 3), link frame) reaches outside ``capsule`` (its own
    link's; 0 when inside): the largest distance of a vertex from the capsule's segment less its radius."""
    p0, p1 = np.asarray(capsule.p0), np.asarray(capsule.p1)
    axis = p1 - p0
    t = np.clip((vertices - p0) @ axis / max(float(axis @ axis), 1e-300), 0.0, 1.0)
    return max(float(np.max(np.linalg.norm(vertices - (p0 + t[:, None] * axis), axis=1))) - capsule.radius, 0.0)


def _fibonacci_sphere(n: int) -> np.ndarray:
    """(n, 3) unit vectors spread evenly over the sphere."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z * z)
    phi = np.pi * (1.0 + 5.0**0.5) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


class RobotSilhouette:
    """The robot's padded collision geometry, uploaded once, rendered into any camera at any configuration.

    Args:
        robot: the robot model.
        renderer: the renderer to draw with (one is made if None; it holds a GL context).
        geometry: ``"hulls"``, ``"capsules"`` or ``"meshes"`` (module docstring).
        padding: metres by which hulls grow; default: the robot's own ``padding``.
    """

    def __init__(self, robot: RobotModel, renderer: Renderer | None = None, geometry: str = "hulls",
                 padding: float | None = None):
        if not isinstance(geometry, str) or geometry not in GEOMETRIES:
            raise InputError(f"self-filter geometry must be one of {GEOMETRIES}, got {short_repr(geometry)}",
                             field="self_filter")
        if not isinstance(robot, RobotModel):
            raise InputError(f"robot must be a RobotModel, got {short_repr(robot)}", field="robot")
        if renderer is not None and not isinstance(renderer, Renderer):
            raise InputError(f"renderer must be a depthguard Renderer, got {short_repr(renderer)}", field="renderer")
        self.robot = robot
        self.renderer = renderer if renderer is not None else Renderer()
        self.geometry = geometry
        self.padding = robot.padding if padding is None else check_real(padding, "padding", minimum=0.0,
                                                                        unit="metres", field="padding")
        self._meshes: list[tuple[str, int]] = []  # (link, mesh id) with vertices in the link frame
        self._last_instances: tuple | None = None  # ((joints' shape and bytes, base's bytes), the instances)
        #: Metres: how far the rendered geometry reaches beyond the robot's capsules (the hulls' corners; 0 for the
        #: capsules and the meshes, which the capsules contain).
        self.beyond_capsules = 0.0
        for link, capsule in zip(robot.link_names, robot.capsules):
            mesh = robot.collision_meshes[link]
            if geometry == "capsules":
                vertices, faces = primitive_mesh(Capsule(tuple(capsule.p0), tuple(capsule.p1), capsule.radius),
                                                 config.PRIMITIVE_MESH_SEGMENTS)
                mesh_id = self.renderer.add_mesh(vertices, faces, closed=True)
            elif geometry == "hulls":
                vertices, faces = padded_hull(mesh.vertices, self.padding)
                mesh_id = self.renderer.add_mesh(vertices, faces, closed=True)
                self.beyond_capsules = max(self.beyond_capsules, _beyond(vertices, capsule))
            else:
                mesh_id = self.renderer.add_mesh(mesh.vertices, mesh.faces, closed=False)
            self._meshes.append((link, mesh_id))

    def instances(self, q) -> list[MeshInstance]:
        """The robot's meshes placed at configuration ``q`` (label = link index). The last configuration's are kept:
        a set's passes (nearest, farthest, first exit) in each of its cameras place the robot at the same joints."""
        try:
            joints = np.asarray(q, dtype=np.float64)
            key = (joints.shape, joints.tobytes(), np.asarray(self.robot.T_world_base).tobytes())
        except (TypeError, ValueError):
            key = None  # not joints: link_poses says why
        last = self._last_instances
        if key is not None and last is not None and last[0] == key:
            return list(last[1])
        poses = self.robot.link_poses(q)
        placed = [MeshInstance(mesh_id, poses[link], label=i) for i, (link, mesh_id) in enumerate(self._meshes)]
        self._last_instances = (key, tuple(placed))
        return placed

    def render(self, camera: PinholeCamera, q) -> np.ndarray:
        """(h, w) float32 metres: the nearest surface of the robot's padded geometry per pixel of ``camera`` at
        configuration ``q``, 0 where the robot is not."""
        return self.renderer.render_depth(camera, self.instances(q))

    def render_far(self, camera: PinholeCamera, q) -> np.ndarray:
        """(h, w) float32 metres: where the robot's padded geometry ends along each pixel of ``camera`` (its farthest
        surface), 0 where the robot is not. The depth grid checks the space behind it (design §8, case iv)."""
        return self.renderer.render_depth_max(camera, self.instances(q))

    def render_first_exit(self, camera: PinholeCamera, q) -> np.ndarray:
        """(h, w) float32 metres: where each pixel's ray of ``camera`` first leaves the robot's padded geometry, 0
        where the robot is not. Up to :meth:`render_far` the ray may pass between two links: space the depth grid
        leaves unchecked and flags."""
        return self.renderer.render_depth_first_exit(camera, self.instances(q))

    def triangles(self) -> int:
        """Triangles drawn per camera."""
        return sum(self.renderer._mesh(mesh_id).n_faces for _, mesh_id in self._meshes)


class RobotMask:
    """Where the robot is along each pixel of one camera at one instant: the self-filter stage's answer (design §7).

    ``near``, ``far``: (h, w) float32 metres, where each pixel's ray enters the robot's padded geometry and where it
    leaves it for the last time (0 where the robot is not). With known solids, ``far`` runs on through a solid the
    robot rests in (``StaticSolids.extend_robot``) and ``resting`` holds (pixels moved (h, w) bool, far before).
    :attr:`exit`, where each ray first leaves the robot, is rendered when the depth grid first asks for it."""

    def __init__(self, silhouette: RobotSilhouette, camera: PinholeCamera, joints: np.ndarray, near: np.ndarray,
                 far: np.ndarray, resting: tuple | None = None):
        self.silhouette = silhouette
        self.camera = camera
        self.joints = joints
        self.near = near
        self.far = far
        self.resting = resting
        self._exit = None

    @property
    def exit(self) -> np.ndarray:
        """(h, w) float32 metres: where each pixel's ray first leaves the robot (:meth:`RobotSilhouette.
        render_first_exit`); a ray that left the robot only into a known solid leaves both at ``far``."""
        if self._exit is None:
            exit = self.silhouette.render_first_exit(self.camera, self.joints)
            if self.resting is not None:
                moved, far_before = self.resting
                exit = np.where(moved & (exit >= far_before), self.far, exit).astype(np.float32)
            self._exit = exit
        return self._exit


def robot_mask(silhouette: RobotSilhouette, camera: PinholeCamera, joints: np.ndarray, static=None) -> RobotMask:
    """The self-filter stage for one frame: render the robot at ``joints`` (its joint vector when the frame was
    captured) into ``camera``; ``static``: the known solids (:class:`depthguard.static_solids.StaticSolids`, or None)
    the robot's far end may run on through."""
    near = silhouette.render(camera, joints)
    # Where the robot ends along each pixel: what a camera saw past the padded robot then stays a surface rather
    # than blind space (whether one camera answers or several), a secondary camera clears the space there, and the
    # depth grid starts the space behind the robot there (case iv).
    far = silhouette.render_far(camera, joints)
    resting = None
    if static is not None:
        far_before = far
        far, moved = static.extend_robot(camera, near, far)
        if moved.any():
            resting = (moved, far_before)
    return RobotMask(silhouette, camera, joints, near, far, resting)
