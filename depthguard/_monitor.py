"""The user-facing monitor: rig + frames + control points in, distances out."""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Mapping
from dataclasses import replace

import numpy as np

from depthguard import config
from depthguard._answer import Concessions, PreparedSet, QueryPlan, is_stale
from depthguard._settings import MonitorSettings
from depthguard.cameras import Rig
from depthguard.depth import DepthImage, OccupancyImage, checked_frame, depth_image, filled_space, prepare_depth
from depthguard.errors import InputError
from depthguard.results import DistanceResult, Flag
from depthguard.validation import check_points, check_real, short_repr


class DistanceMonitor:
    """Distances from robot control points to unknown obstacles seen by a rig's depth cameras.

    Args:
        rig: the cameras (:func:`depthguard.load_rig`).
        settings: a :class:`MonitorSettings` (how it answers: rho, the policies, time, self-filtering, fusion, the
            memory, the concessions), or None; keyword ``options`` set its fields (``DistanceMonitor(rig, rho=0.5)``),
            over ``settings`` when both are given.
        robot: a :class:`depthguard.robots.RobotModel` to filter out of every frame (design §7); then each new
            frame needs the robot's joint positions at its capture time (``query(..., joints=...)``).
        static: known static solids no person can be inside (the floor, a pedestal, walls, a table built down to the
            floor): a list or tuple of :class:`depthguard.scenes.Box`, world frame. Their surfaces, measured where
            they are known to be, stop counting as obstacles; the space they hide still counts
            (:class:`depthguard.static_solids.StaticSolids`, a concession flagged ``known_solid``: an object within
            ``self_filter_tolerance`` + twice the noise margin of such a surface is taken for it). None (default):
            everything the cameras see counts.
        principals: with frames of several cameras, the principal cameras of the depth grid (design §8): a list
            or tuple of camera names (a bare string is refused); default: the rig's principal, else its first
            camera. Each point gets the largest of the principals' fused distances among those whose view holds
            its whole surveillance region (each is a lower bound).
        maps: principal name -> :class:`depthguard.depthgrid.DepthGridMap` of that principal (checked against the
            rig); maps not given are built from the rig when first needed (milliseconds).

    Every argument is checked here, once: a wrong type or a value out of range raises
    :class:`~depthguard.errors.InputError` naming it.

    A frame passed as a :class:`DepthImage` is prepared once (and filtered with the joints given with it) and reused
    while the same object is passed again; a plain array is checked and prepared on every query.

    Which method answers is decided once per query by one rule (:meth:`plan`): the single-camera method (design
    sections 3-7) when one camera has a usable frame, the depth grid (design §8) when several have.
    """

    def __init__(self, rig: Rig, settings: "MonitorSettings | None" = None, *, robot=None, static=None,
                 principals=None, maps=None, **options):
        if not isinstance(rig, Rig):
            raise InputError(f"rig must be a depthguard Rig, got {type(rig).__name__}", field="rig")
        if settings is None:
            settings = MonitorSettings(**options)
        elif not isinstance(settings, MonitorSettings):
            raise InputError(f"settings must be a depthguard.MonitorSettings, got {short_repr(settings)}",
                             field="settings")
        elif options:
            settings = replace(settings, **options)
        self.settings = settings
        self.rig = rig
        self.rho, self.aggregate, self.unseen, self.method = (settings.rho, settings.aggregate, settings.unseen,
                                                              settings.method)
        self.invalid, self.hole_pixels = settings.invalid, settings.hole_pixels
        self.max_age, self._untimed_stale = settings.max_age_seconds, settings.untimed_stale
        self.self_filter, self.self_filter_tolerance = settings.self_filter, settings.self_filter_tolerance
        self.fusion_margin, self.fusion_pixels = settings.fusion_margin, settings.fusion_pixels
        self.principals = self._principals(principals)
        self.maps = self._maps(maps)
        self.robot = robot
        self._silhouette = None
        self._shell = 0.0  # metres beyond the robot's capsules that self-filtering may take for the robot
        if robot is not None:
            from depthguard.robots import RobotModel

            if not isinstance(robot, RobotModel):
                raise InputError(f"robot must be a depthguard.robots.RobotModel (e.g. RobotModel.default()), got "
                                 f"{short_repr(robot)}", field="robot")
            from depthguard.self_filter import RobotSilhouette  # needs OpenGL: only with a robot

            self._silhouette = RobotSilhouette(robot, geometry=self.self_filter)
            # The self-filter's shell beyond the robot's capsules: what the rendered geometry adds, the tolerance, and
            # twice the noise margin where a camera can see the robot (a concession, flagged robot_shell).
            margin = max(float(camera.noise.margin(np.array([_farthest_robot_depth(camera, robot)]))[0])
                         for camera in rig.cameras.values())
            self._shell = self._silhouette.beyond_capsules + self.self_filter_tolerance + 2.0 * margin
        self._static = None
        if static is not None:
            from depthguard.static_solids import StaticSolids

            self._static = StaticSolids(static, self.self_filter_tolerance)
        self.robot_zone = settings.robot_zone
        self.memory = None
        if settings.memory and rig.workspace is not None and len(rig.cameras) > 1:  # only fused answers use it
            from depthguard.freespace import FreeSpaceMemory, VoxelBox

            self.memory = FreeSpaceMemory(VoxelBox(rig.workspace[0], rig.workspace[1], settings.memory_voxel),
                                          settings.v_max)
            if robot is not None:  # the robot's inside (Robot_k) is found once per model: here, not on a first frame
                robot.inner_capsules_world(np.zeros(robot.n_joints), check=False)
        self.detectable = None
        self.hidden_band = 0.0  # metres (detection_capability only): see _hidden_band
        self._static_voxels = None
        if settings.detection_capability is not None:
            self._detectable_space(static, settings.detection_capability, settings.detectable_voxel)
        self._remembered: set[int] = set()  # ids of the frames the memory has taken in
        self._free_now = None  # (free, box, remembered only) behind the fused frames last built
        self._prepared: dict[str, tuple[object, _CameraFrame]] = {}
        self._masks: dict = {}  # camera name -> the RobotMask of its last frame (reused while the robot stands still)
        self._fused_frames: dict[str, tuple[tuple, object]] = {}  # principal -> (its frames, their FusedFrames)

    def _detectable_space(self, static, capability, voxel) -> None:
        from depthguard.freespace import DetectableSpace, VoxelBox, solid_voxels
        from depthguard.freespace import closed_faces

        if self.rig.workspace is None:
            raise InputError("detection_capability needs the rig's workspace (the box whose voxels it looks at)",
                             field="detection_capability")
        band, why = self._hidden_band()
        if capability + band > config.SSM_INTRUSION_LIMIT * (1.0 + 1e-12):
            raise InputError(f"detection_capability {capability:g} m plus the {band:.3f} m this monitor's concessions "
                             f"can hide next to a surface ({why}) is {capability + band:.3f} m, coarser than ISO "
                             "13855's 70 mm: no intrusion distance C covers it (a smaller robot_zone, "
                             "invalid='occupied' or a smaller capability)", field="detection_capability")
        try:
            box = VoxelBox(self.rig.workspace[0], self.rig.workspace[1], voxel)
        except InputError as error:
            raise InputError(str(error), field="detectable_voxel") from None
        beyond = None if self._static is None else closed_faces(box, self._static.boxes)
        self.detectable = DetectableSpace(box, capability, beyond)
        self.hidden_band = band
        if self._static is not None:
            # Only the solids' inside is free here, and the frames are taken as measured (not substituted): a
            # known solid hides nothing from the detectable space.
            self._static_voxels = np.zeros(box.shape, dtype=bool)
            solid_voxels(box, self._static.boxes, self._static_voxels)

    def query_hidden_band(self) -> tuple[float, str]:
        """(metres, what): the thickest layer next to a surface in which :meth:`query` may not see an object, for
        speed and separation monitoring on its distances (the effective detection capability, design §9):

        - with a robot, the self-filter's shell: the capsules' padding and gap to the meshes
          (``RobotModel.capsule_gap``), what the rendered geometry adds beyond the capsules, ``self_filter_tolerance``
          and twice the noise margin at the farthest depth at which a camera can see the robot (its base's depth
          plus ``RobotModel.reach``): a measurement that near the robot is the robot; with a robot zone, the zone
          instead where it is thicker;
        - known solids: the largest band a replaced measurement may hide (``StaticSolids.largest_band``);
        - ``invalid="neighbors"``: the widest object a filled hole hides (as :meth:`_hidden_band`).
        """
        parts = {}
        if self.robot is not None:
            body = self.robot.padding + self.robot.capsule_gap()
            parts["the self-filter's shell"] = body + self._shell
            if self.robot_zone > 0.0:
                parts["robot zone + padding + the capsules' gap to the meshes"] = body + self.robot_zone
        if self._static is not None:
            parts["known solids"] = max(self._static.largest_band(camera) for camera in self.rig.cameras.values())
        band, why = self._hidden_band()
        if "filled holes" in why:
            parts["filled holes"] = band
        if not parts:
            return 0.0, "none"
        why = max(parts, key=parts.get)
        return parts[why], f"{why}: {parts[why]:.3f} m"

    def _hidden_band(self) -> tuple[float, str]:
        """(metres, what): the thickest layer next to a surface that the detectable space counts free without a
        camera seeing it free: the robot zone with the capsules' padding (the capsules are the robot's, padding
        and zone included), and with ``invalid="neighbors"`` the widest object a filled hole can hide, 2
        sqrt(hole_pixels / pi) pixels (the widest disc in the hole, at least the 2-pixel lines) at the farthest
        depth at which a camera sees the workspace. The known solids add nothing (their inside only is free, and
        the frames are used as measured)."""
        parts = {}
        if self.robot is not None and self.robot_zone > 0.0:
            parts["robot zone + padding + the capsules' gap to the meshes"] = \
                self.robot_zone + self.robot.padding + self.robot.capsule_gap()
        if self.invalid == "neighbors" and self.hole_pixels:
            pixels = max(2.0, 2.0 * math.sqrt(self.hole_pixels / math.pi))
            widest = max(pixels * _farthest_depth(camera, self.rig.workspace) / min(camera.fx, camera.fy)
                         for camera in self.rig.cameras.values())
            parts["filled holes"] = widest
        if not parts:
            return 0.0, "none"
        why = max(parts, key=parts.get)
        return parts[why], f"{why}: {parts[why]:.3f} m"

    def _find_detectable(self, usable: dict):
        """A new DetectableSpace for the usable frames (None without detection_capability): the voxels some usable
        camera sees entirely free now, the memory's, the robot's capsules grown by the robot zone at every usable
        frame's joints (the space that is the robot at all of them; without a zone, the robot's inside at all of
        them, ``RobotModel.inner_capsules_world``) and the static solids' inside are free."""
        if self.detectable is None:
            return None
        from depthguard.freespace import CameraViews, DetectableSpace, FreeSources

        box = self.detectable.box
        space = DetectableSpace(box, self.detectable.capability, self.detectable.beyond)
        if not usable:
            return space  # never updated: every distance 0, as with no usable frame it must be
        states = list(usable.values())
        views = CameraViews.of([state.camera for state in states], [state.measured_free for state in states],
                               margin=self.fusion_margin, pad=self.fusion_pixels)
        robot = None
        joints = {state.joints.tobytes(): state.joints for state in states if state.joints is not None}
        if self.robot is not None and joints and self.robot_zone > 0.0:
            # the space that is the robot at every frame's joints: its capsules grown by the zone at each of them
            capsules = [[tuple(c.p0) + tuple(c.p1) + (c.radius,) for c in self.robot.capsules_world(q, check=False)]
                        for q in joints.values()]
            robot = (np.array(capsules, dtype=np.float64).reshape(len(capsules), -1, 7), self.robot_zone)
        elif self.robot is not None and joints:
            # design §8a's Robot_k: the robot's own volume at every frame's joints holds no person (balls inside
            # the links' meshes, never their padding); the truth, not a concession
            inner = [self.robot.inner_capsules_world(q, check=False) for q in joints.values()]
            robot = (np.ascontiguousarray(np.stack(inner)), 0.0)
        remembered = None
        if self.memory is not None and self.memory.time is not None:
            times = [state.occupancy.timestamp for state in states if state.occupancy.timestamp is not None]
            remembered = self._remembered_coarse(box, max(times + [self.memory.time]))
        space.watch(FreeSources(views, self._static_voxels, remembered, robot))
        return space

    def _remembered_coarse(self, box, t: float):
        """(coarse, ratio): the memory's voxels certified free at time ``t`` ((mx, my, mz) bool) and how many of
        ``box``'s voxels make one of its a side; None unless the two boxes share their near corner and the memory's
        voxel is a whole number of ``box``'s."""
        ratio = self.memory.box.voxel / box.voxel
        whole = int(round(ratio))
        coarse = self.memory.box
        if whole >= 1 and abs(whole - ratio) <= 1e-9 and np.allclose(coarse.lo, box.lo, rtol=0, atol=1e-12) and \
                all(coarse.shape[a] * whole >= box.shape[a] for a in range(3)):
            return np.ascontiguousarray(self.memory.free_at(t)), whole
        return None

    def _principals(self, principals) -> tuple[str, ...]:
        """The principal cameras' names: a list or tuple of names of the rig's cameras (a bare string is refused:
        ``"cam"`` is not the three cameras 'c', 'a', 'm')."""
        if principals is None:
            return (self.rig.principal or next(iter(self.rig.cameras)),)
        if not isinstance(principals, (list, tuple)):
            raise InputError(f"principals must be a list or tuple of camera names, got {short_repr(principals)}",
                             field="principals")
        if not principals:
            raise InputError("principals must name at least one camera", field="principals")
        for name in principals:
            if not isinstance(name, str):
                raise InputError(f"principals must be camera names (strings), got {short_repr(name)}",
                                 field="principals")
            self.rig.camera(name)
        if len(set(principals)) != len(principals):
            raise InputError(f"principals names a camera twice: {list(principals)}", field="principals")
        return tuple(principals)

    def _maps(self, maps) -> dict:
        """Depth grid maps by principal name, each checked against the rig and filed under its own principal."""
        if maps is None:
            return {}
        if not isinstance(maps, Mapping):
            raise InputError(f"maps must map principal camera names to DepthGridMap objects, got "
                             f"{short_repr(maps)}", field="maps")
        from depthguard.depthgrid import DepthGridMap

        checked = {}
        for name, grid in maps.items():
            if not isinstance(grid, DepthGridMap):
                raise InputError(f"maps[{short_repr(name)}] must be a DepthGridMap (depthguard.depthgrid.build_map or "
                                 f"load_map), got {type(grid).__name__}", field="maps")
            grid.check_rig(self.rig)
            if name != grid.principal:
                raise InputError(f"maps[{short_repr(name)}] is the map of principal camera {grid.principal!r}",
                                 field="maps")
            checked[name] = grid
        return checked

    def prepare(self, name: str, frame, joints=None) -> OccupancyImage:
        """Check a frame of camera ``name`` and prepare it (cached while the same :class:`DepthImage` comes back).

        ``joints``: with a robot, its joint positions at the frame's capture time (by name or in
        ``robot.joint_names`` order), for self-filtering.
        """
        return self._camera_frame(name, frame, joints).occupancy

    def _camera_frame(self, name: str, frame, joints) -> "_CameraFrame":
        """Stages check, self-filter and prepare for one frame of camera ``name`` (kept while the same
        :class:`DepthImage` comes back)."""
        camera = self.rig.camera(name)
        cached = self._prepared.get(name)
        if cached is not None and cached[0] is frame:
            if joints is not None and self.robot is not None:
                # Checked like any other (NaN, a wrong count, an unknown name), though the frame keeps the joints it
                # was filtered with: its capture time, not this call's, is when the robot was where they say.
                self.robot.joint_vector(joints)
            return cached[1]
        # check (depthguard.depth): a DepthImage is a plain dataclass, whoever built it may have bypassed
        # depth_image; its data is checked again and copied, so that nothing the caller does to its array can change
        # the prepared frame.
        image = checked_frame(frame, camera) if isinstance(frame, DepthImage) else depth_image(frame, camera)
        measured, solid_band = image, 0.0
        if self._static is not None:  # known solids (depthguard.static_solids) stand in for what they hide
            image, solid_band = self._static.substitute_band(image, camera)
        mask = None
        if self._silhouette is not None:  # self-filter (depthguard.self_filter)
            if joints is None:
                raise InputError(f"camera {name!r}: this monitor filters the robot out of its frames: pass the robot's "
                                 "joint positions at the frame's capture time (query(..., joints=...))")
            from depthguard.self_filter import robot_mask

            q = self.robot.joint_vector(joints)
            mask = self._masks.get(name)
            if mask is None or not np.array_equal(mask.joints, q):
                # A robot that stood still since this camera's last frame (the same joints, exactly) is where it
                # was: its renders are kept, not made again (they depend on the joints, the camera and the solids
                # alone, and nothing writes into them).
                mask = robot_mask(self._silhouette, camera, q, self._static)
                self._masks[name] = mask
        # prepare (depthguard.depth)
        occupancy = prepare_depth(image, camera, self.invalid, self.hole_pixels,
                                  robot_near=None if mask is None else mask.near,
                                  robot_tolerance=self.self_filter_tolerance,
                                  robot_far=None if mask is None else mask.far)
        state = _CameraFrame(camera, image, occupancy, mask, measured=measured, solid_band=solid_band)
        if isinstance(frame, DepthImage):
            self._prepared[name] = (frame, state)
        return state

    def query(self, frames: Mapping[str, object], points_world, *, joints=None, camera_joints=None,
              now: float | None = None, check: bool = True) -> DistanceResult:
        """Distances of control points given the latest frame of each camera.

        Args:
            frames: camera name -> :class:`DepthImage` (or a (height, width) array in the camera's units).
            points_world: (n, 3) float64, metres, world frame.
            joints: with a robot: its joint positions when the new frames were captured (a dict by name or a
                sequence in ``robot.joint_names`` order, radians). Only frames not prepared before use it.
            camera_joints: with a robot whose cameras captured their frames at different times: a mapping camera
                name -> its joint positions at that camera's capture time (given instead of ``joints``).
            now: the current time in the frames' clock, seconds (a finite number), or None; needed when ``max_age``
                is given explicitly. None under the default ``max_age="auto"``: the newest timestamp among
                ``frames`` stands for it (a camera whose frame lags the others by more than max_age is stale; one
                that froze alone is caught only with ``now``: pass it).
            check: validate the points (``False`` for a hot loop that passes a checked (n, 3) float64 array).

        Time (design §8): a frame is stale, and counts as blind (it clears nothing, results flag
        ``STALE_CAMERA``), when

        - its timestamp is NaN or infinite (whatever ``max_age``);
        - ``now`` is given and it is stamped later than ``now + config.CLOCK_SKEW_TOLERANCE`` (its time is wrong;
          also without ``max_age``);
        - it is older than ``max_age`` at ``now``, or it has no timestamp and ``max_age`` was given explicitly.

        The answer is as old as the oldest usable frame (``DistanceResult.ages``; ``age``): a camera's free space is
        what it saw when it captured its frame.

        Then :meth:`plan` decides, by one rule, which method answers: none (distance 0, with no usable frame), the
        single-camera method (one usable frame) or the depth grid (several); a stale or missing camera of the rig
        flags every answer.
        """
        if not isinstance(check, bool):
            raise InputError(f"check must be True or False, got {short_repr(check)}", field="check")
        points = check_points(points_world) if check else points_world
        return self.prepare_set(frames, joints=joints, camera_joints=camera_joints, now=now).query(points, check=False)

    def prepare_set(self, frames: Mapping[str, object], *, joints=None, camera_joints=None,
                    now: float | None = None) -> "PreparedSet":
        """Prepare one set of frames for any number of queries: check and prepare each frame (self-filtering it),
        take it into the free-space memory, decide the plan (:meth:`plan`), and set up the depth grid's fusion.
        Arguments as :meth:`query`, which is ``prepare_set(...).query(points)``. Frames prepared before (the same
        :class:`DepthImage` objects) are not prepared again. The :class:`PreparedSet` does not change when the
        monitor prepares the next one: one thread may query it while another prepares the next
        (:class:`depthguard.LiveMonitor`)."""
        if not isinstance(frames, Mapping):
            raise InputError(f"frames must map camera names to depth images, got {type(frames).__name__}",
                             field="frames")
        if camera_joints is not None:
            if joints is not None:
                raise InputError("give joints (one set for every frame) or camera_joints (per camera), not both",
                                 field="camera_joints")
            if not isinstance(camera_joints, Mapping):
                raise InputError(f"camera_joints must map camera names to joint positions, got "
                                 f"{short_repr(camera_joints)}", field="camera_joints")
            for name in camera_joints:
                self.rig.camera(name)
        if now is not None:
            now = check_real(now, "now", unit="seconds", field="now")
        if self._untimed_stale and now is None:
            raise InputError("this monitor has max_age set: pass now= (seconds, the frames' clock) to query()",
                             field="now")
        tick = time.perf_counter()
        # The pipeline (docs/design.md, "Layers and the pipeline"): check, self-filter and prepare each frame ...
        states: dict[str, _CameraFrame] = {}
        for name, frame in frames.items():
            if not isinstance(name, str):
                raise InputError(f"frames must be keyed by camera name, got {short_repr(name)}", field="frames")
            states[name] = self._camera_frame(name, frame,
                                              joints if camera_joints is None else camera_joints.get(name))
        clock, usable, stale = self._split_by_age(states, now)
        if self.memory is not None:  # ... remember (depthguard.freespace) ...
            self._remember(usable)
        plan = self.plan(usable, stale)
        fused = self._fused_frames_of(plan, usable) if plan.kind == "fused" else ()  # ... fuse (depthguard.depthgrid)
        times = [state.occupancy.timestamp for state in usable.values() if state.occupancy.timestamp is not None]
        detectable = self._find_detectable(usable)
        concessions = self._concessions(plan, usable)
        # ... and answer: PreparedSet.query (depthguard.depthspace or the fusion, then the concessions' flags).
        return PreparedSet(plan=plan, usable=dict(usable), fused=fused, free_now=self._free_now if fused else None,
                           rho=self.rho, aggregate=self.aggregate, unseen=self.unseen, method=self.method,
                           time=min(times) if times else None, detectable=detectable, now=clock,
                           newest=max(times) if times else None, max_age=self.max_age,
                           untimed_stale=self._untimed_stale, concessions=concessions,
                           capability=None if self.detectable is None else (self.detectable.capability,
                                                                            self.hidden_band),
                           prepare_seconds=time.perf_counter() - tick)

    def _split_by_age(self, states: dict, now: float | None) -> tuple:
        """(the clock, usable frames by camera, stale frames' timestamps by camera): the check of time (design §8).
        Under the default ``max_age="auto"`` without ``now``, the newest timestamp among the frames is the clock."""
        if now is None:
            times = [s.occupancy.timestamp for s in states.values() if s.occupancy.timestamp is not None
                     and math.isfinite(s.occupancy.timestamp)]
            clock = max(times) if times else None
        else:
            clock = now
        usable: dict[str, _CameraFrame] = {}
        stale: dict[str, float | None] = {}
        for name, state in states.items():
            if self.is_stale(state.occupancy.timestamp, clock):
                stale[name] = state.occupancy.timestamp
            else:
                usable[name] = state
        return clock, usable, stale

    def _concessions(self, plan: "QueryPlan", usable: dict) -> "Concessions":
        """Where the concessions of this set of frames counted space free that no camera saw free (design section
        11a): the robot zone (fused answers and the detectable space), the known solids' bands, the filled holes."""
        capsules = None  # the robot's capsules at every usable frame's joints: (n, 7) world frame
        if self.robot is not None:
            joints = {s.joints.tobytes(): s.joints for s in usable.values() if s.joints is not None}
            rows = [tuple(c.p0) + tuple(c.p1) + (c.radius,) for q in joints.values()
                    for c in self.robot.capsules_world(q, check=False)]
            if rows:
                capsules = np.array(rows, dtype=np.float64)
        zoned = (plan.kind == "fused" or self.detectable is not None) and self.robot_zone
        zone = (capsules, self.robot_zone) if zoned and capsules is not None else None
        solids = None
        if self._static is not None:  # query() only: the detectable space uses the frames as measured
            band = max([s.solid_band for s in usable.values()], default=0.0)
            if band > 0.0:
                solids = (self._static.boxes, band)
        fills = tuple(s.filled for s in usable.values() if s.occupancy.invalid_policy == "neighbors"
                      and s.occupancy.invalid_pixels and s.filled is not None)
        shell = (capsules, self._shell) if capsules is not None else None
        return Concessions(zone, solids, fills, zone_in_query=plan.kind == "fused", shell=shell)

    def _remember(self, usable: dict) -> None:
        """Take the usable frames the memory has not seen into it (design §8a), as of the earliest capture time
        among them: a voxel a frame saw free at t_j was free at t_j, and dating it earlier only shortens how long it
        is remembered. A frame without a timestamp, or older than the memory's last update, adds nothing."""
        last = self.memory.time if self.memory.time is not None else -math.inf
        new = [state for state in usable.values() if id(state) not in self._remembered
               and state.occupancy.timestamp is not None and state.occupancy.timestamp >= last]
        if not new:
            return
        from depthguard.freespace import remember_frames, robot_inside_voxels, robot_voxels, surface_voxels

        box = self.memory.box
        t = min(state.occupancy.timestamp for state in new)
        robot = near = inner = region = None
        if self.robot is not None:  # Robot_k: inside the links at the joints of the frames captured at t
            joints = [state.joints for state in new if state.occupancy.timestamp == t and state.joints is not None]
            if joints:
                moments = [self.robot.inner_capsules_world(q, check=False) for q in joints]
                robot = robot_inside_voxels(box, moments)
                # the voxels touching the padded capsules, judged piece by piece; the robot's pieces only where the
                # frames of t agree on the joints (else the cameras alone)
                # (every moment's capsules in one array: the marks and their sub-box are those of all of them)
                radii = [capsule.radius for capsule in self.robot.capsules]
                padded = np.concatenate([np.column_stack([self.robot.capsule_segments(q, check=False).reshape(-1, 6),
                                                          radii]) for q in joints])
                near = np.zeros(box.shape, dtype=bool)
                region = robot_voxels(box, padded, box.voxel * math.sqrt(3.0), near)
                same = all(np.array_equal(m, moments[0]) for m in moments)
                inner = moments[0] if same else None
        remember_frames(
            self.memory, t, [state.camera for state in new], [state.free for state in new],
            [functools.partial(surface_voxels, box, state.camera, state.image, state.occupancy) for state in new],
            margin=self.fusion_margin, pad=self.fusion_pixels, robot=robot, near_robot=near, inner=inner,
            near_region=region)
        self._remembered = {id(state) for state in usable.values()}

    def plan(self, usable, stale) -> "QueryPlan":
        """How a query answers, decided once by one rule from which of the rig's cameras have a usable frame
        (``usable``: names of fresh frames) and which a stale one (``stale``); every other camera of the rig is
        missing:

        - no usable frame: no camera answers; every point gets distance 0 (``DistanceResult.blind``);
        - one usable frame: the single-camera method on it (design §3-7), the same answer whatever other
          cameras the rig holds;
        - several: the depth grid (design §8) of each principal camera with a usable frame; when none of the
          principals has one, the first camera of the rig that has takes their place. Every other camera of the rig
          is a secondary camera; a stale or missing one is blind (it clears nothing).

        Whatever the case, every answer carries ``STALE_CAMERA`` when a camera of the rig has a stale frame and
        ``MISSING_CAMERA`` when one has none, and ``DistanceResult.principal`` names the camera that answered.
        """
        names = [name for name in self.rig.cameras if name in usable]
        absent = Flag(0)
        if any(name in stale for name in self.rig.cameras):
            absent |= Flag.STALE_CAMERA
        if any(name not in usable and name not in stale for name in self.rig.cameras):
            absent |= Flag.MISSING_CAMERA
        if not names:
            return QueryPlan("blind", (), absent, dict(stale))
        if len(names) == 1:
            return QueryPlan("single", (names[0],), absent, dict(stale))
        principals = tuple(name for name in self.principals if name in usable) or (names[0],)
        return QueryPlan("fused", principals, absent, dict(stale))

    def is_stale(self, timestamp: float | None, now: float | None) -> bool:
        """Whether a frame stamped ``timestamp`` (seconds, or None) counts as blind at ``now`` (see :meth:`query`)."""
        return is_stale(timestamp, now, self.max_age, self._untimed_stale)

    def _fused_frames_of(self, plan: "QueryPlan", usable: dict) -> tuple:
        """The FusedFrames of each of the plan's principals on these frames (kept while the same frames come back,
        with the cells they have classified so far)."""
        from depthguard.depthgrid import FusedFrames, build_map

        if self.method != "exact":
            raise InputError("fusing several cameras uses the exact method only")
        out = []
        for name in plan.principals:
            grid = self.maps.get(name)
            if grid is None:
                grid = self.maps[name] = build_map(self.rig, name)
            key = tuple(usable.get(other) for other in (name,) + grid.secondaries)
            cached = self._fused_frames.get(name)
            if cached is None or len(cached[0]) != len(key) or any(a is not b for a, b in zip(cached[0], key)):
                secondaries = {other: (usable[other].free if other in usable else None) for other in grid.secondaries}
                state = usable[name]
                zone, shell = self._robot_zone_and_shell(state)
                cached = self._fused_frames[name] = (key, FusedFrames(
                    grid, self.rig, state.occupancy, secondaries, robot_far=state.robot_far,
                    margin=self.fusion_margin, pad=self.fusion_pixels,
                    robot_tolerance=self.self_filter_tolerance, check=False, robot_near=state.robot_near,
                    robot_exit=state.robot_exit, remembered=self._remembered_free(usable),
                    robot_zone=zone, robot_shell=shell))
            out.append(cached[1])
        return tuple(out)

    def _robot_zone_and_shell(self, state: "_CameraFrame") -> tuple:
        """(zone, shell) for FusedFrames, from the robot's capsules when ``state``'s frame was captured ((n, 7) world
        frame: p0, p1, radius with the padding): the robot zone, (capsules, ``robot_zone``), None with
        ``robot_zone=0``; and the shell round the links a ray meets after its first, the capsules grown by how far
        the rendered geometry reaches beyond them. (None, None) without a robot or joints."""
        if self.robot is None or state.joints is None:
            return None, None
        capsules = np.array([c.p0 + c.p1 + (c.radius,) for c in self.robot.capsules_world(state.joints, check=False)])
        shell = capsules.copy()
        shell[:, 6] += self._silhouette.beyond_capsules
        return ((capsules, self.robot_zone) if self.robot_zone else None), shell

    def _remembered_free(self, usable: dict):
        """(free voxels, box) for FusedFrames: what the memory certifies free at the latest capture time of the
        usable frames, or the memory's last update if that is later (None without memory). Keeps, for the flag,
        ``self._free_now`` = (free, box, the part of free that no frame of the last update saw free)."""
        self._free_now = None
        if self.memory is None or self.memory.time is None:
            return None
        times = [state.occupancy.timestamp for state in usable.values() if state.occupancy.timestamp is not None]
        if not times:
            return None
        free = self.memory.free_at(max(max(times), self.memory.time))
        self._free_now = (free, self.memory.box, free & ~self.memory.taken_now)  # remembered: free, not taken now
        return free, self.memory.box


