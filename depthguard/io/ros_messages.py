"""ROS 2 messages as depthguard reads and writes them, in bags and live (design §12a, §12b): the message types, the
checks of a depth ``Image``, its ``CameraInfo`` and a ``JointState`` against the rig and the robot, and the messages
written for a recording. One decoder for ``replay`` and ``live``.

Messages are the objects of ``rosbags``' type store (:func:`ros_typestore`, ROS 2 Humble's definitions; Jazzy's give
the same type hashes for these types), so no ROS installation is needed. Every check raises an
:class:`~depthguard.errors.InputError` naming the source (the bag or topic), the camera and the field.
"""

from __future__ import annotations

import math
from decimal import Decimal

import numpy as np

from depthguard import config
from depthguard.cameras import PinholeCamera
from depthguard.errors import InputError
from depthguard.validation import short_repr

__all__ = ["IMAGE", "CAMERA_INFO", "JOINT_STATE", "JOINT_STATES_TOPIC", "ENCODINGS", "ros_typestore", "header_seconds",
           "image_array", "check_camera_info", "joint_state", "ros_header", "joint_state_message", "depth_messages",
           "ros_nanoseconds"]

IMAGE = "sensor_msgs/msg/Image"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
JOINT_STATE = "sensor_msgs/msg/JointState"
#: The robot's joint states, in a bag and by default live.
JOINT_STATES_TOPIC = "/joint_states"
#: Image encodings read: ROS name -> numpy dtype (byte order from is_bigendian).
ENCODINGS = {"16UC1": np.uint16, "32FC1": np.float32}
#: Intrinsics in a camera_info agree with the rig's within this many pixels.
INTRINSICS_TOLERANCE = 1e-6


