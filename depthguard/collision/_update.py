"""Pick-and-place (design §10, step 8; Henrich & Gecks section 4.1): the reference image update loop (U, R, E, O)
and the gripped work piece as part of the robot.

When the robot picks a work piece up or puts it down, the cameras see a change where it lay or now lies: foreground
against the reference, a virtual obstacle. The update replaces those tiles of the reference (their features, or
their pixels of a reference depth image) with the current image's, tile by tile, once nothing hides them: neither
the robot (R) nor anything that may be an obstacle in front of them (O). Tile images are (rows, cols) bool arrays of
a camera's :class:`TileGrid`.

Boxes are :class:`depthguard.scenes.Box`: ``center`` (3,) metres, ``half_extents`` (3,) metres (>= 0) along the box's
own axes, ``R_world_box`` (3, 3) its rotation, all in the frame the function names (the world frame, or the
end-effector link's frame for a gripped piece, where ``R_world_box`` is then the box's rotation in that link frame).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from scipy import ndimage

from depthguard.collision._difference import (
    FOUR_NEIGHBOURS,
    depth_difference_image,
    depth_metres,
    difference_image,
    tile_features,
)
from depthguard.collision._boxes import box_corners, grid_bits, moved_box
from depthguard.collision._tables import (
    OBSTACLE,
    POSSIBLE,
    Verdict,
    obstacle_image,
    revised_obstacle_images,
)
from depthguard.collision._test import ImageCollisionTest
from depthguard.errors import InputError
from depthguard.scenes import Box
from depthguard.transforms import invert

# ------------------------------------------------------------------------------------------------ the update

class ReferenceUpdate:
    """The paper's reference image update for pick-and-place (section 4.1) over an :class:`ImageCollisionTest`, and
    the gripped work piece as part of the robot.

    Args:
        test: the :class:`~depthguard.collision.ImageCollisionTest` whose reference it updates; its reference set
            (:meth:`~depthguard.collision.ImageCollisionTest.set_reference`) before :meth:`step`. At least two
            cameras: with one, nothing tells a hand in front of the update area from the moved work piece.

    Use, per pick or place:

    - :meth:`start` (``piece`` world frame, ``joints_t0``) when the robot picks a work piece up or puts it down: its
      tiles become part of the update area U (the paper's U; :attr:`pending`). At a pick, :meth:`gripped` with the
      piece in the end-effector link's frame (:meth:`start` returns it); at a place, :meth:`released`.
    - :meth:`step` per set of images, **instead of** ``test.observe``: it calls ``test.observe`` itself, revises
      the obstacle images again with the gripped piece as part of the robot's image (:meth:`robot_image`; else the
      piece is an obstacle glued to the gripper, for the test and for O) and leaves them in ``test.revised``; then
      one pass of the loop; it returns True once U is empty. Calling it after ``test.observe`` would observe twice.
    - Future configurations with the piece in the gripper: :meth:`test` and :meth:`test_motion` (the robot's tile
      images with the piece's ORed in, against the revised obstacle images of the last :meth:`step`).
      ``test.test(joints)`` still tests the bare robot (e.g. after the place).

    One pass of the loop (:meth:`step`), per camera a:

    - R: the robot's tiles now, with the gripped piece's (:meth:`robot_image`).
    - E = U \\ R.
    - O (:meth:`possible_obstacles`): the tiles of U that may show something other than the work piece's change
      and the static background: see there for the rule and why it is fail-safe.
    - E = E \\ O; E's tiles of the reference become the current image's: for intensity images their features (the
      mean grey value divided by the camera's light gain, so the reference keeps its brightness; a camera whose
      gain cannot be estimated updates nothing), for depth images their pixels (metres); U = U \\ E.

    The revised obstacle images this step leaves in ``test.revised`` are computed against the reference before its
    update: the tiles absorbed now read as background from the next set of images on.

    Attributes:
        collision_test: the ImageCollisionTest (``test`` above; its ``reference`` is replaced by every step).
        pending: per camera, (rows, cols) bool: U, the tiles still to update.
        absorbed: per camera, (rows, cols) bool: E of the last :meth:`step`, the tiles it updated.
        blocked: per camera, (rows, cols) bool: O of the last :meth:`step`, the tiles of U it held back.
        piece_in_gripper: the gripped :class:`Box` in the end-effector link's frame, or None.
        link: the end-effector link (the link of the robot's end-effector control point), whose pose
            ``test.robot.link_poses(q)[link]`` (``T_world_link``) carries the gripped piece.
        joints_t0: (n,) float64, radians: the joints given to the last :meth:`start`, or None.
    """

    def __init__(self, test):
        if not isinstance(test, ImageCollisionTest):
            raise InputError(f"test must be an ImageCollisionTest, got {type(test).__name__}", field="test")
        if len(test.grids) < 2:
            raise InputError("the reference update needs at least two cameras: with one, nothing tells an obstacle "
                             "in front of the update area from the moved work piece", field="test")
        self.collision_test = test
        robot = test.robot
        self.link = robot.control_points[robot.end_effector_index].link
        self.pending = self._empty()
        self.absorbed = self._empty()
        self.blocked = self._empty()
        self.piece_in_gripper: Box | None = None
        self.joints_t0: np.ndarray | None = None

    def _empty(self) -> list[np.ndarray]:
        return [np.zeros((grid.rows, grid.cols), dtype=bool) for grid in self.collision_test.grids]

    @property
    def done(self) -> bool:
        """True when the update area U is empty in every camera."""
        return not any(u.any() for u in self.pending)

    # ----------------------------------------------------------------------------------------- pick and place

    def start(self, piece: Box, joints_t0) -> Box:
        """The robot picks ``piece`` up or puts it down (time t0): its tiles (:func:`box_tiles`, per camera) join the
        update area U (a union: an earlier update still running keeps its tiles).

        Args:
            piece: the work piece where it lies (a pick) or now lies (a place), world frame, metres.
            joints_t0: (n,) radians, the robot's joints at t0 (its joint order, or a mapping by name).

        Returns the piece in the end-effector link's frame at ``joints_t0`` (what :meth:`gripped` takes at a pick).
        """
        corners = box_corners(piece, "piece")
        robot = self.collision_test.robot
        q = robot.joint_vector(joints_t0)
        for c, grid in enumerate(self.collision_test.grids):
            self.pending[c] |= grid.unpack(grid_bits(grid, corners[None])[0])
        self.joints_t0 = q
        return moved_box(piece, invert(robot.link_poses(q)[self.link]))

    def gripped(self, piece_in_gripper: Box) -> None:
        """The robot holds ``piece_in_gripper`` (end-effector link frame, metres; :meth:`start` gives it at a pick):
        from now on it is part of the robot (:meth:`robot_image`) until :meth:`released`."""
        box_corners(piece_in_gripper, "piece_in_gripper")
        self.piece_in_gripper = piece_in_gripper
        self.collision_test.piece = piece_in_gripper  # part of the robot's render (robot_pixels)

    def released(self) -> None:
        """The robot let go of its work piece (call :meth:`start` with it where it now lies)."""
        self.piece_in_gripper = None
        self.collision_test.piece = None

    def piece_at(self, joints) -> Box | None:
        """The gripped piece at ``joints`` ((n,) radians), world frame; None when nothing is gripped."""
        if self.piece_in_gripper is None:
            return None
        q = self.collision_test.robot.joint_vector(joints)
        return moved_box(self.piece_in_gripper, self.collision_test.robot.link_poses(q)[self.link])

    def robot_image(self, joints, future: bool = False) -> list[np.ndarray]:
        """Per camera, (rows, cols) bool: the robot's tiles at ``joints`` ((n,) radians; ``test.robot_image``, with
        ``future`` the links a joint moves only) ORed with the gripped piece's tiles at the end-effector link's pose
        there (:func:`box_tiles`)."""
        test = self.collision_test
        q = test.robot.joint_vector(joints)
        images = test.robot_image(q, future=future)
        piece = self.piece_at(q)
        if piece is None:
            return images
        corners = box_corners(piece)[None]
        return [image | grid.unpack(grid_bits(grid, corners)[0]) for image, grid in zip(images, test.grids)]

    # -------------------------------------------------------------------------------------------- the loop

    def step(self, images: Mapping[str, np.ndarray], joints) -> bool:
        """One set of images (camera name -> (height, width) image, as ``test.observe`` takes them) captured at
        ``joints`` ((n,) radians): observe them, then one pass of the update loop. Returns True when the update area U
        is empty (nothing left to update).

        Observing: ``test.observe(images, joints)`` (steps 2-5, which check the images and need the reference), then
        the revised obstacle images again with the gripped piece part of the robot (:meth:`robot_image`): outside
        the bare robot's tiles ``observe``'s obstacle labels are the difference image, and Table III treats unknown
        and error tiles alike, so nothing is lost. ``test.revised`` holds the result, ``test.gains`` ``observe``'s."""
        test = self.collision_test
        q = test.robot.joint_vector(joints)
        test.observe(images, q)
        robot_now = self.robot_image(q)
        # Table I again over the robot with the piece: foreground outside the bare robot's tiles, and with
        # robot_pixels the tiles whose change neither the robot nor the piece explains, stay obstacles
        seen = [revised == OBSTACLE for revised in test.revised]
        odd = test.unexplained or [None] * len(seen)
        obstacles = [obstacle_image(fg, robot, u) for fg, robot, u in zip(seen, robot_now, odd)]
        test.revised = revised_obstacle_images(obstacles, test.bands, test.theta)
        test.robot_now = robot_now

        # Per camera: the current image's reference content (tile features, or depth pixels in metres), and the
        # difference image against the reference as it would be with all of U updated (for O).
        currents, after = [], []
        for c, (grid, name) in enumerate(zip(test.grids, test.names)):
            reference, gain, pending = test.reference[c], test.gains[c], self.pending[c]
            if test.images == "intensity":  # the reference: (rows, cols, 2) tile features
                features = tile_features(images[name], grid)
                current = features.copy()
                current[..., 0] /= gain  # at the reference's brightness (NaN: no estimate, nothing is updated)
                where = pending
            else:  # the reference: (height, width) depth image, metres
                current = depth_metres(images[name], grid)
                where = grid.pixels(pending)
            future = np.array(reference, dtype=np.float64, copy=True)
            future[where] = current[where]
            if test.images == "intensity":
                after.append(difference_image(features, future, test.thresholds, gain, test.classifier))
            else:
                after.append(depth_difference_image(images[name], future, grid, test.thresholds))
            currents.append(current)
        self.blocked = self.possible_obstacles(after, robot_now)

        references = []
        unreferenced = [None] * len(test.grids)
        for c, grid in enumerate(test.grids):
            absorb = self.pending[c] & ~robot_now[c] & ~self.blocked[c]
            if not math.isfinite(test.gains[c]):  # no trustworthy light estimate: the camera updates nothing
                absorb[:] = False
            reference = np.array(test.reference[c], dtype=np.float64, copy=True)
            pixels = grid.pixels(absorb)  # the absorbed tiles' pixels
            if test.images == "intensity":
                reference[absorb] = currents[c][absorb]
                if test.reference_images is not None:  # the pixels robot_pixels compares, at the same brightness
                    image = np.array(test.reference_images[c], dtype=np.float64, copy=True)
                    image[pixels] = np.asarray(images[test.names[c]], dtype=np.float64)[pixels] / test.gains[c]
                    test.reference_images[c] = image
            else:
                reference[pixels] = currents[c][pixels]
            references.append(reference)
            self.absorbed[c] = absorb
            self.pending[c] = self.pending[c] & ~absorb
            if test.unreferenced is not None and test.unreferenced[c] is not None:
                unreferenced[c] = test.unreferenced[c] & ~pixels  # the room behind them is in the reference now
        test.reference = references
        if test.unreferenced is not None:
            test._set_unreferenced(unreferenced)
        if test.images == "depth":  # the reference is the image itself
            test.reference_images = references
        return self.done

    def possible_obstacles(self, foreground, robot_now) -> list[np.ndarray]:
        """O: per camera, (rows, cols) bool, the tiles of the update area U that may show an obstacle rather than
        the work piece's change, and so must not be absorbed now.

        Args:
            foreground: per camera, (rows, cols) bool, the difference image of the current image against the
                reference as it would be with every tile of U updated (U's tiles replaced by the current image's):
                U's own change then makes no foreground, and the difference image's closing joins no tile to it.
            robot_now: per camera, (rows, cols) bool, the robot's tiles now with the gripped piece (R).

        The rule. Inside U a difference tells nothing: the moved piece makes U foreground, and so does a hand next
        to it. Outside U and outside the robot it does: there a foreground tile is something the piece does not
        explain. So, per camera b:

        - X_b, the *unexplained* obstacles: foreground tiles outside U_b and R_b;
        - P_b, the robot tiles that may hide one: R_b's tiles whose epipolar band meets X_c in any other camera c
          (Table III on the unexplained obstacle images with theta = C - 1: one camera suffices, whatever the
          test's theta).

        A tile t of camera a's U is in O when

        1. for any other camera b, t's epipolar band in b meets X_b (one camera suffices, not C - theta); or
        2. t is 4-connected through U_a to a tile of X_a or P_a: an obstacle in camera a's own image, seen or
           possibly behind the robot, that reaches into the update area.

        Why it is fail-safe. Absorbing a tile that shows an obstacle would hide that obstacle from this camera for
        good; keeping a tile in U costs only time (it stays foreground: a virtual obstacle, on the safe side). Any
        point of an obstacle in t's viewing frustum, within the workspace, projects into t's band in every other
        camera b (the bands are conservative, :class:`EpipolarBands`). If one of them sees that point outside its
        U_b and its robot, the point's tile is in X_b and (1) blocks t. So a tile is absorbed while it shows an
        obstacle only if every other camera sees each of the obstacle's points in t's frustum inside its own update
        area or behind its robot, and camera a's image of the obstacle touches no unexplained or possible obstacle
        outside U_a (else (2)). With the robot away, that is an obstacle wholly inside the work piece's tile-rounded
        visual hull and seen by no camera outside it: a thing lying on the piece that the cameras cannot tell from
        it, as the difference image cannot tell an obstacle that looks like the background. A hand comes on an arm.

        Why (1) needs no possible obstacles of the other cameras: a point of t's frustum that the robot hides from b
        is either seen unexplained by another camera c, and (1) blocks t through c, or by none, and then it makes no
        possible obstacle anywhere. Adding them would hold tiles back for obstacles elsewhere along the bands.

        The price: while anything unexplained is seen along a tile's bands (a person anywhere on them, a tile the
        closing adds between the robot's image and something else), that tile waits.
        """
        test = self.collision_test
        grids, bands = test.grids, test.bands
        c = len(grids)
        foreground = self._masks(foreground, "foreground")
        robot_now = self._masks(robot_now, "robot_now")
        unexplained = [obstacle_image(fg & ~u, robot) for fg, u, robot in zip(foreground, self.pending, robot_now)]
        seen = [image == OBSTACLE for image in unexplained]
        possible = [image == POSSIBLE for image in revised_obstacle_images(unexplained, bands, c - 1)]
        packed = [grid.pack(x) for grid, x in zip(grids, seen)]
        out = []
        for a, grid in enumerate(grids):
            pending = self.pending[a]
            blocked = np.zeros_like(pending)
            tiles = np.flatnonzero(pending)
            if len(tiles):
                hit = np.zeros(len(tiles), dtype=bool)
                for b in range(c):  # (1)
                    if b != a and seen[b].any():
                        hit |= np.any(bands.bits[(a, b)][tiles] & packed[b], axis=1)
                blocked.reshape(-1)[tiles[hit]] = True
                seeds = seen[a] | possible[a]
                if seeds.any():  # (2)
                    labels, _ = ndimage.label(pending | seeds, structure=FOUR_NEIGHBOURS)
                    touched = np.unique(labels[seeds])
                    blocked |= pending & np.isin(labels, touched[touched > 0])
            out.append(blocked)
        return out

    def _masks(self, images, name: str) -> list[np.ndarray]:
        grids = self.collision_test.grids
        if isinstance(images, np.ndarray) or len(images) != len(grids):
            raise InputError(f"{name} must hold one tile image per camera ({len(grids)})", field=name)
        out = []
        for image, grid in zip(images, grids):
            image = np.asarray(image)
            if image.dtype != np.bool_ or image.shape != (grid.rows, grid.cols):
                raise InputError(f"{name} must be ({grid.rows}, {grid.cols}) bool tile images, got {image.dtype} "
                                 f"{image.shape}", camera=grid.camera.name, field=name)
            out.append(image)
        return out

    # ------------------------------------------------------------------------------------ future configurations

    def _verdict(self, robot_images) -> Verdict:
        if self.collision_test.revised is None:
            raise InputError("observe a set of images first (step)", field="revised")
        return self.collision_test._verdict(robot_images)  # the test's rule, its shell against the robot with the piece

    def test(self, joints) -> Verdict:
        """Step 6 for the configuration ``joints`` ((n,) radians) with the gripped piece (:meth:`robot_image`),
        against the revised obstacle images of the last :meth:`step` (the test's theta and unseen rule)."""
        return self._verdict(self.robot_image(joints, future=True))

    def test_motion(self, path, chunk: int = 8) -> Verdict:
        """Steps 6-7 for a whole motion ``path`` ((P, n) radians, straight lines in joint space) with the gripped
        piece, cut into pieces of ``chunk`` samples as ``test.test_motion`` cuts it: per piece, the robot's swept
        tiles (``test.projector.swept_images``) ORed with the piece's at each sample, widened by x_max / 2 along its
        axes (a box holding every point within x_max / 2 of it). The motion collides iff a piece does; the verdict is
        the first colliding piece's, else the one of highest class.

        The samples are spaced so that no point of the piece travels more than x_max between two: joint i's speed
        bound is the robot's ``joint_reaches`` plus the piece's farthest corner's distance from an end of the
        end-effector link's capsule (a point of the link whose distance from the joint's axis the reach bounds).
        Without a gripped piece, ``test.test_motion(path, chunk)``."""
        test = self.collision_test
        if self.piece_in_gripper is None:
            return test.test_motion(path, chunk)
        if isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1:
            raise InputError(f"chunk must be a whole number of steps >= 1, got {chunk!r}", field="chunk")
        projector = test.projector
        projector.samples(path)  # checks the path (shape, finite, limits)
        q = np.asarray(path, dtype=np.float64)
        q = q[None] if q.ndim == 1 else q
        robot = test.robot
        capsule = next((cap for cap in robot.capsules if cap.link == self.link), None)
        if capsule is None:
            raise InputError(f"the end-effector link {self.link!r} carries no capsule: no bound on the gripped "
                             "piece's speed", field="piece_in_gripper")
        local = box_corners(self.piece_in_gripper, "piece_in_gripper")
        reaches = projector.reaches + float(np.linalg.norm(local - capsule.p0, axis=1).max())
        samples = projector.samples(q, reaches)
        widen = projector.x_max / 2.0 if len(samples) > 1 else 0.0
        piece = Box(self.piece_in_gripper.center, tuple(np.asarray(self.piece_in_gripper.half_extents) + widen),
                    self.piece_in_gripper.R_world_box)
        local = box_corners(piece)
        world = np.empty((len(samples), 8, 3))
        for k, joints in enumerate(samples):
            T = robot.link_poses(joints, check=False)[self.link]
            world[k] = local @ T[:3, :3].T + T[:3, 3]
        best = None
        for first in range(0, max(len(samples) - 1, 1), chunk):
            part = slice(first, first + chunk + 1)
            images = []
            for image, grid in zip(projector.swept_images(samples[part], moving_only=True), test.grids):
                images.append(image | grid.unpack(np.bitwise_or.reduce(grid_bits(grid, world[part]), axis=0)))
            v = self._verdict(images)
            if v.collision:
                return v
            best = v if best is None or v.klass > best.klass else best
        return best
