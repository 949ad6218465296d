"""``depthguard coverage``: camera placement, the space within rho of the robot that no camera of a rig can clear."""

from __future__ import annotations

import json
from pathlib import Path

import depthguard as dg
from depthguard import config
from depthguard.cli.options import load_robot, real_option
from depthguard.coverage import (
    CLEARANCE,
    RHO_RANGE,
    SPACING,
    TABLE_HEADER,
    USEFUL_MARGIN,
    coverage,
    default_poses,
    plot,
    suggest_camera,
    table_row,
    trajectory_poses,
)
from depthguard.errors import InputError
from depthguard.io.files import write_whole

HELP = ("camera placement: the space within rho of the robot that no camera of a rig can clear, as fractions and a "
        "picture")


def add_arguments(parser) -> None:
    parser.add_argument("--rig", required=True, help="rig YAML file (docs/design.md §2)")
    parser.add_argument("--robot", default="iiwa", metavar="URDF",
                        help="the robot: a URDF file, or 'iiwa' / 'panda' for the models shipped with pybullet_data "
                             "(default: iiwa)")
    parser.add_argument("--trajectory", metavar="joint_states.csv",
                        help="robot poses: a CSV time,<joint names...> (a recording's joint_states.csv), at most "
                             "20 rows used, evenly spread (default: scenario B's posture and four poses along its "
                             "trajectory for the iiwa, else the zero configuration)")
    parser.add_argument("--rho", type=real_option(*RHO_RANGE, "metres"), default=config.DEFAULT_RHO,
                        help=f"surveillance radius, metres, in [{RHO_RANGE[0]:g}, {RHO_RANGE[1]:g}]")
    parser.add_argument("--out", default="out/coverage", help="output folder for coverage.json and coverage.png")
    parser.add_argument("--suggest", action="store_true",
                        help="also find where one more camera (the principal's model) would clear most of what the "
                             "rig cannot, check it by running the coverage again with it, and write that rig to "
                             "rig_suggested.yaml")


def run(args) -> int:
    """``depthguard coverage``: load the rig (a file) and the robot (``"iiwa"``, ``"panda"`` or a URDF file), take
    the poses (``trajectory``: a joint_states.csv file, else :func:`default_poses`), print the table, write
    coverage.json and coverage.png into ``out``. Bad input raises before any work."""
    rig, robot, trajectory, rho, out = args.rig, args.robot, args.trajectory, args.rho, Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: exists and is not a folder")
    rig_path = rig
    rig = dg.load_rig(rig_path)
    model = load_robot(robot)
    poses = trajectory_poses(model, trajectory) if trajectory is not None else default_poses(model)
    print(f"Coverage of {rig_path} ({', '.join(rig.cameras)}) around {model.name}, rho = {rho:g} m: frames of the "
          "robot alone above a floor, no memory.")
    print(f"Samples every {SPACING * 100:g} cm, from {CLEARANCE * 100:g} cm outside the padded link capsules to rho, "
          "on noise-free frames. Not clearable: the monitor's")
    print("min(distance, blind_distance) < the spacing; occupied: its distance is (no camera sees through there); "
          "unchecked: only its blind")
    print(f"distance is (behind the robot). cp < rho: of the control points more than rho + {USEFUL_MARGIN:g} m from "
          "the floor, those whose fused")
    print("distance (hybrid) is below rho, on noise-free (exact) frames and with the rig's noise model (noisy).\n")
    print("  " + TABLE_HEADER)
    result = coverage(rig, model, poses, rho=rho, progress=True)
    numbers = {"rig": str(rig_path), **result.summary()}
    print("  " + table_row("all poses", numbers))
    out.mkdir(parents=True, exist_ok=True)
    if args.suggest:
        numbers["suggestion"] = _suggest(rig, model, poses, result, rho, out)
    try:
        import matplotlib  # noqa: F401 - the plots extra
    except ImportError:
        picture = None
    else:
        picture = plot(result, out / "coverage.png")
    numbers["picture"] = None if picture is None else str(picture)
    write_whole(out / "coverage.json", json.dumps(numbers, indent=2))
    drawn = f"and {picture}" if picture is not None else "(no picture: matplotlib is not installed, depthguard[plots])"
    print(f"{len(result.poses)} poses in {result.seconds:.1f} s; wrote {out / 'coverage.json'} {drawn}")
    return 0


def _suggest(rig, model, poses, result, rho, out: Path) -> dict | None:
    """``--suggest``: print and return where one more camera would clear most (:func:`suggest_camera`), with the
    coverage of the rig with that camera, and write that rig to ``out``/rig_suggested.yaml."""
    suggestion = suggest_camera(rig, model, poses, result)
    if suggestion is None:
        print("--suggest: every sample is clearable already; no camera suggested")
        return None
    eye, target = (", ".join(f"{x:.2f}" for x in point) for point in (suggestion.eye, suggestion.target))
    print(f"\n--suggest: of {suggestion.tried} places round the robot, one more camera at ({eye}) looking at "
          f"({target}) sees past {100 * suggestion.sees_past:.0f} % of the samples this rig cannot clear. With it:")
    bigger = dg.Rig({**rig.cameras, "suggested": suggestion.camera}, principal=rig.principal,
                    workspace=rig.workspace)
    print("  " + TABLE_HEADER)
    with_it = coverage(bigger, model, poses, rho=rho, progress=True)
    figures_with_it = with_it.summary()
    print("  " + table_row("all poses", figures_with_it))
    path = out / "rig_suggested.yaml"
    dg.save_rig(bigger, path)
    print(f"  wrote {path}")
    return {"eye": [float(x) for x in suggestion.eye], "target": [float(x) for x in suggestion.target],
            "sees_past": suggestion.sees_past, "places_tried": suggestion.tried, "rig": str(path),
            "with_it": {k: v for k, v in figures_with_it.items() if k != "poses"}}
