"""The ``depthguard collide`` command, and what ``depthguard plan`` shares with it (design §10): the image-based collision test and the
wave-propagation planner on image files, as a user runs them on recorded or simulated cameras.

Both read a rig file (the cameras' intrinsics and poses; its ``workspace`` bounds the epipolar bands unless
``--workspace`` is given), the images from which each camera's reference is made (``--reference NAME=GLOB``: the
per-pixel median), one current image per camera (``--image NAME=PATH``), and the robot (a URDF file or a built-in
name) at its joints when the images were taken (``--current``). Images are 8-bit grayscale PNGs, or with ``--depth``
depth images in any format ``depthguard distance`` reads (16-bit PNG in the camera's depth_scale units, ...).

Everything a user gives is checked before any work: a camera without an image or reference, an unknown camera
name, a glob that matches nothing, joint values of the wrong count or beyond the limits end with exit status 2 and
one line naming the camera and option.
"""

from __future__ import annotations

import glob
import json
import math

import numpy as np

from depthguard import config
from depthguard.errors import InputError

HELP = ("the image-based collision test (Henrich & Gecks, docs/design.md §10): would these configurations or "
        "this motion collide with what the cameras see?")

#: The most reference images per camera (their median is taken in memory).
MAX_REFERENCE_IMAGES = 200



def add_options(parser, *, plan: bool) -> None:
    """The options ``collide`` and ``plan`` share, then each one's own."""
    parser.add_argument("--rig", required=True, help="rig YAML file: the cameras (design §2)")
    parser.add_argument("--reference", action="append", required=True, metavar="NAME=GLOB",
                        help="images of camera NAME without obstacles, the robot in several configurations (their "
                             "per-pixel median is the reference); a glob, quoted; repeat for every camera")
    parser.add_argument("--reference-joints", metavar="VALUES;VALUES;...", default=None,
                        help="the robot's joints in each reference image, in the order of the sorted file names "
                             "(the same count for every camera): the reference then leaves the robot out wherever "
                             "another image shows the room behind it")
    parser.add_argument("--image", action="append", required=True, metavar="NAME=PATH",
                        help="the current image of camera NAME; repeat for every camera")
    parser.add_argument("--robot", required=True, metavar="URDF",
                        help="the robot: a URDF file, or iiwa / panda / xarm6 (pybullet_data's models)")
    parser.add_argument("--base", metavar="X,Y,Z[,YAW]", default=None,
                        help="the robot base's position in the world, metres, and yaw about z, radians (default: "
                             "the origin)")
    parser.add_argument("--current", required=True, metavar="VALUES",
                        help="the joints when the images were taken, radians: name=value,... or the movable joints' "
                             "values in URDF order")
    parser.add_argument("--workspace", metavar="X0,Y0,Z0,X1,Y1,Z1", default=None,
                        help="the box, metres, world frame, that holds the robot and whatever may meet it (default: "
                             "the rig's workspace)")
    parser.add_argument("--tiles", metavar="ROWSxCOLS", default="64x64",
                        help="the difference images' tiles per camera (default 64x64, the paper's)")
    parser.add_argument("--theta", type=int, default=None,
                        help="the occlusion threshold: the most cameras in which the robot may hide an obstacle at "
                             "once (default: cameras - 1, no assumption; the paper used 1)")
    parser.add_argument("--unseen", choices=("occupied", "free"), default="occupied",
                        help="a configuration that meets possible obstacles (space the robot hides from a camera) "
                             "in every camera but obstacles in fewer than cameras - theta: occupied (fail-safe, "
                             "default) or free (the paper's class B)")
    parser.add_argument("--depth", action="store_true",
                        help="depth images instead of 8-bit intensity images (the depth variant)")
    parser.add_argument("--no-robot-pixels", action="store_true",
                        help="the paper's Table I: a changed tile under the robot's tile image is unknown even where "
                             "its pixels show something the robot cannot be (default: an obstacle; without it a hand "
                             "lying along a link is missed)")
    parser.add_argument("--gripped", metavar="CX,CY,CZ,HX,HY,HZ", default=None,
                        help="a work piece the robot holds: a box in the end-effector link's frame (centre and half "
                             "extents, metres), part of the robot in the images and in every test")
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")
    if plan:
        parser.add_argument("--goal", required=True, metavar="VALUES", help="the goal configuration, as --current")
        parser.add_argument("--counts", metavar="N,N,...", default=None,
                            help="values per joint of the configuration grid (default: 8,192 configurations, the "
                                 "paper's, more values for joints that move the robot further)")
        parser.add_argument("--lower", metavar="VALUES", default=None,
                            help="each joint's first grid value (default: the lower of its current and goal values "
                                 "minus 0.5 rad, within its limits and -pi)")
        parser.add_argument("--upper", metavar="VALUES", default=None,
                            help="each joint's last grid value (default: the higher of its current and goal values "
                                 "plus 0.5 rad, within its limits and pi)")
    else:
        parser.add_argument("--future", action="append", default=[], metavar="VALUES",
                            help="a configuration to test, as --current; repeatable")
        parser.add_argument("--motion", metavar="VALUES;VALUES;...", default=None,
                            help="a motion to test as a whole (its swept volume): configurations joined by straight "
                                 "lines in joint space, separated by ';'")


