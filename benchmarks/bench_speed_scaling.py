"""What speed scaling (``depthguard live --ssm``, depthguard.avoidance.SpeedScaling) adds to a set of frames, against
the same monitor without it, in the same run.

Scene: scenario B (the person reaching, the KUKA iiwa moving), two 640 x 480 depth cameras; 12 consecutive sets,
played three times. Per set: the baseline prepares the set and answers the robot's control points (what ``live``
publishes); with speed scaling the monitor also keeps its detectable space (``detection_capability`` 0.04 m), and
the factor is computed on it for the robot's surface spheres (joint speeds 0.5 rad/s). Medians of the last two passes.

    .venv/bin/python benchmarks/bench_speed_scaling.py
"""

from __future__ import annotations

import time
from importlib import resources
from pathlib import Path

import numpy as np

import depthguard as dg
from depthguard.avoidance import SpeedScaling
from depthguard_lab.simulation import load_workcell
from depthguard_lab.simulation._episode import sense_at
from _common import report

START = 0.5
SETS = 12
PASSES = 3


def main() -> None:
    workcell = load_workcell(Path(str(resources.files("depthguard_lab.simulation") / "scenario_b.yaml")))
    rig, robot = workcell.rig, workcell.robot
    times = START + np.arange(SETS) / workcell.rate
    frames = sense_at(workcell, times)
    rows = {}
    for name, options in (("baseline: prepare + answer", {}),
                          ("with speed scaling", dict(detection_capability=0.04))):
        monitor = dg.DistanceMonitor(rig, robot=robot, **options)
        scaling = SpeedScaling(monitor, joint_speed=0.5) if options else None
        steps = []
        for k in range(SETS * PASSES):
            t, frame = times[k % SETS], frames[k % SETS]
            q = workcell.joints_at(t)
            start = time.perf_counter()
            images = {n: dg.depth_image(d, rig.cameras[n], timestamp=t) for n, d in frame.depth.items()}
            prepared = monitor.prepare_set(images, joints=q, now=t)
            prepared.query(robot.control_point_positions(q))
            answered = time.perf_counter()
            if scaling is not None:
                scaling.factor(prepared, q, clock=lambda: t + 0.05)
            steps.append((answered - start, time.perf_counter() - answered))
        rows[name] = np.median(np.array(steps[SETS:]), axis=0) * 1e3
    base = rows["baseline: prepare + answer"].sum()
    print(f"two 640 x 480 cameras, scenario B, {SETS} sets x {PASSES} passes (medians of the last {PASSES - 1}), ms:")
    print(f"{'':28s} {'answer':>8s} {'factor':>8s} {'set':>8s} {'ratio':>7s}")
    for name, (answer, factor) in rows.items():
        print(f"{name:28s} {answer:8.1f} {factor:8.1f} {answer + factor:8.1f} {(answer + factor) / base:7.2f}")
    print("the distances are published after 'answer'; the factor follows (live publishes it after them)")


if __name__ == "__main__":
    with report(__file__):
        main()
