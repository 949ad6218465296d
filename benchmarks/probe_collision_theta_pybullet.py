"""theta against tests/test_collision_pybullet.py's judge (issue 27, "defaults from measurement"): pybullet draws the
images of four 352 x 288 cameras round an xArm 6 and a box and measures the truth (getClosestPoints); for each theta
(class B collides), the configurations closer than the padding (2 cm) to the box that are judged free (missed), and
those more than 0.15 m from it judged colliding (false alarms). Two current configurations: the judge's own (the
robot's tile image meets the box's in one camera) and ``BOX_IN_VIEW_BEHIND_ROBOT_IMAGE`` (the robot hides the box in
one camera and overlaps its tiles in another).

    .venv/bin/python benchmarks/probe_collision_theta_pybullet.py
"""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.dirname(__file__))
sys.path.insert(0, os.path.join(os.path.dirname(__file__), os.pardir, "tests"))

from _common import report  # noqa: E402

FAR = 0.15


def main() -> None:
    import test_collision_pybullet as judge

    worlds = judge.world.__wrapped__()
    world = next(worlds)
    futures = judge.futures.__wrapped__(world)
    print(f"{'current configuration':44s} {'theta':>5s} {'missed':>14s} {'false alarms (> 0.15 m)':>24s}")
    for name, now in (("the judge's (box beside the robot's image)", None),
                      ("the robot hides the box in one camera", judge.BOX_IN_VIEW_BEHIND_ROBOT_IMAGE)):
        for theta in (1, 2, None):
            run = judge.run(world, futures, "352x288", now=now, theta=theta)
            close = run.distance < run.test.robot.padding
            far = run.distance > FAR
            missed = int((close & ~run.collision).sum())
            alarms = int((far & run.collision).sum())
            print(f"{name:44s} {run.test.theta:5d} {missed:5d} of {close.sum():5d} {alarms:9d} of {far.sum():4d} "
                  f"({alarms / max(far.sum(), 1):4.0%})")


if __name__ == "__main__":
    with report(__file__):
        main()
