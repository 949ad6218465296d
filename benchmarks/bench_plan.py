"""The wave-propagation planner (Henrich & Gecks, section 5): a shortest path over a discretised configuration space.

For the paper's 8,192 configurations (a 6-joint grid of 8 x 8 x 8 x 4 x 2 x 2 cells) with random obstacle cells
(10 % and 30 %, seeded) and start and goal at opposite corners (both made free): the median time of
:func:`depthguard.collision._plan.wave_propagation` (checks, the numba wave and the path as index tuples). Goal:
<= 50 ms per plan. Baseline in the same run: the same wave in plain Python (a ``collections.deque`` over flat
indices, the same early stop and tie-breaking; its path is checked equal). One more row at 262,144 cells
(16 x 16 x 16 x 8 x 4 x 2).

    .venv/bin/python benchmarks/bench_plan.py [--repeats 50] [--baseline-repeats 5]
"""

from __future__ import annotations

import argparse
import os
import sys
from collections import deque

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))

from _common import report, timings  # noqa: E402

from depthguard.collision._plan import wave_propagation  # noqa: E402

GOAL_MS = 50.0


def python_wave(free, start, goal):
    """The planner's wave in plain Python: breadth first from ``goal`` over flat indices until ``start`` is
    numbered, then down the numbers from ``start`` (joint 0 first, step down before up). None when unreachable."""
    shape = free.shape
    strides = [int(np.prod(shape[d + 1:])) for d in range(len(shape))]
    flat = free.reshape(-1).tolist()
    s = sum(i * k for i, k in zip(start, strides))
    g = sum(i * k for i, k in zip(goal, strides))
    if not flat[s] or not flat[g]:
        return None
    axes = list(zip(strides, shape))
    wave = {g: 0}
    queue = deque([g])
    while queue and s not in wave:
        cell = queue.popleft()
        number = wave[cell] + 1
        for stride, count in axes:
            index = cell // stride % count
            if index > 0 and flat[cell - stride] and cell - stride not in wave:
                wave[cell - stride] = number
                queue.append(cell - stride)
            if index < count - 1 and flat[cell + stride] and cell + stride not in wave:
                wave[cell + stride] = number
                queue.append(cell + stride)
    if s not in wave:
        return None
    path = [s]
    while path[-1] != g:
        cell = path[-1]
        for stride, count in axes:
            index = cell // stride % count
            if index > 0 and wave.get(cell - stride) == wave[cell] - 1:
                path.append(cell - stride)
                break
            if index < count - 1 and wave.get(cell + stride) == wave[cell] - 1:
                path.append(cell + stride)
                break
    return [tuple(int(i) for i in np.unravel_index(cell, shape)) for cell in path]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=50)
    parser.add_argument("--baseline-repeats", type=int, default=5)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    rows = []
    for shape, obstacles in [((8, 8, 8, 4, 2, 2), 0.1), ((8, 8, 8, 4, 2, 2), 0.3), ((16, 16, 16, 8, 4, 2), 0.1),
                             ((16, 16, 16, 8, 4, 2), 0.3)]:
        free = rng.random(shape) >= obstacles
        start, goal = (0,) * len(shape), tuple(c - 1 for c in shape)
        free[start] = free[goal] = True
        path = wave_propagation(free, start, goal)  # compiles (or loads) the kernel
        assert path == python_wave(free, start, goal)
        fast = float(np.median(timings(lambda: wave_propagation(free, start, goal), args.repeats))) * 1e3
        slow = float(np.median(timings(lambda: python_wave(free, start, goal), args.baseline_repeats,
                                       warmup=1))) * 1e3
        rows.append((shape, free.size, obstacles, "none" if path is None else len(path) - 1, fast, slow))
    print(f"wave propagation, corner to corner, median of {args.repeats} plans (Python deque: "
          f"{args.baseline_repeats}); goal <= {GOAL_MS:.0f} ms")
    print(f"{'grid':22s} {'cells':>8s} {'obstacles':>9s} {'steps':>5s} {'wave ms':>8s} {'goal':>5s} "
          f"{'Python ms':>9s} {'ratio':>6s}")
    for shape, cells, obstacles, steps, fast, slow in rows:
        grid = " x ".join(map(str, shape))
        ok = "ok" if fast <= GOAL_MS else "MISS"
        print(f"{grid:22s} {cells:8d} {obstacles:9.0%} {steps!s:>5s} {fast:8.3f} {ok:>5s} {slow:9.1f} "
              f"{slow / fast:5.0f}x")


if __name__ == "__main__":
    with report(__file__):
        main()
