"""Speed and separation monitoring (design §9; ISO/TS 15066 with ISO 13855's human speeds and intrusion).

The protective separation distance, metres, between a control point of the robot and an obstacle (a person) is

    S_p = v_h (T_r + T_s) + v_r T_r + S_s + C + Z_d + Z_r

- v_h: the human's approach speed, m/s (ISO 13855: 2.0 m/s when the separation is within 0.5 m, else 1.6 m/s);
- T_r: the system's reaction time, seconds: the age of the depth data when the command is sent, plus computation,
  plus one control cycle. The caller knows the data's age, so it is an argument of every call;
- v_r: the robot's speed towards the obstacle, m/s (motion away counts as 0);
- T_s, S_s: the robot's stopping time (seconds) and distance (metres). The robot is taken to decelerate uniformly
  from v_r to rest in T_s, so S_s = v_r T_s / 2, plus a fixed ``stopping_distance_extra``;
- C: the intrusion distance, metres, from the sensors' detection capability d (:func:`intrusion_distance`);
- Z_d, Z_r: the sensing and the robot-position uncertainties, metres.

:class:`SpeedSeparationMonitor` scales the commanded joint velocities by one factor k in [0, 1] so that each control
point's speed towards its obstacle is at most what its reported distance allows (:func:`allowed_approach_speed`).
Scaling the whole joint velocity keeps the commanded path and only slows the robot along it; a point moving away
from its obstacle imposes nothing, so motion away is never slowed, and a robot whose motion approaches no obstacle
is not slowed at all.

**Looking ahead, when no direction can be trusted.** A depth monitor's "obstacle" is every possibly occupied point
within rho (people, unseen space), and one direction cannot summarise it: moving away from the nearest point can
approach another. What bounds the approach to all of them at once is the distance D' reported at the point looked
ahead to, P' = P + T v with T = T_r + T_s / 2 (:meth:`SpeedSeparationMonitor.lookahead_time`) and v the point's
velocity under the unscaled command. If

    D' >= S_p(0) + T |v|        (S_p(0): S_p at rest, v_h chosen by the point's own distance D <= every d_p)

then every possibly occupied point p that the point approaches (v . u_p > 0, u_p the unit vector from P to p, d_p
its distance) keeps d_p - T v . u_p >= S_p(0), which is S_p's condition d_p >= S_p(v . u_p); and so does every
scaled command k v, k in [0, 1]. Proof: |P' - p|^2 = (d_p - T v.u_p)^2 + T^2 (|v|^2 - (v.u_p)^2), so d_p - T v.u_p
>= |P' - p| - T |v| >= D' - T |v| when d_p - T v.u_p >= 0; when it is negative, |P' - p|^2 < T^2 |v|^2 - d_p^2,
so |P' - p| < T |v| <= D', impossible. For k < 1, |P + k T v - p| >= D' - (1 - k) T |v| >= S_p(0) + k T |v| and the
same argument holds with k v. Such a point imposes nothing: a point moving straight away from everything within
reach (D' = D + T |v|) is not slowed while D >= S_p(0); one moving sideways or towards is slowed as if it approached
at its whole speed. The bound needs nothing but distances, so it holds for whatever the monitor counts as occupied.
Robot points are taken as spheres: pass distances from the spheres' surfaces (the distance minus the radius) for
both D and D'.

Frames and units: world frame, metres, seconds, radians. Directions point from the obstacle towards the point (the
way to move away), as in :class:`~depthguard.DistanceResult`.
"""

from __future__ import annotations

import math

from dataclasses import dataclass, fields

import numpy as np

from depthguard.config import (  # the SSM defaults (ISO/TS 15066, ISO 13855)
    SSM_DETECTION_CAPABILITY,
    SSM_HUMAN_SPEED,
    SSM_HUMAN_SPEED_NEAR,
    SSM_INTRUSION_FINGER,
    SSM_INTRUSION_HAND,
    SSM_INTRUSION_LIMIT,
    SSM_INTRUSION_REACH,
    SSM_INTRUSION_SLOPE,
    SSM_MAXIMA,
    SSM_NEAR_SEPARATION,
    SSM_ROBOT_UNCERTAINTY,
    SSM_ROUNDING,
    SSM_SENSING_UNCERTAINTY,
    SSM_STOPPING_DISTANCE_EXTRA,
    SSM_STOPPING_TIME,
    SSM_UNIT_TOLERANCE,
)
from depthguard.errors import InputError
from depthguard.validation import NOT_A_NUMBER, check_real
from depthguard.results import DetectableResult, DistanceResult

