"""What SSM's detectable space costs (``DistanceMonitor(detection_capability=0.04)``, issue 9), against the same
monitor without it, in the SSM cell (scenario_b_reach.yaml seen by scenario_b_ssm.yaml's five cameras, the room's
solids known, the loop's rho). With the settings the monitor accepts for it: no robot zone and holes occupied (with
the loop's robot zone and hole fills, d plus what they hide is above ISO 13855's 70 mm and the monitor refuses).

Per set of frames (the same sets for both monitors, rendered once beforehand): ``prepare_set`` with and without the
detectable space; per control step: the nine control points' detectable distances against the depth grid's query of
the same points (its first query on a set, which classifies the cells, and a second one). Medians over the sets, and
their ratios:

    .venv/bin/python benchmarks/bench_detectable_space.py [--sets 12]
"""

from __future__ import annotations

import argparse
import time
from importlib import resources
from pathlib import Path

import numpy as np

import depthguard as dg
from depthguard import config
from depthguard_lab.simulation import load_workcell
from depthguard_lab.simulation._episode import sense_at
from _common import report


def _seconds(function) -> tuple[float, object]:
    start = time.perf_counter()
    value = function()
    return time.perf_counter() - start, value


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sets", type=int, default=12, help="sets of frames, spread over the scene (default 12)")
    args = parser.parse_args(argv)
    package = resources.files("depthguard_lab.simulation")
    workcell = load_workcell(Path(str(package / "scenario_b_reach.yaml")),
                             layout=Path(str(package / "scenario_b_ssm.yaml")))
    robot = workcell.robot
    static = workcell.background_parts()
    options = dict(rho=1.2, robot=robot, aggregate="hybrid", static=static)
    monitors = {"without": dg.DistanceMonitor(workcell.rig, **options),
                "with": dg.DistanceMonitor(workcell.rig, **options,
                                           detection_capability=config.SSM_DETECTION_CAPABILITY)}
    times = np.linspace(0.5, workcell.duration - 0.1, args.sets)
    frames = [(frame.time, frame.joints, frame) for frame in sense_at(workcell, times)]
    rows = {key: [] for key in ("prepare without", "prepare with", "query first", "query again", "detectable")}
    for index, (t, q, frame) in enumerate(frames):
        points = robot.control_point_positions(q)
        seconds, _ = _seconds(lambda: monitors["without"].prepare_set(frame.depth, joints=q, now=t))
        seconds_with, prepared = _seconds(lambda: monitors["with"].prepare_set(frame.depth, joints=q, now=t))
        first, _ = _seconds(lambda: prepared.query(points))
        again, _ = _seconds(lambda: prepared.query(points))
        detectable, _ = _seconds(lambda: prepared.detectable_distances(points, limit=1.2))
        if index == 0:
            continue  # the first set compiles and loads what it needs
        for key, value in zip(rows, (seconds, seconds_with, first, again, detectable)):
            rows[key].append(value)
    median = {key: float(np.median(values)) for key, values in rows.items()}
    box = monitors["with"].detectable.box
    print(f"{len(workcell.rig.cameras)} cameras, detectable space {box.shape} voxels of {box.voxel * 100:g} cm; "
          f"medians over {len(rows['detectable'])} sets of frames\n")
    print(f"{'per set of frames':34s} {'ms':>8s}")
    print(f"{'prepare_set without':34s} {median['prepare without'] * 1e3:8.1f}")
    print(f"{'prepare_set with the detectable':34s} {median['prepare with'] * 1e3:8.1f}   "
          f"x{median['prepare with'] / median['prepare without']:.2f}")
    print(f"\n{'per control step, 9 points':34s} {'ms':>8s}")
    print(f"{'depth grid query, first on a set':34s} {median['query first'] * 1e3:8.2f}")
    print(f"{'depth grid query, again':34s} {median['query again'] * 1e3:8.2f}")
    print(f"{'detectable distances':34s} {median['detectable'] * 1e3:8.2f}   "
          f"x{median['detectable'] / median['query again']:.2f} of the query again")


if __name__ == "__main__":
    with report(__file__):
        main()
