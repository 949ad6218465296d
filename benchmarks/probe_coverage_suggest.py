"""Where one more camera would clear what scenario B's layouts cannot (issue 35, item 6): ``depthguard coverage
--suggest`` on the lab's two- and four-camera rigs (scenario_b.yaml, scenario_b_four.yaml; 640x480, the default
poses of the iiwa: scenario B's posture and four poses of its trajectory), and the coverage again with the suggested
camera. The robot alone above a floor, no memory (coverage's setting): the share of far control points whose fused
distance is below rho, on exact frames and with the rig's noise, before and after.

    .venv/bin/python benchmarks/probe_coverage_suggest.py
"""

from __future__ import annotations

import time
from importlib import resources

import depthguard as dg
from depthguard import coverage as cov
from depthguard.robots import RobotModel
from depthguard_lab.simulation import load_workcell
from _common import report

SCENES = ("scenario_b.yaml", "scenario_b_four.yaml")


def main() -> None:
    started = time.perf_counter()
    robot = RobotModel.default()
    poses = cov.default_poses(robot)
    print(f"{len(poses)} poses of the iiwa; samples every {cov.SPACING * 100:g} cm, rho {dg.config.DEFAULT_RHO:g} m; "
          f"{len(cov.SUGGEST_HEIGHTS) * cov.SUGGEST_AZIMUTHS} places tried for one more camera (heights above the "
          f"floor {cov.SUGGEST_HEIGHTS} m, {cov.SUGGEST_AZIMUTHS} azimuths)\n")
    print(f"  {'rig':28s} {'cameras':>7s} {'not clearable':>14s} {'cp < rho, exact':>16s} {'cp < rho, noisy':>16s}")
    for scene in SCENES:
        rig = load_workcell(resources.files("depthguard_lab.simulation") / scene).rig
        before = cov.coverage(rig, robot, poses)
        suggestion = cov.suggest_camera(rig, robot, poses, before)
        rows = [(scene, rig, before)]
        if suggestion is not None:
            bigger = dg.Rig({**rig.cameras, "suggested": suggestion.camera}, principal=rig.principal,
                            workspace=rig.workspace)
            rows.append((" + the suggested camera", bigger, cov.coverage(bigger, robot, poses)))
        for label, r, result in rows:
            f = cov.figures(result.poses)
            print(f"  {label:28s} {len(r.cameras):7d} {100 * f['not_clearable_fraction']:13.2f}% "
                  f"{f['control_points_below_rho']:6d}/{f['control_points_far']} "
                  f"{100 * f['control_alarm_fraction']:5.1f}% {f['control_points_below_rho_noisy']:6d}/"
                  f"{f['control_points_far']} {100 * f['control_alarm_fraction_noisy']:5.1f}%")
        if suggestion is not None:
            eye = ", ".join(f"{x:.2f}" for x in suggestion.eye)
            print(f"    suggested: the principal's model at ({eye}), looking at the robot's control points' centre; "
                  f"it sees past {100 * suggestion.sees_past:.0f} % of the samples the rig cannot clear")
    print(f"\n(run took {time.perf_counter() - started:.0f} s)")


if __name__ == "__main__":
    with report(__file__):
        main()