_UNITS = {"human_speed": "m/s", "human_speed_near": "m/s", "stopping_time": "seconds"}


def intrusion_distance(detection_capability: float) -> float:
    """ISO 13855's intrusion distance C, metres, for sensors of detection capability d (metres, the smallest object
    they are sure to detect): 0 for d <= 14 mm; 8 (d - 14 mm) for 14 mm < d <= 40 mm (0.208 m at 40 mm); 0.85 m (an
    arm's reach) for 40 mm < d <= 70 mm. The standard gives no C for a coarser d (such a sensor detects only the
    trunk, and needs another formula): d > 70 mm (``SSM_INTRUSION_LIMIT``) is refused with :class:`InputError`
    naming ``detection_capability``."""
    if isinstance(detection_capability, (int, float, np.floating, np.integer)) and \
            not isinstance(detection_capability, bool) and detection_capability > SSM_INTRUSION_LIMIT:
        raise InputError(f"detection_capability {float(detection_capability):g} m is coarser than ISO 13855's 70 mm: "
                         "no intrusion distance C is defined for it (the sensors would detect only the trunk)",
                         field="detection_capability")
    d = check_real(detection_capability, "detection_capability", minimum=0.0, maximum=SSM_INTRUSION_LIMIT,
                   unit="metres", field="detection_capability")
    if d <= SSM_INTRUSION_FINGER:
        return 0.0
    if d <= SSM_INTRUSION_HAND:
        return SSM_INTRUSION_SLOPE * (d - SSM_INTRUSION_FINGER)
    return SSM_INTRUSION_REACH


@dataclass(frozen=True)
class SSMParams:
    """The parameters of speed and separation monitoring (see the module's docstring for the formula).

    Attributes:
        human_speed: v_h, m/s, when the separation is above ``near_separation``.
        human_speed_near: v_h, m/s, when the separation is at most ``near_separation``; at least ``human_speed``.
        near_separation: metres.
        stopping_time: T_s, seconds, > 0.
        stopping_distance_extra: metres, added to the stopping distance v_r T_s / 2.
        detection_capability: d, metres (gives the intrusion distance C, :attr:`intrusion`).
        sensing_uncertainty: Z_d, metres.
        robot_uncertainty: Z_r, metres.

    Every field is a finite number >= 0 and at most ``SSM_MAXIMA[field]``; :class:`~depthguard.errors.InputError`
    naming the field otherwise.
    """

    human_speed: float = SSM_HUMAN_SPEED
    human_speed_near: float = SSM_HUMAN_SPEED_NEAR
    near_separation: float = SSM_NEAR_SEPARATION
    stopping_time: float = SSM_STOPPING_TIME
    stopping_distance_extra: float = SSM_STOPPING_DISTANCE_EXTRA
    detection_capability: float = SSM_DETECTION_CAPABILITY
    sensing_uncertainty: float = SSM_SENSING_UNCERTAINTY
    robot_uncertainty: float = SSM_ROBOT_UNCERTAINTY

    def __post_init__(self):
        for f in fields(self):
            value = check_real(getattr(self, f.name), f.name, minimum=0.0, maximum=SSM_MAXIMA[f.name],
                               above_minimum=f.name == "stopping_time", unit=_UNITS.get(f.name, "metres"),
                               field=f.name)
            object.__setattr__(self, f.name, value)
        if self.human_speed_near < self.human_speed:
            raise InputError(f"human_speed_near ({self.human_speed_near:g} m/s) must be at least human_speed "
                             f"({self.human_speed:g} m/s)", field="human_speed_near")

    @property
    def intrusion(self) -> float:
        """C, metres: :func:`intrusion_distance` of ``detection_capability``."""
        return intrusion_distance(self.detection_capability)


