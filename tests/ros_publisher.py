"""The ROS side of the live tests, with no ROS: a zenoh peer on 127.0.0.1 that publishes a recording's depth frames,
camera_info and joint states as CDR messages, in rmw_zenoh's layout (keys with the type hash, attachments) or the
bridge's (bare topic names), restamped on the host's clock as a camera driver stamps them.

In rmw_zenoh's layout it behaves as image_transport's publishers and realsense-ros do: a camera's image and
camera_info go out only while it counts a subscriber of the image topic, from rmw_zenoh's liveliness tokens (kind
``MS``) in its domain. A node that declares no subscriber token gets no frame. In the bridge's layout it plays
zenoh-bridge-ros2dds and a DDS driver behind it: the bridge creates a DDS reader of a topic only for another
session's route token of kind ``MS`` (``bridge_route``), and the driver publishes only while it counts one."""

from __future__ import annotations

import json
import re
import socket
import struct
import threading
import time

import numpy as np

from depthguard.io.ros_messages import depth_messages, joint_state_message
from depthguard.live import wire


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


#: zenoh-plugin-ros2dds 1.10.0's route tokens (``liveliness_mgt.rs``, kedefine ``ke_liveliness_pub`` and
#: ``ke_liveliness_sub``: ``@ros2_lv/${zenoh_id:*}/MP|MS/${ke:*}/${typ:*}/${qos_ke:*}``, ``/`` in ke and typ written
#: ``§``); its ``key_expr_to_qos`` refuses a QoS text that is not 4 fields between ``:``, each empty or a number
#: (history: ``kind,depth``).
_BRIDGE_ROUTE = re.compile(r"@ros2_lv/([^/*$?#]+)/(MP|MS)/([^/*$?#]+)/([^/*$?#]+)/(K?):(\d*):(\d*):(\d+,\d+)?")


def bridge_route(key: str):
    """(zenoh id, kind, topic, type, (keyless, reliability, durability, history)) of a bridge route token, as the
    bridge reads it, or None when the bridge would not accept it."""
    match = _BRIDGE_ROUTE.fullmatch(key)
    if match is None:
        return None
    zid, kind, ke, typ, keyed, reliability, durability, history = match.groups()
    return (zid, kind, "/" + ke.replace("\u00a7", "/"), typ.replace("\u00a7", "/"),
            (not keyed, reliability, durability, history))


