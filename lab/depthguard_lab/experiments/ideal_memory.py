"""The bound: what an ideal sound free-space memory clears next to the robot, from the simulation's exact geometry
(SPEC §8a, issue 35 item 6).

SPEC §8a's recursion, F_k = erode(F_{k-1}, v_max (t_k - t_{k-1})) ∪ Seen_k ∪ Robot_k, is run on the points of a
regular grid over the workspace with what no depthguard code can know:

- ``Seen_k``: a grid point is seen free when some camera's exact ray (the simulation's noise-free render,
  ``SimFrame.depth_exact``, on the pixel the point projects to) passes it before the first surface: its optical depth
  is below that pixel's depth, less the camera's noise margin k sigma(d) when ``noise_margin`` (what the cameras'
  noise costs even an ideal memory), less ``calibration`` and over ``pad`` pixels round it when asked (the
  project's calibration margin and pixel of pad), and nothing else (no footprint, no voxel rounding);
- ``Robot_k``: the points inside the robot's collision meshes at the frame's joints (each link's mesh with its open
  ends closed, voxelised at ``robot_pitch`` and filled: exact to that pitch), and inside the known background
  (floor, pedestal: no person is inside a solid);
- the erosion: a point's earliest possible arrival of a person is the frame's time plus its Euclidean distance to the
  nearest possibly-occupied point (or to the outside of the workspace, but for its floor) over v_max, and a point
  where a camera sees a surface that is not the robot's is forgotten (something is there now).

A point is possibly occupied at t_k when its arrival is at most t_k and it is neither seen free nor inside the robot
or a solid. :meth:`IdealMemory.distances` answers, for query points, how far the nearest possibly-occupied point
is, outside the robot's padded capsules (the space fusion gives to the robot by default): the bound the project's
fused answers are measured against (``benchmarks/probe_memory_robot.py``). The grid's points stand for themselves
(no rounding to voxels): this is generous, as a bound should be.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy import ndimage

from depthguard import config
from depthguard.robots import closed_triangles

#: Default grid spacing, metres.
SPACING = 0.03
#: Pitch of the robot links' voxelised volume, metres.
ROBOT_PITCH = 0.005


def measured_depths(frames: dict) -> dict:
    """Camera name -> (h, w) float64 metres, 0 where the camera measured nothing: ``frames`` (camera name ->
    :class:`depthguard.depth.DepthImage`, as the simulated sensor made them) in the form :meth:`IdealMemory.update`
    takes with ``measured``."""
    return {name: np.nan_to_num(np.asarray(image.metres(), dtype=np.float64), nan=0.0)
            for name, image in frames.items()}


class IdealMemory:
    """SPEC §8a's memory on exact geometry, for one simulated workcell (:func:`depthguard_lab.simulation.load_workcell`).

    Args:
        workcell: the workcell (its rig, robot, workspace, background and labels).
        spacing: grid spacing, metres.
        noise_margin: subtract each camera's noise margin from its exact depths (else none).
        v_max: metres/second (``config.FREESPACE_V_MAX``).
        measured: the depths given to :meth:`update` are the simulated sensor's frames (noise and dropouts), not the
            exact renders: a pixel without a measurement (0) sees nothing free, rather than everything.
        bounds: ((3,), (3,)) metres, world frame: the grid's box (default the workspace), for a finer grid near
            the robot.
        opening: metres, SSM's detection capability d (0: no opening, the memory of every consumer).
        calibration: metres every camera must see beyond a point, on top of the noise margin (the project's
            ``fusion_margin``; 0: the calibration is taken as exact).
        pad: pixels: a point is seen free by a camera only when every pixel within ``pad`` of its own (a square of
            2 pad + 1 a side) sees past it (the project's ``fusion_pixels``; 0: the one pixel it projects to).
    """

    def __init__(self, workcell, spacing: float = SPACING, noise_margin: bool = False,
                 v_max: float = config.FREESPACE_V_MAX, measured: bool = False, bounds=None, opening: float = 0.0,
                 calibration: float = 0.0, pad: int = 0):
        lo, hi = (np.asarray(c, dtype=np.float64) for c in (workcell.rig.workspace if bounds is None else bounds))
        self.spacing, self.v_max, self.noise_margin = float(spacing), float(v_max), bool(noise_margin)
        self.measured, self.opening = bool(measured), float(opening)
        self.calibration, self.pad = float(calibration), int(pad)
        self.shape = tuple(int(n) for n in np.maximum(np.floor((hi - lo) / spacing), 1))
        self.lo, self.hi = lo, lo + np.asarray(self.shape) * spacing
        axes = [lo[i] + (np.arange(self.shape[i]) + 0.5) * spacing for i in range(3)]
        self.points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        self.robot = workcell.robot
        self.cameras = dict(workcell.rig.cameras)
        self._robot_labels = {i for i, (name, _) in enumerate(workcell.labels()) if name.startswith("robot/")}
        self._links = {}
        for link, mesh in self.robot.collision_meshes.items():
            triangles = closed_triangles(mesh)
            if triangles is not None:
                mesh = trimesh.Trimesh(vertices=triangles.reshape(-1, 3),
                                       faces=np.arange(3 * len(triangles)).reshape(-1, 3))
                mesh.merge_vertices()
            self._links[link] = mesh.voxelized(ROBOT_PITCH).fill()
        solid = np.zeros(len(self.points), dtype=bool)
        for box in workcell.background_parts():
            solid |= box.distance(self.points) <= 0.0
        self.solid = solid.reshape(self.shape)
        self.arrival = np.full(self.shape, -np.inf)
        self.ever_seen = np.zeros(self.shape, dtype=bool)
        self.possibly = np.ones(self.shape, dtype=bool)
        self._tree = None

    def inside_robot(self, joints) -> np.ndarray:
        """(nx, ny, nz) bool: the grid points inside the robot's links at ``joints``."""
        out = np.zeros(len(self.points), dtype=bool)
        poses = self.robot.link_poses(joints)
        for link, grid in self._links.items():
            T = np.asarray(poses[link])
            local = (self.points - T[:3, 3]) @ T[:3, :3]
            lo, hi = grid.bounds
            near = np.flatnonzero(np.all((local >= lo) & (local <= hi), axis=1))
            if len(near):
                out[near[grid.is_filled(local[near])]] = True
        return out.reshape(self.shape)

    def update(self, time: float, joints, depth_exact: dict, labels: dict) -> None:
        """Take in one frame: its time (seconds), joints, each camera's exact depth ((h, w) metres, 0 = nothing;
        with ``measured``, its measured depth, 0 = no measurement) and label image ((h, w), indices into the
        workcell's labels)."""
        seen = np.zeros(len(self.points), dtype=bool)
        surfaces = np.zeros(len(self.points), dtype=bool)
        for name, camera in self.cameras.items():
            depth = np.asarray(depth_exact[name], dtype=np.float64)
            h, w = depth.shape
            local = camera.world_to_camera(self.points)
            z = local[:, 2]
            front = z > 1e-3
            u = np.full(len(z), -1, dtype=np.int64)
            v = np.full(len(z), -1, dtype=np.int64)
            u[front] = np.rint(camera.fx * local[front, 0] / z[front] + camera.cx).astype(np.int64)
            v[front] = np.rint(camera.fy * local[front, 1] / z[front] + camera.cy).astype(np.int64)
            inside = front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
            reach = np.where(depth > 0.0, depth - (camera.noise.margin(depth) if self.noise_margin else 0.0)
                             - self.calibration, 0.0 if self.measured else np.inf)
            if self.pad > 0:  # the nearest reach within pad pixels; beyond the image's edge, nothing is seen
                reach = ndimage.minimum_filter(reach, size=2 * self.pad + 1, mode="constant", cval=0.0)
            seen[np.flatnonzero(inside)[z[inside] < reach[v[inside], u[inside]]]] = True
            # what this camera sees that is not the robot: a surface is there now
            label = np.asarray(labels[name])
            hit = (depth > 0.0) & ~np.isin(label, list(self._robot_labels))
            rows, cols = np.nonzero(hit)
            zs = depth[rows, cols]
            rays = np.stack([(cols - camera.cx) / camera.fx * zs, (rows - camera.cy) / camera.fy * zs, zs], axis=1)
            T = np.linalg.inv(camera.T_camera_world)
            world = rays @ T[:3, :3].T + T[:3, 3]
            index = np.floor((world - self.lo) / self.spacing).astype(np.int64)
            keep = np.all((index >= 0) & (index < self.shape), axis=1)
            surfaces[np.ravel_multi_index(index[keep].T, self.shape)] = True
        seen = (seen & ~surfaces).reshape(self.shape)
        self.arrival.reshape(-1)[surfaces] = -np.inf
        free = seen | self.inside_robot(joints) | self.solid
        possibly = (self.arrival <= time) & ~free
        if self.opening > 0.0:
            possibly = opened(possibly, self.opening / 2.0 / self.spacing)
        # distance to the nearest possibly-occupied point (the grid's outside is no source); none: nothing arrives
        distance = ndimage.distance_transform_edt(~possibly) * self.spacing if possibly.any() else np.inf
        np.maximum(self.arrival, time + distance / self.v_max, out=self.arrival)
        self.possibly, self.surfaces = possibly, surfaces.reshape(self.shape)
        self._tree = None  # nearest()'s, of these possibly-occupied points
        self.ever_seen |= seen

    def nearest(self, points: np.ndarray) -> np.ndarray:
        """(m,) metres: each of the (m, 3) query points' distance to the nearest possibly-occupied grid point, at
        most its distance to the grid box's side (beyond it nothing is known: the distance is "at least" that)."""
        from scipy.spatial import cKDTree

        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        side = np.minimum(points - self.lo, self.hi - points).min(axis=1)
        if self._tree is None:
            where = self.points[self.possibly.reshape(-1)]
            self._tree = cKDTree(where) if len(where) else False
        if not len(points) or self._tree is False:
            return np.maximum(side, 0.0)
        distance, _ = self._tree.query(points, distance_upper_bound=max(float(side.max()), 0.0) + 1e-9)
        return np.maximum(np.minimum(distance, side), 0.0)

    def distances(self, points: np.ndarray, capsules, rho: float) -> tuple[np.ndarray, list[str]]:
        """For each of the (m, 3) query points: the distance (metres, inf beyond ``rho``) to the nearest point
        possibly occupied now outside the padded ``capsules`` (:class:`depthguard.scenes.Capsule` list), and where
        that point is: "never seen" (no camera has seen it free yet), "seen before" (seen free earlier, reached by
        the erosion since), or "" (none within rho)."""
        candidates = np.flatnonzero(self.possibly.reshape(-1))
        where = self.points[candidates]
        for capsule in capsules:
            p0, p1 = np.asarray(capsule.p0), np.asarray(capsule.p1)
            axis = p1 - p0
            s = np.clip((where - p0) @ axis / max(float(axis @ axis), 1e-12), 0.0, 1.0)
            outside = np.linalg.norm(where - (p0 + s[:, None] * axis), axis=1) > capsule.radius
            candidates, where = candidates[outside], where[outside]
        out = np.full(len(points), np.inf)
        kinds = [""] * len(points)
        ever = self.ever_seen.reshape(-1)
        for i, point in enumerate(np.asarray(points, dtype=np.float64)):
            d = np.linalg.norm(where - point, axis=1)
            if len(d) and d.min() <= rho:
                j = int(np.argmin(d))
                out[i] = d[j]
                kinds[i] = "seen before" if ever[candidates[j]] else "never seen"
        return out, kinds


def opened(mask: np.ndarray, radius: float) -> np.ndarray:
    """The opening of a boolean grid by a ball of ``radius`` (in grid steps): the True points that lie in some ball
    centred on a grid point whose grid points within ``radius`` are all True."""
    centres = ndimage.distance_transform_edt(mask) > radius
    if not centres.any():
        return np.zeros_like(mask)
    return mask & (ndimage.distance_transform_edt(~centres) <= radius)
