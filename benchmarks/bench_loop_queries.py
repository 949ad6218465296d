"""What the closed loop's distance queries cost per set of frames: the papers' control points against the spheres
that cover the robot's surface (the loop's default, design §9), with the monitor's defaults and with the loop's
concessions (a 6 cm robot zone, holes filled from their neighbours); "hybrid" for every point, and as the loop asks
now: "min" for every point and "hybrid" for the end-effector alone (its repulsion's direction, design §9).

Scenario B's elbow scene (two 640 x 480 depth cameras, the KUKA iiwa self-filtered, the free-space memory on,
rho = 0.4 m): per set, its preparation (``DistanceMonitor.prepare_set``), the first query (which classifies the
depth grid's cells in reach) and the later queries on the same set (the controller asks at every control step,
about 16 times a set at 500 Hz; here 8 queries, the points moved by a millimetre each). The baseline, in the same
run: the papers' 9 control points with the monitor's defaults (what ``bench_frame_budget`` times). Medians over the
sets; the camera period is 33 ms.

    .venv/bin/python benchmarks/bench_loop_queries.py [--sets 12]
"""

from __future__ import annotations

import argparse
import time
from importlib import resources

import numpy as np

import depthguard as dg
from depthguard import config
from _common import report


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sets", type=int, default=12)
    args = parser.parse_args()

    from depthguard_lab.simulation import load_workcell
    from depthguard_lab.simulation._episode import SceneRenderer, sense
    from depthguard_lab.simulation._truth import TruthComputer

    with resources.as_file(resources.files("depthguard_lab.simulation").joinpath("scenario_b_elbow.yaml")) as path:
        workcell = load_workcell(path)
    robot = workcell.robot
    scene, truth = SceneRenderer(workcell, None), TruthComputer(robot)
    part_names = {name: workcell.part_names(name) for name in workcell.obstacle_names}
    frames = []
    for k in range(args.sets + 1):  # the first set compiles nothing new but warms the caches; it is not counted
        t = 3.0 + k / workcell.rate  # the box on the forearm's path, the arm rising towards it
        q = workcell.joints_at(t)
        frames.append((t, q, sense(workcell, scene, truth, part_names, q.copy(), t, int(round(t * workcell.rate)),
                                   workcell.seed).depth))
    surface = robot.with_surface_points(config.SSM_ROBOT_UNCERTAINTY)
    concessions = {"robot_zone": config.LOOP_ROBOT_ZONE, "invalid": "neighbors"}
    # (points, their model, the monitor's options, whether the end-effector alone is asked again with "hybrid")
    rows = [("papers' control points", robot, "hybrid", {}, False),
            ("papers' control points", robot, "hybrid", concessions, False),
            ("surface spheres", surface, "hybrid", {}, False),
            ("surface spheres", surface, "hybrid", concessions, False),
            ("surface spheres (the loop's)", surface, "min + ee hybrid", concessions, True)]
    print(f"scenario B, elbow scene, {len(workcell.rig.cameras)} cameras, {args.sets} sets from 3.0 s, rho 0.4 m, "
          f"memory on; medians, ms")
    print(f"{'points':30s} {'n':>3s} {'aggregate':16s} {'concessions':22s} {'prepare':>8s} {'first query':>12s} "
          f"{'later query':>12s} {'set + 16 later':>15s} {'ratio':>6s}")
    baseline = None
    for label, model, aggregate, kwargs, ee_hybrid in rows:
        name = "zone 6 cm, holes filled" if kwargs else "none (defaults)"
        monitor = dg.DistanceMonitor(workcell.rig, rho=0.4, robot=robot,
                                     aggregate="min" if ee_hybrid else aggregate, **kwargs)
        ee = model.end_effector_index
        prepare, first, later = [], [], []
        for index, (t, q, depth) in enumerate(frames):
            start = time.perf_counter()
            prepared = monitor.prepare_set(depth, joints=q, now=t)
            ready = time.perf_counter()
            p = model.control_point_positions(q)
            ask(prepared, p, ee, ee_hybrid)
            done = time.perf_counter()
            times = []
            for step in range(8):
                tick = time.perf_counter()
                ask(prepared, p + 0.001 * (step + 1), ee, ee_hybrid)
                times.append(time.perf_counter() - tick)
            if index:
                prepare.append(ready - start)
                first.append(done - ready)
                later.append(float(np.median(times)))
        row = [np.median(prepare) * 1e3, np.median(first) * 1e3, np.median(later) * 1e3]
        total = row[0] + row[1] + 16 * row[2]
        baseline = total if baseline is None else baseline
        print(f"{label:30s} {len(model.control_points):3d} {aggregate:16s} {name:22s} {row[0]:8.1f} "
              f"{row[1]:12.1f} {row[2]:12.2f} {total:15.1f} {total / baseline:6.2f}")


def ask(prepared, points, ee: int, ee_hybrid: bool) -> None:
    """One query as the loop asks it (``_avoidance_query``: every point with the monitor's aggregate, and the
    end-effector again with "hybrid" when ``ee_hybrid``), or one plain query."""
    prepared.query(points, check=False)
    if ee_hybrid:
        prepared.query(points[ee: ee + 1], check=False, aggregate="hybrid")


if __name__ == "__main__":
    with report(__file__):
        main()
