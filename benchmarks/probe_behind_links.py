"""Why points on the robot read below rho when fused (issue 8): the uncleared cells right behind the links.

For every principal pixel that shows the robot, the depth grid's candidate space starts at ``blind_from`` (where the
robot's padded body ends along the pixel, plus the self-filter's slack and the noise margin). This probe classifies
the 12 cells from there on with the fusion's own kernel (:func:`depthguard.kernels.depthgrid.classify_run`) and
counts how many cells in a row no secondary camera clears: a run of 0 means the space right behind the link is
cleared; a short run is a thin shell that only a detection capability (an object size below which unseen space is not
an obstacle) could remove; a long run is a real hidden pocket (around the base, the pedestal, links hiding each
other).

It runs scenario B's shadow and hidden-hand frames (every 25th) for the layouts given (default: the two-camera and
the four-camera ToF layout) and prints the distribution of run lengths over a sample of those pixels (every 7th):

    .venv/bin/python benchmarks/probe_behind_links.py [--scene scenario_b_four_tof.yaml ...]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import depthguard as dg
from depthguard.kernels import depthgrid as grid_kernels
from depthguard_lab.experiments import fusion_workcell as fw
from depthguard_lab.simulation import load_workcell, simulate
from _common import report

CELLS = 12  # cells probed behind blind_from; the last bin counts runs of CELLS - 1 or more


def run_lengths(path: Path, frame_step: int = 25, pixel_step: int = 7) -> np.ndarray:
    """(CELLS,) int: how many sampled robot pixels of the principal camera have a run of 0, 1, ..., >= CELLS - 1
    uncleared cells from blind_from on."""
    workcell = load_workcell(path)
    robot = workcell.robot
    monitor = dg.DistanceMonitor(workcell.rig, memory=False, rho=fw.RHO, aggregate="min", invalid="neighbors",
                                 robot=robot)
    counts = np.zeros(CELLS, dtype=np.int64)
    for frame in simulate(workcell, seed=0, frames=fw.case_frames(workcell)[::frame_step]):
        prepared = monitor.prepare_set(dict(frame.depth), joints=frame.joints)
        fused = prepared.fused[0]
        grid = fused.grid
        state = fused.kernel_state()
        vs, us = np.nonzero(np.isfinite(fused._blind_from))
        for v, u in zip(vs[::pixel_step], us[::pixel_step]):
            k0 = int((fused._blind_from[v, u] - grid.d_min) / grid.delta_d)
            if k0 < 0 or k0 + CELLS >= grid.n_cells:
                continue
            grid_kernels.classify_run(u, v, k0, k0 + CELLS - 1, state)
            cells = fused._cells[v, u, k0:k0 + CELLS]
            n = 0
            while n < CELLS and cells[n] == 2:
                n += 1
            counts[min(n, CELLS - 1)] += 1
    return counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", action="append", help="a scene YAML (default: scenario_b and scenario_b_four_tof)")
    args = parser.parse_args()
    paths = [Path(p) for p in args.scene] if args.scene else fw.scene_paths(("scenario_b.yaml",
                                                                             "scenario_b_four_tof.yaml"))
    print(f"{'layout':24s} {'pixels':>7s} {'cleared':>8s} {'run 1-2':>8s} {'run 3-10':>9s} {'run 11+':>8s}   "
          "(shares of the pixels with a run: 1-2 / 3-10 / 11+)")
    for path in paths:
        c = run_lengths(path)
        total, hidden = c.sum(), c[1:].sum()
        short, mid, long_ = c[1:3].sum(), c[3:CELLS - 1].sum(), c[CELLS - 1]
        share = " / ".join(f"{x / max(hidden, 1):.0%}" for x in (short, mid, long_))
        print(f"{path.stem:24s} {total:7d} {c[0] / total:8.1%} {short:8d} {mid:9d} {long_:8d}   ({share})")


if __name__ == "__main__":
    with report(__file__):
        main()
