"""The ``depthguard`` command line.

    depthguard distance --rig RIG.yaml --depth NAME=PATH --points POINTS [--rho 0.4] [--aggregate hybrid] ...
    depthguard build-map --rig RIG.yaml [--principal NAME] [--d-min M --d-max M --delta-d M] --out MAP
    depthguard simulate [SCENE.yaml] --out DIR [--seed N] [--duration S] [--bag]
    depthguard replay RECORDING --out RESULTS.csv [--robot URDF|iiwa|panda] [--points POINTS] [--rho 0.4] ...
    depthguard demo [--out DIR] [--duration S] [--mode none|avoid|ssm ...] [--cameras 4|2] [--no-bag]
                    [--ssm-in-layout]
    depthguard workcell [--out DIR] [--duration S]
    depthguard fusion-workcell [--out DIR] [--scene SCENE.yaml ...] [--all-frames]
    depthguard coverage --rig RIG.yaml [--robot URDF|iiwa|panda] [--trajectory joint_states.csv] [--rho 0.4] ...
    depthguard scenario-a [--out DIR]
    depthguard real-room [--out DIR] [--data FOLDER]
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
- ``--duration``: finite seconds, at least one frame period of the scene (1/30 s for the default scenes); longer
  than the scene simulates the whole scene;
- ``--seed``: a whole number in [0, ``config.MAX_SEED``]; ``--repeats``: in [1, ``config.MAX_REPEATS``];
- ``--joints``: finite numbers (radians, or metres for prismatic joints).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys

from depthguard import config
from depthguard.errors import DepthguardError


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (no usage dump) and exit status 2."""

    def error(self, message):
        self.exit(2, f"depthguard: error: {message}\n")


def _real(minimum: float, maximum: float, unit: str, above_minimum: bool = False):
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


def _whole(minimum: int, maximum: int):
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


_METRES = _real(config.RHO_MIN, config.RHO_MAX, "metres")
_GRID_METRES = _real(0.0, config.COORDINATE_LIMIT, "metres", above_minimum=True)
_SECONDS = _real(0.0, math.inf, "seconds", above_minimum=True)
_SPEED = _real(0.0, config.COORDINATE_LIMIT, "metres/second", above_minimum=True)


