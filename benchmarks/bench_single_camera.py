"""Single-camera distance queries per second: depthguard against the papers' and the practical baselines.

Scene: one 640x480 camera, a person 1.5-2.5 m away, 9 control points within 0.5 m of the person, rho = 0.4 m
(issue 2's figures). Every method runs in the same process on the same frame; the table reports medians because
this machine is shared and noisy.

    .venv/bin/python benchmarks/bench_single_camera.py [--repeats 300]
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))

import depthguard as dg  # noqa: E402
from depthguard import baselines  # noqa: E402
from _common import person_scene, report, timings  # noqa: E402

RHO = 0.4


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=300)
    args = parser.parse_args(argv)
    camera, depth, _, points = person_scene()
    occupancy = dg.prepare_depth(depth, camera)
    distances = {a: dg.single_camera_distances(occupancy, points, RHO, a) for a in ("min", "mean", "hybrid")}
    contributors = distances["hybrid"].count
    print(f"scene: 640x480, person 1.5-2.5 m from the camera, {len(points)} control points, rho = {RHO} m; "
          f"contributors per point: {contributors.min()}-{contributors.max()} (total {contributors.sum()})")

    def query(aggregate, method="exact"):
        return lambda: dg.single_camera_distances(occupancy, points, RHO, aggregate, method=method, check=False)

    rows = [
        ("depthguard hybrid, 9 points (prepared frame)", query("hybrid")),
        ("depthguard mean, 9 points (prepared frame)", query("mean")),
        ("depthguard min, 9 points (prepared frame)", query("min")),
        ("depthguard frame preparation (once per frame)", lambda: dg.prepare_depth(depth, camera)),
        ("depthguard new frame + hybrid query", lambda: dg.single_camera_distances(
            dg.prepare_depth(depth, camera), points, RHO, "hybrid", check=False)),
        ("paper formulas (method='paper'), hybrid, 9 points", query("hybrid", "paper")),
        ("Cartesian window baseline (2015 sec. 4), 9 points", lambda: baselines.cartesian_region_distances(
            depth, camera, points, RHO)),
        ("KD-tree baseline: build + query per frame", lambda: baselines.kdtree_distances(depth, camera, points, RHO)),
    ]
    results = {}
    print(f"\n{'method':55s} {'median ms':>10s} {'p90 ms':>9s} {'best ms':>9s} {'per s':>9s}")
    for name, fn in rows:
        t = timings(fn, args.repeats if "KD" not in name else max(10, args.repeats // 10))
        results[name] = t
        print(f"{name:55s} {np.median(t) * 1e3:10.3f} {np.percentile(t, 90) * 1e3:9.3f} {t.min() * 1e3:9.3f} "
              f"{1.0 / np.median(t):9.0f}")
    hybrid = np.median(results[rows[0][0]])
    new_frame = np.median(results[rows[4][0]])
    kdtree = np.median(results[rows[-1][0]])
    print(f"\nhybrid queries per second (goal >= 1000): {1.0 / hybrid:.0f}")
    print(f"KD-tree baseline / depthguard, per new frame (both include the frame's preprocessing): "
          f"{kdtree / new_frame:.1f}x")
    print(f"KD-tree baseline / depthguard hybrid query on a prepared frame: {kdtree / hybrid:.1f}x")


if __name__ == "__main__":
    with report(__file__):
        main()
