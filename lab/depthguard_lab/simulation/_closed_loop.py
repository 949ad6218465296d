"""The avoidance loop in simulated time (design §9): cameras at the workcell's rate, control at 500 Hz.

Per control step k (t = k dt):

1. when a camera period has passed, every camera captures the workcell with the robot where it **is** (its joints
   under the loop's own command, not the scripted trajectory) and the people where their scripts put them; the set
   goes to the :class:`~depthguard.DistanceMonitor`, self-filtered with the joints at its capture time, and becomes
   usable ``latency`` seconds later (the time a real pipeline takes to prepare it);
2. the control points' distances at the current joints, from the latest usable set (its age is the data's age);
3. the command, by ``mode``:

   - ``"none"``: the task alone (the joints' limits still hold);
   - ``"avoid"``: the papers' avoidance (:class:`~depthguard.avoidance.AvoidanceController`);
   - ``"ssm"``: the task, slowed by speed and separation monitoring
     (:class:`~depthguard.avoidance.SpeedSeparationMonitor`), with the reaction time = the age of the set's oldest
     frame + the set's measured preparation time (wall clock) + one control step, the stopping time from the
     robot's braking (its joints' acceleration limits, the robot braking along its path), and the detection
     capability that of the monitor's answers: d plus what its concessions can hide next to a surface
     (:meth:`~depthguard.DistanceMonitor.query_hidden_band`); above ISO 13855's 70 mm no C covers it, and the loop
     refuses to run SSM (:class:`~depthguard.errors.InputError` naming ``detection_capability``);

4. the joints move by the command (Euler, within their limits).

A blind answer (no camera could see yet) stops the robot in every mode that uses the monitor.

The task: the end-effector follows the workcell's scripted trajectory (its end-effector position over time, x_ref):
desired velocity dx_ref/dt + ``gain`` (x_ref - x); the arm's redundancy pulls towards the scripted joints
(``AvoidanceParams.posture_gain``), so the posture comes back after an avoidance.

Exact ground truth (:class:`~depthguard_lab.simulation.TruthComputer`: coal between the robot's collision meshes and the
obstacles) every ``truth_every`` control steps and at every camera frame.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from depthguard import config
from depthguard.avoidance import AvoidanceController, AvoidanceParams, JointLimits, reachable
from depthguard.errors import InputError
from depthguard.validation import check_real
from depthguard.results import DistanceResult, Flag

MODES = ("none", "avoid", "ssm")


@dataclass(frozen=True)
class LoopSettings:
    """How the loop runs.

    Attributes:
        control_rate: Hz, control steps per second (the papers: 500).
        latency: seconds from a set's capture to when its distances can be used.
        gain: 1/s, the task's position feedback.
        posture_gain: 1/s, the redundancy's pull towards the scripted joints.
        truth_every: ground truth every this many control steps (and at every camera frame).
        avoidance: the avoidance's parameters (:class:`~depthguard.avoidance.AvoidanceParams`; its rho is the
            monitor's; distances from the links' surfaces by default).
        acceleration: rad/s^2, the joints' acceleration limits (URDF has none).
        ssm: :class:`~depthguard.avoidance.SSMParams` of mode "ssm" (default: its defaults).
        ssm_rho: metres, the monitor's rho in mode "ssm": above the protective separation distance at the
            robot's speed plus the links' radii (0.90 m at standstill with the defaults and the robot zone in Z_d),
            or nothing could be seen far enough away to move at all.
        ssm_lookahead: mode "ssm": where a point would be slowed, ask the monitor for the distance at the point
            looked ahead to (``SpeedSeparationMonitor.lookahead_time``), so that a point moving away from everything
            possibly occupied is not slowed (the rule and its proof: ``depthguard.avoidance._ssm``). The monitor's
            directions are never trusted: one direction summarises all the possibly occupied space within rho (the
            mean direction with ``hybrid``), and moving away from it can approach a person elsewhere in that space
            (with them, ``tests/test_closed_loop.py`` once found the end-effector approaching the person at 8 mm/s
            while truly inside S_p). False: every point moving within reach of S_p is slowed as if it approached at
            its whole speed.
        ssm_ramp: seconds, mode "ssm": the speed factor applied rises from 0 to 1 no faster than over this time (and
            falls at once): where the factor SSM allows flickers between stopping and going, as a person's distance
            crosses S_p at rest, the robot does not start and stop with it (measured in the SSM cell's elbow
            scenario: 1.96 reversals a second without it). Applying less than SSM allows is always within its rule.
            0: no ramp.
        ssm_capability: mode "ssm": SSM's distances leave out possibly occupied regions thinner than its detection
            capability d (``DistanceMonitor(detection_capability=d)``, :class:`depthguard.freespace.DetectableSpace`):
            a body part thinner than d reaches at most the intrusion distance C beyond the detected body, and S_p
            counts C. Its space is what any camera sees entirely free (not only through the principal), in 1 cm
            voxels over the rig's workspace: about 0.3-0.5 s of work per set of frames, so off by default.
        cover_surface: the avoidance and SSM measure from spheres that cover every moving link's padded capsule
            (``RobotModel.with_surface_points``), none more than ``surface_tolerance`` metres (SSM's Z_r) beyond it,
            and the end-effector's control point; False: from the robot's control points only (the papers' nine,
            which leave 4-5 cm of the iiwa's capsules outside their spheres).
        surface_tolerance: metres, > 0: how far the covering spheres may reach beyond the capsules (default SSM's
            Z_r, which counts it).
        known_solids: tell the monitor the workcell's known static boxes (``Workcell.background()``: floor, walls,
            pedestal) as ``DistanceMonitor(static=...)``: they stop counting as possibly a person, what they hide
            still counts.
        monitor: keyword arguments of :class:`~depthguard.DistanceMonitor` besides rig and robot. The default robot
            zone is ``config.LOOP_ROBOT_ZONE`` (the shell round the links that no depth camera can tell from them; see
            there): a stated tolerance (a distance may exceed the truth by up to its thickness), added to the
            avoidance's ``tolerance`` and to SSM's Z_d. The default aggregate is "min": the avoidance bounds the
            control points other than the end-effector along the direction to the nearest obstacle (design §9), and
            asks "hybrid" for the end-effector alone (``_avoidance_query``).
    """

    control_rate: float = 500.0
    latency: float = 1.0 / 30.0
    gain: float = 5.0
    posture_gain: float = 2.0
    truth_every: int = 5
    avoidance: AvoidanceParams = field(default_factory=AvoidanceParams)
    acceleration: float = config.JOINT_ACCELERATION
    ssm: object = None
    ssm_rho: float = 1.2
    ssm_lookahead: bool = True
    ssm_ramp: float = 0.25
    ssm_capability: bool = False
    known_solids: bool = False
    cover_surface: bool = True
    surface_tolerance: float = config.SSM_ROBOT_UNCERTAINTY
    monitor: dict = field(default_factory=lambda: dict(aggregate="min", invalid="neighbors",
                                                       robot_zone=config.LOOP_ROBOT_ZONE))

    def __post_init__(self):
        check_real(self.control_rate, "control_rate", minimum=1.0, maximum=1e5, unit="Hz", field="control_rate")
        check_real(self.latency, "latency", minimum=0.0, maximum=10.0, unit="seconds", field="latency")
        check_real(self.gain, "gain", minimum=0.0, maximum=1e3, unit="1/s", field="gain")
        check_real(self.posture_gain, "posture_gain", minimum=0.0, maximum=1e3, unit="1/s", field="posture_gain")
        if isinstance(self.truth_every, bool) or not isinstance(self.truth_every, int) or self.truth_every < 1:
            raise InputError("truth_every must be a whole number >= 1", field="truth_every")
        check_real(self.surface_tolerance, "surface_tolerance", minimum=0.0, above_minimum=True, maximum=1.0,
                   unit="metres", field="surface_tolerance")
        for name in ("ssm_lookahead", "ssm_capability", "known_solids", "cover_surface"):
            if not isinstance(getattr(self, name), bool):
                raise InputError(f"{name} must be True or False", field=name)
        check_real(self.ssm_ramp, "ssm_ramp", minimum=0.0, maximum=10.0, unit="seconds", field="ssm_ramp")
        check_real(self.ssm_rho, "ssm_rho", minimum=0.0, above_minimum=True, maximum=10.0, unit="metres",
                   field="ssm_rho")
        if not isinstance(self.monitor, dict):
            raise InputError("monitor must be a dict of DistanceMonitor keyword arguments", field="monitor")
        # The robot zone is also a tolerance of the avoidance and of SSM here: checked before it is added to them.
        check_real(self.monitor.get("robot_zone", config.DEFAULT_ROBOT_ZONE), "robot_zone", minimum=0.0,
                   maximum=config.ROBOT_ZONE_MAX, unit="metres", field="robot_zone")


@dataclass(frozen=True, eq=False)
class LoopLog:
    """What happened, per control step (T steps, n joints, m control points; world frame, metres, seconds).

    Attributes:
        mode: "none", "avoid" or "ssm".
        times: (T,) seconds.
        q, dq: (T, n) joints and the command applied from that step.
        dq_requested: (T, n) what the task asked for before speed and separation monitoring scaled it (mode "ssm";
            the command itself in the other modes).
        ee, ee_ref: (T, 3) the end-effector control point and where the task wants it.
        reported: (T, m) the monitor's distances (inf: nothing within rho).
        flags: (T, m) int flag bits.
        repulsive: (T, 3) m/s, the end-effector's repulsive velocity ("avoid").
        scale: (T,) the fraction of the task's velocity commanded (avoidance's task scale, or SSM's speed factor).
        data_age: (T,) seconds, the age of the frames the distances came from (inf before the first).
        step_seconds: (T,) wall-clock seconds of each step's distances and command.
        truth_steps: (K,) indices into the steps where the ground truth was computed.
        truth: (K, m) metres, each control point to the nearest obstacle.
        clearance: (K,) metres, robot collision meshes to the nearest obstacle (<= 0: a collision).
        frames: how many camera sets were captured. wall_seconds: the whole run, wall clock.
        captures: with ``keep_frames``, each captured set as (capture time, joints, {camera: DepthImage}); else
            empty.
        robot: the robot whose control points the avoidance and SSM measured from (the rows of ``reported`` and
            ``flags``, ``robot.control_point_names``): with ``LoopSettings.cover_surface``, spheres covering every
            moving link (``RobotModel.with_surface_points``) and the end-effector; ``truth`` is per control point of
            the workcell's robot.
    """

    mode: str
    times: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    dq_requested: np.ndarray
    ee: np.ndarray
    ee_ref: np.ndarray
    reported: np.ndarray
    flags: np.ndarray
    repulsive: np.ndarray
    scale: np.ndarray
    data_age: np.ndarray
    step_seconds: np.ndarray
    truth_steps: np.ndarray
    truth: np.ndarray
    clearance: np.ndarray
    frames: int
    wall_seconds: float
    captures: tuple = ()
    robot: object = None

    @property
    def task_error(self) -> np.ndarray:
        """(T,) metres between the end-effector and where the task wants it."""
        return np.linalg.norm(self.ee - self.ee_ref, axis=1)


def run_closed_loop(workcell, mode: str = "avoid", duration: float | None = None, start: float = 0.0,
                    settings: LoopSettings | None = None, seed: int | None = None, progress: bool = False,
                    renderer=None, keep_frames: bool = False, measure: bool = True) -> LoopLog:
    """Run ``workcell`` (:class:`~depthguard_lab.simulation.Workcell`) in closed loop from ``start`` for ``duration``
    seconds (default: to the episode's end) with ``mode`` ("none", "avoid", "ssm"). See the module's docstring.
    ``keep_frames``: keep every captured set of depth images in the log (``LoopLog.captures``, for a recording:
    about 0.6 MB per 640x480 image). ``measure=False`` (mode "none" only, whose commands do not read the distances):
    no monitor runs, so the log's reported distances stay what a loop reports before its first set (0, flagged
    missing) and only the truth is kept (a run that asks only whether the task alone meets the person)."""
    import depthguard as dg
    from depthguard_lab.simulation._episode import SceneRenderer, check_seed, sense
    from depthguard_lab.simulation._truth import TruthComputer

    if mode not in MODES:
        raise InputError(f"mode must be one of {', '.join(MODES)}, got {mode!r}", field="mode")
    if measure is not True and (measure is not False or mode != "none"):
        raise InputError(f"measure must be True, or False in mode none only (got {measure!r} in mode {mode})",
                         field="measure")
    settings = LoopSettings() if settings is None else settings
    seed = check_seed(workcell.seed if seed is None else seed)
    start = check_real(start, "start", minimum=0.0, maximum=workcell.duration, unit="seconds", field="start")
    end = workcell.duration if duration is None else start + check_real(
        duration, "duration", minimum=0.0, maximum=workcell.duration - start, above_minimum=True, unit="seconds",
        field="duration")
    robot = workcell.robot
    dt = 1.0 / settings.control_rate
    steps = int(round((end - start) / dt))
    camera_period = 1.0 / workcell.rate
    # The robot zone is a sensing tolerance: a distance may exceed the truth by up to its thickness.
    zone = settings.monitor.get("robot_zone", config.DEFAULT_ROBOT_ZONE)
    params = replace(settings.avoidance, posture_gain=settings.posture_gain,
                     tolerance=settings.avoidance.tolerance + zone)
    limits = JointLimits.from_robot(robot, acceleration=settings.acceleration)
    # The points the avoidance and SSM measure from: spheres that cover every moving link's padded capsule, none more
    # than Z_r beyond it, and the end-effector's control point (design §9: distances from the robot's surface).
    points_robot = robot.with_surface_points(settings.surface_tolerance) if settings.cover_surface else robot
    controller = AvoidanceController(points_robot, params, limits)
    options = dict(settings.monitor)
    if settings.known_solids:
        options["static"] = workcell.background_parts()
    capability = mode == "ssm" and settings.ssm_capability
    ssm_params = None
    if mode == "ssm":
        from depthguard.avoidance import SSMParams

        ssm_params = SSMParams() if settings.ssm is None else settings.ssm
        if capability:
            options["detection_capability"] = ssm_params.detection_capability
    monitor = dg.DistanceMonitor(workcell.rig, rho=settings.ssm_rho if mode == "ssm" else params.rho, robot=robot,
                                 **options)
    ssm = None
    if mode == "ssm":
        ssm = _ssm_monitor(monitor, ssm_params, capability, zone, settings.ssm_rho, limits)
    truth = TruthComputer(robot)
    part_names = {name: workcell.part_names(name) for name in workcell.obstacle_names}
    m, n = len(points_robot.control_points), robot.n_joints
    ee = points_robot.end_effector_index
    radii = points_robot.control_point_radii
    nothing = _empty_result(m)

    def reference(t):
        q_ref = workcell.joints_at(min(max(t, 0.0), workcell.duration))
        return points_robot.control_point_positions(q_ref, check=False)[ee], q_ref

    q = workcell.joints_at(start).copy()
    dq = np.zeros(n)
    requested_before = dq  # mode "ssm": the task's command at the step before, before SSM scaled it
    ssm_scale = 0.0  # mode "ssm": the speed factor applied at the step before
    if mode == "ssm":  # where SSM's distances come from: the detectable space, or the monitor's query
        ask = (lambda prepared, p: _detectable(prepared, p, settings.ssm_rho)) if capability else _query
        ssm_distances = _MovedSince(ask, settings.ssm_rho, config.SSM_REQUERY)
    log = {key: [] for key in ("times", "q", "dq", "dq_requested", "ee", "ee_ref", "reported", "flags", "repulsive",
                               "scale", "data_age", "step_seconds")}
    truth_steps, truth_rows, clearance = [], [], []
    pending = []  # (usable from, PreparedSet, capture time)
    current = None  # (PreparedSet, capture time)
    next_frame = start
    upcoming = reference(start)  # (end-effector, joints) the task wants at the step about to run
    frames = 0
    captures = []
    scene = SceneRenderer(workcell, renderer)
    wall = time.perf_counter()
    try:
        iterator = range(steps)
        if progress:
            from tqdm import tqdm

            iterator = tqdm(iterator, desc=f"closed loop, {mode}", unit="step", mininterval=1.0)
        for k in iterator:
            t = start + k * dt
            captured = t >= next_frame - 1e-9
            if captured:
                frame = sense(workcell, scene, truth, part_names, q.copy(), t, int(round(t * workcell.rate)), seed)
                if measure:
                    prepared = monitor.prepare_set(frame.depth, joints=q.copy(), now=t)
                    pending.append((t + settings.latency, prepared, t))
                next_frame += camera_period
                frames += 1
                if keep_frames:
                    captures.append((t, q.copy(), dict(frame.depth)))
            while pending and pending[0][0] <= t + 1e-9:
                _, prepared, captured_at = pending.pop(0)
                current = (prepared, captured_at)
            tick = time.perf_counter()
            points, jacobians = points_robot.control_point_kinematics(q, check=False)
            if current is None:
                result = DistanceResult.blind(m, Flag.MISSING_CAMERA, {})  # nothing seen yet: distance 0
                age = math.inf
            elif mode == "ssm":
                result = replace(nothing, distance=ssm_distances(current[0], points))
                age = t - current[1]
            else:
                result = _avoidance_query(current[0], points, ee)
                age = t - current[1]
            (x_ref, q_ref), upcoming = upcoming, reference(t + dt)  # each reference computed once
            x_next = upcoming[0]
            task = (x_next - x_ref) / dt + settings.gain * (x_ref - points[ee])
            if mode == "avoid":
                command = controller.command(result, q, task, dq, dt, jacobians=jacobians, posture=q_ref,
                                             check=False)
                dq_new, scale, repulsive = command.dq, command.scale, command.repulsive
                requested = dq_new
            else:
                # Under SSM the task's command evolves from what the task asked for last (its acceleration limits
                # taken from there), not from what SSM let through: a command re-planned from the slowed one changes
                # direction from step to step, and SSM, judging each, alternates between letting it pass and stopping
                # it (measured: 42 reversals a second in scenario_b_elbow.yaml). The command sent is still brought
                # within the joints' limits from the one applied (below).
                command = controller.command(nothing, q, task, dq if mode != "ssm" else requested_before, dt,
                                             jacobians=jacobians, posture=q_ref, check=False)
                dq_new, scale, repulsive = command.dq, command.scale, np.zeros(3)
                requested = requested_before = dq_new
                if mode == "ssm":
                    # Nothing seen yet: no reaction time can be stated, and the robot stays. T_r: the set's oldest
                    # frame's age + its measured preparation + one control step.
                    reaction = math.inf if current is None else age + current[0].prepare_seconds + dt
                    scale = 0.0 if current is None else _ssm_factor(ssm, current[0], result.distance, points,
                                                                    jacobians, dq_new, reaction, radii,
                                                                    settings.ssm_lookahead, ask)
                    if settings.ssm_ramp > 0.0:  # rises no faster than the ramp; falls at once
                        scale = min(scale, ssm_scale + dt / settings.ssm_ramp)
                    ssm_scale = scale
                    dq_new = _ssm_command(dq_new * scale, dq, scale, limits, dt)
            log["step_seconds"].append(time.perf_counter() - tick)
            if captured or k % settings.truth_every == 0:
                g = frame.truth if captured else truth(q, workcell.obstacles_at(t), part_names)
                truth_steps.append(k)
                truth_rows.append(g.distance)
                clearance.append(g.clearance)
            for key, value in (("times", t), ("q", q.copy()), ("dq", dq_new), ("dq_requested", requested),
                               ("ee", points[ee]), ("ee_ref", x_ref),
                               ("reported", result.distance), ("flags", [int(f) for f in result.flags]),
                               ("repulsive", repulsive), ("scale", scale), ("data_age", age)):
                log[key].append(value)
            dq = dq_new
            q = np.clip(q + dq * dt, limits.lower, limits.upper)
    finally:
        scene.release()
    arrays = {key: np.array(value) for key, value in log.items()}
    return LoopLog(mode=mode, truth_steps=np.array(truth_steps, dtype=np.int64), truth=np.array(truth_rows),
                   clearance=np.array(clearance), frames=frames, wall_seconds=time.perf_counter() - wall,
                   captures=tuple(captures), robot=points_robot, **arrays)


def _ssm_monitor(monitor, params, capability: bool, zone: float, rho: float, limits):
    """The loop's :class:`~depthguard.avoidance.SpeedSeparationMonitor`: C for the detection capability of the
    monitor's answers (d + the band its concessions can hide, or that band alone on the query's distances), the robot
    zone in Z_d (a distance from the links may exceed the truth by its thickness), T_s from the joints' braking.
    Raises :class:`InputError` naming ``detection_capability`` where that capability is above ISO 13855's 70 mm."""
    from depthguard.avoidance import SpeedSeparationMonitor

    if capability:
        d, why = monitor.detectable.capability + monitor.hidden_band, f"d {monitor.detectable.capability:g} m + " \
            f"{monitor.hidden_band:.3f} m hidden"
    else:
        d, why = monitor.query_hidden_band()
    if d > config.SSM_INTRUSION_LIMIT * (1.0 + 1e-12):
        raise InputError(f"SSM cannot be sound here: its distances may leave out an object {d:.3f} m thick next to a "
                         f"surface ({why}), coarser than ISO 13855's 70 mm, for which no intrusion distance C is "
                         "defined", field="detection_capability")
    params = replace(params, detection_capability=d, sensing_uncertainty=params.sensing_uncertainty + zone)
    return SpeedSeparationMonitor(params, rho=rho, braking=limits.acceleration, reaches=monitor.robot.joint_reaches())


