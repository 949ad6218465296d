"""What the commands share: the argument parser, number options checked where they are parsed, joint values and
robot names."""

from __future__ import annotations

import argparse
import math

from depthguard import config
from depthguard.errors import InputError


class Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (no usage dump) and exit status 2, prefixed with the program's name."""

    def error(self, message):
        self.exit(2, f"{self.prog.split()[0]}: error: {message}\n")


def real_option(minimum: float, maximum: float, unit: str, above_minimum: bool = False):
    """An argparse type: a finite number in [minimum, maximum] (``(minimum, maximum]`` with ``above_minimum``).
    argparse reports a refusal as one line naming the option."""

    def number(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        low_ok = value > minimum if above_minimum else value >= minimum
        if not (math.isfinite(value) and low_ok and value <= maximum):
            low = f"{'>' if above_minimum else '>='} {minimum:g}"
            bounds = f"in {'(' if above_minimum else '['}{minimum:g}, {maximum:g}]" if math.isfinite(maximum) else low
            raise argparse.ArgumentTypeError(f"must be a finite number of {unit} {bounds}, got {text!r}")
        return value

    return number


def whole_option(minimum: int, maximum: int):
    """An argparse type: a whole number in [minimum, maximum]."""

    def whole(text: str) -> int:
        try:
            value = int(text.strip()) if len(text) <= 40 else None
        except ValueError:
            value = None
        if value is None or not minimum <= value <= maximum:
            shown = text if len(text) <= 40 else text[:37] + "..."
            raise argparse.ArgumentTypeError(f"must be a whole number in [{minimum}, {maximum}], got {shown!r}")
        return value

    return whole


#: --rho and the like: metres in [config.RHO_MIN, config.RHO_MAX].
METRES = real_option(config.RHO_MIN, config.RHO_MAX, "metres")
#: The depth grid's --d-min, --d-max, --delta-d: metres in (0, config.COORDINATE_LIMIT].
GRID_METRES = real_option(0.0, config.COORDINATE_LIMIT, "metres", above_minimum=True)
#: A speed: metres/second in (0, config.COORDINATE_LIMIT].
SPEED = real_option(0.0, config.COORDINATE_LIMIT, "metres/second", above_minimum=True)
SECONDS = real_option(0.0, config.MAX_AGE_LIMIT, "seconds", above_minimum=True)


#: Options whose values may start with a minus sign (joint values, coordinates): "--current -0.3,0.2" is read as
#: "--current=-0.3,0.2" (argparse would take "-0.3,0.2" for an option).
_NUMBER_LIST_OPTIONS = ("--current", "--future", "--goal", "--motion", "--lower", "--upper", "--joints", "--base",
                        "--workspace", "--reference-joints")


def attach_number_lists(argv: list[str]) -> list[str]:
    """``argv`` with a number list that starts with a minus sign joined to its option (``--current=-0.3,0.2``)."""
    out, i = [], 0
    while i < len(argv):
        if argv[i] in _NUMBER_LIST_OPTIONS and i + 1 < len(argv) and argv[i + 1][:1] == "-" and \
                argv[i + 1][1:2] in tuple("0123456789.") and len(argv[i + 1]) > 1:
            out.append(f"{argv[i]}={argv[i + 1]}")
            i += 2
        else:
            out.append(argv[i])
            i += 1
    return out


def parse_joints(text: str, option: str = "--joints"):
    """``"a=0.1,b=0.2"`` -> {"a": 0.1, "b": 0.2}; ``"0.1,0.2"`` -> [0.1, 0.2]. InputError naming ``option`` if
    malformed."""
    items = [item.strip() for item in text.split(",") if item.strip()]
    if not items:
        raise InputError(f"{option}: no values in {text!r}")
    named = ["=" in item for item in items]
    if any(named) and not all(named):
        raise InputError(f"{option} mixes name=value and plain values: {text!r}")
    pairs = [item.split("=", 1) if "=" in item else (None, item) for item in items]
    try:
        values = [float(value) for _, value in pairs]
    except ValueError:
        raise InputError(f"{option}: not numbers: {text!r}") from None
    if not all(math.isfinite(value) for value in values):
        raise InputError(f"{option}: values must be finite numbers (radians, or metres for prismatic joints): "
                         f"{text!r}")
    if not all(named):
        return values
    names = [name.strip() for name, _ in pairs]
    if len(set(names)) != len(names):
        raise InputError(f"{option} names a joint twice: {text!r}")
    return dict(zip(names, values))


def load_robot(name: str, base: str | None = None):
    """``--robot``: 'iiwa' or 'panda' (the models shipped with pybullet_data) or a URDF file; ``base``: ``--base``
    (:func:`parse_base`), where the robot's base stands in the world."""
    from depthguard.robots import RobotModel

    model = {"iiwa": RobotModel.default, "panda": RobotModel.panda}.get(name)
    robot = model() if model is not None else RobotModel.from_urdf(name)
    return robot if base is None else robot.with_base(parse_base(base))


def add_base_option(parser) -> None:
    """``--base X,Y,Z[,YAW]``: the robot base's pose in the world."""
    parser.add_argument("--base", metavar="X,Y,Z[,YAW]", default=None,
                        help="the robot base's position in the world, metres, and yaw about z, radians (default: "
                             "the world origin)")


def parse_base(text: str):
    """``--base``: "X,Y,Z" or "X,Y,Z,YAW" (finite metres, radians) -> the (4, 4) pose of the base in the world."""
    from depthguard.transforms import yaw_pose

    try:
        values = [float(x) for x in text.split(",")] if text.count(",") in (2, 3) else []
    except ValueError:
        values = []
    if len(values) not in (3, 4) or not all(math.isfinite(v) and abs(v) <= config.COORDINATE_LIMIT for v in values):
        raise InputError(f"--base: expected X,Y,Z or X,Y,Z,YAW (finite metres, radians), got {text!r}")
    return yaw_pose(values[:3], values[3] if len(values) == 4 else 0.0)


def robot_and_joints(args):
    """(RobotModel or None, joint positions or None) from ``--robot`` and ``--joints``."""
    if args.robot is None:
        if args.joints is not None:
            raise InputError("--joints needs --robot")
        return None, None
    if args.joints is None:
        raise InputError("--robot needs --joints (the robot's joint positions when the images were taken)")
    robot = load_robot(args.robot)
    return robot, robot.joint_vector(parse_joints(args.joints))


def add_monitor_options(parser, memory: bool = False) -> None:
    """The monitor's settings a command passes on: ``--rho``, ``--aggregate``, ``--invalid``; with ``memory``
    (``replay``, ``live``) also ``--max-age`` and ``--v-max`` / ``--no-memory``. :func:`monitor_options` reads them
    back as :class:`~depthguard.DistanceMonitor`'s keyword arguments.

    ``replay`` and ``live`` write and publish distances and flags, no direction: their ``--aggregate`` defaults to
    ``min``, whose distances are hybrid's (design §6) and whose first query on a new set of fused frames classifies
    fewer cells (it stops at the nearest obstacle found so far); ``hybrid`` stays one option away."""
    parser.add_argument("--rho", type=METRES, default=config.DEFAULT_RHO,
                        help=f"surveillance radius, metres, in [{config.RHO_MIN:g}, {config.RHO_MAX:g}]")
    if memory:
        parser.add_argument("--aggregate", choices=config.AGGREGATES, default="min",
                            help="min (default: the distances, which are hybrid's), mean, or hybrid (hybrid's "
                                 "direction is neither written nor published)")
    else:
        parser.add_argument("--aggregate", choices=config.AGGREGATES, default=config.DEFAULT_AGGREGATE)
    parser.add_argument("--invalid", choices=config.INVALID_POLICIES, default=config.DEFAULT_INVALID,
                        help="pixels without a measurement: occupied (fail-safe), neighbors, free")
    if not memory:
        return
    parser.add_argument("--max-age", type=SECONDS, default=config.DEFAULT_MAX_AGE,
                        help="a camera whose frame is older than this many seconds at an answer sees nothing "
                             f"(stale, flagged; default {config.DEFAULT_MAX_AGE:g})")
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--v-max", type=SPEED, default=config.FREESPACE_V_MAX,
                       help="the free-space memory's fastest person, metres/second (default "
                            f"{config.FREESPACE_V_MAX:g}, ISO 13855's hand speed; docs/design.md §8a); the memory "
                            "needs a workspace in the rig")
    group.add_argument("--no-memory", action="store_true",
                       help="do not remember free space: only what the cameras see now clears space")


def monitor_options(args) -> dict:
    """:class:`~depthguard.DistanceMonitor`'s keyword arguments from :func:`add_monitor_options`' options."""
    options = dict(rho=args.rho, aggregate=args.aggregate, invalid=args.invalid)
    if hasattr(args, "max_age"):
        options.update(max_age=args.max_age, memory=not args.no_memory, v_max=args.v_max)
    return options