# ------------------------------------------------------------------------------------------------- the formula


def _fixed_part(params: SSMParams, reaction_time: float, separation, stopping_time=None) -> np.ndarray:
    """S_p at v_r = 0: v_h (T_r + T_s) + extra + C + Z_d + Z_r, with v_h chosen by ``separation`` (None: near) and
    T_s = ``stopping_time`` (None: ``params.stopping_time``)."""
    if separation is None:
        v_h = params.human_speed_near
    else:
        v_h = np.where(separation <= params.near_separation, params.human_speed_near, params.human_speed)
    t_s = params.stopping_time if stopping_time is None else stopping_time
    return (v_h * (reaction_time + t_s) + params.stopping_distance_extra + params.intrusion
            + params.sensing_uncertainty + params.robot_uncertainty)


def _speed_slope(params: SSMParams, reaction_time: float, stopping_time=None) -> float:
    """dS_p / dv_r, seconds: T_r (travel while reacting) + T_s / 2 (uniform deceleration)."""
    return reaction_time + 0.5 * (params.stopping_time if stopping_time is None else stopping_time)


def _protective(params, approach_speed, reaction_time, separation, stopping_time=None) -> np.ndarray:
    return _fixed_part(params, reaction_time, separation, stopping_time) + \
        np.maximum(approach_speed, 0.0) * _speed_slope(params, reaction_time, stopping_time)


def _allowed(params, distance, reaction_time, stopping_time=None) -> np.ndarray:
    finite = np.isfinite(distance)
    d = np.where(finite, distance, 0.0)
    room = d - _fixed_part(params, reaction_time, distance, stopping_time) - SSM_ROUNDING * np.maximum(d, 1.0)
    return np.where(finite, np.maximum(room, 0.0) / _speed_slope(params, reaction_time, stopping_time), np.inf)


# ------------------------------------------------------------------------------------------------- validation


def _params(params) -> SSMParams:
    if not isinstance(params, SSMParams):
        raise InputError(f"params must be SSMParams, got {type(params).__name__}", field="params")
    return params


def _reaction_time(reaction_time) -> float:
    return check_real(reaction_time, "reaction_time", minimum=0.0, unit="seconds", field="reaction_time")


def _array(value, name: str, *, shape=None, allow_inf: bool = False, nonnegative: bool = False) -> np.ndarray:
    """``value`` as a float64 array after checking its shape (a tuple, None for any dimension) and values."""
    try:
        array = np.asarray(value, dtype=np.float64)
    except NOT_A_NUMBER:
        raise InputError(f"{name} must be an array of real numbers", field=name) from None
    if shape is not None and (array.ndim != len(shape) or
                              any(want is not None and got != want for got, want in zip(array.shape, shape))):
        wanted = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise InputError(f"{name} must have shape {wanted}, got {array.shape}", field=name)
    bad = np.isnan(array) | (np.isinf(array) if not allow_inf else np.isneginf(array))
    if bad.any():
        raise InputError(f"{name} must be {'NaN-free and not -inf' if allow_inf else 'finite'}", field=name)
    if nonnegative and (array < 0).any():
        raise InputError(f"{name} must be >= 0 (metres)", field=name)
    return array


def _result(value):
    return float(value) if np.ndim(value) == 0 else value


# ------------------------------------------------------------------------------------------------- public API


