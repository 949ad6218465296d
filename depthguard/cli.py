"""The ``depthguard`` command line: the commands a cell runs (the lab's simulations and experiments are
``depthguard-lab``'s).

    depthguard distance --rig RIG.yaml --depth NAME=PATH --points POINTS [--rho 0.4] [--aggregate hybrid] ...
    depthguard build-map --rig RIG.yaml [--principal NAME] [--d-min M --d-max M --delta-d M] --out MAP
    depthguard replay RECORDING --out RESULTS.csv [--robot URDF|iiwa|panda] [--points POINTS] [--rho 0.4] ...
    depthguard coverage --rig RIG.yaml [--robot URDF|iiwa|panda] [--trajectory joint_states.csv] [--rho 0.4] ...
    depthguard collide --rig RIG.yaml --reference NAME=GLOB ... --image NAME=PATH ... --robot URDF|iiwa|panda|xarm6
                       --current VALUES --future VALUES [...] [--motion "VALUES;VALUES"] [--theta N] [--json]
    depthguard plan --rig RIG.yaml --reference NAME=GLOB ... --image NAME=PATH ... --robot URDF --current VALUES
                    --goal VALUES [--counts N,N,...] [--json]
    depthguard warmup

Bad input ends with exit status 2 and one line on standard error that says what is wrong (exit status 3 means a bug).
Numeric options are checked where they are parsed (``inf``, ``nan`` and ``1e999`` are refused), in these ranges:

- ``--rho``: metres in [``config.RHO_MIN``, ``config.RHO_MAX``] (``coverage``: in ``coverage.RHO_RANGE``);
- ``--d-min``, ``--d-max``, ``--delta-d``: metres in (0, ``config.COORDINATE_LIMIT``], with d-max > d-min and at
  most ``config.DEPTH_GRID_MAX_CELLS`` cells;
- ``--joints``: finite numbers (radians, or metres for prismatic joints).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys

from depthguard import config
from depthguard._options import parse_joints
from depthguard.errors import DepthguardError


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


_METRES = real_option(config.RHO_MIN, config.RHO_MAX, "metres")
_GRID_METRES = real_option(0.0, config.COORDINATE_LIMIT, "metres", above_minimum=True)
_SPEED = real_option(0.0, config.COORDINATE_LIMIT, "metres/second", above_minimum=True)


def _build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="depthguard", description="Distances between a robot and unknown obstacles, computed in "
                                                     "the depth space of calibrated depth cameras.")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=Parser)

    distance = commands.add_parser("distance", help="distances from control points to what the cameras see")
    distance.add_argument("--rig", required=True, help="rig YAML file (docs/design.md §2)")
    distance.add_argument("--depth", action="append", required=True, metavar="NAME=PATH",
                          help="depth image of camera NAME (16-bit PNG/PGM in depth_scale units, .npy, float TIFF)")
    distance.add_argument("--points", required=True, help="control points: CSV with header x,y,z or JSON list of "
                                                          "[x, y, z] (world frame, metres)")
    distance.add_argument("--rho", type=_METRES, default=config.DEFAULT_RHO,
                          help=f"surveillance radius, metres, in [{config.RHO_MIN:g}, {config.RHO_MAX:g}]")
    distance.add_argument("--aggregate", choices=config.AGGREGATES, default=config.DEFAULT_AGGREGATE)
    distance.add_argument("--invalid", choices=config.INVALID_POLICIES, default=config.DEFAULT_INVALID,
                          help="pixels without a measurement: occupied (fail-safe), neighbors, free")
    distance.add_argument("--unseen", choices=config.UNSEEN_POLICIES, default=config.DEFAULT_UNSEEN,
                          help="space no camera observes: occupied (fail-safe) or free")
    distance.add_argument("--method", choices=config.METHODS, default=config.DEFAULT_METHOD,
                          help="exact (design) or paper (the 2015 paper's unsafe formulas, for comparison)")
    distance.add_argument("--robot", metavar="URDF",
                          help="filter this robot out of the images (a URDF file, or 'iiwa' / 'panda' for the models "
                               "shipped with pybullet_data); needs --joints")
    distance.add_argument("--joints", metavar="VALUES",
                          help="the robot's joint positions when the images were taken, radians: name=value,... or "
                               "the movable joints' values in URDF order, comma-separated")
    distance.add_argument("--principal", action="append", metavar="NAME",
                          help="with several --depth: a principal camera of the depth grid (repeatable; default: "
                               "the rig's principal, else its first camera)")
    distance.add_argument("--map", action="append", metavar="MAP",
                          help="a depth grid map written by build-map (repeatable); maps not given are built from "
                               "the rig")
    distance.add_argument("--json", action="store_true", help="print one JSON array, one object per point")

    build = commands.add_parser("build-map", help="build the depth grid map of a rig's principal camera (design "
                                                  "section 8) and save it")
    build.add_argument("--rig", required=True, help="rig YAML file")
    build.add_argument("--principal", help="principal camera (default: the rig's principal, else its first camera)")
    build.add_argument("--d-min", type=_GRID_METRES, default=None,
                       help="grid start, metres (default: from the rig, as the monitor's: where the principal sees the "
                            "rig's workspace, within its depth_range)")
    build.add_argument("--d-max", type=_GRID_METRES, default=None, help="grid end, metres (default: from the rig)")
    build.add_argument("--delta-d", type=_GRID_METRES, default=None,
                       help=f"cell depth, metres (default {config.DEPTH_GRID_DELTA_D:g}; at most "
                            f"{config.DEPTH_GRID_MAX_CELLS} cells in all)")
    build.add_argument("--out", required=True, help="map file to write (.npz)")

    replay = commands.add_parser("replay", help="run a recording (folder or ROS 2 bag, docs/design.md §12a) through the "
                                                "monitor in capture-time order, one answer per set of frames")
    replay.add_argument("recording", metavar="RECORDING", help="a recording folder (rig.yaml, frames.csv, depth/, "
                                                                "joint_states.csv), a rosbag2 folder or an .mcap file")
    replay.add_argument("--out", required=True, metavar="RESULTS.csv",
                        help="results: time,frame,control_point,x,y,z,distance,blind_distance,flags")
    replay.add_argument("--robot", default="iiwa", metavar="URDF",
                        help="the recorded robot, filtered out of the images: a URDF file, or 'iiwa' / 'panda' for the "
                             "models shipped with pybullet_data (default: iiwa); its joints must be the recording's")
    replay.add_argument("--points", metavar="POINTS",
                        help="fixed control points (CSV x,y,z or JSON, world frame, metres), named p0, p1, ... "
                             "(default: the robot's control points, moving with the recorded joints)")
    replay.add_argument("--rho", type=_METRES, default=config.DEFAULT_RHO,
                        help=f"surveillance radius, metres, in [{config.RHO_MIN:g}, {config.RHO_MAX:g}]")
    replay.add_argument("--aggregate", choices=config.AGGREGATES, default=config.DEFAULT_AGGREGATE)
    replay.add_argument("--invalid", choices=config.INVALID_POLICIES, default=config.DEFAULT_INVALID,
                        help="pixels without a measurement: occupied (fail-safe), neighbors, free")
    replay.add_argument("--rig", metavar="RIG.yaml",
                        help="the rig (default: rig.yaml in the recording, the bag folder or beside the .mcap file)")
    memory = replay.add_mutually_exclusive_group()
    memory.add_argument("--v-max", type=_SPEED, default=config.FREESPACE_V_MAX,
                        help="the free-space memory's fastest person, metres/second (default "
                             f"{config.FREESPACE_V_MAX:g}, ISO 13855's hand speed; docs/design.md §8a); the memory "
                             "needs a workspace in the rig")
    memory.add_argument("--no-memory", action="store_true",
                        help="do not remember free space: only what the cameras see now clears space")
    replay.add_argument("--json", action="store_true", help="also print a JSON summary to standard output")

    coverage = commands.add_parser("coverage", help="camera placement: the space within rho of the robot that no "
                                                    "camera of a rig can clear, as fractions and a picture")
    coverage.add_argument("--rig", required=True, help="rig YAML file (docs/design.md §2)")
    coverage.add_argument("--robot", default="iiwa", metavar="URDF",
                          help="the robot: a URDF file, or 'iiwa' / 'panda' for the models shipped with pybullet_data "
                               "(default: iiwa)")
    coverage.add_argument("--trajectory", metavar="joint_states.csv",
                          help="robot poses: a CSV time,<joint names...> (a recording's joint_states.csv), at most "
                               "20 rows used, evenly spread (default: scenario B's posture and four poses along its "
                               "trajectory for the iiwa, else the zero configuration)")
    from depthguard._coverage import RHO_RANGE  # the samples fill rho around the robot: bounded

    coverage.add_argument("--rho", type=real_option(*RHO_RANGE, "metres"), default=config.DEFAULT_RHO,
                          help=f"surveillance radius, metres, in [{RHO_RANGE[0]:g}, {RHO_RANGE[1]:g}]")
    coverage.add_argument("--out", default="out/coverage", help="output folder for coverage.json and coverage.png")

    from depthguard import _collision_command as _command

    collide = commands.add_parser("collide", help="the image-based collision test (Henrich & Gecks, docs/design.md §10): "
                                                  "would these configurations or this motion collide with what the "
                                                  "cameras see?")
    _command.add_arguments(collide, plan=False)
    plan = commands.add_parser("plan", help="a collision-free path through the configuration space by wave "
                                            "propagation, every configuration judged by the image-based test")
    _command.add_arguments(plan, plan=True)

    commands.add_parser("warmup", help="compile every numba kernel that is not cached yet (after an install or an "
                                       "upgrade), so that no query has to")
    return parser


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


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = _build_parser().parse_args(attach_number_lists(argv))
    return run(lambda: _COMMANDS[args.command](args), "depthguard")


def run(command, program: str) -> int:
    """Run ``command()`` (a command's body, returning its exit status) as every depthguard command line does: a
    :class:`~depthguard.DepthguardError` (bad input) or an ``OSError`` ends with exit status 2 and one line on
    standard error, ``<program>: error: ...``; any other exception is a bug: exit status 3 and one line
    (``DEPTHGUARD_DEBUG=1`` raises it instead, with its traceback)."""
    try:
        return command()
    except DepthguardError as exc:
        print(f"{program}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"{program}: error: {exc.filename or ''}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # a bug, not bad input: still one line, the traceback on request
        if os.environ.get("DEPTHGUARD_DEBUG"):
            raise
        print(f"{program}: internal error: {type(exc).__name__}: {exc} (set DEPTHGUARD_DEBUG=1 for the traceback)",
              file=sys.stderr)
        return 3


def _warmup(args) -> int:
    from depthguard import _warmup

    return _warmup.main()


def _coverage(args) -> int:
    from depthguard import _coverage as coverage

    return coverage.main(args.rig, robot=args.robot, trajectory=args.trajectory, rho=args.rho, out=args.out)


def _collide(args) -> int:
    from depthguard import _collision_command as command

    return command.collide(args)


def _plan(args) -> int:
    from depthguard import _collision_command as command

    return command.plan(args)


def _distance(args) -> int:
    from depthguard import DistanceMonitor, load_depth, load_rig
    from depthguard._points_io import load_points
    from depthguard.errors import InputError

    rig = load_rig(args.rig)
    frames = {}
    for item in args.depth:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            raise InputError(f"--depth expects NAME=PATH, got {item!r}")
        if name in frames:
            raise InputError(f"--depth names camera {name!r} twice")
        frames[name] = load_depth(path, rig.camera(name))
    points = load_points(args.points)
    robot, joints = _robot_and_joints(args)
    from depthguard.depthgrid import load_map

    maps = {}
    for path in args.map or []:
        grid = load_map(path, rig)
        maps[grid.principal] = grid
    principals = args.principal or (list(maps) if maps else None)
    monitor = DistanceMonitor(rig, rho=args.rho, aggregate=args.aggregate, invalid=args.invalid, unseen=args.unseen,
                              method=args.method, robot=robot, principals=principals, maps=maps)
    result = monitor.query(frames, points, joints=joints)
    records = result.records(points)
    if args.json:
        print(json.dumps(records))
        return 0
    print(f"{'x':>8s} {'y':>8s} {'z':>8s} {'distance':>9s} {'direction':>26s} {'count':>6s}  flags")
    for r in records:
        d = "none" if r["distance"] is None else f"{r['distance']:.4f}"
        direction = "[" + ", ".join(f"{c:+.3f}" for c in r["direction"]) + "]"
        print(f"{r['point'][0]:8.3f} {r['point'][1]:8.3f} {r['point'][2]:8.3f} {d:>9s} {direction:>26s} "
              f"{r['count']:6d}  {','.join(r['flags']) or '-'}")
    return 0


def _build_map(args) -> int:
    import time
    from pathlib import Path

    from depthguard import load_rig
    from depthguard.depthgrid import build_map, save_map

    from depthguard.errors import InputError

    out = Path(args.out)
    if out.exists() and not out.is_file():  # a folder, a FIFO, a device: never written to
        raise InputError(f"--out {args.out}: exists and is not a regular file")
    rig = load_rig(args.rig)
    start = time.perf_counter()
    try:
        grid = build_map(rig, args.principal, d_min=args.d_min, d_max=args.d_max, delta_d=args.delta_d)
    except InputError as exc:
        if exc.field not in ("d_min", "d_max", "delta_d", "n_cells"):
            raise
        raise InputError(f"--{exc.field.replace('_', '-')}: {exc.message}") from None
    save_map(grid, args.out)
    camera = rig.cameras[grid.principal]
    print(f"depth grid of {grid.principal!r} ({camera.width}x{camera.height}x{grid.n_cells} cells, "
          f"{grid.d_min:g}-{grid.d_max:g} m) to {', '.join(grid.secondaries)}: {grid.nbytes / 1e6:.1f} MB, built in "
          f"{time.perf_counter() - start:.2f} s, written to {args.out}")
    return 0


def _replay(args) -> int:
    import csv
    from pathlib import Path

    import numpy as np

    from depthguard import DistanceMonitor
    from depthguard.errors import InputError
    from depthguard.files import atomic_write
    from depthguard.recordings import open_recording

    out = Path(args.out)
    if out.exists() and not out.is_file():  # a folder, a FIFO, a device: never written to
        raise InputError(f"--out {args.out}: exists and is not a regular file")
    recording = open_recording(args.recording, rig=args.rig)
    robot = _replay_robot(args.robot)
    names = recording.joint_names
    if set(names) != set(robot.joint_names) or len(names) != len(robot.joint_names):
        missing = [n for n in robot.joint_names if n not in names]
        unknown = [n for n in names if n not in robot.joint_names]
        raise InputError(f"the recording's joints are not the robot's ({robot.name}): "
                         + "; ".join(part for part in (f"missing {', '.join(missing)}" if missing else "",
                                                       f"not the robot's {', '.join(unknown)}" if unknown else "")
                                     if part), source=str(recording.path), field="joints")
    order = [names.index(n) for n in robot.joint_names]  # recording's joint order -> the robot's
    if args.points is not None:
        from depthguard._points_io import load_points

        fixed = load_points(args.points)
        if len(fixed) == 0:
            raise InputError(f"--points {args.points}: holds no points")
        point_names = [f"p{i}" for i in range(len(fixed))]
    else:
        fixed = None
        point_names = list(robot.control_point_names)
    monitor = DistanceMonitor(recording.rig, rho=args.rho, aggregate=args.aggregate, invalid=args.invalid,
                              robot=robot, memory=not args.no_memory, v_max=args.v_max)
    distances, flagged, answered = [], 0, 0
    with atomic_write(out, newline="") as f:  # --out appears once every set is answered
        writer = csv.writer(f)
        writer.writerow(["time", "frame", "control_point", "x", "y", "z", "distance", "blind_distance", "flags"])
        print(f"replaying {len(recording)} frame sets ...", file=sys.stderr, flush=True)
        for frame_set in recording.frame_sets():
            points = fixed if fixed is not None else \
                robot.control_point_positions(recording.joints_at(frame_set.time)[order])
            camera_joints = {camera: q[order] for camera, q in frame_set.joints.items()}
            result = monitor.query(frame_set.images, points, camera_joints=camera_joints, now=frame_set.time)
            for i, name in enumerate(point_names):
                flags = result.flags[i].names
                writer.writerow([repr(float(frame_set.time)), frame_set.frame, name,
                                 *(repr(float(c)) for c in points[i]), repr(float(result.distance[i])),
                                 repr(float(result.blind_distance[i])), ";".join(flags)])
                flagged += bool(flags)
            distances.append(np.asarray(result.distance, dtype=np.float64))
            answered += 1
    if args.json:
        values = np.concatenate(distances) if distances else np.zeros(0)
        finite = lambda x: None if not math.isfinite(x) else float(x)  # noqa: E731 - inf: nothing within rho
        print(json.dumps({"recording": str(recording.path), "out": str(out), "frames": answered,
                          "points": len(point_names), "answers": int(values.size), "flagged": flagged,
                          "distance_min": finite(values.min()) if values.size else None,
                          "distance_median": finite(float(np.median(values))) if values.size else None}))
    else:
        print(f"replayed {answered} frame sets of {', '.join(recording.rig.cameras)} with {len(point_names)} points "
              f"each ({flagged} answers flagged) into {out}")
    return 0


def _replay_robot(name: str):
    """``--robot`` of replay: 'iiwa', 'panda' or a URDF file (as ``distance --robot``)."""
    from depthguard.robots import RobotModel

    robot = {"iiwa": RobotModel.default, "panda": RobotModel.panda}.get(name)
    return robot() if robot is not None else RobotModel.from_urdf(name)


def _robot_and_joints(args):
    """(RobotModel or None, joint positions or None) from ``--robot`` and ``--joints``."""
    from depthguard.errors import InputError

    if args.robot is None:
        if args.joints is not None:
            raise InputError("--joints needs --robot")
        return None, None
    if args.joints is None:
        raise InputError("--robot needs --joints (the robot's joint positions when the images were taken)")
    from depthguard.robots import RobotModel

    robot = {"iiwa": RobotModel.default, "panda": RobotModel.panda}.get(args.robot)
    robot = robot() if robot is not None else RobotModel.from_urdf(args.robot)
    return robot, robot.joint_vector(parse_joints(args.joints))


#: The commands: name -> the function that runs it on the parsed arguments (its exit status).
_COMMANDS = {"distance": _distance, "build-map": _build_map, "replay": _replay, "coverage": _coverage,
             "collide": _collide, "plan": _plan, "warmup": _warmup}


if __name__ == "__main__":
    sys.exit(main())
