"""Planning around the person in scenario C (issue 27: "plan finds a path around a person standing next to the
robot"): the frame at which the person stands nearest the robot while more than 0.15 m from it, the paper's
8 x 8 x 8 x 4 x 2 x 2 configuration grid over the xArm's joints (within +-pi), from the robot's configuration to a
goal on the other side (-2.0, 0.3, -1.0, 0, 0.8, 0). Per rule: the free cells, missed collisions and false alarms
against coal's truth, whether the start and goal cells are free, and whether the wave finds a path; the same on the
true free cells, and the depth grid's verdict (DepthGridCollisionTest) of every cell.

    .venv/bin/python benchmarks/probe_plan_scenario_c.py
"""

from __future__ import annotations

import os
import sys
import time
from importlib import resources

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))

import depthguard as dg  # noqa: E402
from depthguard.collision import (  # noqa: E402
    ConfigurationGrid,
    ConfigurationTable,
    DepthGridCollisionTest,
    ImageCollisionTest,
    plan_path,
)
from depthguard_lab.simulation import load_workcell, simulate  # noqa: E402
from depthguard_lab.simulation._truth import TruthComputer  # noqa: E402
from _common import report  # noqa: E402
from probe_collision_scenario_c import FALSE_ALARM_CLEARANCE  # noqa: E402

GOAL = (-2.0, 0.3, -1.0, 0.0, 0.8, 0.0)
COUNTS = (8, 8, 8, 4, 2, 2)
RULES = [("paper (theta 1, B free)", 1, "free", False), ("theta 1, B occupied", 1, "occupied", False),
         ("theta 2, B occupied", 2, "occupied", False), ("default (C-1, occupied)", None, "occupied", False),
         ("theta 1 + depth order", 1, "occupied", True), ("default + depth order", None, "occupied", True)]


def main() -> None:
    with resources.as_file(resources.files("depthguard_lab.simulation").joinpath("scenario_c.yaml")) as path:
        workcell = load_workcell(path)
    robot = workcell.robot
    reference = list(range(0, int(3.0 * workcell.rate), 5))
    truth = TruthComputer(robot)
    parts = {n: workcell.part_names(n) for n in workcell.obstacle_names}
    candidates = list(range(int(3.0 * workcell.rate), workcell.n_frames, 6))
    frames = {f.index: f for f in simulate(workcell, frames=sorted(set(reference) | set(candidates)))}
    clear = {i: truth(frames[i].joints, workcell.obstacles_at(frames[i].time), parts).clearance for i in candidates}
    i = min((k for k in clear if clear[k] > FALSE_ALARM_CLEARANCE), key=clear.get)
    frame = frames[i]
    print(f"frame {i} at {frame.time:.2f} s: the robot {clear[i]:.3f} m from the person")
    grid = ConfigurationGrid(np.maximum(robot.lower, -np.pi), np.minimum(robot.upper, np.pi), COUNTS)
    cells = grid.configurations()
    obstacles = workcell.obstacles_at(frame.time)
    truly = np.array([truth(q, obstacles, parts).clearance for q in cells])
    far = truly > FALSE_ALARM_CLEARANCE
    start, goal = frame.joints, np.array(GOAL)
    possible = plan_path(grid, (truly > 0).reshape(grid.shape), start, goal) is not None
    print(f"{len(cells)} cells: {(truly < 0).sum()} touch the person, {far.sum()} are more than 0.15 m from it; a "
          f"path over the truly free cells: {'yes' if possible else 'no'}")
    print(f"{'images':9s} {'rule':26s} {'free cells':>10s} {'missed':>7s} {'false alarms':>14s} {'start':>6s} "
          f"{'goal':>5s} {'path':>6s}")
    s, g = grid.nearest(start), grid.nearest(goal)
    for kind in ("intensity", "depth"):
        source = (lambda f: f.intensity) if kind == "intensity" else (lambda f: {n: d.data for n, d in f.depth.items()})
        for rule, theta, unseen, order in RULES:
            if order and kind != "depth":
                continue
            test = ImageCollisionTest(workcell.rig, robot, workcell.rig.workspace, tiles=(64, 64), theta=theta,
                                      images=kind, unseen=unseen, depth_order=order)
            test.set_reference({n: [source(frames[j])[n] for j in reference] for n in workcell.rig.cameras},
                               joints=[frames[j].joints for j in reference])
            test.observe(source(frame), frame.joints)
            free = ~ConfigurationTable(test, cells).verdicts()[0]
            _row(kind, rule, free, truly, far, grid, s, g, plan_path(grid, free.reshape(grid.shape), start, goal))
    monitor = dg.DistanceMonitor(workcell.rig, robot=robot, rho=0.3)
    images = {n: dg.depth_image(d.data, workcell.rig.cameras[n], timestamp=frame.time) for n, d in frame.depth.items()}
    prepared = monitor.prepare_set(images, joints=frame.joints, now=frame.time)
    started = time.perf_counter()
    free = ~DepthGridCollisionTest(robot, 0.01).verdicts(prepared, cells).collision
    seconds = time.perf_counter() - started
    _row("depth", "depth grid's verdict", free, truly, far, grid, s, g,
         plan_path(grid, free.reshape(grid.shape), start, goal))
    print(f"(the depth grid's verdicts of {len(cells)} cells took {seconds:.1f} s)")


def _row(kind, rule, free, truly, far, grid, s, g, path) -> None:
    missed = int(((truly < 0) & free).sum())
    alarms = int((far & ~free).sum())
    shaped = free.reshape(grid.shape)
    print(f"{kind:9s} {rule:26s} {free.sum():10d} {missed:7d} {alarms:6d} ({alarms / max(far.sum(), 1):4.0%}) "
          f"{'free' if shaped[s] else 'no':>6s} {'free' if shaped[g] else 'no':>5s} "
          f"{'found' if path is not None else 'none':>6s}")


if __name__ == "__main__":
    with report(__file__):
        main()
