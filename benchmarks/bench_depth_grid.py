"""The depth grid's figures (issue 4): map build time and memory, fused queries per second, and a scaling table.

Goals: map build for 640x480x343 cells with one and with three secondary cameras <= 5 s and <= 256 MB; two
640x480 cameras, 9 control points, hybrid, rho = 0.4 m, on workcell frames with a person near the robot >= 500 fused
queries per second.

Cameras deliver frames at 30 Hz; a controller asks for distances at 500 Hz, the robot moving in between. So per new
set of frames the table gives: the preparation (self-filtering each frame, the secondaries' free images), the first
query (the fusion's set-up and the grid cells its points need, classified once for the frame), and the later
queries (the robot moving 2 mrad per joint per query; cells classified before are reused). The baseline in the same
run is the principal camera alone, queried the same way. Medians, because this machine is noisy.

    .venv/bin/python benchmarks/bench_depth_grid.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import time
import tracemalloc

import numpy as np

import depthguard as dg
from depthguard.depthgrid import build_map
from depthguard.rendering import Renderer
from depthguard.robots import RobotModel
from depthguard.scenes import Box, render_depth
from depthguard_lab.simulation import standing_person
from depthguard.self_filter import RobotSilhouette
from depthguard.transforms import look_at
from _common import nearer, report

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
        depth = nearer(arm, room)
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
    renderer = Renderer()
    all_cameras = cameras(list(EYES))
    frames = workcell_frames(all_cameras, robot, q, renderer)
    # The controller's 500 Hz between two 30 Hz frames: 16 queries, every joint moving at 1 rad/s (2 mrad a query).
    steps = [robot.control_point_positions(q + 0.002 * k) for k in range(LATER + 1)]
    print(f"\nfused queries: KUKA iiwa, a person reaching towards it, hybrid, rho = 0.4 m, {args.repeats} new sets of "
          f"frames, each prepared, then queried once and {LATER} more times with the robot moving (medians):")
    print(f"  {'cameras':>7s} {'points':>6s} {'prepare ms':>10s} {'1st query ms':>12s} {'later ms':>9s} "
          f"{'later q/s':>9s} {'1 camera ms':>11s} {'ratio':>6s} {'per frame ms':>12s}")
    rows = {}
    for n_cameras in (1, 2, 4):
        names = list(EYES)[:n_cameras]
        for n_points in (1, 9, 27):
            pick = (lambda p: p[-1:]) if n_points == 1 else ((lambda p: p) if n_points == 9 else
                                                            (lambda p: np.repeat(p, 3, axis=0)))
            fused = measure(all_cameras, names, robot, frames, [pick(p) for p in steps], q, args.repeats)
            single = measure(all_cameras, names[:1], robot, frames, [pick(p) for p in steps], q, args.repeats)
            rows[(n_cameras, n_points)] = fused
            per_frame = fused["prepare"] + fused["first"] + LATER * fused["later"]
            print(f"  {n_cameras:7d} {n_points:6d} {fused['prepare'] * 1e3:10.1f} {fused['first'] * 1e3:12.1f} "
                  f"{fused['later'] * 1e3:9.2f} {1 / fused['later']:9.0f} {single['later'] * 1e3:11.2f} "
                  f"{fused['later'] / single['later']:6.1f} {per_frame * 1e3:12.1f}")
    two = rows[(2, 9)]
    per_frame = two["prepare"] + two["first"] + LATER * two["later"]
    print(f"\ntwo cameras, 9 control points: {1 / two['later']:.0f} fused queries per second on prepared frames "
          f"(goal >= 500); a new pair of frames costs {two['prepare'] * 1e3:.1f} ms to prepare and "
          f"{two['first'] * 1e3:.1f} ms for its first query; a 30 Hz frame with {LATER + 1} queries takes "
          f"{per_frame * 1e3:.1f} ms of the {1e3 / 30:.1f} ms it lasts ({(LATER + 1) / per_frame:.0f} queries/s "
          "sustained)")
    still = measure(all_cameras, list(EYES)[:2], robot, frames, steps, q, args.repeats, still=True)
    print(f"the same with a robot that stood still (each set at the same joints: its renders kept): a new pair of "
          f"frames costs {still['prepare'] * 1e3:.1f} ms to prepare ({two['prepare'] * 1e3:.1f} ms moving) and "
          f"{still['first'] * 1e3:.1f} ms for its first query")


LATER = 15  # queries per frame after the first (500 Hz control, 30 Hz cameras)


def measure(all_cameras, names, robot, frames, steps, q, repeats, still=False):
    """Median seconds to prepare a new set of frames (self-filtering at joints of its own, free images; the fusion's
    set-up is in the first query), for its first query, and for each later query on the same frames as the robot
    moves. ``still``: every set at the same joints (a robot that stood still)."""
    rig = dg.Rig({n: all_cameras[n] for n in names}, principal=names[0])
    monitor = dg.DistanceMonitor(rig, rho=0.4, aggregate="hybrid", invalid="neighbors", robot=robot)
    prepare, first, later = [], [], []
    for r in range(repeats + 1):  # the first round compiles and builds the map: not counted
        new = {n: dg.depth_image(frames[n].data, all_cameras[n], timestamp=float(r)) for n in names}
        # Each set at joints of its own (a microradian apart: the same frames fit them), as a moving robot's: a
        # robot that stood still keeps its renders from the set before, and that is not what this measures.
        joints = q if still else q + 1e-6 * r
        t0 = time.perf_counter()
        for n in names:
            monitor.prepare(n, new[n], joints=joints)
        t1 = time.perf_counter()
        monitor.query(new, steps[0], check=False)
        t2 = time.perf_counter()
        for points in steps[1:]:
            t = time.perf_counter()
            monitor.query(new, points, check=False)
            if r:
                later.append(time.perf_counter() - t)
        if r:
            prepare.append(t1 - t0)
            first.append(t2 - t1)
    return {"prepare": np.median(prepare), "first": np.median(first), "later": np.median(later)}


if __name__ == "__main__":
    with report(__file__):
        main()
