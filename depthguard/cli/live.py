"""``depthguard live``: depth frames and joint states from ROS 2 topics through zenoh, distances and status back
(design §12b). Needs the ``live`` extra (``eclipse-zenoh``); nothing comes from ROS."""

from __future__ import annotations

import re
import sys
import time
from pathlib import Path

from depthguard import config
from depthguard.cli.options import (SECONDS, add_base_option, add_monitor_options, load_robot, monitor_options,
                                    real_option)

HELP = ("listen to ROS 2 depth cameras and joint states through zenoh (rmw_zenoh or zenoh-bridge-ros2dds) and "
        "publish distances and status (docs/design.md §12b)")

CAPABILITY = real_option(0.0, config.SSM_INTRUSION_LIMIT, "metres", above_minimum=True)
HOLD = real_option(0.0, 10.0, "seconds")

_CAMERA = re.compile(r"(?P<name>[^=]+)=(?P<image>[^:]+)(?::(?P<info>.+))?")


def add_arguments(parser) -> None:
    parser.add_argument("--rig", required=True, metavar="RIG.yaml", help="the cameras (docs/design.md §2)")
    parser.add_argument("--robot", default="iiwa", metavar="URDF",
                        help="the robot: a URDF file, or 'iiwa' / 'panda' (pybullet_data's models; default iiwa)")
    parser.add_argument("--camera", action="append", default=[], metavar="NAME=IMAGE_TOPIC[:INFO_TOPIC]",
                        help="a camera of the rig and its topics (default for every camera: /NAME/depth/image_raw "
                             "and its sibling camera_info)")
    parser.add_argument("--joint-states", default="/joint_states", metavar="TOPIC",
                        help="sensor_msgs/msg/JointState (default /joint_states); joints other than the robot's "
                             "are ignored")
    parser.add_argument("--connect", action="append", metavar="ENDPOINT",
                        help="the zenoh router (or listening peer) to connect to, as client (default "
                             "tcp/127.0.0.1:7447, rmw_zenoh's router); never listens")
    parser.add_argument("--layout", choices=("rmw_zenoh", "bridge"), default="rmw_zenoh",
                        help="rmw_zenoh's keys, hashes and attachments, or zenoh-bridge-ros2dds' bare topic names")
    parser.add_argument("--ros-distro", choices=("auto", "jazzy", "humble"), default="auto",
                        help="rmw_zenoh's type-hash style: Jazzy and later (RIHS01 hashes) or Humble "
                             "(TypeHashNotSupported); auto: the one the peers' liveliness tokens use (default)")
    parser.add_argument("--domain", type=int, default=None,
                        help="ROS domain id, 0-232 (rmw_zenoh layout; default: $ROS_DOMAIN_ID, else 0)")
    add_base_option(parser)
    add_monitor_options(parser, memory=True)
    ssm = parser.add_argument_group("speed scaling (--ssm; docs/design.md §9, §12b)")
    ssm.add_argument("--ssm", action="store_true",
                     help="also publish /depthguard/speed_scaling (control_msgs/msg/SpeedScalingFactor): speed and "
                          "separation monitoring's factor for a controller that scales its trajectory")
    ssm.add_argument("--detection-capability", type=CAPABILITY, metavar="D",
                     help="metres: with --ssm, SSM's distances leave out what is thinner than D (ISO 13855's C is "
                          f"taken for it; default {config.SSM_DETECTION_CAPABILITY:g})")
    ssm.add_argument("--ssm-joint-speed", metavar="RAD_S[,...]",
                     help="the most each joint of the trajectory moves at factor 1, rad/s: one number or one per "
                          "joint (default: the URDF's velocity limits)")
    ssm.add_argument("--ssm-braking", metavar="RAD_S2[,...]",
                     help="the deceleration each joint is sure of, rad/s^2: one number or one per joint (default "
                          f"{config.JOINT_ACCELERATION:g})")
    ssm.add_argument("--speed-scaling-topic", metavar="TOPIC",
                     help="where the factor goes (default /depthguard/speed_scaling); joint_trajectory_controller "
                          "listens on /<controller>/speed_scaling_input")
    ssm.add_argument("--ssm-hold", type=HOLD, default=config.SSM_HOLD, metavar="S",
                     help="seconds the controller applies a factor with no newer one before it stops (its "
                          f"watchdog; counted in the reaction time; default {config.SSM_HOLD:g})")
    parser.add_argument("--out", metavar="RESULTS.csv",
                        help="also write one row per point per answer: replay's columns, cameras, latency_ms")
    parser.add_argument("--record", metavar="DIR",
                        help="also write the messages received, unchanged, and the outputs into a new ROS 2 bag "
                             "folder DIR (MCAP, with rig.yaml), which replay reads back to the same answers")
    parser.add_argument("--duration", type=SECONDS, metavar="S", help="stop after S seconds (default: run until ^C)")
    parser.add_argument("--dry-run", action="store_true",
                        help="check the topics, each CameraInfo against the rig and the joint names, then exit: 0 "
                             "when all agree, 2 with the reason")
    parser.add_argument("--dry-run-wait", type=SECONDS, default=5.0, metavar="S",
                        help="how long --dry-run waits for every topic (default 5 s)")