def _pairs(items, option: str, cameras) -> dict:
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name or not value:
            raise InputError(f"{option} takes NAME=VALUE, got {item!r}")
        if name not in cameras:
            raise InputError(f"{option}: no camera {name!r} in the rig (cameras: {', '.join(cameras)})", camera=name)
        if name in out:
            raise InputError(f"{option} names camera {name!r} twice", camera=name)
        out[name] = value
    missing = [name for name in cameras if name not in out]
    if missing:
        raise InputError(f"{option} is missing for camera(s) {', '.join(missing)}: every camera of the rig takes "
                         "part", camera=missing[0])
    return out


def _numbers(text: str, count: int, option: str) -> list[float]:
    try:
        values = [float(x) for x in text.split(",")]
    except ValueError:
        raise InputError(f"{option}: not {count} comma-separated numbers: {text!r}") from None
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise InputError(f"{option}: expected {count} finite numbers, got {text!r}")
    return values


def _robot(args):
    from depthguard.cli.options import parse_base
    from depthguard.robots import RobotModel

    kwargs = {}
    if args.base is not None:
        kwargs["T_world_base"] = parse_base(args.base)
    if args.robot in ("iiwa", "panda", "xarm6"):
        robot = RobotModel.builtin(args.robot)
        return robot.with_base(kwargs["T_world_base"]) if kwargs else robot
    return RobotModel.from_urdf(args.robot, **kwargs)


def joint_values(robot, text: str, option: str) -> np.ndarray:
    from depthguard.cli.options import parse_joints

    values = parse_joints(text, option)  # its errors name the option
    try:
        return robot.joint_vector(values)
    except InputError as exc:
        raise InputError(f"{option}: {exc.message}") from None


def _read(path: str, camera, depth: bool) -> np.ndarray:
    from depthguard.depth import read_depth_file, read_intensity_png

    return read_depth_file(path, camera) if depth else read_intensity_png(path, camera)


