"""Where the fused answers on far robot points stop (issue 35): for each control point truly farther than rho + 5 cm
whose fused answer reads below rho, the nearest possibly-occupied point Q the answer found, how far Q lies outside
the robot's padded capsules, and what each camera's frame shows along its ray through Q.

The monitors are probe_memory_robot.py's (scenario B's layouts, rho 0.4 m, invalid "neighbors", the robot
self-filtered, the free-space memory on), with the ``min`` aggregation, whose direction points from Q: Q = P -
distance * direction. Every frame from the start goes through the monitor (the memory needs them all); the points
are queried on every ``--step``-th frame of the shadow and hidden-hand cases. Per camera, along the pixel Q projects
to, the simulated sensor's measurement (what the monitor saw) is compared with Q's depth:

- "beyond, within the margins": the camera measures a surface behind Q, but by less than its noise margin there
  plus the fusion margin (``config.DEFAULT_FUSION_MARGIN``): no sound rule can clear Q from that camera;
- "beyond": it measures a surface farther behind Q than that;
- "in front": a surface nearer than Q hides it; "no depth": the pixel has no measurement; "outside": Q is out of its
  view.

The point looked at is 5 mm beyond Q into the obstacle (Q itself lies on the edge between two pixels' frusta). Each
far pair below rho is counted once by what the principal camera shows there and by the best a secondary camera does
(beyond > beyond within the margins > the rest), with whether each one's surface there is the robot (the simulation's
labels).

    .venv/bin/python benchmarks/probe_where_answers_stop.py [--scene scenario_b_three.yaml ...] [--step 12]
"""

from __future__ import annotations

import argparse
from collections import Counter

import numpy as np

import depthguard as dg
from depthguard import config
from depthguard_lab.experiments import fusion_workcell as fw
from depthguard_lab.experiments.workcell import scene_distance
from depthguard_lab.simulation import load_workcell, simulate
from _common import report

USEFUL_MARGIN = 0.05  # as probe_memory_robot: pairs truly farther than rho + 5 cm
GAP_BINS = (-np.inf, 0.0, 0.02, 0.05, 0.10, np.inf)  # metres outside the padded capsules
INSIDE = 0.005  # metres: the point looked at lies this far beyond Q, into the obstacle (Q lies on a frustum's edge)
RANK = {"beyond": 0, "beyond, within the margins": 1, "in front": 2, "no depth": 3, "outside": 4}


def ray_view(camera, depth: np.ndarray, labels: np.ndarray, names: list, q: np.ndarray) -> tuple[str, bool, float]:
    """(what camera's frame shows along its ray through the world point q, whether that surface is the robot,
    metres measured beyond q (nan without a measurement))."""
    x, y, z_q = (float(c[0]) for c in camera.project(camera.world_to_camera(q[None])))
    if not (z_q > 0.0 and -0.5 <= x < camera.width - 0.5 and -0.5 <= y < camera.height - 0.5):
        return "outside", False, np.nan
    u, v = int(round(x)), int(round(y))
    z = float(depth[v, u])
    label = int(labels[v, u])
    robot = label >= 0 and names[label][0].startswith("robot/")
    if not np.isfinite(z) or z <= 0.0:
        return "no depth", robot, np.nan
    beyond = z - z_q
    if beyond <= 0.0:
        return "in front", robot, beyond
    margin = float(camera.noise.margin(np.array([z]))[0]) + config.DEFAULT_FUSION_MARGIN
    return ("beyond" if beyond > margin else "beyond, within the margins"), robot, beyond


def probe(path, step: int) -> tuple[int, int, Counter, Counter]:
    """(far pairs, far pairs below rho, Counter of (best view, robot) over those, Counter of gap bins)."""
    workcell = load_workcell(path)
    robot, rig = workcell.robot, workcell.rig
    monitor = dg.DistanceMonitor(rig, rho=fw.RHO, aggregate="min", invalid="neighbors", robot=robot, memory=True)
    names = workcell.labels()
    background = workcell.background_parts()
    cases = fw.case_frames(workcell)
    measured = set(cases[::step])
    far_count = below_count = 0
    views, gaps = Counter(), Counter()
    for frame in simulate(workcell, seed=0, frames=range(max(cases) + 1)):
        prepared = monitor.prepare_set(dict(frame.depth), joints=frame.joints, now=frame.time)
        if frame.index not in measured:
            continue
        points = robot.control_point_positions(frame.joints)
        truth = np.minimum(frame.truth.distance, scene_distance(background, points))
        result = prepared.query(points)
        far = truth >= fw.RHO + USEFUL_MARGIN
        below = far & (result.distance < fw.RHO)
        far_count += int(far.sum())
        below_count += int(below.sum())
        capsules = robot.capsules_world(frame.joints)
        metres = {name: np.asarray(image.metres()) for name, image in frame.depth.items()}
        for i in np.flatnonzero(below):
            q = points[i] - result.distance[i] * result.direction[i]
            gap = min(float(c.distance(q[None])[0]) for c in capsules)
            gaps[int(np.searchsorted(GAP_BINS, gap, side="right")) - 1] += 1
            inside = points[i] - (result.distance[i] + INSIDE) * result.direction[i]  # off the frustum's edge
            first = ray_view(rig.cameras[rig.principal], metres[rig.principal], frame.label[rig.principal], names,
                             inside)
            seen = [ray_view(camera, metres[name], frame.label[name], names, inside)
                    for name, camera in rig.cameras.items() if name != rig.principal]
            best = min(seen, key=lambda s: RANK[s[0]])
            views[(first[0], first[1], best[0], best[1])] += 1
    return far_count, below_count, views, gaps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", action="append", help="scene YAML (default: scenario_b, _three and _four)")
    parser.add_argument("--step", type=int, default=12, help="query every step-th frame of the two cases")
    args = parser.parse_args()
    names = args.scene or ["scenario_b.yaml", "scenario_b_three.yaml", "scenario_b_four.yaml"]
    bins = [f"{lo * 100:g}-{hi * 100:g} cm" for lo, hi in zip(GAP_BINS[:-1], GAP_BINS[1:])]
    bins[0], bins[-1] = "inside", f"> {GAP_BINS[-2] * 100:g} cm"
    for path in fw.scene_paths(tuple(names)):
        far, below, views, gaps = probe(path, args.step)
        print(f"{path.stem}: {below} of {far} far pairs read below rho (memory on, every {args.step}th frame of the "
              f"cases)")
        print("  Q outside the padded capsules: " + ", ".join(f"{b} {gaps[k]}" for k, b in enumerate(bins)))
        print("  the principal camera, and the best a secondary camera does, along their rays through Q:")
        for (first, first_robot, view, on_robot), n in sorted(views.items(), key=lambda item: -item[1]):
            print(f"    principal: {first:28s} {'(the robot)' if first_robot else '(not the robot)':16s} "
                  f"secondary: {view:28s} {'(the robot)' if on_robot else '(not the robot)':16s} {n:5d}  "
                  f"{n / max(below, 1):6.1%}")


if __name__ == "__main__":
    with report(__file__):
        main()
