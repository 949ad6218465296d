"""The robot's tile images (design §10, steps 3 and 7; Henrich & Gecks sections 3.3 and 3.6), projected
analytically from the robot's padded capsules: no rendering, a few microseconds per configuration and camera.

Each capsule is the convex hull of its two end balls, so its image is the convex hull of the balls' images; a ball's
image lies within the pixel rectangle of its tangent planes. A tile is covered when its footprint meets the convex
hull of the two rectangles: a superset of the tiles the capsule is seen in (tests/test_collision.py compares it with
a rendering of the same capsules).

Swept volumes (step 7): a motion from one configuration to the next is sampled so that between two samples no point
of the robot travels more than ``x_max`` (metres), and the samples' capsules are widened by x_max / 2: every point
the robot passes lies within x_max / 2 of where the same point of the robot is at the nearer sample.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from depthguard import config
from depthguard.kernels import collision as collision_kernels
from depthguard.collision._epipolar import TileGrid
from depthguard.errors import InputError
from depthguard.validation import NOT_A_NUMBER


class RobotProjector:
    """The robot's padded capsules projected onto the tile grids of C cameras.

    Args:
        robot: the :class:`~depthguard.robots.RobotModel` (its capsules include its padding).
        grids: one :class:`TileGrid` per camera.
        x_max: metres, the most any point of the robot may travel between two samples of a swept volume (the paper
            used the smallest link cross-section); the samples' capsules are widened by x_max / 2.

    Bit images are (words,) uint64 bitsets in tile index order (:meth:`TileGrid.pack`).
    """

    def __init__(self, robot, grids: Sequence[TileGrid], x_max: float = 0.02):
        if isinstance(x_max, bool) or not isinstance(x_max, (int, float, np.floating)) or \
                not (math.isfinite(x_max) and 0.001 <= x_max <= 0.5):
            raise InputError(f"x_max must be a distance in [0.001, 0.5] metres, got {x_max!r}", field="x_max")
        self.robot = robot
        self.grids = list(grids)
        self.x_max = float(x_max)
        self.radii = np.array([capsule.radius for capsule in robot.capsules], dtype=np.float64)
        #: (n,) metres per radian: how fast a point of the robot can move per unit of each joint's velocity.
        self.reaches = robot.joint_reaches()
        #: (m,) bool: the capsules a joint moves (the base and what is fixed to it never do).
        self.moving = robot.moving_links()
        self._poses = []
        for grid in self.grids:
            T = grid.camera.T_camera_world
            cam = grid.camera
            self._poses.append((np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]),
                                float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy)))

    def _segments(self, configurations, field: str = "configurations") -> np.ndarray:
        n = self.robot.n_joints
        try:
            q = np.asarray(configurations, dtype=np.float64)
        except NOT_A_NUMBER:
            raise InputError(f"{field} must be (K, {n}) joint positions, got {type(configurations).__name__}",
                             field=field) from None
        if q.ndim != 2 or q.shape[1] != n or not np.all(np.isfinite(q)):
            raise InputError(f"{field} must be (K, {n}) finite joint positions, got {q.shape}", field=field)
        tol = config.JOINT_LIMIT_TOLERANCE
        outside = np.any((q < self.robot.lower - tol) | (q > self.robot.upper + tol), axis=1)
        if outside.any():
            self.robot.joint_vector(q[np.argmax(outside)])  # raises, naming the joints beyond their limits
        ends = np.empty((len(q), len(self.radii), 2, 3))
        for k, joints in enumerate(q):
            ends[k] = self.robot.capsule_segments(joints, check=False)
        return ends

    def _bits(self, ends: np.ndarray, radii: np.ndarray) -> np.ndarray:
        words = max(grid.words for grid in self.grids)
        out = np.zeros((len(self.grids), ends.shape[0], words), dtype=np.uint64)
        project = collision_kernels.capsule_tile_bits_parallel if len(ends) >= 64 else collision_kernels.capsule_tile_bits
        for c, (grid, (R, t, fx, fy, cx, cy)) in enumerate(zip(self.grids, self._poses)):
            project(ends, radii, R, t, fx, fy, cx, cy, grid.col_edges, grid.row_edges, grid.words,
                    out[c, :, : grid.words])
        return out

    def bits(self, configurations, moving_only: bool = False) -> np.ndarray:
        """(C, K, words) uint64: per camera, the tiles covered by each of the (K, n) configurations (with
        ``moving_only``, by the links a joint moves: see :meth:`images`)."""
        ends = self._segments(configurations)
        if moving_only:
            return self._bits(np.ascontiguousarray(ends[:, self.moving]), self.radii[self.moving])
        return self._bits(ends, self.radii)

    def capsule_bits(self, configurations, moving_only: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Per capsule, for the depth order of the collision test: (bits (C, K, m, words) uint64: the tiles each of
        the m capsules covers in each of the (K, n) configurations; far (C, K, m) float64 metres: the deepest optical
        depth any point of that capsule has in that camera, its ends' depth plus its radius). ``moving_only``: the
        capsules a joint moves only (:meth:`images`)."""
        ends = self._segments(configurations)
        radii = self.radii
        if moving_only:
            ends, radii = np.ascontiguousarray(ends[:, self.moving]), radii[self.moving]
        words = max(grid.words for grid in self.grids)
        bits = np.zeros((len(self.grids), ends.shape[0], ends.shape[1], words), dtype=np.uint64)
        for j in range(ends.shape[1]):
            bits[:, :, j] = self._bits(np.ascontiguousarray(ends[:, j: j + 1]), radii[j: j + 1])
        far = np.empty((len(self.grids), ends.shape[0], ends.shape[1]))
        for c, (R, t, *_rest) in enumerate(self._poses):
            depth = ends @ R[2] + t[2]  # (K, m, 2) optical depth of each capsule's two ends
            far[c] = depth.max(axis=2) + radii
        return bits, far

    def images(self, joints, moving_only: bool = False) -> list[np.ndarray]:
        """Step 3 at ``joints`` ((n,) radians): per camera, (rows, cols) bool tiles covered by the robot; with
        ``moving_only``, by the links a joint moves only. A future configuration is tested with those: its base is
        where the current base is, inside the robot's own volume, where no obstacle can be (the paper's "the robot is
        collision-free within its very own volume"), and the tiles it shares with everything else would otherwise
        meet every possible obstacle the base's tiles hold."""
        return self.unpack(self.bits(np.asarray(joints, dtype=np.float64)[None], moving_only)[:, 0])

    def samples(self, path, reaches=None) -> np.ndarray:
        """(N, n) configurations along the piecewise-linear joint-space ``path`` ((P, n), P >= 1): each segment
        from q_a to q_b is cut into s = max(1, sum_i ceil(|dq_i| l_i / x_max)) equal steps, l_i = :attr:`reaches`.

        This is the paper's n = sum_i n_i with joint i's step x_max / l_i, the arc on which a point at l_i from the
        axis travels x_max, instead of the paper's 2 arcsin(x_max / (2 l_i)), the chord: when joints move together
        their points' paths add up as arcs, and with the chord the total travel per step could exceed x_max.
        ``reaches``: (n,) other bounds than :attr:`reaches` (e.g. with a gripped piece). At most
        ``config.MAX_MOTION_SAMPLES`` samples, else InputError (field ``path``)."""
        try:
            q = np.asarray(path, dtype=np.float64)
        except NOT_A_NUMBER:
            raise InputError(f"path must be (P, n) joint positions, got {type(path).__name__}", field="path") from None
        if q.ndim == 1:
            q = q[None]
        self._segments(q, "path")  # checks the path (shape, finite, limits)
        reaches = self.reaches if reaches is None else np.asarray(reaches, dtype=np.float64)
        steps = [max(1, int(np.sum(np.ceil(np.abs(b - a) * reaches / self.x_max - 1e-12))))
                 for a, b in zip(q[:-1], q[1:])]
        if sum(steps) > config.MAX_MOTION_SAMPLES:
            raise InputError(f"the motion needs {sum(steps)} samples {self.x_max:g} m apart, at most "
                             f"{config.MAX_MOTION_SAMPLES}: test it in parts", field="path")
        out = [q[:1]]
        for a, b, n in zip(q[:-1], q[1:], steps):
            out.append(a + np.arange(1, n + 1)[:, None] / n * (b - a))
        return np.concatenate(out)

    def swept_bits(self, path, moving_only: bool = False) -> np.ndarray:
        """Step 7: (C, words) uint64, per camera, the tiles covered by the volume the robot sweeps along ``path``
        ((P, n) configurations, joint-space straight lines between them): the union of the :meth:`samples`'
        capsules, each widened by x_max / 2 (a single configuration is not widened). ``moving_only``: as
        :meth:`images`."""
        q = self.samples(path)
        keep = self.moving if moving_only else np.ones(len(self.radii), dtype=bool)
        ends = np.ascontiguousarray(self._segments(q)[:, keep]).reshape(1, -1, 2, 3)
        widen = self.x_max / 2.0 if len(q) > 1 else 0.0
        return self._bits(ends, np.tile(self.radii[keep] + widen, len(q)))[:, 0]

    def swept_images(self, path, moving_only: bool = False) -> list[np.ndarray]:
        """:meth:`swept_bits` as per camera (rows, cols) bool images."""
        return self.unpack(self.swept_bits(path, moving_only))

    def unpack(self, bits: np.ndarray) -> list[np.ndarray]:
        """(C, words) bitsets -> per camera (rows, cols) bool."""
        return [grid.unpack(row) for grid, row in zip(self.grids, bits)]