def _build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="depthguard", description="Distances between a robot and unknown obstacles, computed in "
                                                     "the depth space of calibrated depth cameras.")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    distance = commands.add_parser("distance", help="distances from control points to what the cameras see")
    distance.add_argument("--rig", required=True, help="rig YAML file (SPEC section 2)")
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
                          help="exact (SPEC) or paper (the 2015 paper's unsafe formulas, for comparison)")
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

    build = commands.add_parser("build-map", help="build the depth grid map of a rig's principal camera (SPEC "
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

    simulate = commands.add_parser("simulate", help="simulate a workcell and write its frames, rig, joint states "
                                                     "and ground truth")
    simulate.add_argument("scene", nargs="?", help="scene YAML (default: reference scenario B)")
    simulate.add_argument("--out", required=True, help="output folder")
    simulate.add_argument("--seed", type=_whole(0, config.MAX_SEED), default=None,
                          help="sensor-noise seed (default: the scene's)")
    simulate.add_argument("--duration", type=_SECONDS, default=None,
                          help="simulate only the first S seconds (at least one frame period)")
    simulate.add_argument("--bag", action="store_true", help="also write the recording as a ROS 2 bag (MCAP) into "
                                                             "OUT/bag/ (depth images, camera_info, joint_states)")

    replay = commands.add_parser("replay", help="run a recording (folder or ROS 2 bag, SPEC section 12a) through the "
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
                             f"{config.FREESPACE_V_MAX:g}, ISO 13855's hand speed; SPEC section 8a); the memory "
                             "needs a workspace in the rig")
    memory.add_argument("--no-memory", action="store_true",
                        help="do not remember free space: only what the cameras see now clears space")
    replay.add_argument("--json", action="store_true", help="also print a JSON summary to standard output")

    demo = commands.add_parser("demo", help="the Quick start's main job: a robot doing its task next to a person "
                                            "in closed loop, without avoidance, with the papers' avoidance and "
                                            "with speed and separation monitoring, judged by exact geometry")
    demo.add_argument("--out", default="out/demo", help="output folder for plots and summary.json")
    demo.add_argument("--duration", type=_SECONDS, default=None,
                      help="only the first S seconds, at least one frame (1/30 s) (default: the whole scene, 5.5 s)")
    demo.add_argument("--mode", action="append", choices=("none", "avoid", "ssm"),
                      help="run only this mode (repeatable; default: none, avoid and ssm)")
    demo.add_argument("--cameras", type=int, choices=(2, 4), default=4,
                      help="four depth cameras round the robot (issue 8's reference layout, default) or the scene's "
                           "two front ones (faster)")
    demo.add_argument("--no-bag", action="store_true",
                      help="do not write the avoid run as a recording (DIR/bag_avoid, an MCAP file of about 150 MB)")
    demo.add_argument("--ssm-in-layout", action="store_true",
                      help="run ssm in the other modes' camera layout (where it stops the robot for good) instead of "
                           "scenario_b_ssm.yaml's five cameras, known solids and detectable distances")

    workcell = commands.add_parser("workcell", help="the simulated workcell of reference scenario B, each camera's "
                                                    "distances on its own against the truth")
    workcell.add_argument("--out", default="out/workcell", help="output folder for plots and summary.json")
    workcell.add_argument("--duration", type=_SECONDS, default=None,
                          help="only the first S seconds, at least one frame (1/30 s) (default: all 12)")

    fusion = commands.add_parser("fusion-workcell", help="scenario B's shadow and hidden-hand cases: a camera alone "
                                                         "against all fused through the depth grid, without and with "
                                                         "the free-space memory")
    fusion.add_argument("--out", default="out/fusion-workcell", help="output folder for plots and summary.json")
    fusion.add_argument("--scene", action="append", metavar="SCENE", help="a camera layout (scene YAML) to run "
                                                                           "(repeatable; default: scenario_b.yaml and "
                                                                           "scenario_b_four.yaml)")
    fusion.add_argument("--all-frames", action="store_true", help="simulate the whole episode (default: the two "
                                                                  "cases and 0.5 s around them)")

    coverage = commands.add_parser("coverage", help="camera placement: the space within rho of the robot that no "
                                                    "camera of a rig can clear, as fractions and a picture")
    coverage.add_argument("--rig", required=True, help="rig YAML file (SPEC section 2)")
    coverage.add_argument("--robot", default="iiwa", metavar="URDF",
                          help="the robot: a URDF file, or 'iiwa' / 'panda' for the models shipped with pybullet_data "
                               "(default: iiwa)")
    coverage.add_argument("--trajectory", metavar="joint_states.csv",
                          help="robot poses: a CSV time,<joint names...> (a recording's joint_states.csv), at most "
                               "20 rows used, evenly spread (default: scenario B's posture and four poses along its "
                               "trajectory for the iiwa, else the zero configuration)")
    from depthguard.experiments.coverage import RHO_RANGE  # the samples fill rho around the robot: bounded

    coverage.add_argument("--rho", type=_real(*RHO_RANGE, "metres"), default=config.DEFAULT_RHO,
                          help=f"surveillance radius, metres, in [{RHO_RANGE[0]:g}, {RHO_RANGE[1]:g}]")
    coverage.add_argument("--out", default="out/coverage", help="output folder for coverage.json and coverage.png")

    room = commands.add_parser("real-room", help="real data: three calibrated views of a room fused through the "
                                                 "depth grid; the calibration error and the fusion margin it needs")
    room.add_argument("--out", default="out/real-room", help="output folder for plots and summary.json")
    room.add_argument("--data", default=None, help="the slambook2-room folder (default: ../shared/data/real/...)")

    scenario_a = commands.add_parser("scenario-a", help="reference scenario A of the 2015 paper: plots and a "
                                                        "timing table")
    scenario_a.add_argument("--out", default="out/scenario-a", help="output folder for plots and tables")
    scenario_a.add_argument("--repeats", type=_whole(1, config.MAX_REPEATS), default=20,
                            help="timing repetitions per control point position")

    from depthguard import _collision_command as _command

    collide = commands.add_parser("collide", help="the image-based collision test (Henrich & Gecks, SPEC section 10): "
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


def _attach_number_lists(argv: list[str]) -> list[str]:
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
    args = _build_parser().parse_args(_attach_number_lists(argv))
    try:
        if args.command == "distance":
            return _distance(args)
        if args.command == "simulate":
            return _simulate(args)
        if args.command == "replay":
            return _replay(args)
        if args.command == "build-map":
            return _build_map(args)
        if args.command == "real-room":
            from depthguard.experiments import real_room

            return real_room.main(args.out, folder=args.data)
        if args.command == "demo":
            from depthguard.experiments import avoidance_demo

            return avoidance_demo.main(out=args.out, duration=_duration(args.duration, config.SIM_RATE),
                                       modes=args.mode, bag=not args.no_bag, cameras=args.cameras,
                                       ssm_cell=not args.ssm_in_layout)
        if args.command == "workcell":
            from depthguard.experiments import workcell

            return workcell.main(out=args.out, duration=_duration(args.duration, config.SIM_RATE))
        if args.command == "warmup":
            from depthguard import _warmup

            return _warmup.main()
        if args.command == "coverage":
            from depthguard.experiments import coverage

            return coverage.main(args.rig, robot=args.robot, trajectory=args.trajectory, rho=args.rho, out=args.out)
        if args.command in ("collide", "plan"):
            from depthguard import _collision_command as _command

            return _command.collide(args) if args.command == "collide" else _command.plan(args)
        if args.command == "fusion-workcell":
            from depthguard.experiments import fusion_workcell

            return fusion_workcell.main(out=args.out, scenes=args.scene, all_frames=args.all_frames)
        from depthguard.experiments import scenario_a

        return scenario_a.main(out=args.out, repeats=args.repeats)
    except DepthguardError as exc:
        print(f"depthguard: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"depthguard: error: {exc.filename or ''}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # a bug, not bad input: still one line, the traceback on request
        if os.environ.get("DEPTHGUARD_DEBUG"):
            raise
        print(f"depthguard: internal error: {type(exc).__name__}: {exc} (set DEPTHGUARD_DEBUG=1 for the traceback)",
              file=sys.stderr)
        return 3


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


def _simulate(args) -> int:
    from pathlib import Path

    from depthguard.errors import InputError
    from depthguard.simulation import default_workcell, load_workcell, write_episode

    if args.bag and (Path(args.out) / "bag").exists():  # refused before the simulation, not after it
        raise InputError(f"--bag: {Path(args.out) / 'bag'} exists already; a bag is written into a new folder")
    workcell = load_workcell(args.scene) if args.scene else default_workcell()
    duration = _duration(args.duration, workcell.rate)
    frames = None if duration is None else range(min(workcell.n_frames, int(round(duration * workcell.rate))))
    n = workcell.n_frames if frames is None else len(frames)
    print(f"simulating {n} frames of {', '.join(workcell.rig.cameras)} at {workcell.rate:g} Hz into {args.out}")
    out = write_episode(workcell, args.out, seed=args.seed, progress=True, frames=frames)
    print(f"wrote {out}: rig.yaml, frames.csv, depth/, intensity/, joint_states.csv, ground_truth.csv, scene.yaml")
    if args.bag:
        from depthguard.recordings import open_recording, write_bag

        bag = write_bag(open_recording(out), out / "bag")
        print(f"wrote {bag}: ROS 2 bag (MCAP) with the same frames and joint states, and rig.yaml")
    return 0


def _replay(args) -> int:
    import csv
    from pathlib import Path

    import numpy as np
    from tqdm import tqdm

    from depthguard import DistanceMonitor
    from depthguard._files import atomic_write
    from depthguard.errors import InputError
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
        for frame_set in tqdm(recording.frame_sets(), total=len(recording), unit="set", desc="replaying",
                              file=sys.stderr):
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


def _duration(value, rate: float):
    """``--duration`` (finite seconds, or None): at least one frame period of a scene simulated at ``rate`` Hz."""
    from depthguard.errors import InputError

    if value is not None and value < 1.0 / rate:
        raise InputError(f"--duration must be at least one frame period (1/{rate:g} s), got {value:g} s")
    return value


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


def parse_joints(text: str, option: str = "--joints"):
    """``"a=0.1,b=0.2"`` -> {"a": 0.1, "b": 0.2}; ``"0.1,0.2"`` -> [0.1, 0.2]. InputError naming ``option`` if
    malformed."""
    from depthguard.errors import InputError

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


if __name__ == "__main__":
    sys.exit(main())
