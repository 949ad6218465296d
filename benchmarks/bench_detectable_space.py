"""What SSM's detectable space costs (``DistanceMonitor(detection_capability=0.04)``, issue 9), against the same
monitor without it, in the SSM cell (scenario_b_reach.yaml seen by scenario_b_ssm.yaml's five cameras, the room's
solids known, the loop's rho). With the settings the monitor accepts for it: no robot zone and holes occupied (with
the loop's robot zone and hole fills, d plus what they hide is above ISO 13855's 70 mm and the monitor refuses).

Per set of frames (the same sets for both monitors, rendered once beforehand): ``prepare_set`` with and without the
detectable space, and what the detectable space adds to a set: since it is decided block by block where queries
reach (``DetectableSpace.watch``), the set's first detectable query of the nine control points pays for it. Baseline
in the same run: the whole box decided every set (``FreeSources.mask`` and ``DetectableSpace.update``, what the
monitor did before), whose answers must be the same bit for bit. Per control step: the nine control points'
detectable distances again, against the depth grid's query of the same points (its first query on a set, which
classifies the cells, and a second one). Medians over the sets, and their ratios:

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
from depthguard.freespace import DetectableSpace
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
    keys = ("prepare without", "prepare with", "query first", "query again", "detectable first", "detectable",
            "off first", "whole box")
    rows = {key: [] for key in keys}
    off_answers = []
    for index, (t, q, frame) in enumerate(frames):
        points = robot.control_point_positions(q)
        seconds, _ = _seconds(lambda: monitors["without"].prepare_set(frame.depth, joints=q, now=t))
        seconds_with, prepared = _seconds(lambda: monitors["with"].prepare_set(frame.depth, joints=q, now=t))
        first, _ = _seconds(lambda: prepared.query(points))
        again, _ = _seconds(lambda: prepared.query(points))
        detectable_first, answer = _seconds(lambda: prepared.detectable_distances(points, limit=1.2))
        detectable, _ = _seconds(lambda: prepared.detectable_distances(points, limit=1.2))
        # The control points lie on the arm, whose own body the detectable space counts as possibly occupied (no
        # robot zone): their answers are 0 and cost little. Nine points 0.2 m out from them (horizontally, away
        # from the base's axis) have answers to look for: the same frames prepared again, their first query.
        radial = points[:, :2] / np.maximum(np.linalg.norm(points[:, :2], axis=1, keepdims=True), 1e-9)
        off = points + 0.2 * np.concatenate([radial, np.zeros((len(points), 1))], axis=1)
        again_prepared = monitors["with"].prepare_set(frame.depth, joints=q, now=t)
        off_first, off_answer = _seconds(lambda: again_prepared.detectable_distances(off, limit=1.2))
        off_answers.append(off_answer.distance)
        space = prepared.detectable
        twin = DetectableSpace(space.box, space.capability, space.beyond)
        whole, _ = _seconds(lambda: twin.update(space._watched[0].mask(space.box)))
        for where in (points, off):
            if not np.array_equal(twin.distances(where, 1.2), space.distances(where, 1.2)):
                raise SystemExit("the watched space and the whole box disagree")
        if index == 0:
            continue  # the first set compiles and loads what it needs
        for key, value in zip(keys, (seconds, seconds_with, first, again, detectable_first, detectable, off_first,
                                     whole)):
            rows[key].append(value)
    median = {key: float(np.median(values)) for key, values in rows.items()}
    box = monitors["with"].detectable.box
    print(f"{len(workcell.rig.cameras)} cameras, detectable space {box.shape} voxels of {box.voxel * 100:g} cm; "
          f"medians over {len(rows['detectable'])} sets of frames\n")
    print(f"{'per set of frames':34s} {'ms':>8s}")
    print(f"{'prepare_set without':34s} {median['prepare without'] * 1e3:8.1f}")
    print(f"{'prepare_set with the detectable':34s} {median['prepare with'] * 1e3:8.1f}   "
          f"x{median['prepare with'] / median['prepare without']:.2f}")
    views = median['prepare with'] - median['prepare without']
    whole = views + median['whole box']
    print(f"{'  first detectable query, 9 points':34s}")
    for label, key, note in (("on the arm (answers 0)", "detectable first", ""),
                             ("0.2 m out from it", "off first",
                              f" (answers {np.min(off_answers):.2f}-{np.max(off_answers):.2f} m)")):
        added = views + median[key]
        print(f"{'    ' + label:34s} {median[key] * 1e3:8.1f}   added per set {added * 1e3:.1f} ms, goal <= 15 ms: "
              f"{'met' if added <= 0.015 else 'NOT met'}; x{whole / added:.0f} less than the whole box{note}")
    print(f"{'  added per set: the whole box':34s} {whole * 1e3:8.1f}   (baseline in this run, what the monitor did "
          f"before: the same answers)")
    print(f"\n{'per control step, 9 points':34s} {'ms':>8s}")
    print(f"{'depth grid query, first on a set':34s} {median['query first'] * 1e3:8.2f}")
    print(f"{'depth grid query, again':34s} {median['query again'] * 1e3:8.2f}")
    print(f"{'detectable distances again':34s} {median['detectable'] * 1e3:8.2f}   "
          f"x{median['detectable'] / median['query again']:.2f} of the query again")


if __name__ == "__main__":
    with report(__file__):
        main()
