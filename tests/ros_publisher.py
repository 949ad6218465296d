"""The ROS side of the live tests, with no ROS: a zenoh peer on 127.0.0.1 that publishes a recording's depth frames,
camera_info and joint states as CDR messages, in rmw_zenoh's layout (keys with the type hash, attachments) or the
bridge's (bare topic names), restamped on the host's clock as a camera driver stamps them."""

from __future__ import annotations

import json
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


class RosPublisher:
    """A zenoh peer listening on 127.0.0.1:port. :meth:`publish_set` sends one set of frames (and the joint state at
    their stamp); :meth:`wait_answer` waits for the node's distances."""

    def __init__(self, rig, joint_names, layout="rmw_zenoh", port=None, type_hash=None):
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
        self.session = zenoh.open(conf)
        self.store = wire.type_store()
        self.sequences: dict[str, int] = {}  # rmw_zenoh numbers each publisher's messages from 1
        self.type_hash = type_hash  # a wrong hash in the image keys, when given
        self._publishers = {}
        self.answers = []
        self._answered = threading.Condition()
        key = wire.subscription_key("/depthguard/distances", "std_msgs/msg/Float64MultiArray", layout)
        self._sub = self.session.declare_subscriber(key, self._on_answer)
        self.scaling = []  # (key, has an attachment, factor) of /depthguard/speed_scaling (live --ssm)
        self._scale = self.session.declare_subscriber(
            wire.subscription_key("/depthguard/speed_scaling", "control_msgs/msg/SpeedScalingFactor", layout),
            lambda sample: self.scaling.append((str(sample.key_expr), sample.attachment is not None, wire.deserialize(
                sample.payload.to_bytes(), "control_msgs/msg/SpeedScalingFactor").factor)))
        self.diagnostics = []  # diagnostic_msgs/DiagnosticArray messages on /diagnostics
        self._diag = self.session.declare_subscriber(
            wire.subscription_key("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", layout),
            lambda sample: self.diagnostics.append(wire.deserialize(sample.payload.to_bytes(),
                                                                    "diagnostic_msgs/msg/DiagnosticArray")))
        # Every publisher declared up front: a put right after its declaration can go before the route to the
        # node's subscriber is known.
        for name in rig.cameras:
            self._publisher(f"/{name}/depth/camera_info", "sensor_msgs/msg/CameraInfo")
            self._publisher(f"/{name}/depth/image_raw", "sensor_msgs/msg/Image")
        self._publisher("/joint_states", "sensor_msgs/msg/JointState")

    def wait_for_node(self, timeout: float = 20.0) -> bool:
        """Wait until the node's subscriptions reach every publisher (zenoh's matching status): a sample put
        before then goes nowhere."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if all(p.matching_status.matching for p in self._publishers.values()):
                return True
            time.sleep(0.02)
        return False

    def _publisher(self, topic: str, msgtype: str):
        key = wire.data_key(topic, msgtype, self.layout)
        if self.type_hash is not None and msgtype == "sensor_msgs/msg/Image":
            key = key.rsplit("/", 1)[0] + "/" + self.type_hash
        publisher = self._publishers.get(key)
        if publisher is None:
            # BLOCK: a test's sample is never dropped for a full queue (zenoh's default drops under congestion,
            # as rmw_zenoh's keep-last publishers do; the node counts such losses from the sequence numbers).
            import zenoh

            publisher = self._publishers[key] = self.session.declare_publisher(
                key, congestion_control=zenoh.CongestionControl.BLOCK)
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
        if self.layout == "rmw_zenoh":
            publisher.put(payload, attachment=wire.attachment_bytes(sequence, time.time_ns(), b"p" * 16))
        else:
            publisher.put(payload)

    def publish_joints(self, ns: int, positions) -> None:
        self.put("/joint_states", "sensor_msgs/msg/JointState",
                 joint_state_message(self.store, ns, self.joint_names, positions))

    def publish_frame(self, camera: str, ns: int, data: np.ndarray, *, big_endian=False, padding=0, info=None):
        info_message, image = depth_messages(self.store, ns, self.rig.cameras[camera], data)
        if big_endian or padding:
            array = np.ascontiguousarray(data, dtype=data.dtype.newbyteorder(">" if big_endian else "<"))
            rows = array.view(np.uint8).reshape(data.shape[0], -1)
            rows = np.concatenate([rows, np.zeros((rows.shape[0], padding), np.uint8)], axis=1)
            image = type(image)(header=image.header, height=image.height, width=image.width, encoding=image.encoding,
                                is_bigendian=int(big_endian), step=rows.shape[1], data=rows.ravel())
        self.put(f"/{camera}/depth/camera_info", "sensor_msgs/msg/CameraInfo", info or info_message)
        self.put(f"/{camera}/depth/image_raw", "sensor_msgs/msg/Image", image)

    def close(self):
        self._sub.undeclare()
        self._diag.undeclare()
        self._scale.undeclare()
        for publisher in self._publishers.values():
            publisher.undeclare()
        self.session.close()


def attachment_fields(data: bytes):
    return struct.unpack_from("<qqB", data)