def topics_of(args, rig):
    """The :class:`~depthguard.live.Topics` from ``--camera`` and ``--joint-states``."""
    from depthguard.errors import InputError
    from depthguard.live import Topics, wire

    cameras = {name: (Topics.default_image(name), Topics.info_of(Topics.default_image(name))) for name in rig.cameras}
    for text in args.camera:
        match = _CAMERA.fullmatch(text)
        if match is None:
            raise InputError(f"--camera {text!r}: give NAME=IMAGE_TOPIC[:INFO_TOPIC]", field="camera")
        name = match["name"]
        if name not in rig.cameras:
            raise InputError(f"--camera {text!r}: the rig has no camera {name!r} (cameras: "
                             f"{', '.join(rig.cameras)})", camera=name, field="camera")
        image = wire.ros_name(match["image"])  # ~ and relative names as ROS 2 expands them in /depthguard
        cameras[name] = (image, wire.ros_name(match["info"]) if match["info"] else Topics.info_of(image))
    return Topics(cameras, wire.ros_name(args.joint_states))


def per_joint(text: str | None, option: str, robot):
    """``--ssm-joint-speed`` / ``--ssm-braking``: None, one number for every joint, or one per joint of ``robot``;
    each finite and > 0. InputError naming the option otherwise."""
    import math

    from depthguard.errors import InputError

    if text is None:
        return None
    try:
        values = [float(x) for x in text.split(",")]
    except ValueError:
        values = []
    if len(values) not in (1, robot.n_joints) or not all(math.isfinite(v) and v > 0.0 for v in values):
        raise InputError(f"{option}: expected one number > 0 or {robot.n_joints} of them (one per joint of "
                         f"{robot.name}), got {text!r}", field=option.lstrip("-").replace("-", "_"))
    return values[0] if len(values) == 1 else values


def ssm_options(args, robot) -> dict | None:
    """:class:`~depthguard.live.LiveNode`'s ``ssm`` from the --ssm options (None without --ssm)."""
    from depthguard.errors import InputError

    if not args.ssm:
        for name in ("detection_capability", "ssm_joint_speed", "ssm_braking", "speed_scaling_topic"):
            if getattr(args, name) is not None:
                raise InputError(f"--{name.replace('_', '-')} needs --ssm", field=name)
        return None
    return dict(joint_speed=per_joint(args.ssm_joint_speed, "--ssm-joint-speed", robot),
                braking=per_joint(args.ssm_braking, "--ssm-braking", robot), hold=args.ssm_hold)


def ros_domain(given: int | None) -> int:
    """The ROS domain id: ``--domain`` when given, else ``ROS_DOMAIN_ID`` as ROS 2 reads it (unset or empty: 0),
    checked (0-232) with an error naming whichever it came from."""
    import os

    from depthguard.errors import InputError
    from depthguard.validation import short_repr

    if given is not None:
        field, text = "domain", str(given)
    else:
        field, text = "ROS_DOMAIN_ID", os.environ.get("ROS_DOMAIN_ID", "").strip()
        if not text:
            return 0
    if not (text.isascii() and text.isdigit() and len(text) <= 3) or not 0 <= int(text) <= 232:  # not "²", 5000 digits
        raise InputError(f"{'--domain' if given is not None else 'ROS_DOMAIN_ID'} must be a ROS domain id, a whole "
                         f"number in [0, 232], got {short_repr(text)}", field=field)
    return int(text)