def _ssm_command(target, dq, scale: float, limits, dt: float):
    """The joint velocities the loop sends under SSM (n,): ``target`` (the task's command times SSM's factor) where
    the joints' accelerations reach it from ``dq`` within one step; where SSM slowed the robot (``scale`` < 1) and
    they cannot, the robot brakes along its path (every joint in proportion, the slowest at its limit), as the
    stopping time T_s of SSM takes it (``depthguard.avoidance.brake_along_path``)."""
    from depthguard.avoidance import brake_along_path

    low, high = reachable(np.minimum(target, 0.0), np.maximum(target, 0.0), dq, limits.acceleration * dt)
    reached = np.clip(target, low, high)
    if scale < 1.0 and not np.allclose(reached, target, rtol=0.0, atol=1e-12):
        return brake_along_path(dq, limits.acceleration, dt)
    return reached


class _MovedSince:
    """SSM's distances of the control points on one set of frames, asked again only for the points that moved more
    than ``tolerance`` metres since they were asked. A distance to a fixed set is 1-Lipschitz in the point, so a
    lower bound L(P) of the distance from P gives L(P) - |P' - P| for P' (inf: at least ``rho``); SSM needs only a
    lower bound. ``ask(prepared, points (k, 3)) -> (k,)`` asks the set. Each new set asks every point."""

    def __init__(self, ask, rho: float, tolerance: float):
        self.ask, self.rho, self.tolerance = ask, rho, tolerance
        self.prepared = None

    def __call__(self, prepared, points: np.ndarray) -> np.ndarray:
        if prepared is not self.prepared:
            self.prepared, self.points, self.distance = prepared, points.copy(), self.ask(prepared, points)
            return self.distance.copy()
        moved = np.linalg.norm(points - self.points, axis=1)
        stale = moved > self.tolerance
        if stale.any():
            self.points[stale] = points[stale]
            self.distance[stale] = self.ask(prepared, points[stale])
            moved[stale] = 0.0
        bound = np.maximum(np.minimum(self.distance, self.rho) - moved, 0.0)
        return np.where(moved > 0.0, bound, self.distance)


