"""Robots: kinematics, collision geometry, capsules and control points read from a URDF.

Typical use::

    from depthguard.robots import RobotModel
    robot = RobotModel.default()                      # KUKA LBR iiwa, 9 control points
    q = robot.joint_vector({"lbr_iiwa_joint_1": 0.1, ...})   # every movable joint by name, radians
    points_world = robot.control_point_positions(q)    # (9, 3) metres, world frame
    J = robot.control_point_jacobians(q)               # (9, 3, 7) metres per radian, world frame
"""

from depthguard.robots._capsules import LinkCapsule, enclosing_circle, fit_capsule, segment_distances
from depthguard.robots._inner import closed_triangles
from depthguard.robots._model import ControlPoint, RobotModel, default_robot_path, panda_robot_path, xarm6_robot_path

__all__ = [
    "ControlPoint",
    "LinkCapsule",
    "RobotModel",
    "closed_triangles",
    "default_robot_path",
    "enclosing_circle",
    "fit_capsule",
    "panda_robot_path",
    "xarm6_robot_path",
    "segment_distances",
]