class RosPublisher:
    """A zenoh peer listening on 127.0.0.1:port. :meth:`publish_set` sends one set of frames (and the joint state at
    their stamp); :meth:`wait_answer` waits for the node's distances."""

    def __init__(self, rig, joint_names, layout="rmw_zenoh", port=None, type_hash=None,
                 scaling_topic="/depthguard/speed_scaling", latched_info=False, distro="jazzy", old_attachment=False):
        import zenoh

        self.rig = rig
        self.joint_names = list(joint_names)
        self.layout = layout
        self.port = port or free_port()
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        conf = zenoh.Config()
        conf.insert_json5("mode", json.dumps("peer"))
        conf.insert_json5("listen/endpoints", json.dumps([self.endpoint]))
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("timestamping/enabled", "true")  # as rmw_zenoh's sessions: its advanced publishers need it
        self.session = zenoh.open(conf)
        self.store = wire.type_store()
        self.sequences: dict[str, int] = {}  # rmw_zenoh numbers each publisher's messages from 1
        self.type_hash = type_hash  # a wrong hash in the image keys, when given
        self.distro = distro  # rmw_zenoh's hash style: Jazzy's RIHS01 hashes or Humble's TypeHashNotSupported
        self.old_attachment = old_attachment  # an older rmw_zenoh's attachment: named fields, not the 33 bytes
        self._declared = []  # the liveliness tokens of this peer's publishers and subscriptions
        self._publishers = {}
        self.answers = []
        self._answered = threading.Condition()
        # Subscribed at the exact key of this peer's hash style, as rmw_zenoh's subscriptions are: a node that
        # speaks the other style is not heard.
        key = wire.data_key("/depthguard/distances", "std_msgs/msg/Float64MultiArray", layout, distro=distro)
        self._sub = self.session.declare_subscriber(key, self._on_answer)
        self._token("MS", "/depthguard/distances", "std_msgs/msg/Float64MultiArray")
        self.scaling = []  # (key, has an attachment, factor) of /depthguard/speed_scaling (live --ssm)
        self._scale = self.session.declare_subscriber(
            wire.subscription_key(scaling_topic, "control_msgs/msg/SpeedScalingFactor", layout),
            lambda sample: self.scaling.append((str(sample.key_expr), sample.attachment is not None, wire.deserialize(
                sample.payload.to_bytes(), "control_msgs/msg/SpeedScalingFactor").factor)))
        self.scaling_times = []  # when each factor arrived (time.monotonic)
        self._scale_times = self.session.declare_subscriber(
            wire.subscription_key(scaling_topic, "control_msgs/msg/SpeedScalingFactor", layout),
            lambda sample: self.scaling_times.append(time.monotonic()))
        self.diagnostics = []  # diagnostic_msgs/DiagnosticArray messages on /diagnostics
        self._diag = self.session.declare_subscriber(
            wire.subscription_key("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", layout),
            lambda sample: self.diagnostics.append(wire.deserialize(sample.payload.to_bytes(),
                                                                    "diagnostic_msgs/msg/DiagnosticArray")))
        # Every publisher declared up front: a put right after its declaration can go before the route to the
        # node's subscriber is known.
        self.latched_info = latched_info  # camera_info transient local: kept in an advanced publisher's cache
        for name in rig.cameras:
            self._publisher(f"/{name}/depth/camera_info", "sensor_msgs/msg/CameraInfo")
            self._publisher(f"/{name}/depth/image_raw", "sensor_msgs/msg/Image")
        self._publisher("/joint_states", "sensor_msgs/msg/JointState")
        self.tokens: set[str] = set()  # the rmw_zenoh liveliness tokens alive in the domain
        self.withheld = 0  # frames not published: no subscriber counted
        # rmw_zenoh's graph in its domain, or, playing zenoh-bridge-ros2dds, every bridge route token
        # (``@ros2_lv/<zenoh id>/...``, its liveliness_mgt.rs).
        self._tokens = self.session.liveliness().declare_subscriber(
            "@ros2_lv/0/**" if layout == "rmw_zenoh" else "@ros2_lv/**", self._on_token, history=True)

    def _on_token(self, sample):
        import zenoh

        key = str(sample.key_expr)
        if sample.kind == zenoh.SampleKind.PUT:
            self.tokens.add(key)
        else:
            self.tokens.discard(key)

    def subscribers(self, topic: str) -> int:
        """How many subscriptions of ``topic`` the domain's liveliness tokens declare (rmw_zenoh's graph count,
        what ``getNumSubscribers()`` returns to a driver). In the bridge layout: how many route tokens of kind MS
        announce it, parsed as zenoh-plugin-ros2dds 1.10.0 parses them (``liveliness_mgt.rs``: ``ke_liveliness_sub``
        and ``key_expr_to_qos``), each one a DDS reader the bridge creates, which the DDS driver counts."""
        if self.layout == "rmw_zenoh":
            parsed = [wire.parse_liveliness_key(key) for key in list(self.tokens)]
            return sum(1 for token in parsed if token is not None and token.kind == "MS" and token.topic == topic)
        return sum(1 for key in list(self.tokens) if (route := bridge_route(key)) is not None
                   and route[1] == "MS" and route[2] == topic)

    def _token(self, kind: str, topic: str, msgtype: str) -> None:
        """Declare this peer's liveliness token for one of its entities, as rmw_zenoh does (rmw_zenoh layout)."""
        if self.layout == "rmw_zenoh":
            key = wire.liveliness_key(str(self.session.info.zid()), 100 + len(self._declared), kind, "camera_driver",
                                      topic, msgtype, distro=self.distro)
            self._declared.append(self.session.liveliness().declare_token(key))

    def wait_for_node(self, timeout: float = 20.0) -> bool:
        """Wait until the node's subscriptions reach every publisher (zenoh's matching status): a sample put
        before then goes nowhere."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if all(p.matching_status.matching for p in self._publishers.values() if hasattr(p, "matching_status")) and (
                    all(self.subscribers(f"/{name}/depth/image_raw") for name in self.rig.cameras)):
                return True
            time.sleep(0.02)
        return False

    def _publisher(self, topic: str, msgtype: str):
        key = wire.data_key(topic, msgtype, self.layout, distro=self.distro)
        if self.type_hash is not None and msgtype == "sensor_msgs/msg/Image":
            key = key.rsplit("/", 1)[0] + "/" + self.type_hash
        publisher = self._publishers.get(key)
        if publisher is None:
            # BLOCK: a test's sample is never dropped for a full queue (zenoh's default drops under congestion,
            # as rmw_zenoh's keep-last publishers do; the node counts such losses from the sequence numbers).
            import zenoh

            if self.latched_info and msgtype == "sensor_msgs/msg/CameraInfo":  # as rmw_zenoh's transient local
                import zenoh.ext

                publisher = self._publishers[key] = zenoh.ext.declare_advanced_publisher(
                    self.session, key, cache=zenoh.ext.CacheConfig(max_samples=1), publisher_detection=True)
            else:
                publisher = self._publishers[key] = self.session.declare_publisher(
                    key, congestion_control=zenoh.CongestionControl.BLOCK)
            self._token("MP", topic, msgtype)
        return publisher

    def _on_answer(self, sample):
        message = wire.deserialize(sample.payload.to_bytes(), "std_msgs/msg/Float64MultiArray")
        with self._answered:
            self.answers.append((str(sample.key_expr), sample.attachment is not None, np.array(message.data)))
            self._answered.notify_all()

    def wait_answer(self, count: int, timeout: float = 30.0) -> bool:
        with self._answered:
            return self._answered.wait_for(lambda: len(self.answers) >= count, timeout)

    def put(self, topic: str, msgtype: str, message, raw: bytes | None = None) -> None:
        publisher = self._publisher(topic, msgtype)
        payload = raw if raw is not None else wire.serialize(message, msgtype)
        sequence = self.sequences[topic] = self.sequences.get(topic, 0) + 1
        if self.layout == "rmw_zenoh" and self.old_attachment:  # key-value pairs, as zenoh's serializer wrote them
            publisher.put(payload, attachment=b"\x0fsequence_number" + struct.pack("<q", sequence)
                          + b"\x0fsource_timestamp" + struct.pack("<q", time.time_ns()) + b"\x0csource_gid" + b"p" * 16)
        elif self.layout == "rmw_zenoh":
            publisher.put(payload, attachment=wire.attachment_bytes(sequence, time.time_ns(), b"p" * 16))
        else:
            publisher.put(payload)

    def latch_info(self, camera: str, ns: int) -> None:
        """Publish ``camera``'s CameraInfo once, into the advanced publisher's cache (``latched_info``): a driver
        that latches it at start-up and never sends it again."""
        info_message, _ = depth_messages(self.store, ns, self.rig.cameras[camera],
                                         np.zeros(1, dtype=np.uint16).reshape(1, 1))
        self.put(f"/{camera}/depth/camera_info", "sensor_msgs/msg/CameraInfo", info_message)

    def publish_joints(self, ns: int, positions) -> None:
        self.put("/joint_states", "sensor_msgs/msg/JointState",
                 joint_state_message(self.store, ns, self.joint_names, positions))

    def publish_frame(self, camera: str, ns: int, data: np.ndarray, *, big_endian=False, padding=0, info=None) -> bool:
        """Publish one frame and its camera_info; in rmw_zenoh's layout only while a subscriber of the image topic
        is counted, and in the bridge's only while a route token makes the bridge create a DDS reader of it (else
        nothing goes out, ``withheld`` counts it, and False comes back)."""
        if not self.subscribers(f"/{camera}/depth/image_raw"):
            self.withheld += 1
            return False
        info_message, image = depth_messages(self.store, ns, self.rig.cameras[camera], data)
        if big_endian or padding:
            array = np.ascontiguousarray(data, dtype=data.dtype.newbyteorder(">" if big_endian else "<"))
            rows = array.view(np.uint8).reshape(data.shape[0], -1)
            rows = np.concatenate([rows, np.zeros((rows.shape[0], padding), np.uint8)], axis=1)
            image = type(image)(header=image.header, height=image.height, width=image.width, encoding=image.encoding,
                                is_bigendian=int(big_endian), step=rows.shape[1], data=rows.ravel())
        if not self.latched_info:
            self.put(f"/{camera}/depth/camera_info", "sensor_msgs/msg/CameraInfo", info or info_message)
        self.put(f"/{camera}/depth/image_raw", "sensor_msgs/msg/Image", image)
        return True

    def close(self):
        self._sub.undeclare()
        self._diag.undeclare()
        self._scale.undeclare()
        self._scale_times.undeclare()
        if self._tokens is not None:
            self._tokens.undeclare()
        for token in self._declared:
            token.undeclare()
        for publisher in self._publishers.values():
            publisher.undeclare()
        self.session.close()


def attachment_fields(data: bytes):
    return struct.unpack_from("<qqB", data)