def protective_separation_distance(params: SSMParams, approach_speed, reaction_time: float, separation=None):
    """S_p, metres (see the module's docstring).

    Args:
        params: :class:`SSMParams`.
        approach_speed: v_r, m/s, the robot's speed towards the obstacle; a number or an array. Negative (moving
            away) counts as 0.
        reaction_time: T_r, seconds, >= 0.
        separation: the current separation, metres (>= 0, inf allowed), a number or an array broadcast against
            ``approach_speed``: it picks v_h (``human_speed_near`` when at most ``near_separation``, else
            ``human_speed``). None: ``human_speed_near`` (conservative).

    Returns:
        a float when every argument is a number, else an array of the broadcast shape, metres.
    """
    params = _params(params)
    reaction_time = _reaction_time(reaction_time)
    speed = _array(approach_speed, "approach_speed")
    if separation is not None:
        separation = _array(separation, "separation", allow_inf=True, nonnegative=True)
        try:
            np.broadcast_shapes(speed.shape, separation.shape)
        except ValueError:
            raise InputError(f"separation's shape {separation.shape} does not broadcast against approach_speed's "
                             f"{speed.shape}", field="separation") from None
    return _result(_protective(params, speed, reaction_time, separation))


def allowed_approach_speed(params: SSMParams, distance, reaction_time: float):
    """The largest approach speed v_r >= 0, m/s, with S_p(v_r) <= distance, v_h chosen with separation = distance:

        v_r = (distance - v_h (T_r + T_s) - extra - C - Z_d - Z_r) / (T_r + T_s / 2)

    0 when even v_r = 0 does not fit; inf where the distance is inf (nothing within rho). The distance is lowered by
    ``SSM_ROUNDING`` max(1 m, distance) first, so that S_p at the answer never exceeds the distance after rounding.

    Args:
        params: :class:`SSMParams`.
        distance: metres, >= 0 (inf allowed): a number or an (m,) array (any shape works).
        reaction_time: T_r, seconds, >= 0.

    Returns:
        m/s, a float for a number, else an array of ``distance``'s shape.
    """
    params = _params(params)
    reaction_time = _reaction_time(reaction_time)
    distance = _array(distance, "distance", allow_inf=True, nonnegative=True)
    return _result(_allowed(params, distance, reaction_time))


@dataclass(frozen=True, eq=False)
class SSMVerdict:
    """One control step's speed and separation verdict for m control points. The command to send is ``factor * dq``.

    Attributes:
        factor: k in [0, 1], the fraction of the commanded joint velocities allowed.
        approach_speed: (m,) float64, m/s, each point's speed towards its obstacle under the unscaled command
            (negative: moving away; the whole speed where the direction is unknown).
        allowed_speed: (m,) float64, m/s, :func:`allowed_approach_speed` of each point's distance (inf: nothing
            within rho).
        protective_distance: (m,) float64, metres, S_p at each point's scaled approach speed ``factor *
            approach_speed`` (separation = its distance). At most the distance wherever that speed is > 0 and the
            point is not ``certified``.
        limiting: index of the point that set ``factor``, or -1 when the factor is 1.
        certified: (m,) bool, the points that the distance looked ahead to showed approach nothing faster than its
            distance allows (see the module's docstring); they impose nothing. All False without ``ahead``.
        stopping_time: T_s, seconds, as this verdict took it (:meth:`SpeedSeparationMonitor.stopping_time`).
    """

    factor: float
    approach_speed: np.ndarray
    allowed_speed: np.ndarray
    protective_distance: np.ndarray
    limiting: int
    certified: np.ndarray
    stopping_time: float = 0.0


