"""Does preparing a set of frames hold up a thread that receives the next frames? (the GIL)

A node receives frames on one thread (zenoh's callback, a ROS subscriber) while another prepares the last set. Every
moment the preparing thread holds Python's GIL, the receiving thread waits. Here a receiving thread wakes every
2 ms (``time.sleep``, which releases the GIL) and measures how late it runs, while the main thread:

1. sleeps (the baseline: the receiver alone);
2. prepares new sets of frames one after another (scenario B's two 640x480 cameras, the iiwa self-filtered, memory
   on, 9 control points): ``DistanceMonitor.query`` on frames it has not seen;
3. runs later queries on one prepared set (the kernels alone, nothing to prepare);

and, to show what the receiver would see, two calibrations: a 20 ms numba loop compiled as depthguard's kernels were
before they released the GIL, and the same loop with ``nogil=True``.

It prints the receiver's lateness (median, p99, max) in each case. Python's switch interval, the longest a thread
running Python code keeps the GIL from one that waits, is ``sys.getswitchinterval()`` (5 ms by default): a wait
longer than that comes from code that holds the GIL without running Python (a kernel, a C call).

    .venv/bin/python benchmarks/bench_gil.py [--seconds 4] [--sets 8]
"""

from __future__ import annotations

import argparse
import sys
import threading
import time

import numpy as np

from _common import report

PERIOD = 0.002  # seconds between the receiver's wake-ups


class Receiver(threading.Thread):
    """Wakes every PERIOD seconds and records how late it runs (seconds)."""

    def __init__(self):
        super().__init__(daemon=True)
        self.lateness: list[float] = []
        self.stop = threading.Event()

    def run(self):
        while not self.stop.is_set():
            target = time.perf_counter() + PERIOD
            time.sleep(PERIOD)
            self.lateness.append(time.perf_counter() - target)


def measure(work, seconds: float) -> np.ndarray:
    """The receiver's lateness (ms) while ``work()`` runs over and over for ``seconds``."""
    receiver = Receiver()
    receiver.start()
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        work()
    receiver.stop.set()
    receiver.join()
    return np.array(receiver.lateness[5:]) * 1e3


def spin_kernels():
    """Two numba loops of about 20 ms: one holding the GIL while it runs, one releasing it."""
    import numba

    def spin(n):
        x = 0.0
        for i in range(n):
            x += np.sqrt(i + x * 1e-9)
        return x

    held, released = numba.njit(spin), numba.njit(nogil=True)(spin)
    n = 1000
    held(n)
    released(n)
    while True:  # the loop count that takes about 20 ms
        start = time.perf_counter()
        held(n)
        if time.perf_counter() - start > 0.02:
            break
        n *= 2
    return (lambda: held(n)), (lambda: released(n))


def scene(sets: int):
    """Scenario B's two cameras: the rig, the robot and ``sets`` sets of frames (DepthImages, joints, times)."""
    from depthguard_lab.simulation import default_workcell
    from depthguard_lab.simulation._episode import sense_at

    workcell = default_workcell()
    frames = sense_at(workcell, list(np.linspace(1.2, 3.4, sets)))
    return workcell.rig, workcell.robot, [(f.depth, f.joints, float(f.time)) for f in frames]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=4.0, help="seconds per case (default 4)")
    parser.add_argument("--sets", type=int, default=8, help="distinct sets of frames cycled through (default 8)")
    args = parser.parse_args(argv)
    import depthguard as dg

    rig, robot, sets = scene(args.sets)
    monitor = dg.DistanceMonitor(rig, robot=robot)
    for images, joints, t in sets[:2]:  # compile and build the maps first
        monitor.query(images, robot.control_point_positions(joints), joints=joints, now=t)
    counter = {"k": 0, "prepared": 0}

    def prepare():
        images, joints, t = sets[counter["k"] % len(sets)]
        counter["k"] += 1
        # New DepthImage objects: the monitor prepares them afresh, as it would new frames.
        fresh = {name: dg.DepthImage(image.camera, image.data, image.depth_scale, timestamp=t)
                 for name, image in images.items()}
        monitor.query(fresh, robot.control_point_positions(joints), joints=joints, now=t)
        counter["prepared"] += 1

    images, joints, t = sets[0]
    prepared = monitor.prepare_set(images, joints=joints, now=t)
    points = robot.control_point_positions(joints)

    def later_query():
        prepared.query(points, check=False)

    held, released = spin_kernels()
    cases = [("main thread sleeps (baseline)", lambda: time.sleep(0.05)),
             ("calibration: 20 ms kernel holding the GIL", held),
             ("calibration: 20 ms kernel with nogil", released),
             ("main thread prepares new sets", prepare),
             ("main thread queries one prepared set", later_query)]
    print(f"receiving thread: wakes every {PERIOD * 1e3:g} ms; lateness in ms, {args.seconds:g} s per case; "
          f"switch interval {sys.getswitchinterval() * 1e3:g} ms\n")
    print(f"{'main thread':40s} {'wakes':>6s} {'median':>7s} {'p99':>7s} {'max':>7s}")
    for label, work in cases:
        start = counter["prepared"]
        late = measure(work, args.seconds)
        print(f"{label:40s} {len(late):6d} {np.median(late):7.2f} {np.percentile(late, 99):7.2f} {late.max():7.2f}")
        if work is prepare:
            per_set = args.seconds / max(counter["prepared"] - start, 1) * 1e3
            print(f"{'':40s} ({counter['prepared'] - start} sets prepared, {per_set:.1f} ms a set)")
    print("\ngoal: p99 <= 5 ms while sets are prepared")


if __name__ == "__main__":
    with report(__file__):
        main()
