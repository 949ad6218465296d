"""The free-space memory's figures (design §8a): per frame, the voxels the cameras see free and the memory's
update, with 1 and 2 numba threads, and the memory it holds.

The scene: the depth grid benchmark's room seen by two and four 640x480 cameras (525 px focal length, 0.5-7 m), a
person reaching towards a pillar where the robot would stand; the box is 3 x 3 x 2 m around it, cut in 4 cm and 2 cm
voxels. Per frame:

- ``seen_free_voxels`` (the cameras' free images as :func:`depthguard.depthgrid.free_image` gives them, a 1 cm
  margin and 1 pixel of pad, as the depth grid's defaults): which voxels some camera sees entirely free;
- ``FreeSpaceMemory.update`` at 30 Hz with those voxels (its exact distance transform, then the arrival times); its
  baseline in the same run is ``scipy.ndimage.distance_transform_edt`` on the same possibly-occupied voxels padded by
  a layer of them (the distances alone), against our distance transform alone on the same voxels; the ratio is
  scipy's time over ours.

Medians, because this machine is noisy. With numba's OpenMP threading layer, a worker thread that has gone to sleep
between two calls takes milliseconds to wake on some virtual machines (8 ms on the development VM, for every parallel
region); ``OMP_WAIT_POLICY=ACTIVE`` keeps the workers spinning, which shows the kernels' own time with 2 threads:

    .venv/bin/python benchmarks/bench_freespace.py [--repeats 5]
    OMP_WAIT_POLICY=ACTIVE .venv/bin/python benchmarks/bench_freespace.py
"""

from __future__ import annotations

import argparse
import os
import time

import numba
import numpy as np
from scipy import ndimage

import depthguard as dg
from depthguard.depthgrid import free_image
from depthguard.freespace import FreeSpaceMemory, VoxelBox, seen_free_voxels, squared_distance_transform
from depthguard.scenes import Box, render_depth
from depthguard_lab.simulation import standing_person
from depthguard.transforms import look_at
from _common import report

EYES = {"principal": [1.5, -2.0, 1.8], "second": [1.5, 2.0, 1.8], "third": [-1.8, -1.6, 2.0],
        "fourth": [-1.8, 1.6, 2.0]}
TARGET = [0.2, 0.0, 0.9]
BOX = ([-1.3, -1.5, 0.0], [1.7, 1.5, 2.0])  # 3 x 3 x 2 m around the target
RATE = 30.0  # frames per second


def cameras():
    return [dg.PinholeCamera(n, 640, 480, 525.0, 525.0, 319.5, 239.5, look_at(eye, TARGET), depth_range=(0.5, 7.0))
            for n, eye in EYES.items()]


def free_images(cams):
    """Each camera's free image of the room, a pillar where the robot would stand and a person reaching to it."""
    scene = [Box.from_bounds([-2.3, -3.1, -0.05], [4, 3.1, 0.0]), Box.from_bounds([-2.4, -3.1, 0.0], [-2.3, 3.1, 2.5]),
             Box.from_bounds([-2.3, 3.0, 0.0], [4, 3.1, 2.5]), Box.from_bounds([-2.3, -3.1, 0.0], [4, -3.0, 2.5]),
             Box.from_bounds([-0.15, -0.15, 0.0], [0.15, 0.15, 1.0])]
    scene += standing_person((0.95, 0.35), facing=np.pi * 1.1, reach=0.9)
    return [free_image(dg.depth_image(np.round(render_depth(c, scene) * 1000).astype(np.uint16), c), c) for c in cams]


def median_seconds(fn, repeats: int, warmup: int = 2) -> float:
    for _ in range(warmup):
        fn()
    out = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return float(np.median(out))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    cams = cameras()
    images = free_images(cams)
    threads_available = numba.config.NUMBA_NUM_THREADS
    thread_counts = [n for n in (1, 2) if n <= threads_available]
    seen_free_voxels(VoxelBox([0, 0, 1], [0.1, 0.1, 1.1], 0.1), cams[:1], images[:1])  # starts numba's threads
    print(f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} before the run (when it exceeds the number "
          f"of cores, other processes share them and the 2-thread figures mean little); numba threading layer "
          f"{numba.threading_layer()}, OMP_WAIT_POLICY={os.environ.get('OMP_WAIT_POLICY', 'unset')}\n")

    print(f"seen_free_voxels: 640x480 cameras, a {np.subtract(BOX[1], BOX[0]).tolist()} m box, margin 1 cm, pad 1 "
          f"pixel; median of {args.repeats} ms per frame")
    print(f"  {'voxel':>6s} {'voxels':>10s} {'cameras':>7s} " + " ".join(f"{f'{n} thread ms':>11s}"
                                                                      for n in thread_counts) + f" {'seen':>6s}")
    seen_masks = {}
    for voxel in (0.04, 0.02):
        box = VoxelBox(*BOX, voxel)
        for n_cameras in (2, 4):
            times = []
            for threads in thread_counts:
                numba.set_num_threads(threads)
                times.append(median_seconds(lambda: seen_free_voxels(box, cams[:n_cameras], images[:n_cameras],
                                                                     0.01, 1), args.repeats))
            seen = seen_free_voxels(box, cams[:n_cameras], images[:n_cameras], 0.01, 1)
            seen_masks[(voxel, n_cameras)] = seen
            print(f"  {voxel * 100:4.0f}cm {box.size:10d} {n_cameras:7d} " +
                  " ".join(f"{t * 1e3:11.1f}" for t in times) + f" {seen.mean() * 100:5.1f}%")

    print(f"\nFreeSpaceMemory.update at {RATE:.0f} Hz with the four cameras' seen voxels, against scipy's "
          "distance_transform_edt on the same padded possibly-occupied voxels; median ms per update")
    print(f"  {'voxel':>6s} {'voxels':>10s} {'threads':>7s} {'update':>8s} {'our EDT':>8s} {'scipy EDT':>9s} "
          f"{'ratio':>6s} {'memory MB':>9s}")
    for voxel in (0.04, 0.02):
        box = VoxelBox(*BOX, voxel)
        seen = seen_masks[(voxel, 4)]
        for threads in thread_counts:
            numba.set_num_threads(threads)
            memory = FreeSpaceMemory(box)
            clock = [0.0]

            def update():
                clock[0] += 1.0 / RATE
                memory.update(clock[0], seen)

            ours = median_seconds(update, args.repeats)
            occupied = (memory.arrival <= memory.time) & ~seen
            edt = median_seconds(lambda: squared_distance_transform(occupied), args.repeats)
            padded = ~np.pad(occupied, 1, constant_values=True)
            scipy_edt = median_seconds(lambda: ndimage.distance_transform_edt(padded), args.repeats)
            print(f"  {voxel * 100:4.0f}cm {box.size:10d} {threads:7d} {ours * 1e3:8.1f} {edt * 1e3:8.1f} "
                  f"{scipy_edt * 1e3:9.1f} {scipy_edt / edt:6.1f} {memory.nbytes / 1e6:9.1f}")
    big = VoxelBox([0, 0, 0], [2.5, 2.5, 2.5], 2.5 / 251)
    print(f"\nmemory: {FreeSpaceMemory(big).nbytes / 1e6:.0f} MB for the largest box ({big.size} voxels, "
          f"config.FREESPACE_MAX_VOXELS); seen_free_voxels' sparse tables take 10 levels x 640 x 480 float32 = "
          f"{10 * 640 * 480 * 4 / 1e6:.1f} MB per camera while it runs")


if __name__ == "__main__":
    with report(__file__):
        main()
