"""Shared helpers of the benchmarks: scenes and a timer that reports medians (this machine is noisy)."""

from __future__ import annotations

import contextlib
import io
import time
from pathlib import Path

import numpy as np

import depthguard as dg
from depthguard.scenes import Box, render_depth, scene_distance
from depthguard_lab.simulation import standing_person
from depthguard.transforms import look_at


def timings(fn, repeats: int, warmup: int = 3) -> np.ndarray:
    """Seconds per call of ``fn()`` over ``repeats`` calls, after ``warmup`` untimed calls."""
    for _ in range(warmup):
        fn()
    out = np.empty(repeats)
    for i in range(repeats):
        t = time.perf_counter()
        fn()
        out[i] = time.perf_counter() - t
    return out


def nearer(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per pixel the nearer of two depth images ((h, w), metres, 0 where nothing is seen): two renders composited."""
    return np.where(a > 0, np.minimum(a, np.where(b > 0, b, np.inf)), b)


def person_scene(seed: int = 0):
    """The single-camera benchmark scene of issue 2: a 640x480 Kinect-like camera, a standing person 1.5-2.5 m from
    it reaching forward, a floor and a back wall, and 9 control points within 0.5 m of the person.

    Returns (camera, depth image (uint16 millimetres, quantised), primitives, control points (9, 3) world metres).
    """
    camera = dg.PinholeCamera("kinect", 640, 480, 525.0, 525.0, 319.5, 239.5,
                              look_at([2.4, 0.3, 1.5], [0.0, 0.0, 0.9]), depth_range=(0.4, 8.0))
    primitives = [Box.from_bounds([-3, -3, -0.1], [4, 3, 0.0]), Box.from_bounds([-2.2, -3, 0], [-2.1, 3, 3])]
    primitives += standing_person((0.1, 0.0), facing=0.0, reach=0.8)
    depth_m = render_depth(camera, primitives)
    depth = dg.depth_image(np.round(depth_m * 1000.0).astype(np.uint16), camera)
    rng = np.random.default_rng(seed)
    points = []
    person = primitives[2:]
    while len(points) < 9:
        p = rng.uniform([-0.5, -0.7, 0.3], [1.3, 0.7, 1.9])
        d = scene_distance(person, p[None])[0]
        if 0.03 < d < 0.5 and scene_distance(primitives[:2], p[None])[0] > 0.3:
            points.append(p)
    return camera, depth, primitives, np.array(points)


#: Where each benchmark writes its report (docs/figures/<script>.md): the README links these, never copies them.
FIGURES = Path(__file__).resolve().parent.parent / "docs" / "figures"


class _Tee(io.TextIOBase):
    """Writes to the terminal and keeps a copy."""

    def __init__(self, stream):
        self.stream, self.copy = stream, io.StringIO()

    def write(self, text):
        self.copy.write(text)
        return self.stream.write(text)

    def flush(self):
        self.stream.flush()


@contextlib.contextmanager
def report(script: str, name: str | None = None):
    """Run a benchmark's ``main()`` inside this: what it prints goes to the terminal as before and, when it ends
    without an exception, to ``docs/figures/<script's name>.md`` (written whole), headed by the command, the date,
    the machine (CPU, cores, numba threads) and the commit (``name``: another file name than the script's, for a
    benchmark whose options make different tables). A failed run leaves the last report as it was."""
    import datetime
    import os
    import platform
    import subprocess
    import sys

    import numba

    from depthguard.io.files import write_whole

    tee = _Tee(sys.stdout)
    with contextlib.redirect_stdout(tee):
        yield
    name = name or Path(script).stem
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                cwd=FIGURES.parent.parent, timeout=10).stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        commit = "unknown"
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), cpu)
    except OSError:
        pass
    command = " ".join(["benchmarks/" + Path(script).name] + sys.argv[1:])
    header = (f"# {name}\n\n`.venv/bin/python {command}`, {datetime.date.today().isoformat()}, commit {commit}; "
              f"{cpu}, {os.cpu_count()} cores, numba {numba.config.NUMBA_NUM_THREADS} threads.\n\n"
              "Written by the benchmark itself (`benchmarks/_common.py: report`); run it again to refresh.\n\n")
    FIGURES.mkdir(parents=True, exist_ok=True)
    write_whole(FIGURES / f"{name}.md", header + "```\n" + tee.copy.getvalue().rstrip("\n") + "\n```\n")