class SpeedSeparationMonitor:
    """Speed and separation monitoring of a robot's control points (see the module's docstring).

    Args:
        params: :class:`SSMParams` (default: ``SSMParams()``).
        rho: metres, the rho of the distances' monitor (required): a distance of inf says only that nothing is
            within rho, so it counts as rho, with an unknown direction. Choose rho above the protective separation
            distance at the robot's speed, or the robot is slowed whenever it moves. ``inf`` only for distances
            known at any range (such as exact ones).
        braking: None, or (n,) float64, > 0: the deceleration every joint is sure to reach when stopping, rad/s^2
            (m/s^2 for a prismatic joint), as the robot model declares it (:class:`~depthguard.avoidance.JointLimits`
            ``acceleration``). Then T_s is not ``params.stopping_time`` but the time the commanded joint velocities
            take to stop with every joint braking in proportion, the slowest at its limit: T_s = max_i |dq_i| /
            braking_i (:meth:`stopping_time`); the robot keeps its path while it brakes, so each point decelerates
            uniformly and S_s = v_r T_s / 2 holds (a controller that brakes so: ``brake_along_path``) while the
            Jacobians hold still.
        reaches: None, or (n,) float64 metres per radian (``RobotModel.joint_reaches``): how fast any point of the
            robot moves per unit of each joint's velocity, at any configuration. With it, S_s also counts the change
            of the Jacobians along the braking path: a point travels at most V T_s / 2 with V = sum_i reaches_i
            |dq_i|, so (V - |v|) T_s / 2 is added (from full speed the iiwa's points travel up to 1.5 times
            |v| T_s / 2).
    """

    def __init__(self, params: SSMParams | None = None, *, rho: float, braking=None, reaches=None):
        self.params = _params(SSMParams() if params is None else params)
        self.rho = check_real(rho, "rho", minimum=0.0, above_minimum=True, unit="metres", field="rho") \
            if not (isinstance(rho, (int, float)) and rho == math.inf) else math.inf
        self.braking = None
        if braking is not None:
            braking = _array(braking, "braking", shape=(None,))
            if not np.all(braking > 0.0):
                raise InputError("braking must be decelerations > 0 (rad/s^2 or m/s^2), one per joint",
                                 field="braking")
            self.braking = braking
        self.reaches = None
        if reaches is not None:
            reaches = _array(reaches, "reaches", shape=(None,), nonnegative=True)
            if self.braking is not None and reaches.shape != self.braking.shape:
                raise InputError(f"reaches has {reaches.shape[0]} joints, braking {self.braking.shape[0]}",
                                 field="reaches")
            self.reaches = reaches

    def stopping_time(self, dq) -> float:
        """T_s, seconds, for the commanded joint velocities ``dq`` (n,): max_i |dq_i| / braking_i with ``braking``,
        else ``params.stopping_time``."""
        if self.braking is None:
            return self.params.stopping_time
        dq = np.asarray(dq, dtype=np.float64)
        if dq.shape != self.braking.shape:
            raise InputError(f"dq has {dq.shape} joints, braking {self.braking.shape}", field="dq")
        return float(np.max(np.abs(dq) / self.braking)) if dq.size else 0.0

    def lookahead_time(self, reaction_time: float, dq=None) -> float:
        """T = T_r + T_s / 2, seconds: look ahead to P + T v (v: the point's velocity, m/s) for ``ahead`` of
        :meth:`speed_factor` (see the module's docstring); ``dq``: the command, needed with ``braking``."""
        if self.braking is not None and dq is None:
            raise InputError("with braking, T_s depends on the command: pass dq", field="dq")
        t_s = None if self.braking is None else self.stopping_time(dq)
        return _speed_slope(self.params, _reaction_time(reaction_time), t_s)

    def speed_factor(self, result_or_distances, directions, jacobians, dq, reaction_time: float, *,
                     ahead=None, check: bool = True) -> SSMVerdict:
        """The factor k in [0, 1] for the commanded joint velocities ``dq``: the largest k with
        k v_i <= allowed_approach_speed(D_i) for every control point i, where v_i = -direction_i . (J_i dq) is the
        point's speed towards its obstacle.

        - A point moving away (v_i <= 0) imposes nothing: motion away is never slowed.
        - A point with distance inf (nothing within rho) counts as at rho with an unknown direction (its whole
          speed approaching); with ``rho = inf`` it imposes nothing.
        - A point with a finite distance and the zero direction (inside an obstacle, unseen space, or directions that
          cancel out) has an unknown way to its obstacle: its whole speed |J_i dq| counts as approaching.

        Args:
            result_or_distances: a :class:`~depthguard.DistanceResult` of the m control points (its ``distance``
                and ``direction`` are used; pass ``directions=None``), or (m,) float64 distances, metres, >= 0,
                inf when nothing is within rho.
            directions: (m, 3) float64, world frame, unit vectors from the obstacle towards the point, or the zero
                vector (unknown); None with a DistanceResult.
            jacobians: (m, 3, n) float64, the control points' positional Jacobians, world frame, metres per rad
                (per metre for prismatic joints).
            dq: (n,) float64, the commanded joint velocities, rad/s (m/s for prismatic joints).
            reaction_time: T_r, seconds, >= 0: the data's age when the command is sent + computation + one control
                cycle.
            ahead: None, or (m,) float64 metres (>= 0, inf: nothing within rho, counted as rho): the distances
                reported at the points looked ahead to, P_i + T J_i dq with T = :meth:`lookahead_time`, from the
                same possibly occupied space. A point with ahead_i >= S_p at rest + T |J_i dq| approaches nothing
                too fast, whatever its direction, and imposes nothing (``certified``). Give 0 where it was not
                asked.
            check: False skips the validation (the caller guarantees float64 arrays of those shapes and values).

        Returns:
            :class:`SSMVerdict`; send ``verdict.factor * dq``.
        """
        params = self.params
        if isinstance(result_or_distances, DistanceResult):
            if directions is not None:
                raise InputError("directions must be None when a DistanceResult is given (its direction is used)",
                                 field="directions")
            distances, directions = result_or_distances.distance, result_or_distances.direction
        elif isinstance(result_or_distances, DetectableResult):
            check_capability(params, result_or_distances)
            distances = result_or_distances.distance
            if directions is None:
                directions = np.zeros((len(distances), 3))
        else:
            distances = result_or_distances
        if check:
            reaction_time = _reaction_time(reaction_time)
            distances = _array(distances, "distances", shape=(None,), allow_inf=True, nonnegative=True)
            m = len(distances)
            directions = _array(directions, "directions", shape=(m, 3))
            norms = np.linalg.norm(directions, axis=1)
            if np.any((norms != 0.0) & (np.abs(norms - 1.0) > SSM_UNIT_TOLERANCE)):
                raise InputError("directions must be unit vectors or the zero vector (unknown)", field="directions")
            jacobians = _array(jacobians, "jacobians", shape=(m, 3, None))
            dq = _array(dq, "dq", shape=(jacobians.shape[2],))
            if ahead is not None:
                ahead = _array(ahead, "ahead", shape=(m,), allow_inf=True, nonnegative=True)
        beyond = ~np.isfinite(distances)
        if beyond.any() and math.isfinite(self.rho):  # nothing within rho: at least rho, from anywhere
            distances = np.where(beyond, self.rho, distances)
            directions = np.where(beyond[:, None], 0.0, directions)
        velocity = np.einsum("mkn,n->mk", jacobians, dq)  # (m, 3) m/s, world frame
        approach = -np.einsum("mk,mk->m", directions, velocity)
        finite = np.isfinite(distances)
        unknown = finite & ~directions.any(axis=1)
        approach = np.where(unknown, np.linalg.norm(velocity, axis=1), approach)

        if self.braking is not None and dq.shape != self.braking.shape:
            raise InputError(f"dq has {dq.shape[0]} joints, braking {self.braking.shape[0]}", field="dq")
        t_s = self.stopping_time(dq)  # for the unscaled command: k dq stops within k T_s <= T_s
        allowed = _allowed(params, distances, reaction_time, t_s)
        speed = np.linalg.norm(velocity, axis=1)
        # While the robot brakes along its path the Jacobians change: a point travels at most V T_s / 2, V the
        # bound of every point's speed (reaches), rather than |v| T_s / 2; the difference is added to S_s.
        curve = np.zeros(len(distances)) if self.reaches is None else \
            np.maximum(float(self.reaches @ np.abs(dq)) - speed, 0.0) * 0.5 * t_s
        certified = np.zeros(len(distances), dtype=bool)
        if ahead is not None:
            ahead = np.where(np.isfinite(ahead), ahead, self.rho)  # nothing within rho: at least rho
            with np.errstate(invalid="ignore"):  # inf - inf where rho is inf: certified below by the comparison
                room = ahead - SSM_ROUNDING * np.maximum(ahead, 1.0)
            certified = np.where(np.isinf(ahead), True, room >= _fixed_part(params, reaction_time, distances, t_s)
                                 + _speed_slope(params, reaction_time, t_s) * speed + curve)
        approaching = finite & (approach > 0.0) & ~certified
        with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
            # k approach (T_r + T_s / 2) + k curve <= room, i.e. k <= allowed slope / (slope approach + curve)
            slope = _speed_slope(params, reaction_time, t_s)
            ratio = np.where(approaching, allowed * slope / np.where(approaching, approach * slope + curve, 1.0),
                             np.inf)
        limiting = int(np.argmin(ratio)) if len(ratio) and ratio.min() < 1.0 else -1
        factor = float(ratio[limiting]) if limiting >= 0 else 1.0
        protective = _protective(params, factor * approach, reaction_time, distances, t_s) + factor * curve
        return SSMVerdict(factor=factor, approach_speed=approach, allowed_speed=allowed,
                          protective_distance=protective, limiting=limiting, certified=certified,
                          stopping_time=t_s)

    def full_speed_distance(self, jacobians, joint_speed, reaction_time: float, radii=None) -> np.ndarray:
        """(m,) metres: a distance from each sphere's surface at or beyond which that point does not slow
        :meth:`speed_factor_within` at all (its k_i >= 1): S_p with the near human speed at the point's bound speed,
        plus the braking path's bend, and a hair for rounding. Asking distances only up to it (and taking "at least
        it" as it) changes no factor: the space beyond need not be looked at. Arguments as there (unchecked)."""
        radii = np.zeros(len(jacobians)) if radii is None else radii
        speed, whole, t_s = self._bound_speeds(jacobians, joint_speed, radii)
        need = speed * reaction_time + whole * 0.5 * t_s
        fixed = _fixed_part(self.params, reaction_time, None, t_s)  # v_h near: the larger
        return (fixed + need) * (1.0 + 1e-9) + 1e-9

    def _bound_speeds(self, jacobians, joint_speed, radii):
        """(s (m,), V (m,), T_s): each sphere's bound speed, the bound of any point of the robot, the stopping time
        (see :meth:`speed_factor_within`)."""
        columns = np.linalg.norm(jacobians, axis=1)  # (m, n) each joint's speed of each centre per rad/s
        speed = (columns + radii[:, None]) @ joint_speed
        whole = None if self.reaches is None else float(self.reaches @ joint_speed)
        if whole is not None:
            speed = np.minimum(speed, whole)
        whole = speed if whole is None else np.full(len(speed), whole)
        return speed, whole, self.stopping_time(joint_speed)

    def speed_factor_within(self, distances, jacobians, joint_speed, reaction_time: float, *, radii=None,
                            check: bool = True) -> SSMVerdict:
        """The factor k in [0, 1] that keeps SSM's condition for EVERY command k dq with |dq_i| <= joint_speed_i,
        whatever its direction: for a controller that scales a trajectory it does not tell (ros2_control's speed
        scaling, which runs the trajectory at k times its speed), known only to stay within ``joint_speed``.

        Each control point i is a sphere of radius ``radii[i]`` moving with its link; ``distances`` count from the
        spheres' surfaces. Every point of sphere i moves at most s_i = min(V, sum_j joint_speed_j (|J_i[:, j]| +
        radii_i)) (translation plus rotation; V = ``reaches`` . joint_speed, the bound of any point of the robot,
        without ``reaches`` the sum alone), towards anything (no direction is trusted), and the robot stops within
        T_s = max_j joint_speed_j / braking_j (``params.stopping_time`` without ``braking``). :meth:`speed_factor`
        with an unknown direction needs k (|v| T_r + V T_s / 2) <= room(D) for the command's own |v| <= s_i, V and
        T_s <= these bounds, and room(D) = max(D - S_p at rest - rounding, 0) falls as T_s grows: so k_i = room /
        (s_i T_r + V T_s / 2) holds for every such command (``tests/test_speed_scaling.py`` checks it against
        :meth:`speed_factor` for random commands in the box). Returns :class:`SSMVerdict` with
        ``approach_speed`` = s_i.

        Args:
            distances: (m,) float64 metres from the spheres' surfaces, >= 0, inf when nothing is within rho
                (counted as rho).
            jacobians: (m, 3, n) float64, the spheres' centres' positional Jacobians, world frame.
            joint_speed: (n,) float64 > 0, rad/s (m/s prismatic): the most each joint of the scaled trajectory moves
                at factor 1.
            reaction_time: T_r, seconds, >= 0.
            radii: (m,) float64 metres >= 0 (default 0: points).
            check: False skips the validation.
        """
        params = self.params
        if check:
            reaction_time = _reaction_time(reaction_time)
            distances = _array(distances, "distances", shape=(None,), allow_inf=True, nonnegative=True)
            m = len(distances)
            jacobians = _array(jacobians, "jacobians", shape=(m, 3, None))
            joint_speed = _array(joint_speed, "joint_speed", shape=(jacobians.shape[2],))
            if not np.all(joint_speed > 0.0):
                raise InputError("joint_speed must be > 0 for every joint (rad/s or m/s)", field="joint_speed")
            radii = np.zeros(m) if radii is None else _array(radii, "radii", shape=(m,), nonnegative=True)
        elif radii is None:
            radii = np.zeros(len(distances))
        if self.braking is not None and joint_speed.shape != self.braking.shape:
            raise InputError(f"joint_speed has {joint_speed.shape[0]} joints, braking {self.braking.shape[0]}",
                             field="joint_speed")
        distances = np.where(np.isfinite(distances), distances, self.rho)
        speed, whole, t_s = self._bound_speeds(jacobians, joint_speed, radii)
        allowed = _allowed(params, distances, reaction_time, t_s)
        slope = _speed_slope(params, reaction_time, t_s)
        room = np.where(np.isfinite(allowed), allowed * slope, np.inf)
        with np.errstate(divide="ignore", invalid="ignore"):
            need = speed * reaction_time + whole * 0.5 * t_s
            ratio = np.where(np.isfinite(room), np.where(need > 0.0, room / np.where(need > 0.0, need, 1.0),
                                                         np.inf), np.inf)
        limiting = int(np.argmin(ratio)) if len(ratio) and ratio.min() < 1.0 else -1
        factor = float(max(ratio[limiting], 0.0)) if limiting >= 0 else 1.0
        protective = _protective(params, factor * speed, reaction_time, distances, t_s) + \
            factor * (whole - speed) * 0.5 * t_s
        return SSMVerdict(factor=factor, approach_speed=speed, allowed_speed=allowed,
                          protective_distance=protective, limiting=limiting,
                          certified=np.zeros(len(speed), dtype=bool), stopping_time=t_s)


