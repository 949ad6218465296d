"""The user-facing monitor: rig + frames + control points in, distances out."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from depthguard import config
from depthguard.cameras import Rig
from depthguard.depth import DepthImage, OccupancyImage, depth_image, prepare_depth
from depthguard.depthspace import check_points, single_camera_distances
from depthguard.depthspace._distance import check_options
from depthguard.errors import InputError
from depthguard.results import DistanceResult, Flag


class DistanceMonitor:
    """Distances from robot control points to unknown obstacles seen by a rig's depth cameras.

    Args:
        rig: the cameras (:func:`depthguard.load_rig`).
        rho: radius of each control point's surveillance region, metres; obstacles farther away are ignored.
        aggregate: ``"min"``, ``"mean"`` or ``"hybrid"`` (SPEC section 6).
        invalid: policy for pixels without a valid measurement: ``"occupied"`` (fail-safe), ``"neighbors"`` or
            ``"free"`` (SPEC section 3).
        unseen: policy for space no camera observes: ``"occupied"`` (fail-safe) or ``"free"``.
        method: ``"exact"`` (SPEC) or ``"paper"`` (the 2015 paper's unsafe formulas, for comparison only).
        max_age: seconds; a frame older than this at query time (``now``) makes its camera blind and the result
            flagged. None: frames never go stale.
        hole_pixels: largest hole filled by ``invalid="neighbors"``, pixels.
        robot: a :class:`depthguard.robots.RobotModel` to filter out of every frame (SPEC section 7); then each new
            frame needs the robot's joint positions at its capture time (``query(..., joints=...)``).
        self_filter: the geometry rendered for self-filtering: ``"hulls"`` (default), ``"capsules"`` or
            ``"meshes"`` (:mod:`depthguard.self_filter`).
        self_filter_tolerance: metres by which a measurement may lie in front of the rendered robot and still be the
            robot (on top of the noise margin).
        principals: with frames of several cameras, the principal cameras of the depth grid (SPEC section 8), names;
            default: the rig's principal, else its first camera. Each point gets the largest of the principals'
            fused distances among those whose view holds its whole surveillance region (each is a lower bound).
        maps: principal name -> :class:`depthguard.depthgrid.DepthGridMap` (checked against the rig); maps not
            given are built from the rig when first needed (milliseconds).
        fusion_margin: metres a secondary camera must have seen beyond a cell to clear it (the rig's calibration
            error, on top of the noise margin). fusion_pixels: pixels by which a cell's footprint grows in a
            secondary camera.

    A frame passed as a :class:`DepthImage` is prepared once (and filtered with the joints given with it) and reused
    while the same object is passed again; a plain array is checked and prepared on every query.

    With frames of one camera, queries use the single-camera method (SPEC sections 3-7); with frames of several,
    the depth grid fuses them (SPEC section 8).
    """

    def __init__(self, rig: Rig, rho: float = config.DEFAULT_RHO, aggregate: str = config.DEFAULT_AGGREGATE,
                 invalid: str = config.DEFAULT_INVALID, unseen: str = config.DEFAULT_UNSEEN,
                 method: str = config.DEFAULT_METHOD, max_age: float | None = None,
                 hole_pixels: int = config.DEFAULT_NEIGHBOR_HOLE_PIXELS, robot=None, self_filter: str = "hulls",
                 self_filter_tolerance: float = config.SELF_FILTER_TOLERANCE, principals=None, maps=None,
                 fusion_margin: float = config.DEFAULT_FUSION_MARGIN,
                 fusion_pixels: int = config.DEFAULT_FUSION_PIXELS):
        if not isinstance(rig, Rig):
            raise InputError(f"rig must be a depthguard Rig, got {type(rig).__name__}")
        check_options(rho, aggregate, unseen, method)
        if invalid not in config.INVALID_POLICIES:
            raise InputError(f"invalid must be one of {config.INVALID_POLICIES}, got {invalid!r}")
        if max_age is not None and not (np.isfinite(max_age) and max_age > 0):
            raise InputError(f"max_age must be a positive number of seconds or None, got {max_age!r}")
        if isinstance(hole_pixels, bool) or not isinstance(hole_pixels, (int, np.integer)) or hole_pixels < 0:
            raise InputError(f"hole_pixels must be a non-negative integer, got {hole_pixels!r}")
        self.rig = rig
        self.rho = float(rho)
        self.aggregate = aggregate
        self.invalid = invalid
        self.unseen = unseen
        self.method = method
        self.max_age = None if max_age is None else float(max_age)
        self.hole_pixels = int(hole_pixels)
        self.robot = robot
        self.self_filter_tolerance = float(self_filter_tolerance)
        self._silhouette = None
        if robot is not None:
            from depthguard.self_filter import RobotSilhouette  # needs OpenGL: only with a robot

            self._silhouette = RobotSilhouette(robot, geometry=self_filter)
        self._prepared: dict[str, tuple[object, _CameraFrame]] = {}
        self._fused_frames: dict[str, tuple[tuple, object]] = {}  # principal -> (its frames, their FusedFrames)
        names = list(rig.cameras)
        if principals is None:
            principals = [rig.principal or names[0]]
        for name in principals:
            rig.camera(name)
        if not principals:
            raise InputError("principals must name at least one camera")
        self.principals = tuple(principals)
        self.maps = {}
        for name, grid in (maps or {}).items():
            grid.check_rig(rig)
            self.maps[name] = grid
        if not (np.isfinite(fusion_margin) and fusion_margin >= 0):
            raise InputError(f"fusion_margin must be a non-negative number of metres, got {fusion_margin!r}")
        if isinstance(fusion_pixels, bool) or not isinstance(fusion_pixels, (int, np.integer)) or fusion_pixels < 0:
            raise InputError(f"fusion_pixels must be a non-negative integer, got {fusion_pixels!r}")
        self.fusion_margin = float(fusion_margin)
        self.fusion_pixels = int(fusion_pixels)

    def prepare(self, name: str, frame, joints=None) -> OccupancyImage:
        """Check a frame of camera ``name`` and prepare it (cached while the same :class:`DepthImage` comes back).

        ``joints``: with a robot, its joint positions at the frame's capture time (by name or in
        ``robot.joint_names`` order), for self-filtering.
        """
        return self._camera_frame(name, frame, joints).occupancy

    def _camera_frame(self, name: str, frame, joints) -> "_CameraFrame":
        camera = self.rig.camera(name)
        cached = self._prepared.get(name)
        if cached is not None and cached[0] is frame:
            return cached[1]
        if isinstance(frame, DepthImage):
            if frame.camera != name:
                raise InputError(f"the frame given for camera {name!r} was taken by camera {frame.camera!r}")
            image = frame if frame.data.shape == camera.shape else depth_image(frame.data, camera, frame.timestamp)
        else:
            image = depth_image(frame, camera)
        robot_near = robot_far = robot_exit = None
        if self._silhouette is not None:
            if joints is None:
                raise InputError(f"camera {name!r}: this monitor filters the robot out of its frames: pass the robot's "
                                 "joint positions at the frame's capture time (query(..., joints=...))")
            joints = self.robot.joint_vector(joints)
            robot_near = self._silhouette.render(camera, joints)
            if len(self.rig.cameras) > 1:
                # The depth grid needs where the robot ends (case iv); with it, what a camera saw past the padded
                # robot also stays a surface rather than blind space, and a secondary camera clears the space there.
                robot_far = self._silhouette.render_far(camera, joints)
                if name in self.principals:
                    robot_exit = self._silhouette.render_first_exit(camera, joints)
        occupancy = prepare_depth(image, camera, self.invalid, self.hole_pixels, robot_near=robot_near,
                                  robot_tolerance=self.self_filter_tolerance, robot_far=robot_far)
        state = _CameraFrame(self, camera, image, occupancy, joints, robot_near, robot_far, robot_exit)
        if isinstance(frame, DepthImage):
            self._prepared[name] = (frame, state)
        return state

    def query(self, frames: Mapping[str, object], points_world, *, joints=None, now: float | None = None,
              check: bool = True) -> DistanceResult:
        """Distances of control points given the latest frame of each camera.

        Args:
            frames: camera name -> :class:`DepthImage` (or a (height, width) array in the camera's units).
            points_world: (n, 3) float64, metres, world frame.
            joints: with a robot: its joint positions when the new frames were captured (a dict by name or a
                sequence in ``robot.joint_names`` order, radians), or a mapping camera name -> such joint positions
                when the cameras' frames were captured at different times. Only frames not prepared before use it.
            now: the current time in the frames' clock, seconds; needed when ``max_age`` is set.
            check: validate the points (``False`` for a hot loop that passes a checked (n, 3) float64 array).

        With one frame, the single-camera method of SPEC sections 3-6 runs on it. With no usable frame (none given,
        or every one stale) each point gets distance 0 and the flag ``MISSING_CAMERA`` or ``STALE_CAMERA``.
        """
        points = check_points(points_world) if check else points_world
        if not isinstance(frames, Mapping):
            raise InputError(f"frames must map camera names to depth images, got {type(frames).__name__}")
        if self.max_age is not None and now is None:
            raise InputError("this monitor has max_age set: pass now= (seconds, the frames' clock) to query()")
        usable: dict[str, _CameraFrame] = {}
        stale: list[str] = []
        for name, frame in frames.items():
            state = self._camera_frame(name, frame, _joints_for(name, joints, frames))
            timestamp = state.occupancy.timestamp
            if self.max_age is not None and (timestamp is None or now - timestamp > self.max_age):
                stale.append(name)
                continue
            usable[name] = state
        if not usable:
            flag = Flag.STALE_CAMERA if stale else Flag.MISSING_CAMERA
            return _blind_result(len(points), flag, {n: self._prepared[n][1].occupancy.timestamp for n in stale
                                                     if n in self._prepared})
        if len(usable) == 1 and not stale:
            (state,) = usable.values()
            return single_camera_distances(state.occupancy, points, self.rho, self.aggregate, self.unseen,
                                           self.method, check=False)
        return self._fused(usable, points, stale)

    def _fused(self, usable: dict, points: np.ndarray, stale: list) -> DistanceResult:
        """The depth grid of every usable principal; per point, the largest answer among the principals whose view
        holds its whole surveillance region (else the first usable principal's, flagged)."""
        from depthguard.depthgrid import FusedFrames, build_map

        if self.method != "exact":
            raise InputError("fusing several cameras uses the exact method only")
        results = []
        for name in self.principals:
            if name not in usable:
                continue
            grid = self.maps.get(name)
            if grid is None:
                grid = self.maps[name] = build_map(self.rig, name)
            # The same frames as the last query: their fusion, with the cells it has classified so far.
            key = tuple(usable.get(other) for other in (name,) + grid.secondaries)
            cached = self._fused_frames.get(name)
            if cached is None or len(cached[0]) != len(key) or any(a is not b for a, b in zip(cached[0], key)):
                secondaries = {other: (usable[other].free if other in usable else None) for other in grid.secondaries}
                state = usable[name]
                cached = self._fused_frames[name] = (key, FusedFrames(
                    grid, self.rig, state.occupancy, secondaries, robot_far=state.robot_far,
                    margin=self.fusion_margin, pad=self.fusion_pixels, check=False, robot_near=state.robot_near,
                    robot_exit=state.robot_exit))
            results.append(cached[1].distances(points, self.rho, self.aggregate, self.unseen, check=False))
        if not results:
            flag = Flag.STALE_CAMERA if any(n in stale for n in self.principals) else Flag.MISSING_CAMERA
            return _blind_result(len(points), flag, {})
        timestamps = {name: state.occupancy.timestamp for name, state in usable.items()}
        invalid_pixels = {n: s.occupancy.invalid_pixels for n, s in usable.items()}
        stale_flag = Flag.STALE_CAMERA if stale else Flag(0)
        if len(results) == 1:
            (result,) = results
            return DistanceResult(distance=result.distance, direction=result.direction, count=result.count,
                                  invalid_count=result.invalid_count, blind_distance=result.blind_distance,
                                  flags=tuple(f | stale_flag for f in result.flags) if stale else result.flags,
                                  timestamps=timestamps, cameras=tuple(usable), invalid_pixels=invalid_pixels,
                                  principal=(result.cameras[0],) * len(points))
        holds = np.array([[Flag.REGION_OUTSIDE_VIEW not in f for f in r.flags] for r in results])
        distances = np.array([r.distance for r in results])
        candidates = np.where(holds, distances, -np.inf)
        chosen = np.where(holds.any(axis=0), np.argmax(candidates, axis=0), 0)
        pick = lambda attr: np.array([getattr(results[c], attr)[i] for i, c in enumerate(chosen)])  # noqa: E731
        flags = tuple(results[c].flags[i] | stale_flag for i, c in enumerate(chosen))
        return DistanceResult(distance=pick("distance"), direction=pick("direction").reshape(-1, 3),
                              count=pick("count"), invalid_count=pick("invalid_count"), flags=flags,
                              blind_distance=pick("blind_distance"),
                              timestamps=timestamps, cameras=tuple(usable), invalid_pixels=invalid_pixels,
                              principal=tuple(results[c].cameras[0] for c in chosen))


class _CameraFrame:
    """One camera's latest frame as the monitor prepared it: its occupancy, and, when the depth grid needs them,
    where the robot's body ends along each pixel (for a principal) and how far it saw (for a secondary)."""

    def __init__(self, monitor: DistanceMonitor, camera, image: DepthImage, occupancy: OccupancyImage, joints,
                 robot_near=None, robot_far=None, robot_exit=None):
        self._monitor = monitor
        self.camera = camera
        self.image = image
        self.occupancy = occupancy
        self._joints = joints
        self.robot_near = robot_near
        self.robot_exit = robot_exit
        self._robot_far = robot_far
        self._free = None

    @property
    def robot_far(self):
        if self._monitor._silhouette is None:
            return None
        if self._robot_far is None:
            self._robot_far = self._monitor._silhouette.render_far(self.camera, self._joints)
        return self._robot_far

    @property
    def free(self) -> np.ndarray:
        if self._free is None:
            from depthguard.depthgrid import seen_free

            self._free = seen_free(self.image, self.occupancy)
        return self._free


def _joints_for(name: str, joints, frames):
    """The joint positions for camera ``name``: ``joints`` itself, or its entry when it maps camera names."""
    if isinstance(joints, Mapping) and joints and set(joints) <= set(frames) and all(
            not isinstance(v, (int, float)) for v in joints.values()):
        return joints.get(name)
    return joints


def _blind_result(n: int, flag: Flag, timestamps: dict) -> DistanceResult:
    """The conservative answer when no camera can see: distance 0 everywhere, flagged."""
    return DistanceResult(
        distance=np.zeros(n),
        direction=np.zeros((n, 3)),
        count=np.zeros(n, dtype=np.int64),
        invalid_count=np.zeros(n, dtype=np.int64),
        flags=tuple(flag for _ in range(n)),
        timestamps=timestamps,
        cameras=(),
    )
