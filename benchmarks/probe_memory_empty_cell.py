"""What the free-space memory leaves possibly occupied next to the robot in an empty cell after start-up (issue 35's
figures): scenario B's robot tracing its hexagon with nobody in the cell (its people left out; the box stays on its
table 1.4 m away), seen by the scene's two cameras and by scenario_b_four.yaml's four.

Every frame goes through three monitors in time order, the library's defaults as a cell gets them (rho 0.4 m, ``min``,
holes occupied, no concession but the self-filter; the rig's workspace): with the memory (its default 4 cm voxels),
without it, and with it and the hole fills' concession (``invalid="neighbors"``, flagged ``hole_filled``). After ``--start`` seconds (the memory's start-up: the robot moving through its poses), every
``--step``-th frame is queried at the spheres that cover the robot's surface (``RobotModel.with_surface_points``,
1 cm), and each answer is taken from its sphere's surface (distance minus radius, at least 0, at most rho). Printed:
the mean and the 5th percentile over the (frame, sphere) pairs, the share read below rho, and beside them the truth
(the distance from each sphere to the scene's static solids, the floor, pedestal, table and box: what an ideal memory
with perfect sensors could not go beyond) on the same pairs.

    .venv/bin/python benchmarks/probe_memory_empty_cell.py [--start 2.0] [--duration 4.0] [--step 3]
"""

from __future__ import annotations

import argparse
from importlib import resources
from pathlib import Path

import numpy as np

import depthguard as dg
from depthguard import config
from depthguard.io.files import read_yaml
from depthguard.scenes import scene_distance
from depthguard_lab.simulation import simulate
from depthguard_lab.simulation._scene import LAYOUT_KEYS, workcell_from_dict
from _common import report

RHO = 0.4
SCENES = {"two cameras (scenario_b.yaml)": None, "four cameras (scenario_b_four.yaml)": "scenario_b_four.yaml"}


def empty_cell(duration: float, layout: str | None):
    """Scenario B without its people, ``duration`` seconds long, with the cameras of ``layout`` (a scene file of the
    lab's, or None for its own)."""
    folder = Path(str(resources.files("depthguard_lab.simulation")))
    data = read_yaml(folder / "scenario_b.yaml", what="scene file", max_bytes=config.MAX_TEXT_FILE_BYTES)
    if layout is not None:
        cameras = read_yaml(folder / layout, what="scene file", max_bytes=config.MAX_TEXT_FILE_BYTES)
        data.update({key: cameras[key] for key in LAYOUT_KEYS if key in cameras})
    data.pop("people", None)
    data["duration"] = float(duration)
    return workcell_from_dict(data, base_dir=folder)


def probe(workcell, start: float, step: int) -> dict:
    """name -> (answers from the spheres' surfaces, (pairs,) metres in [0, rho]) for the memory, no memory and the
    truth, over the queried frames after ``start``."""
    robot = workcell.robot
    spheres = robot.with_surface_points(0.01)
    radii = np.asarray(spheres.control_point_radii)
    monitors = {name: dg.DistanceMonitor(workcell.rig, rho=RHO, aggregate="min", robot=robot, **options)
                for name, options in (("memory (4 cm voxels)", {}), ("no memory", dict(memory=False)),
                                      ("memory, holes filled", dict(invalid="neighbors")))}
    out = {name: [] for name in [*monitors, "truth (static solids)"]}
    first = int(round(start * workcell.rate))
    for frame in simulate(workcell, seed=0):
        ask = frame.index >= first and (frame.index - first) % step == 0
        centres = spheres.control_point_positions(frame.joints)
        for name, monitor in monitors.items():
            prepared = monitor.prepare_set(dict(frame.depth), joints=frame.joints, now=frame.time)
            if ask:
                distance = prepared.query(centres).distance
                out[name].append(np.clip(distance - radii, 0.0, RHO))
        if ask:
            solids = workcell.primitives_at(frame.time)  # everything but the robot: no one is in the cell
            out["truth (static solids)"].append(np.clip(scene_distance(solids, centres) - radii, 0.0, RHO))
    return {name: np.concatenate(rows) for name, rows in out.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--start", type=float, default=2.0, help="seconds of start-up not counted (default 2)")
    parser.add_argument("--duration", type=float, default=4.0, help="seconds of the episode (default 4)")
    parser.add_argument("--step", type=int, default=3, help="query every step-th frame after the start-up")
    args = parser.parse_args()
    print(f"an empty cell (scenario B, no people), the robot on its hexagon; {args.duration:g} s, start-up "
          f"{args.start:g} s not counted, one frame in {args.step} after it; rho {RHO} m, min, the library's "
          f"defaults; answers from the surface spheres' surfaces (1 cm), clipped to [0, rho], metres")
    for title, layout in SCENES.items():
        workcell = empty_cell(args.duration, layout)
        rows = probe(workcell, args.start, args.step)
        pairs = len(next(iter(rows.values())))
        print(f"\n{title}: {pairs} (frame, sphere) pairs")
        print(f"  {'':24s} {'mean':>6s} {'5th pct':>8s} {'below rho':>10s}")
        for name, values in rows.items():
            print(f"  {name:24s} {values.mean():6.3f} {np.percentile(values, 5):8.3f} {np.mean(values < RHO):10.1%}")


if __name__ == "__main__":
    with report(__file__):
        main()
