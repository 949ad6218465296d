"""A closed-loop run as a ROS 2 bag (MCAP) that a user can open in Foxglove or rerun .

Topics (ROS 2 message types, stamps = simulated time; frame ``world`` is the workcell's world frame, REP 103):

- ``/tf_static`` (tf2_msgs/TFMessage): world -> ``<camera>_optical_frame`` for every camera of the rig;
- ``/<camera>/depth/image_raw`` (sensor_msgs/Image, ``16UC1``) and ``/<camera>/depth/camera_info``
  (sensor_msgs/CameraInfo): every captured frame, as :func:`depthguard.io.recordings.write_bag` writes them;
- ``/joint_states`` (sensor_msgs/JointState): the robot's joints at every control step;
- ``/depthguard/distances`` (std_msgs/Float64MultiArray): the monitor's distance of each control point at every
  control step, metres (``inf``: nothing within rho), in the order the layout's label lists them;
- ``/depthguard/true_distances`` (std_msgs/Float64MultiArray): the exact distances (coal), where the run computed
  them;
- ``/depthguard/repulsive`` (geometry_msgs/Vector3Stamped): the end-effector's repulsive velocity, m/s, world;
- ``/depthguard/robot`` (visualization_msgs/MarkerArray), every ``MARKER_EVERY`` control steps: the robot's link
  capsules (a cylinder and two spheres each) and its control points, coloured by their reported distance (red below
  ``NEAR``, orange below rho, green beyond).

The folder also holds ``rig.yaml``, so the bag replays through ``depthguard replay`` like any recording.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from depthguard.io.files import atomic_folder
from depthguard.cameras import save_rig
from depthguard.errors import InputError
from depthguard.validation import check_path
from depthguard.io.ros_messages import (
    JOINT_STATES_TOPIC,
    depth_messages,
    joint_state_message,
    ros_header,
    ros_nanoseconds,
    ros_typestore,
)
from depthguard.transforms import rotation_with_z

DISTANCES_TOPIC = "/depthguard/distances"
TRUE_DISTANCES_TOPIC = "/depthguard/true_distances"
REPULSIVE_TOPIC = "/depthguard/repulsive"
ROBOT_TOPIC = "/depthguard/robot"
MARKER_EVERY = 10  # control steps between two marker arrays: 50 Hz at 500 Hz control
NEAR = 0.1  # metres: a control point reported nearer than this is drawn red
CONTROL_POINT_SIZE = 0.04  # metres, the diameter of a control point's sphere

_TYPES = {
    "/tf_static": "tf2_msgs/msg/TFMessage",
    JOINT_STATES_TOPIC: "sensor_msgs/msg/JointState",
    DISTANCES_TOPIC: "std_msgs/msg/Float64MultiArray",
    TRUE_DISTANCES_TOPIC: "std_msgs/msg/Float64MultiArray",
    REPULSIVE_TOPIC: "geometry_msgs/msg/Vector3Stamped",
    ROBOT_TOPIC: "visualization_msgs/msg/MarkerArray",
}


def write_loop_bag(path, workcell, log, rho: float) -> Path:
    """Write ``log`` (a :class:`~depthguard_lab.simulation._closed_loop.LoopLog` run with ``keep_frames=True`` on
    ``workcell``) as an MCAP bag in the new folder ``path``; ``rho``: the monitor's rho (metres, for the colours).
    Returns ``path``."""
    from rosbags.rosbag2 import Writer
    from rosbags.rosbag2.enums import StoragePlugin

    if not log.captures:
        raise InputError("the run kept no frames: run it with keep_frames=True", field="log")
    path = check_path(path, "bag folder")
    if path.exists() or path.is_symlink():
        raise InputError("exists already; a bag is written into a new folder", source=str(path))
    store = ros_typestore()
    types = store.types
    rig = workcell.rig
    robot = workcell.robot if log.robot is None else log.robot  # the points the loop measured from
    names = list(robot.control_point_names)
    truth_names = list(workcell.robot.control_point_names)
    messages = []  # (ns, topic, message)
    ns_of = [ros_nanoseconds(t, "control time") for t in log.times]

    transforms = [types["geometry_msgs/msg/TransformStamped"](
        header=ros_header(store, ns_of[0], "world"), child_frame_id=f"{name}_optical_frame",
        transform=_transform(types, camera.T_world_camera)) for name, camera in rig.cameras.items()]
    messages.append((ns_of[0], "/tf_static", types["tf2_msgs/msg/TFMessage"](transforms=transforms)))
    image_topics = {}
    for t, _, depth in log.captures:
        ns = ros_nanoseconds(t, "capture time")
        for name, image in depth.items():
            info, message = depth_messages(store, ns, rig.cameras[name], image.data)
            image_topics[name] = (f"/{name}/depth/image_raw", f"/{name}/depth/camera_info")
            messages.append((ns, image_topics[name][1], info))
            messages.append((ns, image_topics[name][0], message))
    layout = _layout(types, names)
    array = types["std_msgs/msg/Float64MultiArray"]
    for k, ns in enumerate(ns_of):
        messages.append((ns, JOINT_STATES_TOPIC, joint_state_message(store, ns, robot.joint_names, log.q[k])))
        messages.append((ns, DISTANCES_TOPIC, array(layout=layout, data=np.asarray(log.reported[k], np.float64))))
        messages.append((ns, REPULSIVE_TOPIC, types["geometry_msgs/msg/Vector3Stamped"](
            header=ros_header(store, ns, "world"), vector=_vector3(types, log.repulsive[k]))))
        if k % MARKER_EVERY == 0:
            messages.append((ns, ROBOT_TOPIC, _robot_markers(store, ns, robot, log.q[k], log.reported[k], rho)))
    truth_layout = _layout(types, truth_names)
    for row, k in enumerate(log.truth_steps):
        messages.append((ns_of[k], TRUE_DISTANCES_TOPIC, array(layout=truth_layout,
                                                                data=np.asarray(log.truth[row], np.float64))))
    topics = dict(_TYPES)
    for image_topic, info_topic in image_topics.values():
        topics[image_topic] = "sensor_msgs/msg/Image"
        topics[info_topic] = "sensor_msgs/msg/CameraInfo"
    order = sorted(range(len(messages)), key=lambda i: messages[i][0])  # stable: same stamp keeps its order
    # Written beside path and renamed: the bag appears whole, rig.yaml included, or not at all.
    with atomic_folder(path) as folder, Writer(folder, version=Writer.VERSION_LATEST,
                                               storage_plugin=StoragePlugin.MCAP) as writer:
        save_rig(rig, folder / "rig.yaml")
        connections = {topic: writer.add_connection(topic, msgtype, typestore=store) for topic, msgtype in
                       topics.items()}
        for i in order:
            ns, topic, message = messages[i]
            writer.write(connections[topic], ns, store.serialize_cdr(message, topics[topic]))
    return path


def _layout(types, names):
    """A Float64MultiArray layout of one dimension whose label lists the control points."""
    dim = types["std_msgs/msg/MultiArrayDimension"](label="control_points:" + ",".join(names), size=len(names),
                                                    stride=len(names))
    return types["std_msgs/msg/MultiArrayLayout"](dim=[dim], data_offset=0)


def _vector3(types, v):
    return types["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))


def _quaternion(types, R):
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return types["geometry_msgs/msg/Quaternion"](x=float(x), y=float(y), z=float(z), w=float(w))


def _transform(types, T):
    return types["geometry_msgs/msg/Transform"](translation=_vector3(types, T[:3, 3]),
                                                rotation=_quaternion(types, T[:3, :3]))


def _robot_markers(store, ns, robot, q, reported, rho):
    """The link capsules (grey: a cylinder along each axis and a sphere at each end) and the control points (spheres
    coloured by their reported distance) at joints q, in frame world."""
    types = store.types
    Marker = types["visualization_msgs/msg/Marker"]
    Pose, Point = types["geometry_msgs/msg/Pose"], types["geometry_msgs/msg/Point"]
    Color = types["std_msgs/msg/ColorRGBA"]
    blank = dict(lifetime=types["builtin_interfaces/msg/Duration"](sec=0, nanosec=0), frame_locked=False, points=[],
                 colors=[], texture_resource="",
                 texture=types["sensor_msgs/msg/CompressedImage"](header=ros_header(store, 0, ""), format="",
                                                                  data=np.zeros(0, np.uint8)),
                 uv_coordinates=[], text="", mesh_resource="",
                 mesh_file=types["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, np.uint8)),
                 mesh_use_embedded_materials=False)
    grey = Color(r=0.6, g=0.6, b=0.65, a=0.8)
    markers = []

    def add(space, kind, position, R, scale, color):
        markers.append(Marker(header=ros_header(store, ns, "world"), ns=space, id=len(markers), type=kind,
                              action=Marker.ADD,
                              pose=Pose(position=Point(x=float(position[0]), y=float(position[1]),
                                                       z=float(position[2])), orientation=_quaternion(types, R)),
                              scale=_vector3(types, scale), color=color, **blank))

    for capsule in robot.capsules_world(q, check=False):
        p0, p1 = np.asarray(capsule.p0), np.asarray(capsule.p1)
        axis = p1 - p0
        length = float(np.linalg.norm(axis))
        d = 2.0 * capsule.radius
        if length > 1e-9:
            add("links", Marker.CYLINDER, (p0 + p1) / 2, rotation_with_z(axis / length), (d, d, length), grey)
        for end in (p0, p1):
            add("links", Marker.SPHERE, end, np.eye(3), (d, d, d), grey)
    for point, distance in zip(robot.control_point_positions(q, check=False), reported):
        color = Color(r=0.9, g=0.1, b=0.1, a=1.0) if distance < NEAR else (
            Color(r=1.0, g=0.6, b=0.0, a=1.0) if distance < rho else Color(r=0.1, g=0.8, b=0.2, a=1.0))
        add("control_points", Marker.SPHERE, point, np.eye(3), (CONTROL_POINT_SIZE,) * 3, color)
    return types["visualization_msgs/msg/MarkerArray"](markers=markers)

