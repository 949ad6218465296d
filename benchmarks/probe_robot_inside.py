"""How much of each link the robot's inner volume fills (design §8a's Robot_k: ``RobotModel.inner_capsules_world``).

Robot_k counts free in the free-space memory and in SSM's detectable space only where a voxel lies wholly inside one
inner ball. This probe samples points uniformly inside each link's collision mesh (its open ends closed as
``depthguard.robots._inner`` closes them) that lie at least half a 1 cm voxel's diagonal deep, and prints the share
of them round which a 1 cm voxel (any orientation) lies wholly inside one ball, with the time the balls took:

    .venv/bin/python benchmarks/probe_robot_inside.py [--robot iiwa|panda|xarm6] [--samples 1500]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from depthguard import config
from depthguard.robots import RobotModel
from depthguard.robots._inner import _COVER, closed_triangles, inner_balls, points_inside, triangle_distances
from _common import report

ROBOTS = {"iiwa": RobotModel.default, "panda": RobotModel.panda, "xarm6": RobotModel.xarm6}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", choices=tuple(ROBOTS), action="append",
                        help="robot (repeatable; default: all three)")
    parser.add_argument("--samples", type=int, default=1500, help="uniform samples in each link's bounds")
    args = parser.parse_args(argv)
    cover = _COVER
    print(f"points at least {cover * 1000:.1f} mm inside each link's mesh, and the share of them that lie at least "
          "that deep in one inner ball (a 1 cm voxel round them is then Robot_k);\n"
          f"balls: a {config.INNER_BALL_SPACING * 100:g} cm grid of centres, at most {config.INNER_BALLS} a link, "
          f"surface samples every {config.INNER_SURFACE_SAMPLE * 1000:g} mm\n")
    print(f"{'robot':6s} {'link':28s} {'balls':>5s} {'deepest mm':>10s} {'points':>6s} {'filled':>7s}")
    for name in args.robot or list(ROBOTS):
        robot = ROBOTS[name]()
        rng = np.random.default_rng(20261129)
        filled_all, points_all, seconds = 0, 0, 0.0
        for link in dict.fromkeys(capsule.link for capsule in robot.capsules):
            mesh = robot.collision_meshes[link]
            triangles = closed_triangles(mesh)
            start = time.perf_counter()
            balls = np.array([[*ball.p0, ball.radius] for ball in inner_balls(mesh, link)]).reshape(-1, 4)
            seconds += time.perf_counter() - start
            points = rng.uniform(*mesh.bounds, size=(args.samples, 3))
            if triangles is not None:
                points = points[points_inside(points, triangles)]
                points = points[triangle_distances(points, triangles) >= cover]
            else:
                points = points[:0]
            filled = 0
            if len(points) and len(balls):
                deepest = (balls[:, 3][None, :] - np.linalg.norm(points[:, None] - balls[None, :, :3], axis=2)).max(1)
                filled = int(np.count_nonzero(deepest >= cover))
            filled_all += filled
            points_all += len(points)
            share = f"{filled / len(points):7.1%}" if len(points) else f"{'-':>7s}"
            deepest_ball = balls[:, 3].max() * 1000 if len(balls) else 0.0
            print(f"{name:6s} {link:28s} {len(balls):5d} {deepest_ball:10.1f} {len(points):6d} {share}")
        print(f"{name:6s} {'all links':28s} {'':5s} {'':10s} {points_all:6d} {filled_all / max(points_all, 1):7.1%}   "
              f"(the balls took {seconds:.1f} s, found once per model)")


if __name__ == "__main__":
    with report(__file__):
        main()
