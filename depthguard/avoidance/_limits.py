"""A robot's joint limits as the avoidance loop uses them: position, velocity and acceleration."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from depthguard import config
from depthguard.errors import InputError
from depthguard.validation import real_vector


@dataclass(frozen=True, eq=False)
class JointLimits:
    """Joint limits, each (n,) float64 in the robot's ``joint_names`` order: ``lower``, ``upper`` (rad, or m for
    prismatic joints; -inf/+inf for continuous joints), ``velocity`` (rad/s or m/s, > 0) and ``acceleration``
    (rad/s^2 or m/s^2, > 0).

    :meth:`from_robot` takes position and velocity limits from the URDF. URDF has no acceleration limits: they are a
    parameter (``config.JOINT_ACCELERATION`` by default).
    """

    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray

    def __post_init__(self):
        names = ("lower", "upper", "velocity", "acceleration")
        arrays = [real_vector(getattr(self, name), np.size(self.lower), name) for name in names]
        n = arrays[0].shape
        for name, array in zip(names, arrays):
            if array.ndim != 1 or array.shape != n:
                raise InputError(f"joint limits: {name} must be a vector of {n[0] if n else '?'} values, got shape "
                                 f"{array.shape}", field=name)
            if np.isnan(array).any():
                raise InputError(f"joint limits: {name} holds NaN", field=name)
            array.setflags(write=False)
            object.__setattr__(self, name, array)
        lower, upper, velocity, acceleration = arrays
        if not np.all(lower <= upper):
            raise InputError("joint limits: lower must not exceed upper", field="lower")
        for name, array in (("velocity", velocity), ("acceleration", acceleration)):
            if not np.all((array > 0) & np.isfinite(array)):
                raise InputError(f"joint limits: every {name} limit must be a finite number > 0", field=name)

    @classmethod
    def from_robot(cls, robot, velocity=None, acceleration=None) -> "JointLimits":
        """Limits of ``robot`` (:class:`depthguard.robots.RobotModel`): positions and velocities from its URDF, or
        ``velocity`` ((n,) or a number) instead; ``acceleration`` ((n,) or a number, default
        ``config.JOINT_ACCELERATION``)."""
        n = robot.n_joints
        velocity = robot.velocity_limits if velocity is None else _per_joint(velocity, n, "velocity")
        acceleration = _per_joint(config.JOINT_ACCELERATION if acceleration is None else acceleration, n,
                                  "acceleration")
        return cls(lower=robot.lower, upper=robot.upper, velocity=velocity, acceleration=acceleration)

    @property
    def n(self) -> int:
        return len(self.lower)

    def position_velocity_box(self, q, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """The joint velocities that the position and velocity limits allow for the next control step of ``dt``
        seconds from positions ``q`` ((n,)): (low, high), (n,) each, low <= 0 <= high.

        - velocity: |dq| <= velocity;
        - position: the step and a stop at full deceleration after it, in steps of ``dt``, stay within the limit:
          dq dt + dq^2 / (2 acceleration) <= upper - q, i.e. dq <= sqrt((a dt)^2 + 2 a (upper - q)) - a dt (and the
          same towards lower). Braking in steps of dt from dq covers at most dq^2 / (2 a) after the step; the
          continuous bound sqrt(2 a (upper - q)) alone let a joint pass its limit by up to dq dt / 2 (measured:
          1e-4 rad at the iiwa's fourth joint).
        """
        q = np.asarray(q, dtype=np.float64)
        a = self.acceleration
        room_up = np.maximum(self.upper - q, 0.0)
        room_down = np.maximum(q - self.lower, 0.0)
        step = a * dt
        high = np.minimum(self.velocity, np.sqrt(step * step + 2.0 * a * room_up) - step)
        low = -np.minimum(self.velocity, np.sqrt(step * step + 2.0 * a * room_down) - step)
        return low, high


def _per_joint(value, n: int, name: str) -> np.ndarray:
    """A number (the same for every joint) or n numbers, as (n,) float64 (the shape is checked by JointLimits)."""
    array = real_vector(value, n, name)
    return np.full(n, float(array)) if array.ndim == 0 else array


def reachable(low, high, dq_previous, step) -> tuple[np.ndarray, np.ndarray]:
    """The box [low, high] ((n,) each) cut to the velocities within ``step`` ((n,)) of ``dq_previous``; where they do
    not meet, the one velocity of that reach nearest to the box."""
    reach_lo = dq_previous - step
    reach_hi = dq_previous + step
    lo = np.maximum(low, reach_lo)
    hi = np.minimum(high, reach_hi)
    above = lo > hi  # the box lies outside the reach: go as far towards it as the step allows
    nearest = np.where(reach_lo > high, reach_lo, reach_hi)
    lo = np.where(above, nearest, lo)
    hi = np.where(above, nearest, hi)
    return lo, hi