def _detectable(prepared, points, rho) -> np.ndarray:
    """(m,) the detectable distances (``PreparedSet.detectable_distances``) of points (m, 3), inf where at least
    rho (as the monitor's "nothing within rho")."""
    return beyond_rho(prepared.detectable_distances(points, limit=rho, check=False).distance, rho)


def beyond_rho(distance: np.ndarray, rho: float) -> np.ndarray:
    """(m,) ``distance`` (metres) with inf where it is at least rho (the monitor's "nothing within rho")."""
    return np.where(distance >= rho, np.inf, distance)


def _avoidance_query(prepared, points, ee: int) -> DistanceResult:
    """The distances the avoidance takes (design §9): every control point's (the monitor's aggregate, "min" by
    default: the other points are bounded along the direction to the nearest obstacle), with the end-effector's
    direction from "hybrid" (its repulsion follows the mean direction; the distance is the same)."""
    result = prepared.query(points, check=False)
    if prepared.aggregate == "hybrid" or not np.isfinite(result.distance[ee]):
        return result
    direction = np.array(result.direction, copy=True)
    direction[ee] = prepared.query(points[ee: ee + 1], check=False, aggregate="hybrid").direction[0]
    return replace(result, direction=direction)


def _query(prepared, points) -> np.ndarray:
    """(m,) the monitor's distances (``PreparedSet.query``) of points (m, 3), inf where nothing is within rho."""
    return prepared.query(points, check=False).distance


