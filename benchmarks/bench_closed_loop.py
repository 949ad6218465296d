"""Issue 9's figures: the avoidance loop in simulated time, two 640x480 cameras (scenario B), distances at every 2 ms
control step from the loop's points (the spheres covering every moving link, ``LoopSettings.cover_surface``), the
camera simulation included.

The scene is ``scenario_b_reach.yaml`` (a person reaches into the end-effector); the run covers ``--start`` to
``--start + --duration`` seconds. Per mode (none: the task alone, the baseline; avoid: the papers' avoidance; ssm:
speed and separation monitoring, with the monitor's rho at ``LoopSettings.ssm_rho``) it prints:

- simulated seconds per wall-clock second (goal >= 1), the whole loop: rendering the cameras, preparing each set
  (self-filtering, memory, fusion set-up), the distances and the command at every step, and the ground truth
  (coal, every 5th step and at every frame), which a real system would not compute;
- the time of one control step (the distances from the latest set and the command), median and worst: the worst is
  the first query on a new set, which classifies the depth grid's cells;
- what the run did: the smallest clearance (exact, robot meshes to the person), the task error at the end, and the
  share of steps whose command was slowed (task scale or speed factor below 0.99).

    .venv/bin/python benchmarks/bench_closed_loop.py [--start 1.9] [--duration 1.3]
"""

from __future__ import annotations

import argparse
from importlib import resources
from pathlib import Path

import numpy as np

from depthguard.errors import InputError
from depthguard_lab.simulation import load_workcell
from depthguard_lab.simulation._closed_loop import MODES, LoopSettings, run_closed_loop
from _common import report


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--start", type=float, default=1.9)
    parser.add_argument("--duration", type=float, default=1.3)
    args = parser.parse_args()
    workcell = load_workcell(Path(str(resources.files("depthguard_lab.simulation").joinpath("scenario_b_reach.yaml"))))
    print(f"scenario_b_reach, {args.start:g} s to {args.start + args.duration:g} s, control 500 Hz, cameras "
          f"{workcell.rate:g} Hz, 2 cameras 640x480, "
          f"{len(workcell.robot.with_surface_points(LoopSettings().surface_tolerance).control_points)} points covering "
          "the arm")
    print(f"{'mode':6s} {'sim s / wall s':>14s} {'step median ms':>15s} {'step worst ms':>14s} {'min clearance m':>16s} "
          f"{'task error end m':>17s} {'slowed steps':>13s}")
    for mode in MODES:
        try:
            log = run_closed_loop(workcell, mode, start=args.start, duration=args.duration)
        except InputError as error:  # SSM that cannot be sound here (ISO 13855's 70 mm): said, not run
            print(f"{mode:6s} refused: {str(error).split(': ', 1)[-1]}")
            continue
        simulated = len(log.times) / 500.0
        print(f"{mode:6s} {simulated / log.wall_seconds:14.3f} {np.median(log.step_seconds) * 1e3:15.2f} "
              f"{log.step_seconds.max() * 1e3:14.1f} {log.clearance.min():16.3f} {log.task_error[-1]:17.3f} "
              f"{np.mean(log.scale < 0.99):13.0%}")


if __name__ == "__main__":
    with report(__file__):
        main()
