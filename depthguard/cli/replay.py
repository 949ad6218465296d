"""``depthguard replay``: run a recording through the monitor in capture-time order, one answer per set of frames."""

from __future__ import annotations

import json
import math
import sys

from depthguard.cli.options import add_base_option, add_monitor_options, load_robot, monitor_options

HELP = ('run a recording (folder or ROS 2 bag, docs/design.md §12a) through the monitor as the live node would '
        '(§12b): frames grouped by stamp, one answer per set of frames')


def add_arguments(parser) -> None:
    parser.add_argument("recording", metavar="RECORDING", help="a recording folder (rig.yaml, frames.csv, depth/, "
                                                                "joint_states.csv), a rosbag2 folder or an .mcap file")
    parser.add_argument("--out", required=True, metavar="RESULTS.csv",
                        help="results: time,frame,control_point,x,y,z,distance,blind_distance,flags")
    parser.add_argument("--robot", default="iiwa", metavar="URDF",
                        help="the recorded robot, filtered out of the images: a URDF file, or 'iiwa' / 'panda' for the "
                             "models shipped with pybullet_data (default: iiwa); its joints must be the recording's")
    parser.add_argument("--points", metavar="POINTS",
                        help="fixed control points (CSV x,y,z or JSON, world frame, metres), named p0, p1, ... "
                             "(default: the robot's control points, moving with the recorded joints)")
    add_base_option(parser)
    add_monitor_options(parser, memory=True)
    parser.add_argument("--rig", metavar="RIG.yaml",
                        help="the rig (default: rig.yaml in the recording, the bag folder or beside the .mcap file)")
    parser.add_argument("--json", action="store_true", help="also print a JSON summary to standard output")


def run(args) -> int:
    import csv
    from pathlib import Path

    import numpy as np

    from depthguard import DistanceMonitor
    from depthguard.errors import InputError
    from depthguard.io.files import atomic_write
    from depthguard.io.recordings import open_recording
    from depthguard.live import RESULT_COLUMNS, FrameSetLoop, answer_set

    out = Path(args.out)
    if out.exists() and not out.is_file():  # a folder, a FIFO, a device: never written to
        raise InputError(f"--out {args.out}: exists and is not a regular file")
    recording = open_recording(args.recording, rig=args.rig, replay=True)
    robot = load_robot(args.robot, args.base)
    names = recording.joint_names
    missing = [n for n in robot.joint_names if n not in names]
    if missing:  # joints beyond the robot's (a gripper's) are ignored
        raise InputError(f"the recording's joints lack the robot's ({robot.name}) {', '.join(missing)}",
                         source=str(recording.path), field="joints")
    order = [names.index(n) for n in robot.joint_names]  # recording's joint order -> the robot's
    if args.points is not None:
        from depthguard.io.points import load_points

        fixed = load_points(args.points)
        if len(fixed) == 0:
            raise InputError(f"--points {args.points}: holds no points")
        point_names = [f"p{i}" for i in range(len(fixed))]
    else:
        fixed = None
        point_names = list(robot.control_point_names)
    for camera, why in recording.left_out.items():
        print(f"depthguard replay: camera {camera} left out: {why}", file=sys.stderr)
    monitor = DistanceMonitor(recording.rig, robot=robot, **monitor_options(args))
    # The live node's loop (design §12b), driven by the recording's stamps: the same sets, joints and answers.
    loop = FrameSetLoop(tuple(recording.rig.cameras), idle=args.max_age)
    distances, flagged, answered = [], 0, 0
    with atomic_write(out, newline="") as f:  # --out appears once every set is answered
        writer = csv.writer(f)
        writer.writerow(RESULT_COLUMNS)
        print(f"replaying {len(recording.frames)} frames ...", file=sys.stderr, flush=True)

        def answer(sets):
            nonlocal flagged, answered
            for frame_set in sets:
                result = answer_set(monitor, loop, frame_set, robot=robot, points=fixed)
                if result is None:
                    continue
                rows = result.rows(point_names)
                writer.writerows(rows)
                flagged += sum(1 for row in rows if row[-1])
                distances.append(np.asarray(result.result.distance, dtype=np.float64))
                answered += 1

        last = None
        for kind, time, payload in recording.messages():
            answer(loop.tick(time))
            if kind == "joints":
                answer(loop.add_joints(time, payload[order]))
            elif payload.camera not in recording.left_out:
                answer(loop.add_frame(payload))
            last = time
        if last is not None:
            answer(loop.tick(last + loop.wait))  # a set still waiting for a camera at the end
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