def _farthest_robot_depth(camera, robot) -> float:
    """Metres: the largest optical depth at which ``camera`` can see a part of ``robot`` (the depth of its base plus
    its reach), within the camera's depth range."""
    base = camera.world_to_camera(robot.T_world_base[:3, 3][None])[0, 2]
    return max(min(float(base) + robot.reach(), camera.depth_range[1]), 0.0)


def _farthest_depth(camera, workspace) -> float:
    """Metres: the largest optical depth at which ``camera`` sees a corner of ``workspace`` ((2, 3) world box, or
    None: the camera's whole range), within its depth range (its largest finite depth when the range is open)."""
    z_max = camera.depth_range[1]
    if workspace is None:
        return z_max if math.isfinite(z_max) else config.DEPTH_GRID_UNBOUNDED_END
    lo, hi = np.asarray(workspace, dtype=np.float64)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    T_camera_world = np.linalg.inv(camera.T_world_camera)
    depth = float(((corners @ T_camera_world[:3, :3].T) + T_camera_world[:3, 3])[:, 2].max())
    return max(min(depth, z_max), 0.0)


class _CameraFrame:
    """One camera's latest frame as the monitor's stages left it: the frame checked (``image``; ``measured``, before
    known solids replaced any measurement, and ``solid_band``, metres, how far from a known solid the replaced ones
    reach), where the robot is along each pixel (``mask``, a :class:`~depthguard.self_filter.RobotMask`, or None),
    and the prepared frame (``occupancy``); what the fusion and the memory need besides is made when first asked
    for."""

    def __init__(self, camera, image: DepthImage, occupancy: OccupancyImage, mask=None, *, measured=None,
                 solid_band: float = 0.0):
        self.camera = camera
        self.image = image
        self.occupancy = occupancy
        self.mask = mask
        self.measured = image if measured is None else measured
        self.solid_band = solid_band
        self._free = None
        self._filled = None
        self._measured_free = None

    @property
    def joints(self):
        """(n,) the robot's joints at the frame's capture time, or None without a robot."""
        return None if self.mask is None else self.mask.joints

    @property
    def robot_near(self):
        return None if self.mask is None else self.mask.near

    @property
    def robot_far(self):
        return None if self.mask is None else self.mask.far

    @property
    def robot_exit(self):
        return None if self.mask is None else self.mask.exit

    @property
    def measured_free(self) -> np.ndarray:
        """:attr:`free` of the frame as measured, before known solids replaced any measurement (the detectable
        space's, to which a known solid's band is no concession)."""
        if self.measured is self.image:
            return self.free
        if self._measured_free is None:
            from depthguard.depthgrid import seen_free

            self._measured_free = seen_free(self.measured, self.occupancy)
        return self._measured_free

    @property
    def filled(self) -> OccupancyImage | None:
        """The space this frame's filled holes counted free (``invalid="neighbors"``), as an occupancy image whose
        segments are that space: each filled pixel's frustum from the camera's minimum range to where its fill
        starts the possibly occupied space. None when no hole was filled."""
        if self._filled is None:
            self._filled = (filled_space(self.occupancy),)
        return self._filled[0]

    @property
    def free(self) -> np.ndarray:
        """(h, w) float32 metres: how far the camera saw free along each pixel (``depthguard.depthgrid.seen_free``)."""
        if self._free is None:
            from depthguard.depthgrid import seen_free

            self._free = seen_free(self.image, self.occupancy)
        return self._free