def prepare(args):
    """(tester, test, robot, current joints, piece) from the shared options: the reference set and the current
    images observed. ``tester`` answers ``test(q)`` and ``test_motion(path)``: the :class:`ImageCollisionTest`, or
    with ``--gripped`` a :class:`ReferenceUpdate` holding the piece (``piece``, else None) as part of the robot."""
    from depthguard.cameras import load_rig
    from depthguard.collision import ImageCollisionTest, ReferenceUpdate
    from depthguard.scenes import Box

    rig = load_rig(args.rig)
    cameras = rig.cameras
    references = _pairs(args.reference, "--reference", cameras)
    images = _pairs(args.image, "--image", cameras)
    robot = _robot(args)
    current = joint_values(robot, args.current, "--current")
    if args.workspace is not None:
        values = _numbers(args.workspace, 6, "--workspace")
        workspace = [values[:3], values[3:]]
    elif rig.workspace is not None:
        workspace = rig.workspace
    else:
        raise InputError("the rig has no workspace: give --workspace X0,Y0,Z0,X1,Y1,Z1 (metres)")
    rows, sep, cols = args.tiles.partition("x")
    if not sep or not rows.strip().isdigit() or not cols.strip().isdigit():
        raise InputError(f"--tiles takes ROWSxCOLS, e.g. 64x64, got {args.tiles!r}")
    test = ImageCollisionTest(rig, robot, workspace, tiles=(int(rows), int(cols)), theta=args.theta,
                              images="depth" if args.depth else "intensity", unseen=args.unseen,
                              robot_pixels=not args.no_robot_pixels)
    stacks = {}
    for name, pattern in references.items():
        paths = sorted(glob.glob(pattern))
        if not paths:
            raise InputError(f"--reference {name}={pattern}: no file matches", camera=name)
        if len(paths) > MAX_REFERENCE_IMAGES:
            raise InputError(f"--reference {name}={pattern}: {len(paths)} files, at most {MAX_REFERENCE_IMAGES}",
                             camera=name)
        stacks[name] = [_read(path, cameras[name], args.depth) for path in paths]
    joints = None
    if args.reference_joints is not None:
        joints = [joint_values(robot, text, "--reference-joints") for text in args.reference_joints.split(";")
                  if text.strip()]
        for name, stack in stacks.items():
            if len(stack) != len(joints):
                raise InputError(f"--reference-joints gives {len(joints)} configurations, --reference {name} "
                                 f"{len(stack)} images", camera=name)
    test.set_reference(stacks, joints)
    frames = {name: _read(path, cameras[name], args.depth) for name, path in images.items()}
    if args.gripped is None:
        test.observe(frames, current)
        return test, test, robot, current, None
    values = _numbers(args.gripped, 6, "--gripped")
    if not all(0.0 < h <= config.COORDINATE_LIMIT for h in values[3:]):
        raise InputError(f"--gripped: half extents must be > 0 metres, got {args.gripped!r}")
    piece = Box(tuple(values[:3]), tuple(values[3:]))
    update = ReferenceUpdate(test)
    update.gripped(piece)
    update.step(frames, current)  # observes with the piece as part of the robot (nothing to update)
    return update, test, robot, current, piece


def _verdict_json(test, v, **extra) -> dict:
    cameras = {}
    for k, name in enumerate(test.names):
        gain = test.gains[k] if k < len(test.gains) else 1.0
        # pixels the robot covered in every reference image (its base at least; null without --reference-joints)
        unreferenced = None if test.unreferenced is None else \
            int(np.count_nonzero(test.unreferenced[k])) if test.unreferenced[k] is not None else 0
        cameras[name] = {"obstacle": v.obstacle[k], "possible": v.possible[k],
                         "light_gain": None if not math.isfinite(gain) else round(gain, 4),
                         "unreferenced_pixels": unreferenced}
    return {"collision": v.collision, "class": v.klass, "robot_shell": v.shell, **extra, "cameras": cameras}


def run(args) -> int:
    """``depthguard collide``: one verdict per ``--future`` configuration, then one for ``--motion``."""
    tester, test, robot, _, _ = prepare(args)
    if not args.future and args.motion is None:
        raise InputError("nothing to test: give --future VALUES (repeatable) and/or --motion")
    results = []
    for text in args.future:
        q = joint_values(robot, text, "--future")
        results.append(("future", text, _verdict_json(test, tester.test(q), kind="future")))
    if args.motion is not None:
        path = [joint_values(robot, text, "--motion") for text in args.motion.split(";") if text.strip()]
        if not path:
            raise InputError("--motion: no configurations")
        samples = len(test.projector.samples(np.array(path)))
        results.append(("motion", args.motion, _verdict_json(test, tester.test_motion(np.array(path)),
                                                             kind="motion", samples=samples)))
    if args.json:
        print(json.dumps([r for _, _, r in results]))
        return 0
    print(f"{'test':7s} {'collision':9s} {'class':5s} cameras (obstacle/possible)   configuration")
    for kind, text, r in results:
        flags = " ".join(f"{name}:{'O' if c['obstacle'] else '-'}{'P' if c['possible'] else '-'}"
                         for name, c in r["cameras"].items())
        print(f"{kind:7s} {str(r['collision']):9s} {r['class']:5s} {flags:28s} {text}")
    return 0


def add_arguments(parser) -> None:
    add_options(parser, plan=False)
