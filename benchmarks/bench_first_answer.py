"""How soon a new process answers: the time to import depthguard, and to answer a first query on two 640x480
cameras, fused, and on one of them (the baseline), with the kernels already cached (after ``depthguard warmup``).

Each run is a new interpreter; the table gives the median and the range over ``--runs`` runs.

    .venv/bin/python benchmarks/bench_first_answer.py [--runs 5]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

import numpy as np

from _common import report

RUN = r"""
import json, time
t0 = time.perf_counter()
import depthguard as dg
t1 = time.perf_counter()
from depthguard.scenes import Box, Sphere, render_depth
from depthguard.transforms import look_at
cameras = {n: dg.PinholeCamera(n, 640, 480, 525.0, 525.0, 319.5, 239.5, look_at(e, [0, 0, 0.3]), depth_range=(0.3, 6.0))
           for n, e in (("a", (2.0, 1.0, 1.5)), ("b", (2.0, -1.0, 1.5)))}
rig = dg.Rig(cameras, principal="a", workspace=[[-1, -1, -0.1], [1, 1, 1.5]])
scene = [Box.from_bounds([-3, -3, -0.2], [3, 3, 0.0]), Sphere((0.0, 0.0, 0.4), 0.15)]
frames = {n: dg.depth_image(render_depth(c, scene), c, timestamp=0.0) for n, c in cameras.items()}
t2 = time.perf_counter()
dg.DistanceMonitor(dg.Rig({"a": cameras["a"]})).query({"a": frames["a"]}, [[0.0, 0.0, 0.8]], now=0.0)
t3 = time.perf_counter()
dg.DistanceMonitor(rig).query(frames, [[0.0, 0.0, 0.8]], now=0.0)
t4 = time.perf_counter()
print(json.dumps({"import": t1 - t0, "single": t3 - t2, "fused": t4 - t3}))
"""


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args(argv)
    runs = []
    for _ in range(args.runs):
        done = subprocess.run([sys.executable, "-c", RUN], capture_output=True, text=True, timeout=600, check=True)
        runs.append(json.loads(done.stdout.strip().splitlines()[-1]))
    print(f"A new process, kernels cached, {args.runs} runs (median, min-max), seconds\n")
    print(f"{'step':44s} {'median':>7s} {'range':>13s}")
    for key, label in (("import", "import depthguard"),
                       ("single", "first answer, one camera (baseline)"),
                       ("fused", "first answer, two cameras fused (new monitor)")):
        values = np.array([r[key] for r in runs])
        print(f"{label:44s} {np.median(values):7.2f} {values.min():6.2f}-{values.max():.2f}")


if __name__ == "__main__":
    with report(__file__):
        main()
