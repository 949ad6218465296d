"""The collision test of Henrich & Gecks over C calibrated cameras, steps 1-6 together (design §10):
reference images once, then per set of images the revised obstacle images, then any number of configurations
tested against them."""

from __future__ import annotations

import math
from dataclasses import replace
from collections.abc import Mapping, Sequence

import numpy as np
from scipy import ndimage

from depthguard import config
from depthguard.cameras import Rig
from depthguard.collision._boxes import box_corners, grid_bits
from depthguard.collision._difference import (
    depth_metres,
    depth_difference_image,
    tile_free_depth,
    difference_image,
    light_gain,
    reference_image,
    robot_tiles,
    tile_features,
    unexplained_intensity_tiles,
    unexplained_tiles,
)
from depthguard.collision._epipolar import EpipolarBands, TileGrid
from depthguard.collision._robot_image import RobotProjector
from depthguard.collision._tables import (Verdict, camera_collisions, depth_ordered_collisions, obstacle_image,
                                          revised_obstacle_images, verdict)
from depthguard.errors import InputError
from depthguard.validation import NOT_A_NUMBER


class ImageCollisionTest:
    """Whether a robot configuration collides with what the cameras see (the paper's sections 3.1-3.5).

    Args:
        rig: the cameras (intensity or depth); every camera of the rig takes part.
        robot: the :class:`~depthguard.robots.RobotModel` seen by them.
        workspace: (2, 3) world-frame box, metres, holding the robot and the obstacles (bounds the epipolar bands).
        tiles: (rows, cols) of each camera's difference image (the paper: 64 x 64).
        theta: the occlusion threshold, the most cameras in which the robot may hide an obstacle at once; default
            C - 1 (no assumption: an unknown tile is a possible obstacle when any other camera sees an obstacle in
            its epipolar band). The paper used 1 with two cameras.
        unseen: "occupied" (default, fail-safe): a configuration that meets obstacles or possible obstacles in every
            camera collides (classes B, C and D); "free": the paper's section 3.5, class B is collision-free
            (assumes every obstacle is seen by at least C - theta cameras: not so for a hand next to the robot).
            Either way an obstacle that the current robot hides from every camera is not seen (its blind spot), nor
            one that lies within the robot's shell in the cameras that see it and is hidden from the others
            (:attr:`Verdict.shell` marks the free verdicts that rest on that).
        classifier: a fitted :class:`BayesTileClassifier` that decides which intensity tiles are foreground instead
            of the thresholds.
        thresholds: per tile feature, the change that makes a tile foreground (:func:`difference_image`): for
            intensity images (mean grey value, balance point row in tile heights), default (6, 0.05) (scenario C:
            88 % of the tiles a person covers by a tenth; (12, 0.1) found 76 %, a trained BayesTileClassifier 99 %:
            benchmarks/probe_tile_classifier.py); for depth
            images (the change in metres that makes a pixel changed, at least the camera's noise margin; the
            fraction of changed pixels that makes a tile foreground), default (0.05, 0.25): a quarter, above
            the few pixels a depth camera drops at random near edges and at grazing angles.
        images: "intensity" (the paper: 8-bit grey images) or "depth" (beyond the paper: depth images, uint16 in
            the cameras' depth_scale units or float metres; :func:`depth_difference_image`).
        geometry: the robot geometry projected into the cameras: "capsules" (default; the padded capsules projected
            analytically, :class:`RobotProjector`), or "hulls" or "meshes" (rendered by
            :class:`depthguard.self_filter.RobotSilhouette`, padded, far slower).
        x_max: metres, the most a point of the robot travels between two samples of a swept volume
            (:meth:`test_motion`; :class:`RobotProjector`).
        lighting: follow changes of the room's light (beyond the paper): per image, its brightness relative to the
            reference (:func:`light_gain`, the median ratio over the tiles) divides its mean grey values before they
            are compared. A camera whose gain cannot be estimated or lies outside ``config.LIGHT_GAIN_RANGE`` sees
            every tile as foreground (the conservative answer); :attr:`gains` holds the last estimates (NaN there).
        depth_order: with depth images: a camera asserts Coll_RO or Coll_RP at a tile only where the future robot's
            capsule there reaches behind the depth up to which that camera saw the tile free
            (:func:`tile_free_depth`, :func:`depth_ordered_collisions`; design §10); False: the images alone, as the
            paper. Applies to :meth:`test` and :class:`ConfigurationTable`; :meth:`test_motion`'s swept volumes use
            the images alone (more collisions, never fewer). Off by default, measured: in scenario C it removes none
            of 346 false alarms (they rest on possible obstacles behind the current robot, which the order does not
            clear) and costs 11 ms a set (benchmarks/bench_collision.py).

    Use: :meth:`set_reference` once (images of the workspace with the robot in several configurations and no
    obstacle), :meth:`observe` per set of images with the robot's joints at their capture, then :meth:`test` for any
    configuration (the current one, future ones) and :meth:`test_motion` for a whole motion.
    """

    def __init__(self, rig: Rig, robot, workspace, tiles=(64, 64), theta: int | None = None, thresholds=None,
                 geometry: str = "capsules", x_max: float = 0.02, lighting: bool = True, images: str = "intensity",
                 unseen: str = "occupied", classifier=None, depth_order: bool = False, robot_pixels: bool = True):
        if not isinstance(rig, Rig):
            raise InputError(f"rig must be a depthguard Rig, got {type(rig).__name__}", field="rig")
        try:
            rows, cols = tiles
        except (TypeError, ValueError):
            raise InputError(f"tiles must be (rows, cols), got {tiles!r}", field="tiles") from None
        self.names = tuple(rig.cameras)
        self.grids = [TileGrid(camera, rows, cols) for camera in rig.cameras.values()]
        self.bands = EpipolarBands(self.grids, workspace)
        theta = len(self.grids) - 1 if theta is None else theta
        verdict([True] * len(self.grids), [True] * len(self.grids), theta, unseen)  # checks theta and unseen
        self.theta = int(theta)
        self.unseen = unseen
        if images not in ("intensity", "depth"):
            raise InputError(f"images must be 'intensity' or 'depth', got {images!r}", field="images")
        self.images = images
        if thresholds is None:
            thresholds = (6.0, 0.05) if images == "intensity" else (0.05, 0.25)
        try:
            self.thresholds = np.array(thresholds, dtype=np.float64)
        except NOT_A_NUMBER:
            self.thresholds = None
        if self.thresholds is None or self.thresholds.shape != (2,) or not np.all(self.thresholds >= 0.0) or \
                not np.all(np.isfinite(self.thresholds)):
            raise InputError(f"thresholds must be two finite numbers >= 0 (the two tile features' changes), got "
                             f"{thresholds!r}", field="thresholds")
        self.lighting = bool(lighting) and images == "intensity"
        if not isinstance(depth_order, bool):
            raise InputError(f"depth_order must be True or False, got {depth_order!r}", field="depth_order")
        self.depth_order = depth_order and images == "depth"
        if not isinstance(robot_pixels, bool):
            raise InputError(f"robot_pixels must be True or False, got {robot_pixels!r}", field="robot_pixels")
        self.robot_pixels = robot_pixels
        self._pixel_silhouette = None  # the robot's padded hulls, rendered per observed set (robot_pixels)
        self._piece_meshes: dict = {}  # a gripped piece's shape -> its mesh in that renderer
        #: A gripped work piece (a :class:`~depthguard.scenes.Box` in the end-effector link's frame, or None), part of
        #: the robot's render for ``robot_pixels`` (:class:`ReferenceUpdate` sets it when the robot grips one).
        self.piece = None
        #: Per camera, the tiles of the last observed set whose change neither the robot nor its gripped piece
        #: explains ((rows, cols) bool; None without ``robot_pixels``).
        self.unexplained = None
        #: Per camera, the current robot's tile image of the last observed set ((rows, cols) bool; with a gripped
        #: piece, :class:`ReferenceUpdate` ORs its tiles in): what :attr:`Verdict.shell` compares with.
        self.robot_now = None
        self.free = None  # per camera, (rows, cols) metres: the tiles' free depth of the last observed depth images
        self.classifier = classifier
        self.gains = []
        self.robot = robot
        self.projector = RobotProjector(robot, self.grids, x_max)
        if geometry == "capsules":
            self.silhouette = None
        else:
            from depthguard.self_filter import RobotSilhouette  # OpenGL: only when used

            self.silhouette = RobotSilhouette(robot, geometry=geometry)
        self.reference = None
        self.reference_images = None
        #: Per camera, the (height, width) bool pixels that the robot covered in every reference image (the room
        #: behind them never seen, so the reference holds the robot there), or None (no joints given to
        #: :meth:`set_reference`, or no such pixel). Where the robot has left such a pixel, :meth:`observe` counts
        #: its tile changed whatever it shows: an object standing where the robot stood is not taken for the room.
        self.unreferenced = None
        self._unreferenced_boxes = None  # per camera, (first row, end row, first col, end col) around them, or None
        self.revised = None

    def _per_camera(self, images: Mapping, field: str) -> list:
        if not isinstance(images, Mapping) or set(images) != set(self.names):
            got = sorted(images) if isinstance(images, Mapping) else type(images).__name__
            raise InputError(f"{field} must map every camera ({', '.join(self.names)}) to its images, got {got}",
                             field=field)
        return [images[name] for name in self.names]

    def robot_image(self, joints, future: bool = False) -> list[np.ndarray]:
        """Step 3 at ``joints``: per camera, (rows, cols) bool tiles that the robot's padded geometry covers. With
        ``future`` (a configuration to test), the links a joint moves only (:meth:`RobotProjector.images`: the base
        stays inside its own volume); the rendered geometries ("hulls", "meshes") always draw every link."""
        q = self.robot.joint_vector(joints)
        if self.silhouette is None:
            return self.projector.images(q, moving_only=future)
        return [robot_tiles(self.silhouette.render(grid.camera, q) > 0.0, grid) for grid in self.grids]

    def robot_bits(self, configurations) -> np.ndarray:
        """(C, K, words) uint64: per camera, the tiles covered by each of the (K, n) configurations to test (as
        :meth:`robot_image` with ``future``)."""
        if self.silhouette is None:
            return self.projector.bits(configurations, moving_only=True)
        q = np.asarray(configurations, dtype=np.float64)
        n = self.robot.n_joints
        if q.ndim != 2 or q.shape[1] != n or not np.all(np.isfinite(q)):
            raise InputError(f"configurations must be (K, {n}) finite joint positions, got {q.shape}",
                             field="configurations")
        words = max(grid.words for grid in self.grids)
        bits = np.zeros((len(self.grids), len(q), words), dtype=np.uint64)
        for k, joints in enumerate(q):
            for c, (grid, tiles) in enumerate(zip(self.grids, self.robot_image(joints, future=True))):
                bits[c, k, : grid.words] = grid.pack(tiles)
        return bits

    def set_reference(self, images: Mapping[str, Sequence[np.ndarray]], joints=None) -> None:
        """Step 1: per camera name, several images of the workspace without obstacles, the robot in different
        configurations (their per-pixel median is the reference).

        ``joints``: optionally the robot's configuration in each of them, (K, n) radians, the k-th image of every
        camera taken at joints[k]; then each pixel's median leaves out the images in which the robot covers its
        tile (:func:`reference_image`), and the robot vanishes from the reference even where the configurations
        overlap (without them, a pixel the robot covers in half of the images or more keeps the robot)."""
        stacks = self._per_camera(images, "images")
        if self.images == "depth":  # each image in metres first (uint16 units differ per camera)
            stacks = [[depth_metres(image, grid, f"images[{k}]") for k, image in enumerate(stack)]
                      for stack, grid in zip(stacks, self.grids)]
        robots = [None] * len(self.grids)
        if joints is not None:
            q = np.asarray(joints, dtype=np.float64)
            if q.ndim != 2 or any(len(stack) != len(q) for stack in stacks):
                raise InputError(f"joints must be (K, n), one configuration per reference image (K = "
                                 f"{[len(stack) for stack in stacks]}), got shape {q.shape}", field="joints")
        pixels = [None] * len(self.grids)
        if joints is not None and self.robot_pixels:
            # with the robot's render at hand, leave out its pixels (grown by one) rather than its tiles
            renders = [self._robot_renders(joints_k) for joints_k in q]
            pixels = [[ndimage.maximum_filter(render[c] > 0.0, size=3, mode="nearest") for render in renders]
                      for c in range(len(self.grids))]
        elif joints is not None:
            bits = self.projector.bits(q)
            unpacked = [self.projector.unpack(bits[:, k]) for k in range(len(q))]
            robots = [[images[c] for images in unpacked] for c in range(len(self.grids))]
        references = [reference_image(stack, grid, robot, mask)
                      for stack, grid, robot, mask in zip(stacks, self.grids, robots, pixels)]
        self._set_unreferenced(None if joints is None else [
            np.logical_and.reduce(mask) if mask is not None else grid.pixels(np.logical_and.reduce(robot))
            for mask, robot, grid in zip(pixels, robots, self.grids)])
        self.reference_images = references  # per camera, (h, w) float64 medians: what robot_pixels compares
        # intensity: the reference's tile features; depth: the reference depth image itself (metres)
        self.reference = [tile_features(image, grid) if self.images == "intensity" else image
                          for image, grid in zip(references, self.grids)]
        self.revised = None

    def _set_unreferenced(self, masks) -> None:
        """Keep ``masks`` (per camera, (height, width) bool or None; or None for every camera) as
        :attr:`unreferenced`, each with the box round its pixels grown by one pixel (what :meth:`_with_unreferenced`
        looks at)."""
        if masks is None:
            self.unreferenced, self._unreferenced_boxes = None, None
            return
        self.unreferenced, self._unreferenced_boxes = [], []
        for mask in masks:
            rows, cols = np.nonzero(mask) if mask is not None else (np.zeros(0), np.zeros(0))
            if rows.size == 0:
                self.unreferenced.append(None)
                self._unreferenced_boxes.append(None)
                continue
            h, w = mask.shape
            self.unreferenced.append(mask)
            self._unreferenced_boxes.append((max(int(rows.min()) - 1, 0), min(int(rows.max()) + 2, h),
                                             max(int(cols.min()) - 1, 0), min(int(cols.max()) + 2, w)))

    def _with_unreferenced(self, foreground: np.ndarray, c: int, near, robot) -> np.ndarray:
        """Camera ``c``'s difference image ``foreground`` ((rows, cols) bool) with every tile holding a pixel of
        :attr:`unreferenced` that the current robot no longer covers (its render ``near`` grown by one pixel, as the
        reference's masks, or without a render its tile image ``robot``) set: the reference there is the robot, so
        nothing tells the room from an object standing where it stood (Table I makes such a tile an obstacle, or
        under the robot's image unknown unless the pixel rule finds it one)."""
        if self.unreferenced is None or self.unreferenced[c] is None:
            return foreground
        r0, r1, c0, c1 = self._unreferenced_boxes[c]
        grid = self.grids[c]
        rows, cols = grid.tile_of_pixels()
        if near is not None:
            here = ndimage.maximum_filter(near[r0:r1, c0:c1] > 0.0, size=3, mode="nearest")
        else:
            here = robot[rows[r0:r1, None], cols[None, c0:c1]]
        left_r, left_c = np.nonzero(self.unreferenced[c][r0:r1, c0:c1] & ~here)
        if left_r.size == 0:
            return foreground
        foreground = foreground.copy()
        foreground[rows[left_r + r0], cols[left_c + c0]] = True
        return foreground

    def observe(self, images: Mapping[str, np.ndarray], joints) -> list[np.ndarray]:
        """Steps 2-5 for one set of images (camera name -> (height, width) image) captured at ``joints``: the revised
        obstacle images, kept for :meth:`test`, and returned (per camera, (rows, cols) uint8 labels). A set that is
        refused (bad images or joints) leaves no answer behind: :meth:`test` refuses until a set is observed."""
        self.revised = None  # no test answers from older images once a new set arrived
        self.free = None
        self.robot_now = None
        self.unexplained = None
        self.gains = []
        if self.reference is None:
            raise InputError("set_reference first: the difference images need the reference", field="reference")
        frames = self._per_camera(images, "images")
        robot_now = self.robot_image(joints)
        obstacles = []
        gains = []
        near = self._robot_renders(joints) if self.robot_pixels else [None] * len(self.grids)
        unexplained = []
        for c, (frame, grid, reference, robot) in enumerate(zip(frames, self.grids, self.reference, robot_now)):
            if self.images == "depth":
                gains.append(1.0)
                foreground = self._with_unreferenced(
                    depth_difference_image(frame, reference, grid, self.thresholds), c, near[c], robot)
                odd = None if near[c] is None else \
                    unexplained_tiles(frame, reference, near[c], grid, self.thresholds, tiles=foreground & robot)
            else:
                features = tile_features(frame, grid)
                gain = light_gain(features, reference) if self.lighting else 1.0
                if not (math.isfinite(gain) and config.LIGHT_GAIN_RANGE[0] <= gain <= config.LIGHT_GAIN_RANGE[1]):
                    gain = math.nan  # no trustworthy estimate: every tile of this camera is foreground
                gains.append(gain)
                foreground = self._with_unreferenced(
                    difference_image(features, reference, self.thresholds, gain, self.classifier), c, near[c], robot)
                odd = None
                if near[c] is not None:
                    if self.reference_images is None:
                        raise InputError("robot_pixels compares pixels with the reference images: set the reference "
                                         "with set_reference (or robot_pixels=False)", field="reference")
                    odd = unexplained_intensity_tiles(frame, self.reference_images[c], gain, near[c], grid,
                                                      tiles=foreground & robot)
            obstacles.append(obstacle_image(foreground, robot, odd))
            unexplained.append(odd)
        revised = revised_obstacle_images(obstacles, self.bands, self.theta)
        if self.depth_order:
            self.free = [tile_free_depth(frame, grid) for frame, grid in zip(frames, self.grids)]
        self.revised = revised
        self.gains = gains
        self.unexplained = unexplained if self.robot_pixels else None
        self.robot_now = robot_now
        return self.revised

    def _robot_renders(self, joints) -> list[np.ndarray]:
        """Per camera, the robot's padded hulls rendered at ``joints``: (height, width) float32 metres, 0 where it
        is not (:meth:`depthguard.self_filter.RobotSilhouette.render`)."""
        if self._pixel_silhouette is None:
            from depthguard.self_filter import RobotSilhouette  # OpenGL: only with robot_pixels

            self._pixel_silhouette = RobotSilhouette(self.robot, geometry="hulls")
        q = self.robot.joint_vector(joints)
        silhouette = self._pixel_silhouette
        instances = silhouette.instances(q)
        if self.piece is not None:  # drawn with the robot, in the end-effector link's frame
            from depthguard.rendering import MeshInstance

            link = self.robot.control_points[self.robot.end_effector_index].link
            instances.append(MeshInstance(self._piece_mesh(self.piece), self.robot.link_poses(q)[link]))
        return [silhouette.renderer.render_depth(grid.camera, instances) for grid in self.grids]

    def _piece_mesh(self, piece) -> int:
        """The renderer's mesh of a gripped piece (its :class:`Box` in the end-effector link's frame), uploaded once
        per shape."""
        key = (tuple(piece.center), tuple(piece.half_extents), np.asarray(piece.R_world_box).tobytes())
        if key not in self._piece_meshes:
            from depthguard.rendering import primitive_mesh

            vertices, faces = primitive_mesh(piece)
            self._piece_meshes[key] = self._pixel_silhouette.renderer.add_mesh(vertices, faces, closed=True)
        return self._piece_meshes[key]

    def test(self, joints) -> Verdict:
        """Step 6 for the configuration ``joints`` against the last observed images (with the depth order when
        ``depth_order``)."""
        if self.depth_order and self.silhouette is None:
            if self.revised is None:
                raise InputError("observe a set of images first", field="revised")
            q = self.robot.joint_vector(joints)[None]
            return ConfigurationTable(self, q).verdict(0)
        return self._verdict(self.robot_image(joints, future=True))

    def test_motion(self, path, chunk: int = 8) -> Verdict:
        """Steps 6-7 for a whole motion: ``path`` (P, n) configurations joined by straight lines in joint space. The
        motion is sampled (:meth:`RobotProjector.samples`: no point travels more than x_max between samples) and cut
        into pieces of ``chunk`` steps; each piece's swept volume (the padded capsules widened by x_max / 2) is the
        future robot image of one test. The motion collides iff a piece does; the verdict returned is the first
        colliding piece's, else the one of highest class.

        Why pieces: the test compares images camera by camera, so one swept image of a long motion meets an obstacle's
        tiles in one camera at one part of the motion and in another camera at another part, and reads as a
        collision where no part of the motion meets it. Every piece together covers the whole motion, so cutting
        it loses nothing."""
        if isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1:
            raise InputError(f"chunk must be a whole number of steps >= 1, got {chunk!r}", field="chunk")
        samples = self.projector.samples(path)
        if len(samples) == 1:
            return self._verdict(self.projector.swept_images(samples, moving_only=True))
        best = None
        for start in range(0, len(samples) - 1, chunk):
            v = self._verdict(self.projector.swept_images(samples[start: start + chunk + 1], moving_only=True))
            if v.collision:
                return v
            best = v if best is None or v.klass > best.klass else best
        return best

    def _verdict(self, robot_images) -> Verdict:
        if self.revised is None:
            raise InputError("observe a set of images first", field="revised")
        flags = [camera_collisions(revised, robot) for revised, robot in zip(self.revised, robot_images)]
        v = verdict([f[0] for f in flags], [f[1] for f in flags], self.theta, self.unseen)
        # revised images set by hand carry no robot image of theirs: every free verdict then counts as resting on it
        shell = not v.collision and (self.robot_now is None or all(
            bool(np.any(np.asarray(image) & now)) for image, now in zip(robot_images, self.robot_now)))
        return replace(v, shell=shell)


