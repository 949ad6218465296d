"""``depthguard plan``: a collision-free path through the configuration space by wave propagation (Henrich & Gecks,
section 5), every configuration judged by the image-based test."""

from __future__ import annotations

import json
import math

import numpy as np

from depthguard import config
from depthguard.cli.collide import add_options, joint_values, prepare
from depthguard.errors import InputError

HELP = ("a collision-free path through the configuration space by wave propagation, every configuration judged by "
        "the image-based test")

#: radians: by default the plan's grid spans each joint from the current to the goal value, this much beyond both.
DEFAULT_PLAN_MARGIN = 0.5


def add_arguments(parser) -> None:
    add_options(parser, plan=True)


def default_counts(robot, lower, upper, cells: int = 8192) -> np.ndarray:
    """Values per joint for a grid of ``cells`` configurations (a power of two; the paper's 8,192): starting from one
    value per joint, the count of the joint whose step moves the robot furthest (range x reach / count) doubles
    until the grid is full."""
    counts = np.ones(robot.n_joints, dtype=np.int64)
    travel = (np.asarray(upper) - np.asarray(lower)) * robot.joint_reaches()
    while counts.prod() < cells:
        counts[int(np.argmax(travel / counts))] *= 2
    return counts


def run(args) -> int:
    """``depthguard plan``: a wave-propagation path from ``--current`` to ``--goal`` over the configuration grid, each
    cell judged by the collision test, the path (current, the cells, goal) then tested as one motion (its swept
    volume); it is given only if that is free. Exit status 0 with a path, 1 without one."""
    from depthguard.collision import ConfigurationGrid, ConfigurationTable, plan_path

    tester, test, robot, current, piece = prepare(args)
    goal = joint_values(robot, args.goal, "--goal")
    # Default range: the span between the current and the goal configuration, widened by DEFAULT_PLAN_MARGIN on
    # each side, within the joint limits (and +-pi): a joint that need not move gets a narrow range.
    low = np.maximum(np.maximum(robot.lower, -math.pi), np.minimum(current, goal) - DEFAULT_PLAN_MARGIN)
    high = np.minimum(np.minimum(robot.upper, math.pi), np.maximum(current, goal) + DEFAULT_PLAN_MARGIN)
    lower = np.array(joint_values(robot, args.lower, "--lower")) if args.lower is not None else low
    upper = np.array(joint_values(robot, args.upper, "--upper")) if args.upper is not None else high
    if args.counts is not None:
        try:
            counts = [int(x) for x in args.counts.split(",")]
        except ValueError:
            raise InputError(f"--counts: whole numbers separated by commas, got {args.counts!r}") from None
    else:
        counts = default_counts(robot, lower, upper)
    grid = ConfigurationGrid(lower, upper, counts)
    if grid.size > config.MAX_TABLE_CONFIGURATIONS:
        raise InputError(f"--counts: the grid holds {grid.size} configurations, at most "
                         f"{config.MAX_TABLE_CONFIGURATIONS} are judged at once")
    collision, _ = ConfigurationTable(test, grid.configurations(), piece=piece).verdicts()
    free = ~collision.reshape(grid.shape)
    cells_of = {}
    for option, q in (("--current", current), ("--goal", goal)):
        try:
            cells_of[option] = grid.nearest(q)
        except InputError as exc:
            raise InputError(f"{option} lies outside the configuration grid ({exc.message}): widen --lower/--upper")
    start_cell, goal_cell = cells_of["--current"], cells_of["--goal"]
    result = {"path": None, "grid": [int(c) for c in grid.shape], "free_cells": int(free.sum()),
              "start_free": bool(free[start_cell]), "goal_free": bool(free[goal_cell]), "motion": None}
    start_free = result["start_free"]
    free[start_cell] = True  # the robot is there now: the plan leaves it
    cells = plan_path(grid, free, current, goal)
    if cells is not None:
        path = np.vstack([current, cells, goal])
        motion = tester.test_motion(path)
        result["motion"] = {"collision": motion.collision, "class": motion.klass}
        if not motion.collision:
            result["path"] = [[round(float(x), 6) for x in q] for q in path]
    if args.json:
        print(json.dumps(result))
        return 0 if result["path"] is not None else 1
    print(f"grid {' x '.join(map(str, grid.shape))} = {grid.size} configurations, {result['free_cells']} free; start "
          f"{'free' if start_free else 'in collision (the plan leaves it)'}, goal "
          f"{'free' if result['goal_free'] else 'in collision'}")
    if cells is None:
        print("no path: the goal cannot be reached through free configurations")
    elif result["path"] is None:
        print(f"a path of {len(cells)} cells was found, but its swept volume collides (class "
              f"{result['motion']['class']}): no path given")
    else:
        print(f"path of {len(result['path'])} configurations (the swept volume is free):")
        for q in result["path"]:
            print("  " + ", ".join(f"{x:.4f}" for x in q))
    return 0 if result["path"] is not None else 1