def _ssm_factor(ssm, prepared, distance, points, jacobians, dq, reaction_time, radii, lookahead,
                ask=_query) -> float:
    """SSM's speed factor for the command dq (n,) rad/s at the control points (m, 3) with Jacobians (m, 3, n) and
    monitor distances (m,) (inf: nothing within rho). Each point is a sphere of its link's radius (m,): distances
    count from the sphere (inf: at least rho minus the radius), and no direction is trusted. With ``lookahead``, the
    points that would slow the robot are asked again at the points looked ahead to (``prepared``: the set the
    distances came from; ``ask(prepared, points)``: where the distances come from, the set's query by default)."""
    rho = ssm.rho

    def from_spheres(d, r):
        return np.maximum(np.where(np.isfinite(d), d, rho) - r, 0.0)

    surface = from_spheres(distance, radii)
    unknown = np.zeros((len(surface), 3))
    verdict = ssm.speed_factor(surface, unknown, jacobians, dq, reaction_time, check=False)
    if verdict.factor < 1.0 and lookahead:
        # Only a point beyond S_p at rest can be certified (D' <= D + T |v|): ask for those that slow the robot.
        asks = np.flatnonzero((verdict.approach_speed > verdict.allowed_speed) & (verdict.allowed_speed > 0.0))
        looked = points[asks] + ssm.lookahead_time(reaction_time, dq) * (jacobians[asks] @ dq)
        ahead = np.zeros(len(surface))  # not asked: certifies nothing
        ahead[asks] = from_spheres(ask(prepared, looked), radii[asks])
        verdict = ssm.speed_factor(surface, unknown, jacobians, dq, reaction_time, ahead=ahead, check=False)
    return verdict.factor


def _empty_result(m: int) -> DistanceResult:
    """A result with nothing within rho for m points: the task alone."""
    return DistanceResult(distance=np.full(m, np.inf), direction=np.zeros((m, 3)), count=np.zeros(m, dtype=np.int64),
                          invalid_count=np.zeros(m, dtype=np.int64), flags=tuple(Flag(0) for _ in range(m)),
                          timestamps={}, cameras=(), invalid_pixels={}, blind_distance=np.full(m, np.inf))
