"""``depthguard distance``: distances from control points to what the cameras see in one set of depth images."""

from __future__ import annotations

import json

from depthguard import config
from depthguard.cli.options import add_monitor_options, robot_and_joints

HELP = 'distances from control points to what the cameras see'


def add_arguments(parser) -> None:
    parser.add_argument("--rig", required=True, help="rig YAML file (docs/design.md §2)")
    parser.add_argument("--depth", action="append", required=True, metavar="NAME=PATH",
                        help="depth image of camera NAME (16-bit PNG/PGM in depth_scale units, .npy, float TIFF)")
    parser.add_argument("--points", required=True, help="control points: CSV with header x,y,z or JSON list of "
                                                        "[x, y, z] (world frame, metres)")
    add_monitor_options(parser)
    parser.add_argument("--unseen", choices=config.UNSEEN_POLICIES, default=config.DEFAULT_UNSEEN,
                        help="space no camera observes: occupied (fail-safe) or free")
    parser.add_argument("--method", choices=config.METHODS, default=config.DEFAULT_METHOD,
                        help="exact (design) or paper (the 2015 paper's unsafe formulas, for comparison)")
    parser.add_argument("--robot", metavar="URDF",
                        help="filter this robot out of the images (a URDF file, or 'iiwa' / 'panda' for the models "
                             "shipped with pybullet_data); needs --joints")
    parser.add_argument("--joints", metavar="VALUES",
                        help="the robot's joint positions when the images were taken, radians: name=value,... or "
                             "the movable joints' values in URDF order, comma-separated")
    parser.add_argument("--principal", action="append", metavar="NAME",
                        help="with several --depth: a principal camera of the depth grid (repeatable; default: "
                             "the rig's principal, else its first camera)")
    parser.add_argument("--map", action="append", metavar="MAP",
                        help="a depth grid map written by build-map (repeatable); maps not given are built from "
                             "the rig")
    parser.add_argument("--json", action="store_true", help="print one JSON array, one object per point")


def run(args) -> int:
    from depthguard import DistanceMonitor, load_depth, load_rig
    from depthguard.io.points import load_points
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
    robot, joints = robot_and_joints(args)
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
