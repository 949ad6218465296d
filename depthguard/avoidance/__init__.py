"""Collision avoidance from the monitor's distances (design §9): the papers' repulsive velocity and joint
velocity bounds with saturation in the null space, and speed and separation monitoring (ISO/TS 15066)."""

from depthguard.avoidance._controller import (
    AvoidanceCommand,
    AvoidanceController,
    AvoidanceParams,
    damped_pinv,
    repulsive_speed,
    risk,
    sns,
)
from depthguard.avoidance._limits import JointLimits, reachable
from depthguard.avoidance._scaling import ScalingAnswer, SpeedScaling
from depthguard.avoidance._ssm import (
    SpeedSeparationMonitor,
    SSMParams,
    SSMVerdict,
    allowed_approach_speed,
    brake_along_path,
    check_capability,
    intrusion_distance,
    protective_separation_distance,
)

__all__ = [
    "AvoidanceCommand",
    "AvoidanceController",
    "AvoidanceParams",
    "JointLimits",
    "SSMParams",
    "SSMVerdict",
    "ScalingAnswer",
    "SpeedScaling",
    "SpeedSeparationMonitor",
    "allowed_approach_speed",
    "brake_along_path",
    "check_capability",
    "damped_pinv",
    "intrusion_distance",
    "protective_separation_distance",
    "reachable",
    "repulsive_speed",
    "risk",
    "sns",
]
