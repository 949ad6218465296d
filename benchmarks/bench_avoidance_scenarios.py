"""Issue 9's three avoidance scenarios, each with the two-camera and the four-camera layout, in closed loop.

Scenarios (the windows of ``tests/test_closed_loop.py``, where the obstacle meets the robot without avoidance):
``scenario_b_reach.yaml`` (a person reaches into the end-effector and walks away, 1.9-5.5 s),
``scenario_b_board.yaml`` (a board carried edge-on to the principal camera into the end-effector's path and back,
1.6-6.0 s) and ``scenario_b_elbow.yaml`` (a box put above the forearm, which rises into it, and taken away at 4.8 s,
2.4-7.0 s). Layouts: the
scene's own two cameras (the published one), ``scenario_b_four.yaml``'s four room corners
(``load_workcell(..., layout=...)``), and for mode ssm only ``scenario_b_ssm.yaml`` (the four and a ceiling camera,
time-of-flight-class noise) with the room's solids known and the detectable distances (``LoopSettings(ssm_capability=
True, known_solids=True)``, as ``depthguard demo`` runs it). Per run: collisions and the smallest clearance between the robot's meshes and
the obstacles (coal), the task error at the end, how long after the obstacles left the task error fell below 1 cm
and stayed there 0.1 s (``avoidance_demo.resumption``; '-': they did not leave in the window; 'never': it did not
come back), reversals of the reaction per second, and the loop's rate in simulated seconds per wall-clock second
(the camera simulation and the ground truth included):

    .venv/bin/python benchmarks/bench_avoidance_scenarios.py [--scene scenario_b_elbow.yaml ...] [--mode avoid ...]
        [--layout two|four|ssm ...] [--papers]

By default the loop's settings (``LoopSettings()``: distances from the links' surfaces, the 6 cm robot zone taken
as a tolerance); ``--papers`` runs the papers' parameterisation instead (distances from the control points, no robot
zone), the baseline the defaults are measured against.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from importlib import resources
from pathlib import Path

from depthguard.avoidance import AvoidanceParams
from depthguard_lab.experiments.avoidance_demo import resumed_cell, summarize
from depthguard_lab.simulation import load_workcell
from depthguard.errors import InputError
from depthguard_lab.simulation._closed_loop import MODES, LoopSettings, run_closed_loop
from _common import report

WINDOWS = {"scenario_b_reach.yaml": (1.9, 3.6), "scenario_b_board.yaml": (1.6, 4.4),
           "scenario_b_elbow.yaml": (2.4, 4.6)}
LAYOUTS = {"two": None, "four": "scenario_b_four.yaml", "ssm": "scenario_b_ssm.yaml"}
#: Layout "ssm" runs mode ssm only, as ``depthguard demo`` runs it: the known solids and the detectable distances.
SSM_CELL = dict(ssm_capability=True, known_solids=True)


def _packaged(name: str) -> Path:
    return Path(str(resources.files("depthguard_lab.simulation").joinpath(name)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", action="append", choices=sorted(WINDOWS), help="default: all three")
    parser.add_argument("--mode", action="append", choices=MODES, help="default: none, avoid and ssm")
    parser.add_argument("--layout", action="append", choices=sorted(LAYOUTS), help="default: two, four and ssm")
    parser.add_argument("--papers", action="store_true",
                        help="the papers' parameterisation: distances from the control points, no robot zone")
    args = parser.parse_args()
    settings = LoopSettings()
    if args.papers:
        settings = LoopSettings(avoidance=AvoidanceParams(from_surface=False),
                                monitor={**settings.monitor, "robot_zone": 0.0})
    dt = 1.0 / LoopSettings().control_rate
    print(f"{'scene':22s} {'layout':6s} {'mode':6s} {'collisions':>10s} {'clearance m':>12s} {'task error end m':>17s} "
          f"{'resumed after s':>16s} {'reversals /s':>13s} {'sim s / wall s':>15s}")
    for scene in args.scene or list(WINDOWS):
        start, duration = WINDOWS[scene]
        for layout in args.layout or list(LAYOUTS):
            cameras = LAYOUTS[layout]
            workcell = load_workcell(_packaged(scene), layout=None if cameras is None else _packaged(cameras))
            for mode in args.mode or MODES:
                if layout == "ssm" and mode != "ssm":
                    continue
                run_settings = replace(settings, **SSM_CELL) if layout == "ssm" else settings
                try:
                    log = run_closed_loop(workcell, mode, start=start, duration=duration, settings=run_settings)
                except InputError as error:  # SSM that cannot be sound here (ISO 13855's 70 mm): said, not run
                    print(f"{Path(scene).stem:22s} {layout:6s} {mode:6s} refused: {str(error).split(': ', 1)[-1]}",
                          flush=True)
                    continue
                s = summarize(log, dt)
                print(f"{Path(scene).stem:22s} {layout:6s} {mode:6s} {s['collisions']:10d} {s['clearance_m']:12.3f} "
                      f"{s['task_error_after_m']:17.3f} {resumed_cell(s)} {s['oscillation_per_s']:13.2f} "
                      f"{len(log.times) * dt / log.wall_seconds:15.3f}", flush=True)


if __name__ == "__main__":
    with report(__file__):
        main()
