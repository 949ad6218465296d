"""Why no sound depth rule lets scenario C's robot move (issue 27): the collision verdict by plain space carving.

A voxel of the workspace is free when some camera sees it entirely free: every pixel of its footprint, grown by one
pixel, measured beyond its far corner plus 1 cm (:func:`depthguard.freespace.seen_free_voxels`, the depth grid's
confirmation rule) on the frames as measured (no self-filter: the robot is a surface like any other), optionally
with holes of at most ``holes`` pixels filled from their neighbours (``invalid="neighbors"``, a concession); or when
it lies within ``zone`` of the current robot's padded capsules (the robot, and with zone > 0 the robot zone, a
concession: an object lying wholly within the zone is not seen). A future configuration collides when a sphere over
its moving links (``with_surface_points(0.01)``) comes within its radius of a voxel that is not free (the distance
to the nearest one's centre less a voxel diagonal: sound), or leaves the workspace. No concession, no self-filter
shell, no space between links left unchecked: the plainest sound rule, judged as the scenario C probe's rules are
(``probe_collision_scenario_c.scenario_c``: the same sets, every ``--every``-th frame).

It prints, per voxel size, hole policy and zone: missed collisions, false alarms (configurations more than 0.15 m
from the person judged colliding), the time to carve a set, and for the false alarms which link's sphere decided and
how far the best camera saw beyond the deciding voxel's centre along its pixel (metres: a large value means that
camera sees through the voxel's middle, and only the edge of its footprint, next to the robot's silhouette, failed).

    .venv/bin/python benchmarks/probe_collision_carving.py [--every 9]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections import Counter

import numpy as np
from scipy import ndimage

sys.path.insert(0, os.path.dirname(__file__))

import depthguard as dg  # noqa: E402
from depthguard.depthgrid import free_image  # noqa: E402
from depthguard.freespace import VoxelBox, robot_voxels, seen_free_voxels  # noqa: E402
from _common import report  # noqa: E402
from probe_collision_scenario_c import FALSE_ALARM_CLEARANCE, scenario_c  # noqa: E402

VOXELS = (0.02, 0.01)
HOLES = (0, 4)
ZONES = (0.0, 0.02, 0.03, 0.05)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--every", type=int, default=9)
    args = parser.parse_args()
    workcell, _, observed, frames, futures, clearances = scenario_c(args.every)
    robot = workcell.robot
    cameras = list(workcell.rig.cameras.values())
    surface = robot.with_surface_points(0.01)
    radii = surface.control_point_radii
    names = surface.control_point_names
    spheres = {i: np.array([surface.control_point_positions(q) for q in futures[i]]) for i in observed}
    print(f"scenario C: {len(observed)} observed frames, {sum(len(v) for v in futures.values())} future "
          "configurations")
    print(f"{'voxel':>6s} {'holes':>5s} {'zone':>5s} {'missed':>7s} {'false alarms':>17s} {'carve ms':>9s}   "
          "deciding links / best camera's view beyond the voxel (median)")
    for voxel in VOXELS:
        box = VoxelBox(np.array(workcell.rig.workspace[0]), np.array(workcell.rig.workspace[1]), voxel)
        for holes in HOLES:
            filler = dg.DistanceMonitor(workcell.rig, invalid="neighbors", hole_pixels=holes, memory=False) \
                if holes else None
            seen, carve = {}, []
            for i in observed:
                start = time.perf_counter()
                images = {c.name: dg.depth_image(frames[i].depth[c.name].data, c) for c in cameras}
                if filler is None:
                    free_images = [free_image(images[c.name], c) for c in cameras]
                else:
                    prepared = filler.prepare_set(images)
                    free_images = [prepared.usable[c.name].measured_free for c in cameras]
                seen[i] = (seen_free_voxels(box, cameras, free_images, margin=0.01, pad=1), free_images)
                carve.append(time.perf_counter() - start)
            for zone in ZONES:
                missed = alarms = free_count = 0
                links, beyond = Counter(), []
                for i in observed:
                    free = seen[i][0].copy()
                    capsules = np.array([tuple(c.p0) + tuple(c.p1) + (c.radius,)
                                         for c in robot.capsules_world(frames[i].joints)])
                    robot_voxels(box, capsules, zone, free)
                    padded = np.pad(free, 1, constant_values=False)  # outside the box: not free
                    distance, nearest = ndimage.distance_transform_edt(padded, return_indices=True)
                    S = spheres[i]
                    index = np.floor((S - box.lo) / voxel).astype(np.int64)
                    inside = np.all((index >= 0) & (index < np.array(box.shape)), axis=-1)
                    index = np.clip(index, 0, np.array(box.shape) - 1) + 1
                    gap = np.where(inside, distance[index[..., 0], index[..., 1], index[..., 2]] * voxel, 0.0) \
                        - voxel * np.sqrt(3.0) - radii
                    collision = (gap <= 0.0).any(axis=1)
                    c = clearances[i]
                    missed += int(((c < 0) & ~collision).sum())
                    far = c > FALSE_ALARM_CLEARANCE
                    free_count += int(far.sum())
                    alarms += int((far & collision).sum())
                    for k in np.flatnonzero(far & collision):
                        j = int(np.argmin(gap[k]))
                        links[names[j].split("/")[0]] += 1
                        v = nearest[:, index[k, j, 0], index[k, j, 1], index[k, j, 2]] - 1
                        beyond.append(_best_view(box.lo + (v + 0.5) * voxel, cameras, seen[i][1]))
                top = ", ".join(f"{name} {count}" for name, count in links.most_common(3))
                print(f"{voxel:6.2f} {holes:5d} {zone:5.2f} {missed:7d} {alarms:6d} of {free_count:4d} "
                      f"({alarms / max(free_count, 1):4.0%}) {np.median(carve) * 1e3:9.0f}   {top or '-'} / "
                      f"{np.median(beyond) if beyond else float('nan'):.2f} m")


def _best_view(centre, cameras, free_images) -> float:
    """Metres: the most any camera saw beyond ``centre`` (world, (3,)) along the pixel it projects to (-inf if none
    sees it)."""
    best = -np.inf
    for camera, free in zip(cameras, free_images):
        x, y, z = camera.world_to_camera(centre[None])[0]
        if z <= 0:
            continue
        u, v = int(round(camera.fx * x / z + camera.cx)), int(round(camera.fy * y / z + camera.cy))
        if 0 <= u < camera.width and 0 <= v < camera.height:
            best = max(best, float(free[v, u]) - z)
    return best


if __name__ == "__main__":
    with report(__file__):
        main()