def ros_typestore():
    """The ROS 2 message types (Humble) bags are read and written with."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def header_seconds(message, source: str, camera, index: int, what: str = "image") -> float:
    """The header stamp in seconds (nanoseconds / 1e9: a time written by :func:`write_bag` reads back equal)."""
    stamp = message.header.stamp
    if not (0 <= stamp.nanosec < 1_000_000_000):
        raise InputError(f"{what} #{index}: header.stamp.nanosec {stamp.nanosec} is not in [0, 1e9)", source=source,
                         camera=camera, field="header.stamp")
    return (int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)) / 1e9


def image_array(message, camera: PinholeCamera, source: str, index: int, check_only: bool = False):
    """A (height, width) uint16 or float32 array of an Image message, checked against the camera."""
    name = camera.name
    where = f"image #{index}: "
    dtype = ENCODINGS.get(message.encoding)
    if dtype is None:
        raise InputError(f"{where}encoding {short_repr(message.encoding)} holds no depth (16UC1: units of "
                         f"depth_scale, 32FC1: metres)", source=source, camera=name, field="encoding")
    if (message.height, message.width) != camera.shape:
        raise InputError(f"{where}image is {message.width}x{message.height} (width x height) but the camera is "
                         f"{camera.width}x{camera.height}", source=source, camera=name, field="width/height")
    itemsize = np.dtype(dtype).itemsize
    row = camera.width * itemsize
    if message.step < row or message.step % itemsize or len(message.data) != message.step * camera.height:
        raise InputError(f"{where}step {message.step} and {len(message.data)} data bytes do not hold "
                         f"{camera.height} rows of {camera.width} {message.encoding} pixels", source=source,
                         camera=name, field="step")
    if message.is_bigendian not in (0, 1):
        raise InputError(f"{where}is_bigendian must be 0 or 1, got {message.is_bigendian}", source=source,
                         camera=name, field="is_bigendian")
    if check_only:
        return None
    order = ">" if message.is_bigendian else "<"
    array = np.frombuffer(message.data, dtype=np.dtype(dtype).newbyteorder(order))
    return array.reshape(camera.height, message.step // itemsize)[:, : camera.width].astype(dtype)


def check_camera_info(message, camera: PinholeCamera, source: str) -> None:
    """A CameraInfo message of ``image_raw`` agrees with the rig's camera: size, intrinsics from k, zero distortion of
    a pinhole model, r the identity, no binning or ROI (p, of the rectified image, is not used)."""
    name = camera.name
    context = {"source": source, "camera": name}
    for key in ("width", "height"):
        if int(getattr(message, key)) != getattr(camera, key):
            raise InputError(f"camera_info says {key} {getattr(message, key)}, the rig {getattr(camera, key)}",
                             field=key, **context)
    k = np.asarray(message.k, dtype=np.float64)
    if k.shape != (9,) or not np.isfinite(k).all():
        raise InputError(f"camera_info k must be 9 finite numbers, got {short_repr(k.tolist(), 80)}", field="k",
                         **context)
    for key, value in (("fx", float(k[0])), ("fy", float(k[4])), ("cx", float(k[2])), ("cy", float(k[5]))):
        expected = getattr(camera, key)
        if not abs(value - expected) <= INTRINSICS_TOLERANCE * max(1.0, abs(expected)):
            raise InputError(f"camera_info says {key} {value!r}, the rig {expected!r}", field=key, **context)
    if k[1] != 0.0 or k[3] != 0.0 or tuple(k[6:]) != (0.0, 0.0, 1.0):
        raise InputError(f"camera_info k is not a pinhole camera matrix without skew: {k.tolist()}", field="k",
                         **context)
    d = np.asarray(message.d, dtype=np.float64)
    if d.size and not (np.isfinite(d).all() and (d == 0.0).all()):
        raise InputError(f"camera_info has distortion {short_repr(d.tolist(), 80)}; depthguard needs rectified "
                         "images (all coefficients zero)", field="d", **context)
    model = str(message.distortion_model)
    if model and model not in config.PINHOLE_DISTORTION_MODELS:
        raise InputError(f"camera_info has distortion_model {short_repr(model)}, which is not known to be a pinhole "
                         f"camera with zero coefficients (equidistant's is a fisheye); image_raw is read only with "
                         f"{' or '.join(config.PINHOLE_DISTORTION_MODELS)}", field="distortion_model", **context)
    r = np.asarray(message.r, dtype=np.float64)
    if r.shape != (9,) or not (np.abs(r - np.eye(3).ravel()) <= config.ROTATION_TOLERANCE).all():
        raise InputError(f"camera_info r must be the identity, got {short_repr(r.tolist(), 80)}: depthguard cannot "
                         "tell whether the rig's pose is that of the raw camera frame or of the rectified frame, which "
                         "r turns", field="r", **context)
    if message.binning_x > 1 or message.binning_y > 1:
        raise InputError(f"camera_info has binning {message.binning_x}x{message.binning_y}; the rig's intrinsics "
                         "are of unbinned images", field="binning", **context)
    roi = message.roi
    if (roi.x_offset, roi.y_offset, roi.width, roi.height) not in ((0, 0, 0, 0), (0, 0, camera.width, camera.height)):
        raise InputError("camera_info has a region of interest smaller than the image", field="roi", **context)


def joint_state(message, source: str, index: int):
    names = [str(n) for n in message.name]
    values = np.asarray(message.position, dtype=np.float64)
    if not names:
        raise InputError(f"joint state #{index} names no joints", source=source, field="name")
    if len(set(names)) != len(names):
        raise InputError(f"joint state #{index} names a joint twice: {', '.join(names)}", source=source,
                         field="name")
    if values.shape != (len(names),):
        raise InputError(f"joint state #{index} has {values.size} positions for {len(names)} joint names",
                         source=source, field="position")
    if not np.isfinite(values).all():
        bad = [f"{n}={v}" for n, v in zip(names, values) if not math.isfinite(v)]
        raise InputError(f"joint state #{index}: positions must be finite, got {', '.join(bad)}", source=source,
                         field="position")
    return names, values


def ros_header(store, ns: int, frame_id: str):
    """A std_msgs/Header stamped ``ns`` nanoseconds."""
    types = store.types
    return types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](
        sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000), frame_id=frame_id)


def joint_state_message(store, ns: int, names, positions):
    """A sensor_msgs/JointState of ``positions`` (radians, ``names`` order) stamped ``ns`` nanoseconds."""
    empty = np.zeros(0)
    return store.types[JOINT_STATE](header=ros_header(store, ns, ""), name=list(names),
                                      position=np.array(positions, dtype=np.float64), velocity=empty, effort=empty)


def depth_messages(store, ns: int, camera: PinholeCamera, data: np.ndarray):
    """(sensor_msgs/CameraInfo, sensor_msgs/Image) of one depth image of ``camera`` stamped ``ns`` nanoseconds, in
    frame ``<camera>_optical_frame``: ``16UC1`` for an unsigned image (units of the rig's depth_scale), ``32FC1``
    for a float one (metres); a pinhole camera without distortion."""
    types = store.types
    frame_id = f"{camera.name}_optical_frame"
    roi = types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    info = types[CAMERA_INFO](
        header=ros_header(store, ns, frame_id), height=camera.height, width=camera.width,
        distortion_model="plumb_bob", d=np.zeros(5),
        k=np.array([camera.fx, 0.0, camera.cx, 0.0, camera.fy, camera.cy, 0.0, 0.0, 1.0]), r=np.eye(3).ravel(),
        p=np.array([camera.fx, 0.0, camera.cx, 0.0, 0.0, camera.fy, camera.cy, 0.0, 0.0, 0.0, 1.0, 0.0]),
        binning_x=0, binning_y=0, roi=roi)
    data = np.ascontiguousarray(data, dtype=data.dtype.newbyteorder("<"))
    encoding = "16UC1" if data.dtype.kind == "u" else "32FC1"
    image = types[IMAGE](header=ros_header(store, ns, frame_id), height=data.shape[0], width=data.shape[1],
                          encoding=encoding, is_bigendian=0, step=data.shape[1] * data.itemsize,
                          data=data.view(np.uint8).ravel())
    return info, image


def ros_nanoseconds(time: float, what: str) -> int:
    """A time in seconds as whole nanoseconds: its shortest decimal (repr) rounded, so 0.033333 is 33333000."""
    if time is None or not math.isfinite(time) or not 0.0 <= time < 2.0**31:
        raise InputError(f"a {what} of {short_repr(time)} s cannot be a ROS time (0 to 2**31 s)", field="time")
    return int((Decimal(repr(float(time))) * 1_000_000_000).to_integral_value())
