"""The papers' collision avoidance (design §9; 2015 paper section 5, 2016 paper section VII).

From one :class:`~depthguard.DistanceResult` of the robot's control points (the end-effector's among them) and a
desired end-effector velocity, :class:`AvoidanceController` gives the joint velocities of the next control step:

- the end-effector is pushed away from what is near it: a repulsive velocity v(D) along the result's direction
  (hybrid aggregation: every obstacle point within rho contributes to it), added to the task's velocity;
- every other control point C near something limits the joints that would move it towards that: with risk
  f(D) = 1 / (1 + exp((2 D / rho - 1) alpha)) and s = J_C^T (-direction f), a joint with s_i > 0 may move at most
  V_i (1 - f) in the positive sense, one with s_i < 0 at most V_i (1 - f) in the negative sense (the smallest over
  all control points);
- the joint velocities follow the commanded end-effector velocity as closely as these bounds, the joints' position,
  velocity and acceleration limits (:class:`JointLimits`) allow: saturation in the null space (SNS, Flacco, De Luca
  and Khatib, ICRA 2012): a joint that would leave its bounds is held at the bound and the others take up the task
  through the arm's redundancy; when no joint is left to do that, the task's velocity is scaled down (its direction
  kept) to the largest fraction the bounds allow, and the robot slows or stops rather than leave them;
- pseudo-inverses are damped near singularities (damped least squares with a damping that grows as the smallest
  singular value falls below ``config.DLS_EPSILON``).

Frames and units: world frame, metres, seconds, radians. Directions in results point from the obstacle towards the
point (the way to move away).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from depthguard import config
from depthguard.avoidance._limits import JointLimits, reachable
from depthguard.avoidance._ssm import brake_along_path
from depthguard.errors import InputError
from depthguard.validation import check_real, real_vector, short_repr
from depthguard.results import DistanceResult


def repulsive_speed(distance, rho: float, v_max: float, alpha: float) -> np.ndarray:
    """The end-effector's repulsive speed v(D) = v_max / (1 + exp((2 D / rho - 1) alpha)) for D < rho, 0 from rho on
    (and for D = inf: nothing within rho). distance: metres, any shape; returns m/s, the same shape."""
    d = np.asarray(distance, dtype=np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        v = v_max / (1.0 + np.exp((2.0 * d / rho - 1.0) * alpha))
    return np.where(d < rho, v, 0.0)


def risk(distance, rho: float, alpha: float) -> np.ndarray:
    """The risk of collision f(D) = 1 / (1 + exp((2 D / rho - 1) alpha)) in [0, 1) for D < rho, 0 from rho on."""
    return repulsive_speed(distance, rho, 1.0, alpha)


def damped_pinv(J: np.ndarray, epsilon: float = config.DLS_EPSILON,
                lambda_max: float = config.DLS_LAMBDA_MAX) -> np.ndarray:
    """Damped least-squares pseudo-inverse of J ((m, n)): V diag(s / (s^2 + lambda^2)) U^T, with lambda^2 =
    lambda_max^2 (1 - (s_min / epsilon)^2) when the smallest singular value s_min < epsilon, else 0 (the exact
    pseudo-inverse, zero singular values dropped). Returns (n, m)."""
    U, s, Vt = np.linalg.svd(J, full_matrices=False)
    s_min = s[-1] if len(s) else 0.0
    lam2 = lambda_max ** 2 * (1.0 - (s_min / epsilon) ** 2) if s_min < epsilon else 0.0
    denom = s ** 2 + lam2
    inv = np.divide(s, denom, out=np.zeros_like(s), where=denom > 1e-24)
    return (Vt.T * inv) @ U.T


@dataclass(frozen=True)
class AvoidanceParams:
    """The avoidance's parameters (design §9), defaults as the 2015 paper's experiments used them, except
    ``from_surface``.

    Attributes:
        rho: metres, the distance within which obstacles act (the monitor's rho).
        v_max: m/s, the end-effector's largest repulsive speed.
        alpha: the shape factor of the repulsive speed and of the risk function.
        posture_gain: 1/s, how fast the arm's redundancy pulls the joints back towards the task's posture when one is
            given (0: no pull; the papers have none).
        from_surface: measure each control point's distance from its link's surface rather than from the point: the
            distance minus the radius of the link's padded capsule (at least 0), in the repulsion and the risk
            alike. True by default, which departs from the papers: they measure from the point, and control points
            on a link's axis, a link's radius (0.07-0.1 m) from its surface, let the surface meet what it passes:
            with this command law the board and the elbow scenarios collided (-0.002 m, -0.008 m; two cameras,
            ``benchmarks/bench_avoidance_scenarios.py --papers``). False gives the papers' rule.
        tolerance: metres taken off every distance (at least 0 is left) before the repulsion and the risk: how much a
            reported distance may exceed the truth (the monitor's robot zone, ``DistanceMonitor(robot_zone=...)``),
            so that the avoidance acts on the nearest the obstacle may truly be. 0 in the papers.
        on_blind: what a blind answer (no camera could see: ``DistanceResult.is_blind``) makes the command:
            ``"stop"`` (default): brake to rest along the path (every joint in proportion, within its acceleration
            limit); ``"papers"``: the papers' rule, the risk f(0) of every point (0.993 with alpha 5), which scales
            the joint bounds to 0.7 % and lets the arm creep (measured: 2.8 cm/s). The papers' avoidance is a
            reactive controller, not a protective stop: even with ``"stop"`` it does not bring the approach speed to
            0 at contact when it sees (f(0) < 1), and nothing it commands is a safety function.
    """

    rho: float = config.DEFAULT_RHO
    v_max: float = config.AVOID_V_MAX
    alpha: float = config.AVOID_ALPHA
    posture_gain: float = 0.0
    from_surface: bool = True
    tolerance: float = 0.0
    on_blind: str = "stop"

    def __post_init__(self):
        check_real(self.rho, "rho", minimum=0.0, maximum=config.RHO_MAX, above_minimum=True, unit="metres",
                   field="rho")
        check_real(self.v_max, "v_max", minimum=0.0, maximum=100.0, unit="m/s", field="v_max")
        check_real(self.alpha, "alpha", minimum=0.0, maximum=1e3, above_minimum=True, field="alpha")
        check_real(self.posture_gain, "posture_gain", minimum=0.0, maximum=1e3, unit="1/s", field="posture_gain")
        check_real(self.tolerance, "tolerance", minimum=0.0, maximum=config.RHO_MAX, unit="metres", field="tolerance")
        if not isinstance(self.from_surface, bool):
            raise InputError("from_surface must be True or False", field="from_surface")
        if not isinstance(self.on_blind, str) or self.on_blind not in ("stop", "papers"):
            raise InputError(f"on_blind must be 'stop' or 'papers', got {self.on_blind!r}", field="on_blind")


@dataclass(frozen=True, eq=False)
class AvoidanceCommand:
    """One control step's command and why.

    Attributes:
        dq: (n,) joint velocities, rad/s: the command. Within [low, high]: the bounds' command (SNS within the
            joint limits and the control points' bounds) brought as near as the joints' accelerations allow.
        low, high: (n,) the joint velocities allowed this step: the joint limits and the control points' bounds, cut
            to the acceleration's reach from the previous command.
        velocity: (3,) m/s, world frame: the commanded end-effector velocity, task plus repulsion, before scaling.
        repulsive: (3,) m/s, world frame: the end-effector's repulsive velocity (zero when nothing is within rho).
        scale: in [0, 1], the fraction of ``velocity`` the joint limits and the control points' bounds allowed (1:
            the task as commanded; the acceleration's lag behind it is not counted).
        risk: (m,) the risk f(D) of each control point (0 beyond rho).
        saturated: (n,) bool, joints held at a bound.
    """

    dq: np.ndarray
    low: np.ndarray
    high: np.ndarray
    velocity: np.ndarray
    repulsive: np.ndarray
    scale: float
    risk: np.ndarray
    saturated: np.ndarray


class AvoidanceController:
    """The papers' avoidance for one robot (design §9): see the module's docstring.

    Args:
        robot: the :class:`~depthguard.robots.RobotModel` whose control points the distances are of (its
            ``end_effector`` is pushed, the others bound the joints).
        params: :class:`AvoidanceParams`.
        limits: :class:`JointLimits` (default: the URDF's, :meth:`JointLimits.from_robot`).
    """

    def __init__(self, robot, params: AvoidanceParams | None = None, limits: JointLimits | None = None):
        self.robot = robot
        self.params = AvoidanceParams() if params is None else params
        self.limits = JointLimits.from_robot(robot) if limits is None else limits
        if not isinstance(self.params, AvoidanceParams):
            raise InputError("params must be AvoidanceParams", field="params")
        if not isinstance(self.limits, JointLimits) or self.limits.n != robot.n_joints:
            raise InputError(f"limits must be JointLimits for {robot.n_joints} joints", field="limits")
        self.ee = robot.end_effector_index
        self._radius = robot.control_point_radii

    def command(self, result, q, task_velocity, dq_previous, dt: float, *, jacobians=None, posture=None,
                check: bool = True) -> AvoidanceCommand:
        """The joint velocities for the next control step.

        Args:
            result: the :class:`~depthguard.DistanceResult` of the robot's control points at ``q`` (its rows in
                ``robot.control_points`` order). Design §9: the end-effector is pushed along its row's direction
                (the papers': "hybrid") and the other points are bounded along theirs (the papers': "min", the
                direction to the nearest obstacle); ``PreparedSet.query(..., aggregate=)`` gives both from one set
                (the lab's loop: ``_avoidance_query``). A flagged result is taken as it is: its distances are already
                conservative (0 for a blind camera).
            q: (n,) joint positions, rad.
            task_velocity: (3,) m/s, world frame: the desired end-effector velocity (the task, with its feedback).
            dq_previous: (n,) rad/s, the previous step's command (the acceleration limits act from it).
            dt: seconds, the control step.
            jacobians: (m, 3, n) the control points' positional Jacobians at q (default: computed here).
            posture: (n,) rad, optional: the posture the redundancy pulls towards (``params.posture_gain``).
        """
        params, limits = self.params, self.limits
        n = limits.n
        if check:
            q = _vector(q, n, "q")
            dq_previous = _vector(dq_previous, n, "dq_previous")
            task_velocity = _vector(task_velocity, 3, "task_velocity")
            dt = check_real(dt, "dt", minimum=0.0, maximum=10.0, above_minimum=True, unit="seconds", field="dt")
            if posture is not None:
                posture = _vector(posture, n, "posture")
            m = len(self.robot.control_points)
            if len(result.distance) != m:
                raise InputError(f"the result holds {len(result.distance)} points, the robot has {m} control points",
                                 field="result")
        if params.on_blind == "stop" and isinstance(result, DistanceResult) and result.is_blind:
            # Nothing could be seen: brake to rest along the path, every joint in proportion.
            dq = brake_along_path(dq_previous, limits.acceleration, dt)
            zero = np.zeros(3)
            return AvoidanceCommand(dq=dq, low=np.minimum(dq, 0.0), high=np.maximum(dq, 0.0), velocity=zero,
                                    repulsive=zero, scale=0.0, risk=np.ones(len(result.distance)),
                                    saturated=np.zeros(n, dtype=bool))
        if jacobians is None:
            jacobians = self.robot.control_point_jacobians(q, check=False)
        distance = np.asarray(result.distance, dtype=np.float64)
        # From the links' surfaces, less the tolerance (a distance may exceed the truth by that much); at least 0.
        distance = np.maximum(distance - (self._radius if params.from_surface else 0.0) - params.tolerance, 0.0)
        direction = np.asarray(result.direction, dtype=np.float64)
        f = risk(distance, params.rho, params.alpha)
        # The end-effector: repulsion along the result's direction, added to the task.
        repulsive = repulsive_speed(distance[self.ee], params.rho, params.v_max, params.alpha) * direction[self.ee]
        velocity = task_velocity + repulsive
        # The other control points: bounds on the joints that would move them towards what is near.
        low_pv, high_pv = limits.position_velocity_box(q, dt)
        scale_lo = np.ones(n)
        scale_hi = np.ones(n)
        for i in range(len(distance)):
            if f[i] <= 0.0 or (i == self.ee and np.any(direction[i])):
                continue  # the end-effector is pushed away instead, when its direction is known
            columns = jacobians[i]
            moves = np.linalg.norm(columns, axis=0) > 1e-12  # joints after the point's link do not move it
            if np.any(direction[i]):
                s = columns.T @ (-direction[i] * f[i])
                towards_up = moves & (s > 0.0)
                towards_down = moves & (s < 0.0)
            else:  # inside an obstacle, or directions that cancel: every motion of the point may approach it
                towards_up = towards_down = moves
            scale_hi[towards_up] = np.minimum(scale_hi[towards_up], 1.0 - f[i])
            scale_lo[towards_down] = np.minimum(scale_lo[towards_down], 1.0 - f[i])
        # Both boxes hold 0 (the robot may stop).
        safe_low = np.maximum(low_pv, -limits.velocity * scale_lo)
        safe_high = np.minimum(high_pv, limits.velocity * scale_hi)
        J = jacobians[self.ee]
        z = None
        if posture is not None and params.posture_gain > 0.0:
            z = params.posture_gain * (posture - q)
        # The command the bounds allow, then as far towards it as the joints' accelerations allow from the previous
        # command. SNS inside the acceleration's reach instead (a box 2 a dt wide round the previous command, which
        # need not hold the task's direction) scales the task to 0 whenever the task's velocity turns faster than
        # the joints can follow (the hexagon's corners, the task's feedback after an avoidance): measured, 37 % of
        # the steps after the person had left, the end-effector held 5-8 cm off its path.
        goal, scale, saturated = sns(J, velocity, safe_low, safe_high, z)
        low, high = reachable(safe_low, safe_high, dq_previous, limits.acceleration * dt)
        dq = np.clip(goal, low, high)
        return AvoidanceCommand(dq=dq, low=low, high=high, velocity=velocity, repulsive=repulsive, scale=scale,
                                risk=f, saturated=saturated)


def sns(J: np.ndarray, velocity: np.ndarray, low: np.ndarray, high: np.ndarray, z: np.ndarray | None = None):
    """Saturation in the null space with task scaling (Flacco, De Luca, Khatib, ICRA 2012, Algorithm 1): joint
    velocities dq ((n,)) with low <= dq <= high that give the end-effector velocity ``velocity`` ((3,) through J
    (3, n)) where the bounds allow, else the largest fraction s of it, in the same direction. ``z`` ((n,), optional):
    a joint velocity to follow in the task's null space, at a lower priority. The bounds must hold 0 (low <= 0 <=
    high) for a feasible answer to exist; otherwise dq is clipped into them.

    Each round tries the whole task with the joints saturated so far held at their bounds (dq_N) and the others
    (W = 1) taking it up; a joint that leaves its bounds is saturated, the one that limits the task's scale first.
    When the joints left free would take up the task only near a singularity (their Jacobian's smallest singular
    value below ``config.DLS_EPSILON``, or below J's own), the best scaling seen is taken.

    Returns (dq, s, saturated (n,) bool)."""
    n = J.shape[1]
    W = np.ones(n)
    dq_n = np.zeros(n)
    z = np.zeros(n) if z is None else z
    smallest = np.linalg.svd(J, compute_uv=False)[-1]  # a robot already near a singularity may stay there
    best = (0.0, W.copy(), dq_n.copy())

    def solve(W, dq_n, s):
        JW = J * W
        P = damped_pinv(JW)
        a = P @ velocity
        b = dq_n - P @ (J @ dq_n) + (np.diag(W) - P @ JW) @ z
        return a, b, s * a + b

    for _ in range(n):
        a, b, dq = solve(W, dq_n, 1.0)
        over = (dq < low - 1e-12) | (dq > high + 1e-12)
        if not over.any():
            return dq, 1.0, W == 0.0
        scale, j = _task_scale(a, b, low, high, W == 1.0)
        if scale > best[0]:
            best = (scale, W.copy(), dq_n.copy())
        if j < 0 or not over[j]:
            candidates = np.flatnonzero(over & (W == 1.0))
            if not len(candidates):
                break
            j = int(candidates[0])
        W[j] = 0.0
        dq_n[j] = high[j] if dq[j] > high[j] else low[j]
        if np.linalg.svd(J * W, compute_uv=False)[-1] < min(config.DLS_EPSILON, smallest):
            break  # the joints left could take up the task only near a singularity: keep the best scaling
    scale, W, dq_n = best
    dq = solve(W, dq_n, scale)[2]
    return np.clip(dq, low, high), float(scale), W == 0.0


def _task_scale(a, b, low, high, free) -> tuple[float, int]:
    """The largest s in [0, 1] with low <= s a + b <= high on the free joints, and the joint whose bound sets it
    (-1 when none does)."""
    upper = math.inf
    lower = -math.inf
    worst = -1
    for i in np.flatnonzero(free):
        if abs(a[i]) < 1e-12:
            continue
        lo_i = (low[i] - b[i]) / a[i]
        hi_i = (high[i] - b[i]) / a[i]
        if a[i] < 0:
            lo_i, hi_i = hi_i, lo_i
        lower = max(lower, lo_i)
        if hi_i < upper:
            upper = hi_i
            worst = int(i)
    if upper < lower or upper < 0.0:
        return 0.0, worst
    return min(upper, 1.0), worst


def _vector(value, n: int, name: str) -> np.ndarray:
    """(n,) finite real numbers as float64, else InputError naming ``name``."""
    array = real_vector(value, n, name)
    if array.shape != (n,) or not np.all(np.isfinite(array)):
        raise InputError(f"{name} must be {n} finite numbers, got {short_repr(value)}", field=name)
    return array