def run(args) -> int:
    from depthguard.cameras import load_rig
    from depthguard.errors import InputError

    try:
        import zenoh  # noqa: F401 - the live extra
    except ImportError:
        raise InputError("depthguard live needs the live extra: pip install 'depthguard[live]' (eclipse-zenoh)") \
            from None
    from depthguard.live import wire
    from depthguard.live import LiveNode, LiveOptions

    rig = load_rig(args.rig)
    robot = load_robot(args.robot, args.base)
    topics = topics_of(args, rig)
    args.domain = ros_domain(args.domain)
    for image, info in topics.cameras.values():
        wire.data_key(image, "sensor_msgs/msg/Image", args.layout, args.domain)  # names checked before connecting
        wire.data_key(info, "sensor_msgs/msg/CameraInfo", args.layout, args.domain)
    scaling_topic = wire.ros_name(args.speed_scaling_topic or LiveOptions.scaling_topic)
    wire.data_key(scaling_topic, "control_msgs/msg/SpeedScalingFactor", args.layout, args.domain)
    options = LiveOptions(layout=args.layout, domain=args.domain, connect=args.connect or ["tcp/127.0.0.1:7447"],
                          scaling_topic=scaling_topic, distro=args.ros_distro)
    if args.record is not None and Path(args.record).exists():
        raise InputError(f"--record {args.record}: exists already; a recording is written into a new folder",
                         field="record")
    ssm = ssm_options(args, robot)
    monitored = monitor_options(args)
    scaling = None
    if ssm is not None:  # SSM's distances: the detectable space of that capability (design §9)
        from depthguard import DistanceMonitor
        from depthguard.avoidance import SpeedScaling

        monitored["detection_capability"] = args.detection_capability or config.SSM_DETECTION_CAPABILITY
        # Checked here, before connecting (the node makes its own monitor on its thread, where its OpenGL context
        # lives): the detection capability with what the concessions hide, the joint speeds and braking.
        scaling = SpeedScaling(DistanceMonitor(rig, robot=robot, **monitored), **ssm)
    node = LiveNode(rig, robot, topics, options, monitored, out=None if args.dry_run else args.out,
                    record=None if args.dry_run else args.record, ssm=ssm)
    try:
        if args.dry_run:
            deadline = time.monotonic() + args.dry_run_wait
            problem = node.ready()
            while problem is not None and time.monotonic() < deadline:
                time.sleep(0.05)
                problem = node.ready()
            if problem is not None:
                print(f"depthguard live: dry run: {problem}", file=sys.stderr)
                return 2
            print(f"depthguard live: dry run: {len(topics.cameras)} cameras and {topics.joints} agree with the rig "
                  f"and {robot.name}")
            return 0
        node.start()
        outputs = "/depthguard/distances and /depthguard/status" + (f", {scaling_topic}" if ssm else "")
        print(f"depthguard live: listening ({args.layout}, {', '.join(options.connect)}) for "
              f"{', '.join(rig.cameras)}; publishing {outputs}", file=sys.stderr, flush=True)
        if scaling is not None:
            print(f"depthguard live: speed scaling: C {scaling.params.intrusion:g} m ({scaling.hidden}), T_r >= "
                  f"{scaling.extra_time:g} s + the frames' age, stopping within "
                  f"{scaling.ssm.stopping_time(scaling.joint_speed):.3f} s: the robot stops where a surface point is "
                  f"within {scaling.at_rest(scaling.extra_time + 0.05):.2f} m of possibly occupied space",
                  file=sys.stderr, flush=True)
        start = time.monotonic()
        import signal

        def terminate(signum, frame):  # SIGTERM (ros2 launch, systemd, docker stop): close as on Ctrl-C, factor 0
            raise KeyboardInterrupt

        previous = signal.signal(signal.SIGTERM, terminate)
        try:
            while args.duration is None or time.monotonic() - start < args.duration:
                time.sleep(0.05)
        except KeyboardInterrupt:
            pass
        finally:
            signal.signal(signal.SIGTERM, previous)
    finally:
        node.close()
    print(f"depthguard live: {node.answers} answers, {node.dropped} sets dropped, {node.deadline_misses} deadline "
          f"misses; frames received " + ", ".join(f"{n} {c.received} (missed {c.missed})"
                                                    for n, c in node.counts.items()), file=sys.stderr)
    return 0