class ConfigurationTable:
    """Section 3.3's table made cheap (design §10): the robot's tile images of many configurations, per camera,
    as bitsets, so that the verdict for every configuration against one set of revised obstacle images costs a few
    bitwise operations per configuration.

    Args:
        test: the :class:`ImageCollisionTest` (its cameras, grids, theta and robot geometry).
        configurations: (K, n) joint positions, radians, the robot's joint order (e.g. a discretised configuration
            space; the paper used 8,192).
        piece: a gripped work piece, a :class:`~depthguard.scenes.Box` in the end-effector link's frame (what
            :meth:`ReferenceUpdate.gripped` takes): it extends the robot in every configuration.

    ``bits`` is (C, K, words) uint64: camera c's tiles covered by configuration k.
    """

    def __init__(self, test: ImageCollisionTest, configurations, piece=None):
        count = np.shape(configurations)[0] if np.ndim(configurations) else 0
        if count > config.MAX_TABLE_CONFIGURATIONS:
            raise InputError(f"a configuration table holds at most {config.MAX_TABLE_CONFIGURATIONS} configurations "
                             f"(memory), got {count}", field="configurations")
        self.test = test
        self.bits = test.robot_bits(configurations)
        self.configurations = np.asarray(configurations, dtype=np.float64)
        #: with the test's depth order: each capsule's tiles and deepest depth (RobotProjector.capsule_bits)
        self.capsules = None
        if test.depth_order and test.silhouette is None:
            self.capsules = test.projector.capsule_bits(self.configurations, moving_only=True)
        if piece is not None:
            robot = test.robot
            link = robot.control_points[robot.end_effector_index].link
            local = box_corners(piece, "piece")
            corners = np.empty((len(self.configurations), 8, 3))
            for k, q in enumerate(self.configurations):
                T = robot.link_poses(q, check=False)[link]
                corners[k] = local @ T[:3, :3].T + T[:3, 3]
            for c, grid in enumerate(test.grids):
                self.bits[c, :, : grid.words] |= grid_bits(grid, corners)

    def verdicts(self, revised=None) -> tuple[np.ndarray, np.ndarray]:
        """(collision (K,) bool, class (K,) str "A"-"D") of every configuration against ``revised`` (per camera, the
        revised obstacle images; default: the test's last observed ones), by the rule of :func:`verdict`."""
        test = self.test
        revised = test.revised if revised is None else revised
        if revised is None:
            raise InputError("observe a set of images first", field="revised")
        from depthguard.collision._tables import OBSTACLE, POSSIBLE

        c = len(test.grids)
        words = self.bits.shape[2]
        ro = np.empty((c, len(self.configurations)), dtype=bool)
        rp = np.empty_like(ro)
        ordered = self.capsules is not None and test.free is not None and revised is test.revised
        for k, (grid, image) in enumerate(zip(test.grids, revised)):
            if ordered:
                ro[k], rp[k] = depth_ordered_collisions(image, test.free[k], self.capsules[0][k],
                                                        self.capsules[1][k], grid)
                continue
            obstacle = np.zeros(words, dtype=np.uint64)
            possible = np.zeros(words, dtype=np.uint64)
            obstacle[: grid.words] = grid.pack(np.asarray(image) == OBSTACLE)
            possible[: grid.words] = grid.pack(np.asarray(image) == POSSIBLE)
            ro[k] = np.any(self.bits[k] & obstacle, axis=1)
            rp[k] = np.any(self.bits[k] & possible, axis=1)
        n_ro = ro.sum(axis=0)
        every = np.all(ro | rp, axis=0)
        klass = np.where(~every, "A", np.where(n_ro < c - test.theta, "B", np.where(n_ro < c, "C", "D")))
        collision = every if test.unseen == "occupied" else (klass == "C") | (klass == "D")
        meets = np.ones(len(self.configurations), dtype=bool)  # the robot image meets the current one everywhere
        for k, (grid, now) in enumerate(zip(test.grids, test.robot_now or [None] * c)):
            if now is None:  # revised images set by hand: no robot image to compare with (flag every free verdict)
                continue
            current = np.zeros(words, dtype=np.uint64)
            current[: grid.words] = grid.pack(np.asarray(now, dtype=bool))
            meets &= np.any(self.bits[k] & current, axis=1)
        #: (K,) bool: each configuration's :attr:`Verdict.shell` (after :meth:`verdicts`)
        self.shell = ~collision & meets
        self._flags = (ro, rp)
        return collision, klass

    def verdict(self, k: int) -> Verdict:
        """Configuration k's :class:`Verdict` against the test's last observed images."""
        collision, klass = self.verdicts()
        ro, rp = self._flags
        return Verdict(bool(collision[k]), str(klass[k]), tuple(bool(x) for x in ro[:, k]),
                       tuple(bool(x) for x in rp[:, k]), bool(self.shell[k]))