def check_capability(params: SSMParams, result: DetectableResult) -> None:
    """Refuse detectable distances whose effective detection capability (the monitor's d plus the band its
    concessions can hide, :attr:`DetectableResult.effective_capability`) is not SSM's ``detection_capability``: C
    is taken for SSM's d, and one smaller than the monitor's would not cover what the monitor leaves out (design
    section 9: one d). Raises :class:`InputError` naming ``detection_capability``."""
    if abs(result.effective_capability - params.detection_capability) > 1e-9:
        raise InputError(f"SSM's detection_capability ({params.detection_capability:g} m) is not the detectable "
                         f"distances' ({result.capability:g} m + a {result.hidden_band:g} m band the monitor's "
                         f"concessions can hide = {result.effective_capability:g} m): C must be taken for that one "
                         "(SSMParams(detection_capability=result.effective_capability))",
                         field="detection_capability")


def brake_along_path(dq, braking, dt: float):
    """(n,) the joint velocities one control period ``dt`` (seconds) later when the robot brakes from ``dq`` (n,)
    keeping its path: every joint slows in proportion, the one that needs longest at its deceleration limit
    (``braking`` (n,), > 0), so that the robot stops after T_s = max_i |dq_i| / braking_i with every point
    decelerating uniformly (:meth:`SpeedSeparationMonitor.stopping_time`)."""
    dq = np.asarray(dq, dtype=np.float64)
    t_s = float(np.max(np.abs(dq) / braking)) if dq.size else 0.0
    if t_s <= dt:
        return np.zeros_like(dq)
    return dq * (1.0 - dt / t_s)
