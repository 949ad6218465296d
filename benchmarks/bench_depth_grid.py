"""The depth grid's figures (issue 4): map build time and memory, fused queries per second, and a scaling table.

Goals: map build for 640x480x343 cells with one and with three secondary cameras <= 5 s and <= 256 MB; two
640x480 cameras, 9 control points, hybrid, rho = 0.4 m, on workcell frames with a person near the robot >= 500 fused
queries per second. Medians, because this machine is noisy.

    .venv/bin/python benchmarks/bench_depth_grid.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import tracemalloc

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))

import depthguard as dg  # noqa: E402
from depthguard.depthgrid import build_map  # noqa: E402
from depthguard.rendering import Renderer  # noqa: E402
from depthguard.robots import RobotModel  # noqa: E402
from depthguard.scenes import Box, render_depth, standing_person  # noqa: E402
from depthguard.self_filter import RobotSilhouette  # noqa: E402
from depthguard.transforms import look_at  # noqa: E402
from _common import timings  # noqa: E402

EYES = {"principal": [1.5, -2.0, 1.8], "second": [1.5, 2.0, 1.8], "third": [-1.8, -1.6, 2.0],
        "fourth": [-1.8, 1.6, 2.0]}


def cameras(names):
    return {n: dg.PinholeCamera(n, 640, 480, 525.0, 525.0, 319.5, 239.5, look_at(EYES[n], [0.2, 0.0, 0.9]),
                                depth_range=(0.5, 7.0)) for n in names}


def workcell_frames(rig_cameras, robot, q, renderer):
    """Depth images (uint16 mm) of a room, a person reaching towards the robot and the robot, for each camera."""
    scene = [Box.from_bounds([-2.3, -3.1, -0.05], [4, 3.1, 0.0]), Box.from_bounds([-2.4, -3.1, 0.0],
                                                                                  [-2.3, 3.1, 2.5]),
             Box.from_bounds([-2.3, 3.0, 0.0], [4, 3.1, 2.5]), Box.from_bounds([-2.3, -3.1, 0.0], [4, -3.0, 2.5])]
    person = standing_person((0.95, 0.35), facing=np.pi * 1.1, reach=0.9)  # on the floor beside the robot
    silhouette = RobotSilhouette(robot, renderer, geometry="meshes", padding=0.0)
    frames = {}
    for name, camera in rig_cameras.items():
        room = render_depth(camera, scene + person)
        arm = silhouette.render(camera, q)
        depth = np.where(arm > 0, np.minimum(arm, np.where(room > 0, room, np.inf)), room)
        frames[name] = dg.depth_image(np.round(depth * 1000).astype(np.uint16), camera)
    return frames


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)

    print("map build, 640x480 principal, 343 cells:")
    for names in (["principal", "second"], ["principal", "second", "third", "fourth"]):
        rig = dg.Rig(cameras(names), principal="principal")
        tracemalloc.start()
        start = time.perf_counter()
        grid = build_map(rig)
        seconds = time.perf_counter() - start
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        print(f"  {len(names) - 1} secondary camera(s): {seconds:.2f} s, map {grid.nbytes / 1e6:.0f} MB, peak "
              f"allocation {peak / 1e6:.0f} MB (goal <= 5 s, <= 256 MB)")

    robot = RobotModel.default()
    q = np.array([0.3, 0.6, 0.0, -1.2, 0.0, 0.8, 0.0])
    points = robot.control_point_positions(q)
    renderer = Renderer()
    all_cameras = cameras(list(EYES))
    frames = workcell_frames(all_cameras, robot, q, renderer)
    print(f"\nfused queries: KUKA iiwa, a person reaching towards it, hybrid, rho = 0.4 m; {args.repeats} repeats "
          "(median), frames prepared once")
    print(f"  {'cameras':>8s} {'points':>7s} {'ms / query':>11s} {'queries/s':>10s}")
    results = {}
    for n_cameras in (1, 2, 4):
        names = list(EYES)[:n_cameras]
        rig = dg.Rig({n: all_cameras[n] for n in names}, principal="principal")
        monitor = dg.DistanceMonitor(rig, rho=0.4, aggregate="hybrid", invalid="neighbors", robot=robot)
        for n_points in (1, 9, 27):
            pts = points if n_points == 9 else (points[-1:] if n_points == 1 else np.repeat(points, 3, axis=0))
            use = {n: frames[n] for n in names}
            t = timings(lambda: monitor.query(use, pts, joints=q), args.repeats, warmup=1)
            results[(n_cameras, n_points)] = np.median(t)
            print(f"  {n_cameras:8d} {n_points:7d} {np.median(t) * 1e3:11.1f} {1.0 / np.median(t):10.1f}")
    print(f"\ntwo cameras, 9 control points: {1.0 / results[(2, 9)]:.1f} fused queries per second (goal >= 500); "
          f"one camera: {1.0 / results[(1, 9)]:.0f}")


if __name__ == "__main__":
    main()
