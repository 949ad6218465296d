"""The live node (design §12b): ROS 2 topics in through zenoh, answers out, as ``depthguard live`` runs it.

Threads:

- zenoh's own threads run the callbacks: each decodes its message (:mod:`depthguard.io.ros_messages`) and swaps
  it in: the newest frame per camera (a frame replaced before the worker took it counts as ``missed``), joint
  states into a bounded queue. A callback never waits on computing and never raises.
- one worker feeds the frame-set loop (:class:`~depthguard.live.FrameSetLoop`) on the host's clock, prepares each
  set with its :class:`~depthguard.DistanceMonitor` (made on that thread: its OpenGL context lives there), queries
  the robot's control points and publishes. When computing falls behind, the frames that came meanwhile are the
  newest: older ones are dropped and counted, never queued.

Every output goes out as rmw_zenoh sends it (the type hash in the key, an attachment, a liveliness token per
publisher; every subscription has its token too, so that drivers count a subscriber), or at the bare topic name for
the bridge layout, with the route tokens that make zenoh-bridge-ros2dds create a DDS reader for each subscription and
a DDS writer for each output (:func:`~depthguard.live.wire.bridge_liveliness_key`): ``/depthguard/distances``
(``std_msgs/msg/Float64MultiArray``, one value per control point in the robot's order, ``inf`` for nothing within
rho) and ``/depthguard/status`` (``diagnostic_msgs/msg/DiagnosticArray``: one status per control point, its flags,
and one per camera, its age and counts; ERROR while a camera is stale or missing, WARN for other flags), back to
back, the status stamped with the answer's time.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import csv
import json
import logging
import math
import os
import threading
import time as clock
from dataclasses import dataclass, field

import numpy as np

from depthguard import config
from depthguard.depth import depth_image
from depthguard.errors import DepthguardError, InputError
from depthguard.io.ros_messages import (CAMERA_INFO, IMAGE, JOINT_STATE, check_camera_info, header_seconds,
                                        image_array, joint_state, ros_header)
from depthguard.live import wire
from depthguard.live._sets import RESULT_COLUMNS, FrameSetLoop, answer_set

_LOG = logging.getLogger("depthguard")

DISTANCES_TOPIC = "/depthguard/distances"
STATUS_TOPIC = "/depthguard/status"
DISTANCES_TYPE = "std_msgs/msg/Float64MultiArray"
STATUS_TYPE = "diagnostic_msgs/msg/DiagnosticArray"
DIAGNOSTICS_TOPIC = "/diagnostics"
SCALING_TOPIC = "/depthguard/speed_scaling"
SCALING_TYPE = "control_msgs/msg/SpeedScalingFactor"
#: Diagnostic levels (diagnostic_msgs/msg/DiagnosticStatus).
OK, WARN, ERROR = 0, 1, 2
NODE_NAME = wire.NODE_NAME
#: Entity ids: the node 0, its publishers 1-4, its subscriptions from this one on.
_FIRST_SUBSCRIPTION = 10
CSV_HEADER = RESULT_COLUMNS + ["cameras", "latency_ms"]


def speed_scaling_status(scaling) -> tuple[int, str, list[tuple[str, str]]]:
    """(level, message, [(key, value)]) of ``/diagnostics``' "depthguard: speed scaling" status for the last factor
    published (a :class:`~depthguard.avoidance.ScalingAnswer`): ERROR at 0, WARN below 1; the message says why (its
    ``why``, or the surface point that limits it), prefixed "starting: " while the factor may rest on space not seen
    since start-up (``ScalingAnswer.starting``)."""
    level = ERROR if scaling.factor == 0.0 else (WARN if scaling.factor < 1.0 else OK)
    message = scaling.why or (f"limited by {scaling.limiting}" if scaling.limiting else "full speed")
    if scaling.starting:
        message = f"starting: {message}, next to space not seen since start-up (move the robot slowly through its poses)"
    return level, message, [("factor", repr(float(scaling.factor))), ("starting", str(scaling.starting).lower()),
                            ("reaction_ms", f"{scaling.reaction_time * 1e3:.3f}"),
                            ("distance", repr(float(scaling.distance)))]


@dataclass
class Topics:
    """Where the node listens. cameras: camera -> (image topic, camera_info topic); joints: the JointState topic."""

    cameras: dict
    joints: str = "/joint_states"

    @staticmethod
    def default_image(camera: str) -> str:
        return f"/{camera}/depth/image_raw"

    @staticmethod
    def info_of(image_topic: str) -> str:
        """The camera_info topic beside an image topic (its sibling)."""
        return image_topic.rsplit("/", 1)[0] + "/camera_info"


@dataclass
class CameraCounts:
    received: int = 0
    missed: int = 0  # replaced before the worker took it
    errors: int = 0
    last_error: str = ""
    info_error: str = ""  # the CameraInfo disagrees with the rig: the camera is left out
    info_seen: bool = False
    offset: float = math.nan  # the last image's arrival (host clock) minus its stamp, seconds
    sequence: int | None = None  # the last image's rmw_zenoh sequence number
    restarts: int = 0  # the publisher started again (its sequence number went back)
    future: int = 0  # frames stamped more than LIVE_CLOCK_OFFSET ahead of the host's clock: held out of the loop


def session_config(connect: list[str]):
    """A zenoh client configuration: it connects to ``connect`` (a router, or a peer that listens) and never
    listens or scouts."""
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("client"))
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    conf.insert_json5("listen/endpoints", json.dumps([]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return conf


class _Publisher:
    """One output topic: its zenoh publisher, rmw_zenoh's attachment and liveliness token (rmw_zenoh layout), or the
    route token that makes zenoh-bridge-ros2dds create its DDS writer (bridge layout)."""

    def __init__(self, session, topic: str, msgtype: str, layout: str, domain: int, entity: int, gid_seed: bytes,
                 recorder=None, distro: str = "jazzy"):
        self.topic = topic
        self.recorder = recorder
        self.msgtype = msgtype
        self.layout = layout
        self.key = wire.data_key(topic, msgtype, layout, domain, distro)
        self.publisher = session.declare_publisher(self.key)
        self.sequence = 0
        self.gid = (gid_seed + entity.to_bytes(4, "little"))[-16:].rjust(16, b"\x00")
        self.token = session.liveliness().declare_token(
            wire.entity_token(layout, str(session.info.zid()), entity, "MP", topic, msgtype, domain, distro))

    def put(self, message) -> None:
        payload = wire.serialize(message, self.msgtype)
        if self.recorder is not None:
            self.recorder.put(self.topic, self.msgtype, clock.time_ns(), payload)
        self.sequence += 1
        if self.layout == "rmw_zenoh":
            self.publisher.put(payload, attachment=wire.attachment_bytes(self.sequence, clock.time_ns(), self.gid))
        else:
            self.publisher.put(payload)


class _Recorder:
    """``--record DIR``: the messages received, unchanged (their CDR bytes), and the outputs, into a new ROS 2 bag
    folder (MCAP) with the rig as ``rig.yaml``, which ``replay`` reads back (design §12a). Frames and camera_info go
    under ``/<camera>/depth/...`` whatever topic they came on. A thread of its own writes; the callbacks only queue
    (bounded: what does not fit is dropped and counted). The folder appears whole when the node closes."""

    def __init__(self, folder, rig):
        from rosbags.rosbag2 import Writer
        from rosbags.rosbag2.enums import StoragePlugin

        from depthguard.cameras import save_rig
        from depthguard.io.files import atomic_folder
        from depthguard.io.ros_messages import ros_typestore

        # The folder appears whole at close(): the atomic folder stays open past this constructor (an ExitStack
        # holds it), and is discarded if the writer cannot start.
        with contextlib.ExitStack() as stack:
            path = stack.enter_context(atomic_folder(folder))
            self._writer = Writer(path, version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin.MCAP)
            self._writer.open()
            save_rig(rig, path / "rig.yaml")
            self._folder = stack.pop_all()
        self._store = ros_typestore()
        self._connections: dict = {}
        self._queue: collections.deque = collections.deque()
        self._limit = 4096
        self.dropped = 0
        self._wake = threading.Event()
        self._closed = False
        self._thread = threading.Thread(target=self._run, name="depthguard-live-record", daemon=True)
        self._thread.start()

    def put(self, topic: str, msgtype: str, ns: int, payload: bytes) -> None:
        if len(self._queue) >= self._limit:
            self.dropped += 1
            return
        self._queue.append((topic, msgtype, ns, payload))
        self._wake.set()

    def _run(self) -> None:
        while True:
            self._wake.wait(0.05)
            self._wake.clear()
            while self._queue:
                topic, msgtype, ns, payload = self._queue.popleft()
                connection = self._connections.get(topic)
                if connection is None:
                    connection = self._connections[topic] = self._writer.add_connection(topic, msgtype,
                                                                                        typestore=self._store)
                self._writer.write(connection, ns, payload)
            if self._closed:
                return

    def close(self) -> None:
        self._closed = True
        self._wake.set()
        self._thread.join()
        self._writer.close()
        self._folder.close()


@dataclass
class LiveOptions:
    layout: str = "rmw_zenoh"
    domain: int = 0
    connect: list = field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    wait: float = config.FRAME_SET_WAIT
    #: seconds the host's clock is held back when it drives the loop: a frame reaches the node this much after its
    #: stamp (driver, transport, decoding) and still joins its set, as it does in replay
    transport: float = config.LIVE_TRANSPORT
    #: where the speed factor goes (with ``ssm``): joint_trajectory_controller's is
    #: ``/<controller>/speed_scaling_input``
    scaling_topic: str = SCALING_TOPIC
    #: rmw_zenoh's hash style: "jazzy" (RIHS01 hashes), "humble" (TypeHashNotSupported) or "auto" (the peers' tokens
    #: in the domain say; Jazzy when none is found)
    distro: str = "auto"


class LiveNode:
    """Listens to ``topics``, answers each set of frames with ``monitor_options`` (as :class:`DistanceMonitor`
    takes them) for the robot's control points, and publishes the answers (see the module docstring).

    ``out``: a CSV file to write one row per point per answer (replay's columns, plus ``cameras``, those counted as
    seen, and ``latency_ms``, from the set's newest stamp to the answer; with ``ssm`` also ``speed_factor`` and
    ``reaction_ms``). Start with :meth:`start`, stop with :meth:`close`; ``answers``, ``dropped``,
    ``deadline_misses`` and per-camera ``counts`` say how it went.

    ``ssm``: None, or :class:`~depthguard.avoidance.SpeedScaling`'s keyword arguments (``params``, ``joint_speed``,
    ``braking``, ``hold``): then every answer also publishes ``/depthguard/speed_scaling``
    (``control_msgs/msg/SpeedScalingFactor``), right after the status, and 0 whenever no answer can be given (the
    joints unknown, a set that failed)."""

    def __init__(self, rig, robot, topics: Topics, options: LiveOptions, monitor_options: dict, out=None,
                 record=None, ssm: dict | None = None):
        import zenoh

        self.rig = rig
        self.robot = robot
        self.topics = topics
        self.options = options
        self.monitor_options = dict(monitor_options)
        self.max_age = self.monitor_options.get("max_age", config.DEFAULT_MAX_AGE)
        if not isinstance(self.max_age, (int, float)):
            self.max_age = config.DEFAULT_MAX_AGE
        self.counts = {name: CameraCounts() for name in rig.cameras}
        self.answers = 0
        self.joint_states = 0  # joint states received
        self._joint_seen = -math.inf  # the newest joint state's stamp
        self.dropped = 0
        self.deadline_misses = 0
        self.ssm = None if ssm is None else dict(ssm)
        self.scaling = None  # the SpeedScaling, made on the worker's thread with the monitor
        self.last_scaling = None  # the last ScalingAnswer published
        self.scaling_published = 0  # factors published, the deadline's zeros included
        self.deadline_zeros = 0  # zeros published because no answer came within hold
        self.ssm_hold = float((ssm or {}).get("hold", config.SSM_HOLD))
        self.recent: collections.deque = collections.deque(maxlen=1000)  # the last answers' (time, why, seen)
        self.errors: collections.deque = collections.deque(maxlen=100)  # the last errors, one line each
        self.unspeakable = None  # why a peer cannot be spoken to (another rmw_zenoh style), or None
        self._warned: set = set()
        self._lock = threading.Lock()
        self._frames: dict = {}
        self._joints: collections.deque = collections.deque(maxlen=config.JOINT_HISTORY)
        self._joint_order = None
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._out_path = out
        self._recorder = _Recorder(record, rig) if record is not None else None
        try:
            self.session = zenoh.open(session_config(options.connect))
        except zenoh.ZError as exc:  # a malformed endpoint, or a configuration zenoh refuses
            reason = str(exc).split(" at /")[0][:200]  # zenoh's message, without its source location
            raise InputError(f"zenoh cannot open a client session to {', '.join(options.connect)}: {reason}",
                             field="connect") from None
        self.distro = self._distro(options)  # rmw_zenoh's hash style, spoken on every key and token
        self._subscribers = []
        self._subscription_tokens = []  # rmw_zenoh's liveliness token of each subscription
        for name, (image_topic, info_topic) in topics.cameras.items():
            self._subscribe(image_topic, IMAGE, lambda s, n=name: self._on_image(n, s))
            self._subscribe(info_topic, CAMERA_INFO, lambda s, n=name: self._on_info(n, s), latched=True)
        self._subscribe(topics.joints, JOINT_STATE, self._on_joints)
        seed = os.urandom(12)
        self._distances = _Publisher(self.session, DISTANCES_TOPIC, DISTANCES_TYPE, options.layout, options.domain, 1,
                                     seed, self._recorder, self.distro)
        self._status = _Publisher(self.session, STATUS_TOPIC, STATUS_TYPE, options.layout, options.domain, 2, seed,
                                  self._recorder, self.distro)
        self._diagnostics = _Publisher(self.session, DIAGNOSTICS_TOPIC, STATUS_TYPE, options.layout, options.domain, 3,
                                       seed, self._recorder, self.distro)
        self._scaling = None if ssm is None else _Publisher(self.session, options.scaling_topic, SCALING_TYPE,
                                                            options.layout, options.domain, 4, seed, self._recorder,
                                                            self.distro)
        # The factor's deadline, kept by a thread of its own (a set that takes long must not hold it up): each factor
        # holds for ssm's hold seconds; with no newer one by then, 0 goes out, and again every hold seconds.
        self._scaling_lock = threading.Lock()
        self._scaling_deadline = math.inf
        self._keeper = None if ssm is None else threading.Thread(target=self._keep_deadline,
                                                                 name="depthguard-live-deadline", daemon=True)
        self._next_diagnostics = 0.0
        self._node_token = None
        if options.layout == "rmw_zenoh":
            self._node_token = self.session.liveliness().declare_token(
                wire.liveliness_key(str(self.session.info.zid()), 0, "NN", NODE_NAME, domain=options.domain))
        self._worker = threading.Thread(target=self._run, name="depthguard-live-node", daemon=True)
        self._ready = threading.Event()

    # ------------------------------------------------------------------------------------------------ receiving

    def _distro(self, options) -> str:
        """rmw_zenoh's hash style to speak: ``options.distro``, or with "auto" the one the liveliness tokens alive in
        the domain use (asked once, for up to ``config.LIVE_DISCOVERY`` seconds): Humble's when every peer's is,
        else Jazzy's (a peer of the other style is named in the errors)."""
        if options.layout != "rmw_zenoh":
            return "jazzy"
        if options.distro != "auto":
            wire.hash_of(IMAGE, options.distro)  # checked
            return options.distro
        keys = []
        for reply in self.session.liveliness().get(f"@ros2_lv/{options.domain}/**", timeout=config.LIVE_DISCOVERY):
            with contextlib.suppress(Exception):  # an error reply carries no key
                keys.append(str(reply.ok.key_expr))
        found = wire.distros_of(keys)
        if found == {"humble"}:
            return "humble"
        if "humble" in found:
            self.unspeakable = ("peers of both rmw_zenoh hash styles (Humble's TypeHashNotSupported and Jazzy's "
                                "RIHS01) in the domain: speaking Jazzy's; Humble's subscribers will not hear the "
                                "outputs")
            self.errors.append(self.unspeakable)
        return "jazzy"

    def _subscribe(self, topic: str, msgtype: str, callback, latched: bool = False) -> None:
        key = wire.subscription_key(topic, msgtype, self.options.layout, self.options.domain)
        expected = wire.type_hash(msgtype)

        def on_sample(sample):
            try:
                if self.options.layout == "rmw_zenoh" and self.unspeakable is None and sample.attachment is not None \
                        and wire.parse_attachment(sample.attachment.to_bytes()) is None:
                    self.unspeakable = (
                        f"{topic}: its publisher writes rmw_zenoh's attachment in another form "
                        f"({len(sample.attachment.to_bytes())} bytes, not the 33 of rmw_zenoh Jazzy 0.2.4 and "
                        "later): an older rmw_zenoh, whose subscribers cannot read depthguard's outputs; not "
                        "supported")
                found = wire.key_type_hash(str(sample.key_expr))
                if found is not None and found != expected and topic not in self._warned:
                    self._warned.add(topic)
                    _LOG.warning("depthguard live: %s carries %s with type hash %s, expected %s", topic, msgtype,
                                 found, expected)
                callback(sample)
            except Exception as exc:  # noqa: BLE001 - a callback must never raise into zenoh
                self.errors.append(f"{topic}: {exc}")

        if latched and self.options.layout == "rmw_zenoh":
            # A transient-local publisher (camera_info, latched) keeps its last messages in zenoh's advanced
            # publisher cache, as rmw_zenoh does; this subscriber asks every such publisher for them, also one
            # that appears later, as rmw_zenoh's own transient-local subscribers do. Live samples come as usual.
            import zenoh.ext

            self._subscribers.append(zenoh.ext.declare_advanced_subscriber(
                self.session, key, on_sample, history=zenoh.ext.HistoryConfig(detect_late_publishers=True,
                                                                                max_samples=1)))
        else:
            self._subscribers.append(self.session.declare_subscriber(key, on_sample))
        # Counted by the publisher's side as a subscriber (kind MS): by rmw_zenoh's graph, or, in the bridge layout,
        # by the DDS reader the bridge creates when it sees the route token (volatile: a camera_info that a DDS
        # driver only latches is not received through the bridge).
        entity = _FIRST_SUBSCRIPTION + len(self._subscription_tokens)
        self._subscription_tokens.append(self.session.liveliness().declare_token(wire.entity_token(
            self.options.layout, str(self.session.info.zid()), entity, "MS", topic, msgtype, self.options.domain,
            self.distro)))

    def _on_image(self, camera: str, sample) -> None:
        counts = self.counts[camera]
        source = self.topics.cameras[camera][0]
        try:
            message = wire.deserialize(sample.payload.to_bytes(), IMAGE)
            stamp = header_seconds(message, source, camera, counts.received)
            data = image_array(message, self.rig.cameras[camera], source, counts.received)
            image = depth_image(data, self.rig.cameras[camera], timestamp=stamp)
        except DepthguardError as exc:
            counts.errors += 1
            counts.last_error = str(exc)
            return
        if self._recorder is not None:
            self._recorder.put(f"/{camera}/depth/image_raw", IMAGE, clock.time_ns(), sample.payload.to_bytes())
        attachment = wire.parse_attachment(sample.attachment.to_bytes() if sample.attachment is not None else None)
        with self._lock:
            if attachment is not None:  # rmw_zenoh numbers a publisher's messages 1, 2, ...: a gap is a loss
                if counts.sequence is not None and attachment.sequence > counts.sequence + 1:
                    counts.missed += attachment.sequence - counts.sequence - 1
                elif counts.sequence is not None and attachment.sequence <= counts.sequence:
                    counts.restarts += 1
                counts.sequence = attachment.sequence
            counts.received += 1
            counts.offset = clock.time() - image.timestamp
            if camera in self._frames:
                counts.missed += 1
            self._frames[camera] = image
        self._wake.set()

    def _on_info(self, camera: str, sample) -> None:
        counts = self.counts[camera]
        source = self.topics.cameras[camera][1]
        try:
            payload = sample.payload.to_bytes()
            message = wire.deserialize(payload, CAMERA_INFO)
            if self._recorder is not None:
                self._recorder.put(f"/{camera}/depth/camera_info", CAMERA_INFO, clock.time_ns(), payload)
            check_camera_info(message, self.rig.cameras[camera], source)
            counts.info_error = ""
        except DepthguardError as exc:
            counts.info_error = str(exc)
        counts.info_seen = True

    def _on_joints(self, sample) -> None:
        source = self.topics.joints
        try:
            payload = sample.payload.to_bytes()
            message = wire.deserialize(payload, JOINT_STATE)
            stamp = header_seconds(message, source, None, 0, what="joint state")
            if self._recorder is not None:
                self._recorder.put("/joint_states", JOINT_STATE, clock.time_ns(), payload)
            names, values = joint_state(message, source, 0)
            positions = values[self._order_of(names)]
        except (DepthguardError, KeyError) as exc:
            self.errors.append(f"{source}: {exc}")
            return
        self._joints.append((stamp, positions))
        self._joint_seen = max(self._joint_seen, stamp)
        self.joint_states += 1
        self._wake.set()

    @property
    def last(self):
        """(time, why, cameras seen) of the last answer, None before the first."""
        recent = self.recent
        return recent[-1] if recent else None

    def joints_received(self, ns: int) -> bool:
        """Whether a joint state stamped ``ns`` nanoseconds has been received (tests, tools)."""
        return any(abs(t - ns / 1e9) == 0.0 for t, _ in list(self._joints)) or self._joint_seen >= ns / 1e9

    def ready(self) -> str | None:
        """None when every camera's image and camera_info and a joint state have come and agree with the rig and
        the robot; else what is still missing or wrong (``--dry-run``), a peer that cannot be spoken to first."""
        if self.unspeakable is not None:
            return self.unspeakable
        for name, counts in self.counts.items():
            image, info = self.topics.cameras[name]
            if counts.info_error:
                return counts.info_error
            if counts.errors and not counts.received:
                return counts.last_error
            if not counts.received:
                return f"no image on {image} (camera {name})"
            if not counts.info_seen:
                return f"no camera_info on {info} (camera {name})"
        if self._joint_order is None:
            return next((e for e in self.errors if e.startswith(self.topics.joints)),
                        f"no joint state on {self.topics.joints}")
        return None

    def _order_of(self, names) -> np.ndarray:
        """Indices of the robot's joints among a message's names (extra joints, a gripper's, are ignored)."""
        names = tuple(names)
        if self._joint_order is None or self._joint_order[0] != names:
            missing = [n for n in self.robot.joint_names if n not in names]
            if missing:
                raise InputError(f"the joint state lacks the robot's joints {', '.join(missing)}",
                                 source=self.topics.joints, field="name")
            self._joint_order = (names, np.array([names.index(n) for n in self.robot.joint_names]))
        return self._joint_order[1]

    # ------------------------------------------------------------------------------------------------ the worker

    def start(self) -> None:
        self._worker.start()
        self._ready.wait()
        if self._startup_error is not None:
            raise self._startup_error
        if self._keeper is not None:  # zeros from the start, until the first answer
            self._scaling_deadline = clock.monotonic()
            self._keeper.start()

    _startup_error = None

    def close(self) -> None:
        self._stop.set()
        self._wake.set()
        if self._worker.is_alive():
            self._worker.join()
        if self._keeper is not None and self._keeper.is_alive():
            self._keeper.join()
        if self._scaling is not None:  # the last word on the factor: 0 (the stock controller keeps the last one)
            self._publish_scaling(None, why="closing")
        outputs = [p for p in (self._distances, self._status, self._diagnostics, self._scaling) if p is not None]
        for entity in [*self._subscribers, *(p.publisher for p in outputs)]:
            entity.undeclare()
        for token in [*(p.token for p in outputs), *self._subscription_tokens, self._node_token]:
            if token is not None:
                token.undeclare()
        self.session.close()
        if self._recorder is not None:
            self._recorder.close()

    def _run(self) -> None:
        from depthguard import DistanceMonitor

        try:
            monitor = DistanceMonitor(self.rig, robot=self.robot, **self.monitor_options)
            if self.ssm is not None:
                from depthguard.avoidance import SpeedScaling

                self.scaling = SpeedScaling(monitor, **self.ssm)
        except BaseException as exc:  # reported to start()'s caller
            self._startup_error = exc
            self._ready.set()
            return
        loop = FrameSetLoop(tuple(self.rig.cameras), wait=self.options.wait, idle=self.max_age)
        self._ready.set()
        out_file = open(self._out_path, "w", newline="") if self._out_path is not None else None  # noqa: SIM115
        writer = csv.writer(out_file) if out_file is not None else None
        if writer is not None:
            writer.writerow(CSV_HEADER + (["speed_factor", "reaction_ms", "starting"] if self.scaling is not None
                                          else []))
        try:
            while not self._stop.is_set():
                self._wake.wait(0.005)
                self._wake.clear()
                sets = []
                while self._joints:
                    sets += loop.add_joints(*self._joints.popleft())
                with self._lock:
                    frames, self._frames = self._frames, {}
                for name, image in sorted(frames.items(), key=lambda item: item[1].timestamp):
                    counts = self.counts[name]
                    if counts.info_error:
                        continue  # its CameraInfo disagrees with the rig: left out, named in the status
                    if not counts.info_seen:  # its first CameraInfo is still on its way: the frame waits for it
                        with self._lock:
                            self._frames.setdefault(name, image)
                        continue
                    if image.timestamp > clock.time() + config.LIVE_CLOCK_OFFSET:
                        # From the future: it would carry the loop's clock (which never goes back) ahead of the
                        # host's, and every camera's answers would wait for it. Held out; its camera goes stale.
                        counts.future += 1
                        continue
                    sets += loop.add_frame(image)
                sets += loop.tick(clock.time() - self.options.transport)
                if clock.time() >= self._next_diagnostics:
                    self._next_diagnostics = clock.time() + 1.0
                    self._publish_diagnostics(loop)
                if len(sets) > 1:  # computing fell behind: the newest set only, with the resets of those dropped
                    self.dropped += len(sets) - 1
                    reset = tuple(n for n in self.rig.cameras if any(n in fs.reset for fs in sets))
                    sets = [dataclasses.replace(sets[-1], reset=reset)]
                if sets:
                    try:
                        self._answer(monitor, loop, sets[-1], writer)
                    except Exception as exc:  # noqa: BLE001 - the loop must keep answering; the fault is kept
                        self.errors.append(f"answering the set at {sets[-1].time!r} s: {type(exc).__name__}: {exc}")
                        _LOG.exception("depthguard live: a set could not be answered")
                        self._publish_scaling(None)
                    if out_file is not None:
                        out_file.flush()
        except Exception as exc:  # noqa: BLE001 - the loop itself broke: no more answers, the deadline's zeros go on
            self.errors.append(f"the worker stopped: {type(exc).__name__}: {exc}")
            _LOG.exception("depthguard live: the worker stopped; the speed factor falls to 0 at its deadline")
        finally:
            if out_file is not None:
                out_file.close()

    def _answer(self, monitor, loop, frame_set, writer) -> None:
        try:
            # Frames age on the host's clock, less the allowance for their way here (LIVE_TRANSPORT): while the
            # node keeps up that is the set's own time, as in replay; a frame that came late is as old as it is.
            answer = answer_set(monitor, loop, frame_set, robot=self.robot,
                                now=clock.time() - self.options.transport)
        except DepthguardError as exc:
            self.errors.append(str(exc))
            self._publish_scaling(None)
            return
        if answer is None:  # no joints at all yet: the robot's points are unknown
            self._publish_scaling(None)
            return
        newest = max((image.timestamp for image in frame_set.images.values()), default=frame_set.time)
        latency = clock.time() - newest
        if latency > self.max_age:
            self.deadline_misses += 1
        self.answers += 1
        self.recent.append((frame_set.time, frame_set.why, answer.seen))
        self._publish(answer, loop)
        scaling = None
        if self.scaling is not None:  # after the distances, which do not wait for it
            scaling = self.scaling.factor(answer.prepared, answer.joints, clock=clock.time)
            self._publish_scaling(scaling)
        if writer is not None:
            extra = [] if scaling is None else [repr(scaling.factor), f"{scaling.reaction_time * 1e3:.3f}",
                                                str(scaling.starting).lower()]
            for row in answer.rows(self.robot.control_point_names):
                writer.writerow(row + [";".join(answer.seen), f"{latency * 1e3:.3f}"] + extra)

    def _publish_scaling(self, scaling, why: str = "no answer") -> None:
        """The speed factor (with ``ssm``, on ``LiveOptions.scaling_topic``): the factor of ``scaling`` (a
        ScalingAnswer), 0 for None (``why`` says why). A factor above 0 holds for ``hold`` seconds: with no newer one
        by then, :meth:`_keep_deadline` publishes 0."""
        if self._scaling is None:
            return
        from depthguard.avoidance import ScalingAnswer

        scaling = ScalingAnswer(0.0, math.inf, why) if scaling is None else scaling
        with self._scaling_lock:
            self.last_scaling = scaling
            self._scaling_deadline = clock.monotonic() + self.ssm_hold
            self._scaling.put(wire.type_store().types[SCALING_TYPE](factor=float(scaling.factor)))
            self.scaling_published += 1

    def _keep_deadline(self) -> None:
        """Publish 0 whenever ``hold`` seconds passed since the last factor (a stream of zeros while no answer comes:
        the joints or the frames stopped, or a set takes longer than hold)."""
        while not self._stop.wait(min(self.ssm_hold / 4, 0.01)):
            if clock.monotonic() >= self._scaling_deadline:
                self.deadline_zeros += 1
                self._publish_scaling(None, why="no answer within hold")

    def clock_problem(self, name: str) -> str:
        """Why camera ``name``'s clock and the host's disagree, "" when they agree (within
        ``config.LIVE_CLOCK_OFFSET``): its frames arrive with stamps older than that, or from the future."""
        offset = self.counts[name].offset
        if math.isnan(offset) or -config.CLOCK_SKEW_TOLERANCE <= offset <= config.LIVE_CLOCK_OFFSET:
            return ""
        return (f"frames arrive {offset:+.3f} s after their stamps: the camera's and the host's clocks disagree; "
                "its frames count as stale or from the future (blind, flagged) until they are synchronised (PTP, "
                "NTP or the driver's host-time stamping)")

    def _publish_diagnostics(self, loop) -> None:
        """``/diagnostics``, once a second: each camera's age, counts and clock offset, and the node's sets
        dropped and deadline misses."""
        store = wire.type_store()
        types = store.types
        status, value = types["diagnostic_msgs/msg/DiagnosticStatus"], types["diagnostic_msgs/msg/KeyValue"]
        statuses = []
        now = clock.time()
        for name in self.rig.cameras:
            counts = self.counts[name]
            frame = loop.camera(name).frame
            age = now - frame.timestamp if frame is not None else math.inf
            problem = counts.info_error or self.clock_problem(name)
            fresh = age <= self.max_age
            level = ERROR if (problem or not fresh) else OK
            message = problem or ("fresh" if fresh else ("no frame yet" if frame is None else "stale"))
            statuses.append(status(level=level, name=f"depthguard: camera {name}", message=message,
                                   hardware_id=name, values=[
                                       value(key="age_ms", value=f"{age * 1e3:.1f}"),
                                       value(key="received", value=str(counts.received)),
                                       value(key="missed", value=str(counts.missed)),
                                       value(key="restarts", value=str(counts.restarts)),
                                       value(key="from_the_future", value=str(counts.future)),
                                       value(key="clock_offset_ms", value=f"{counts.offset * 1e3:.1f}")]))
        statuses.append(status(level=WARN if self.deadline_misses else OK, name="depthguard: node",
                               message=f"{self.answers} answers", hardware_id="", values=[
                                   value(key="answers", value=str(self.answers)),
                                   value(key="sets_dropped", value=str(self.dropped)),
                                   value(key="deadline_misses", value=str(self.deadline_misses))]))
        if self.last_scaling is not None:
            level, message, pairs = speed_scaling_status(self.last_scaling)
            statuses.append(status(level=level, name="depthguard: speed scaling", message=message, hardware_id="",
                                   values=[value(key=k, value=v) for k, v in pairs]))
        self._diagnostics.put(types[STATUS_TYPE](header=ros_header(store, clock.time_ns(), ""), status=statuses))

    def _publish(self, answer, loop) -> None:
        frame_set, result, seen, named = answer.frame_set, answer.result, answer.seen, answer.named
        store = wire.type_store()
        types = store.types
        dims = [types["std_msgs/msg/MultiArrayDimension"](label="control_points", size=len(result.distance),
                                                          stride=len(result.distance))]
        layout = types["std_msgs/msg/MultiArrayLayout"](dim=dims, data_offset=0)
        self._distances.put(types[DISTANCES_TYPE](layout=layout, data=np.asarray(result.distance,
                                                                                  dtype=np.float64)))
        status = types["diagnostic_msgs/msg/DiagnosticStatus"]
        value = types["diagnostic_msgs/msg/KeyValue"]
        statuses = []
        for k, name in enumerate(self.robot.control_point_names):
            flags = answer.flags(k)
            level = ERROR if named else (WARN if flags else OK)
            statuses.append(status(level=level, name=f"depthguard: {name}",
                                   message=";".join(flags) or "ok", hardware_id="",
                                   values=[value(key="distance", value=repr(float(result.distance[k])))]))
        for name in self.rig.cameras:
            counts = self.counts[name]
            image = frame_set.images.get(name)
            age = frame_set.time - image.timestamp if image is not None else math.inf
            state = "fresh" if name in seen else ("missing" if image is None else "stale")
            problem = counts.info_error or self.clock_problem(name)
            message = state if not problem else f"{state}; {problem}"
            statuses.append(status(level=OK if name in seen else ERROR, name=f"depthguard: camera {name}",
                                   message=message, hardware_id=name,
                                   values=[value(key="age_ms", value=f"{age * 1e3:.3f}"),
                                           value(key="received", value=str(counts.received)),
                                           value(key="missed", value=str(counts.missed)),
                                           value(key="resets", value=str(loop.camera(name).resets))]))
        ns = max(0, int(round(frame_set.time * 1e9)))
        self._status.put(types[STATUS_TYPE](header=ros_header(store, ns, ""), status=statuses))
