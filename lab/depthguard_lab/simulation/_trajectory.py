"""Robot trajectories of a simulated episode: joint-space waypoints, or the papers' vertical hexagon traced by the
end-effector (Cartesian, solved by damped least-squares inverse kinematics).

Both are sampled once, at the episode's frame times, when the workcell is built; :meth:`joints_at` interpolates
linearly between the samples (exact at the frame times).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import PchipInterpolator

from depthguard_lab import config as lab_config
from depthguard.errors import InputError, SceneError


class RobotTrajectory:
    """Joint configurations sampled at times ``times`` ((k,) float64, seconds, increasing, from 0 to the episode's
    duration) as ``joints`` ((k, n) float64, radians, in the robot's :attr:`~RobotModel.joint_names` order)."""

    kind = "joints"

    def __init__(self, times: np.ndarray, joints: np.ndarray):
        self.times = np.asarray(times, dtype=np.float64)
        self.joints = np.asarray(joints, dtype=np.float64)
        self.times.setflags(write=False)
        self.joints.setflags(write=False)

    def joints_at(self, t: float) -> np.ndarray:
        """(n,) float64 radians at time ``t`` (seconds, within [0, duration]); linear between samples."""
        times = self.times
        t = float(t)
        if not (times[0] - 1e-9 <= t <= times[-1] + 1e-9):
            raise InputError(f"time {t} s is outside the episode [0, {times[-1]}] s", field="t")
        k = int(np.searchsorted(times, t, side="right")) - 1
        k = min(max(k, 0), len(times) - 2)
        w = (t - times[k]) / (times[k + 1] - times[k])
        w = min(max(w, 0.0), 1.0)
        return (1.0 - w) * self.joints[k] + w * self.joints[k + 1]


class JointTrajectory(RobotTrajectory):
    """Joint-space waypoints (time, q) joined by a monotone cubic (PCHIP) per joint, so no joint overshoots its
    waypoints (nor, therefore, its limits). Before the first waypoint and after the last the robot holds still."""

    kind = "joints"

    def __init__(self, waypoint_times, waypoint_joints, sample_times):
        waypoint_times = np.asarray(waypoint_times, dtype=np.float64)
        waypoint_joints = np.asarray(waypoint_joints, dtype=np.float64)
        sample_times = np.asarray(sample_times, dtype=np.float64)
        if len(waypoint_times) == 1:
            joints = np.repeat(waypoint_joints, len(sample_times), axis=0)
        else:
            spline = PchipInterpolator(waypoint_times, waypoint_joints, axis=0)
            joints = spline(np.clip(sample_times, waypoint_times[0], waypoint_times[-1]))
        super().__init__(sample_times, joints)
        self.waypoint_times = waypoint_times
        self.waypoint_joints = waypoint_joints


@dataclass(frozen=True)
class Hexagon:
    """A regular hexagon in a plane: the end-effector path of the papers' experiment (2016 paper, section VIII).

    Attributes:
        center: (3,) float64, metres, world frame.
        radius: metres, centre to vertex (= side length).
        plane_normal: (3,) unit vector, world frame, normal of the hexagon's plane (horizontal for a vertical plane).
        start_angle: radians: vertex 0 lies at angle ``start_angle`` from the in-plane horizontal axis ``e1``
            towards the in-plane axis ``e2``; with a horizontal normal, e1 is horizontal and e2 points up.
        speed: m/s along the path.
        direction: +1 (counter-clockwise from e1 to e2) or -1.
    """

    center: np.ndarray
    radius: float
    plane_normal: np.ndarray
    start_angle: float = 0.0
    speed: float = 0.4
    direction: int = 1

    def axes(self) -> tuple[np.ndarray, np.ndarray]:
        """(e1, e2): in-plane unit axes. e1 = up x normal (normalised), e2 = normal x e1."""
        n = np.asarray(self.plane_normal, dtype=np.float64)
        e1 = np.cross([0.0, 0.0, 1.0], n)
        if np.linalg.norm(e1) < 1e-9:  # a horizontal plane: take the world x axis's projection
            e1 = np.cross(n, [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        return e1, np.cross(n, e1)

    def vertices(self) -> np.ndarray:
        """(6, 3) float64 vertices in path order, metres, world frame."""
        e1, e2 = self.axes()
        angles = self.start_angle + self.direction * np.arange(6) * np.pi / 3.0
        return (np.asarray(self.center, dtype=np.float64) + self.radius * np.outer(np.cos(angles), e1)
                + self.radius * np.outer(np.sin(angles), e2))

    @property
    def perimeter(self) -> float:
        """Metres: six sides of length ``radius``."""
        return 6.0 * self.radius

    def position_at(self, t) -> np.ndarray:
        """(3,) (or (k, 3) for (k,) times) end-effector target at time ``t`` seconds, starting at vertex 0 at t = 0
        and moving at ``speed`` along the sides."""
        scalar = np.ndim(t) == 0
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        s = np.mod(self.speed * t, self.perimeter) / self.radius  # in sides
        side = np.minimum(np.floor(s).astype(np.int64), 5)
        frac = (s - side)[:, None]
        v = self.vertices()
        p = (1.0 - frac) * v[side] + frac * v[(side + 1) % 6]
        return p[0] if scalar else p


class HexagonTrajectory(RobotTrajectory):
    """The end-effector control point traces a :class:`Hexagon`; the joints come from damped least-squares IK.

    IK (per sample time, continuing from the previous solution): dq = J^T (J J^T + lambda^2 I)^-1 e
    + (I - J^+ J) k (q_posture - q), J the end-effector's (3, n) positional Jacobian
    (``RobotModel.control_point_jacobians``), e the position error; then the same without the posture pull until
    |e| <= ``lab_config.SIM_IK_TOLERANCE``. Joint values are clipped to the limits. The largest remaining error is
    :attr:`tracking_error` (metres); a path the arm cannot follow within ``lab_config.SIM_IK_MAX_ERROR`` raises
    :class:`SceneError`.
    """

    kind = "hexagon"

    def __init__(self, robot, hexagon: Hexagon, posture: np.ndarray, sample_times, field: str = "robot.trajectory"):
        self.hexagon = hexagon
        self.posture = np.asarray(posture, dtype=np.float64)
        sample_times = np.asarray(sample_times, dtype=np.float64)
        targets = np.atleast_2d(hexagon.position_at(sample_times))
        ee = robot.end_effector_index
        # Approach the first vertex from the posture in small steps, so that the solution stays near the posture.
        q = self.posture.copy()
        start = robot.control_point_positions(q)[ee]
        for w in np.linspace(0.0, 1.0, 21)[1:]:
            q, _ = _solve(robot, ee, (1 - w) * start + w * targets[0], q, self.posture)
        joints = np.empty((len(sample_times), robot.n_joints))
        errors = np.empty(len(sample_times))
        for k, target in enumerate(targets):
            q, errors[k] = _solve(robot, ee, target, q, self.posture)
            joints[k] = q
            if errors[k] > lab_config.SIM_IK_MAX_ERROR:  # stop at the first frame the arm cannot follow
                raise SceneError(f"the end-effector cannot follow the hexagon: {errors[k] * 1000:.1f} mm from its "
                                 f"target {targets[k].round(3).tolist()} at t = {sample_times[k]:.3f} s (out of "
                                 "reach or at a joint limit; move or shrink the hexagon, or change the posture)",
                                 field=field)
        self.targets = targets
        self.errors = errors
        self.tracking_error = float(errors.max())
        super().__init__(sample_times, joints)


def _solve(robot, ee: int, target: np.ndarray, q: np.ndarray, posture: np.ndarray) -> tuple[np.ndarray, float]:
    """Damped least-squares IK of the end-effector control point towards ``target`` from ``q``; (q, |error|)."""
    lam2 = lab_config.SIM_IK_DAMPING**2
    lower, upper = robot.lower, robot.upper
    n = robot.n_joints
    error = math.inf
    for i in range(lab_config.SIM_IK_ITERATIONS):
        positions, jacobians = robot.control_point_kinematics(q, check=False)
        e = target - positions[ee]
        error = float(np.linalg.norm(e))
        if error <= lab_config.SIM_IK_TOLERANCE:
            break
        J = jacobians[ee]
        J_pinv = J.T @ np.linalg.inv(J @ J.T + lam2 * np.eye(3))
        dq = J_pinv @ e
        if i < 5:  # the posture pull only in the first iterations: it would otherwise hold the error above zero
            dq = dq + (np.eye(n) - J_pinv @ J) @ (lab_config.SIM_IK_POSTURE_GAIN * (posture - q))
        q = np.clip(q + dq, lower, upper)
    return q, error
