"""What the free-space memory clears next to its own robot (design §8a): false alarms on the robot's control points,
with the memory off and on, at its default voxel and a finer one, in scenario B with two and with four cameras.

Every frame from the start of the episode up to the end of its last shadow or hidden-hand span goes through each
monitor in time order (the memory needs them all: it remembers what it saw and ages it at v_max); the control
points are queried on the frames of those two cases (every ``--step``-th; design "Several cameras"), the memory's
start-up (the frames before them, the robot moving its end-effector through its hexagon) not counted. Per row: the
share of the (frame, control point) pairs truly farther than rho + 5 cm that read below rho (the false alarms), the
end-effector alone, how many answers carry ``remembered``, the largest excess of a distance over the truth plus the
fused tolerance (2.5 principal footprints + 1 mm; exact geometry by coal; positive is optimistic), the median
time per set, and, with the memory, the share of its voxels it certifies free at each queried frame, by the voxel
centre's distance from the robot's padded capsules (mean over the frames): where next to the robot it clears space;
under each row, how many of the far pairs read below rho carry each flag (why they could be small). Monitors: rho 0.4 m, hybrid, invalid "neighbors", the robot self-filtered (as ``fusion-workcell``).

    .venv/bin/python benchmarks/probe_memory_robot.py [--step 3] [--scene scenario_b.yaml ...] [--exact] [--fed]
        [--voxel 0.01]

Beside them, the bound (issue 35, item 6): ``ideal, exact`` is an ideal sound memory on the simulation's exact
geometry (:mod:`depthguard_lab.experiments.ideal_memory`: exact ray casts per frame, the robot's exact volume, the
erosion at v_max, on a grid of ``--ideal-spacing`` points), ``ideal, noise`` the same with each camera's noise margin
taken off its exact depths; their distances are to the nearest possibly-occupied grid point outside the padded
capsules, their excess is over the truth alone, and under each, where that point lies ("seen before": seen free
earlier and reached by the erosion since; "never seen").

``--fed`` is a diagnosis too: one monitor whose fused answers read the ideal memory's free space (with the noise
margins) instead of its own memory's, beside the ideal rows: the gap between it and the ideal lies in the fused
query, the rest in the memory.

``--ideal-only`` (with ``--ideal-spacing 0.02``) runs only the ideal rows, on a finer grid: the layer the noise
margins leave round the links is 2-4 cm thick, and a 4 cm grid samples little of it (the ideal with noise margins:
scenario_b 57.3 % at 4 cm, 85.6 % at 2 cm; scenario_b_four 0.0 %, 65.7 %). About 13 minutes per ideal and scene at
2 cm. With one ``--scene`` (any rows), the figures go to a file of that scene's own.

``--voxel 0.01`` is a diagnosis too: the memory alone at a finer voxel (1 cm costs about a second a set), to show
whether finer voxels next to the robot would change the answers.

``--ideal-meshes`` measures the ideal's distances to every possibly-occupied point outside the robot's meshes (the
issue's definition: the robot's exact volume, nothing more, given to the robot), instead of outside the padded
capsules.

``--ideal-measured`` (with ``--ideal-only``) runs one ideal on the frames as the cameras measured them (the
simulated sensor's noise and dropouts; a dropout sees nothing free) less each camera's noise margin, point by
point: what the frames themselves allow, before the project's footprints, pads, cells and calibration margin.

``--zone 0.08`` is a diagnosis too: the memory with a robot zone of that thickness as well (a flagged concession,
not a default): how much of what is left lies right next to the padded capsules.

``--exact`` is a diagnosis, not a layout: the simulation's noise-free frames, cameras without a noise margin (and
without the sensor's dropouts), to show what the noise margin alone costs the memory next to the robot; with
``--calibrated`` also without the calibration margin (``fusion_margin`` 0, no pad): the nearest this code comes to
the issue's ideal memory (exact ray casts), but for its voxels and the robot's inner capsules.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import depthguard as dg
from depthguard_lab.experiments import fusion_workcell as fw
from depthguard_lab.experiments.ideal_memory import IdealMemory, measured_depths
from depthguard_lab.experiments.workcell import scene_distance
from depthguard_lab.simulation import load_workcell, simulate
from _common import report

USEFUL_MARGIN = 0.05  # pairs truly farther than rho + 5 cm
CONFIGURATIONS = {"no memory": dict(memory=False), "memory 4 cm": dict(memory=True),
                  "memory 2 cm": dict(memory=True, memory_voxel=0.02)}
#: The bound (issue 35, item 6; :mod:`depthguard_lab.experiments.ideal_memory`): an ideal sound memory on the
#: simulation's exact geometry, with exact ray casts (the issue's definition) and with the cameras' noise margins.
IDEALS = {"ideal, exact": False, "ideal, noise": True}


def noise_free(rig) -> dg.Rig:
    """``rig`` with every camera's noise model none (margin 0), for the simulation's exact frames."""
    from dataclasses import replace

    cameras = {name: replace(camera, noise=dg.NoiseModel.none()) for name, camera in rig.cameras.items()}
    return dg.Rig(cameras, principal=rig.principal, workspace=rig.workspace)


def fed_with(monitor, ideal: IdealMemory) -> None:
    """Make ``monitor``'s fused answers read ``ideal``'s free space (its grid points not possibly occupied, taken as
    the memory's 4 cm voxels, whose centres they are) instead of its memory's: a diagnosis of how much of the gap to
    the bound lies in the fused query rather than in the memory (not sound: a point stands for its voxel)."""
    if monitor.memory.box.shape != ideal.shape:
        raise SystemExit("--fed needs the ideal's grid on the memory's voxel centres (--ideal-spacing 0.04)")

    def remembered_free(usable):
        free = ~ideal.possibly
        monitor._free_now = (free, monitor.memory.box, free)
        return free, monitor.memory.box

    monitor._remembered_free = remembered_free


def probe(path, step: int, exact: bool = False, calibrated: bool = False, ideal_spacing: float = 0.04,
          fed: bool = False, voxels: list | None = None, ideal_only: bool = False, zones: list | None = None,
          meshes: bool = False, measured: bool = False) -> dict:
    """configuration -> (far pairs, below rho, end-effector far, below rho, remembered answers, largest excess in
    metres, seconds per set, per measured frame the memory's certified shares by band (:func:`certified_by_band`),
    and how many of the far pairs read below rho carry each flag)."""
    workcell = load_workcell(path)
    robot = workcell.robot
    options = dict(rho=fw.RHO, aggregate="hybrid", invalid="neighbors", robot=robot)
    if calibrated:  # no calibration margin: a camera clears what it sees beyond, to the pixel
        options.update(fusion_margin=0.0, fusion_pixels=0)
    rig = noise_free(workcell.rig) if exact else workcell.rig
    configurations = {} if ideal_only else CONFIGURATIONS if not voxels else \
        {f"memory {v * 100:g} cm": dict(memory=True, memory_voxel=v) for v in voxels}
    if zones and not ideal_only:  # a diagnosis: the robot zone's concession on top of the memory
        configurations = {**configurations, **{f"mem.+zone {z * 100:g} cm": dict(memory=True, robot_zone=z)
                                               for z in zones}}
    monitors = {name: dg.DistanceMonitor(rig, **options, **extra) for name, extra in configurations.items()}
    ideals = {} if exact or voxels or zones else {name: IdealMemory(workcell, spacing=ideal_spacing, noise_margin=noisy)
                               for name, noisy in IDEALS.items()}
    if measured and ideals:  # the ideal on the frames as the cameras measured them
        ideals = {"ideal, measured": IdealMemory(workcell, spacing=ideal_spacing, noise_margin=True, measured=True)}
    if fed:  # the fused query given the ideal memory's free space (with the noise margins)
        monitors = {"fed the ideal": dg.DistanceMonitor(rig, **options, memory=True)}
        fed_with(monitors["fed the ideal"], ideals["ideal, noise"])
    background = workcell.background_parts()
    principal = workcell.rig.cameras[workcell.rig.principal]
    cases = fw.case_frames(workcell)
    measured = set(cases[::step])
    out = {name: [0, 0, 0, 0, 0, -np.inf, [], [], {}] for name in list(monitors) + list(ideals)}
    for frame in simulate(workcell, seed=0, frames=range(max(cases) + 1)):
        points = robot.control_point_positions(frame.joints)
        ask = frame.index in measured
        frames = {name: dg.depth_image(depth, rig.cameras[name], timestamp=frame.time)
                  for name, depth in frame.depth_exact.items()} if exact else dict(frame.depth)
        depths = measured_depths(frame.depth) if measured else None
        if ask:
            truth = np.minimum(frame.truth.distance, scene_distance(background, points))
            depth = np.maximum(principal.world_to_camera(points)[:, 2], 0.1)
            tolerance = 2.5 * (depth + fw.RHO) / principal.fx + 1e-3
            far = truth >= fw.RHO + USEFUL_MARGIN
        for name, ideal in ideals.items():
            ideal.update(frame.time, frame.joints, depths if ideal.measured else frame.depth_exact, frame.label)
            if not ask:
                continue
            conceded = [] if meshes else robot.capsules_world(frame.joints)
            reported, kinds = ideal.distances(points, conceded, fw.RHO)
            row = out[name]
            row[0] += int(far.sum())
            row[1] += int((far & (reported < fw.RHO)).sum())
            row[2] += int(far[-1])
            row[3] += int(far[-1] and reported[-1] < fw.RHO)
            row[5] = max(row[5], float(np.max(np.minimum(reported, fw.RHO) - truth)))
            for i in np.flatnonzero(far & (reported < fw.RHO)):  # which space holds the bound
                row[8][kinds[i]] = row[8].get(kinds[i], 0) + 1
            row[7].append(ideal_by_band(ideal, robot, frame))
        for name, monitor in monitors.items():
            start = time.perf_counter()
            prepared = monitor.prepare_set(frames, joints=frame.joints, now=frame.time)
            if not ask:
                continue
            result = prepared.query(points)
            row = out[name]
            row[6].append(time.perf_counter() - start)
            reported = result.distance
            row[0] += int(far.sum())
            row[1] += int((far & (reported < fw.RHO)).sum())
            row[2] += int(far[-1])
            row[3] += int(far[-1] and reported[-1] < fw.RHO)
            row[4] += sum(dg.Flag.REMEMBERED in f for f in result.flags)
            row[5] = max(row[5], float(np.max(np.minimum(reported, fw.RHO) - (truth + tolerance))))
            for i in np.flatnonzero(far & (reported < fw.RHO)):  # why a far pair reads below rho: its flags
                for flag in result.flags[i]:
                    row[8][flag.name.lower()] = row[8].get(flag.name.lower(), 0) + 1
            if monitor.memory is not None:
                row[7].append(certified_by_band(monitor, frame))
    return out


#: Bands of distance from the robot's padded capsules (metres, outside them) in which the share of the memory's
#: voxels certified free is reported.
BANDS = (0.0, 0.05, 0.1, 0.2, 0.4)


def certified_by_band(monitor, frame) -> np.ndarray:
    """(len(BANDS) - 1,) the share of the memory's voxels whose centre lies in each band of distance from the robot's
    padded capsules at the frame's joints that the memory certifies free at the frame's time."""
    box = monitor.memory.box
    free = monitor.memory.free_at(frame.time)
    centres = np.stack(np.meshgrid(*box.axis_centres(), indexing="ij"), axis=-1).reshape(-1, 3)
    gap = np.full(len(centres), np.inf)
    for c in monitor.robot.capsules_world(frame.joints):
        p0, p1 = np.array(c.p0), np.array(c.p1)
        d = p1 - p0
        s = np.clip((centres - p0) @ d / max(float(d @ d), 1e-12), 0.0, 1.0)
        gap = np.minimum(gap, np.linalg.norm(centres - (p0 + s[:, None] * d), axis=1) - c.radius)
    free = free.reshape(-1)
    return np.array([free[(gap >= lo) & (gap < hi)].mean() for lo, hi in zip(BANDS[:-1], BANDS[1:])])


def ideal_by_band(ideal: IdealMemory, robot, frame) -> np.ndarray:
    """As :func:`certified_by_band` for the ideal memory: the share of its grid points in each band that it leaves
    free (not possibly occupied) at the frame."""
    gap = np.full(len(ideal.points), np.inf)
    for c in robot.capsules_world(frame.joints):
        gap = np.minimum(gap, c.distance(ideal.points))
    free = ~ideal.possibly.reshape(-1)
    return np.array([free[(gap > lo) & (gap < hi)].mean() for lo, hi in zip(BANDS[:-1], BANDS[1:])])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", action="append", help="scene YAML (default: scenario_b and scenario_b_four)")
    parser.add_argument("--step", type=int, default=3, help="query every step-th frame of the two cases")
    parser.add_argument("--exact", action="store_true",
                        help="the simulation's noise-free frames and cameras without a noise margin (a diagnosis)")
    parser.add_argument("--calibrated", action="store_true",
                        help="with --exact: no calibration margin either (fusion_margin 0, fusion_pixels 0)")
    parser.add_argument("--fed", action="store_true",
                        help="a diagnosis: the fused query given the ideal memory's free space (with noise margins)")
    parser.add_argument("--ideal-spacing", type=float, default=0.04, help="grid spacing of the ideal memory (metres)")
    parser.add_argument("--ideal-only", action="store_true",
                        help="only the ideal rows (with --ideal-spacing 0.02: the noise margins' layer sampled finer)")
    parser.add_argument("--voxel", type=float, action="append",
                        help="a diagnosis: only the memory at this voxel side (metres; repeatable), no ideal rows")
    parser.add_argument("--zone", type=float, action="append",
                        help="a diagnosis: also the memory with this robot zone (metres; repeatable), no ideal rows")
    parser.add_argument("--ideal-meshes", action="store_true",
                        help="the ideal's distances from the robot's meshes (the padded capsules not the robot's)")
    parser.add_argument("--ideal-measured", action="store_true",
                        help="with --ideal-only: one ideal on the frames as measured (noise, dropouts) less the margin")
    args = parser.parse_args()
    names = args.scene or ["scenario_b.yaml", "scenario_b_four.yaml"]
    bands = "  ".join(f"{lo * 100:g}-{hi * 100:g} cm" for lo, hi in zip(BANDS[:-1], BANDS[1:]))
    print(f"{'layout':22s} {'configuration':14s} {'far pairs below rho':>20s} {'end-effector':>13s} "
          f"{'remembered':>10s} {'largest excess':>15s} {'ms per set':>10s}   certified free by distance from the "
          f"padded capsules: {bands}")
    for path in fw.scene_paths(tuple(names)):
        rows = probe(path, args.step, args.exact, args.calibrated, args.ideal_spacing, args.fed,
                     args.voxel, args.ideal_only, args.zone, args.ideal_meshes, args.ideal_measured).items()
        for name, (far, below, ee_far, ee_below, kept, excess, seconds, shares, flags) in rows:
            certified = "  ".join(f"{share:9.1%}" for share in np.mean(shares, axis=0)) if shares else "-"
            label = path.stem + (" exact" if args.exact else "") + (" calibrated" if args.calibrated else "") + \
                (f" {args.ideal_spacing * 100:g} cm" if args.ideal_only else "") + \
                (" meshes" if args.ideal_meshes else "")
            print(f"{label:22s} {name:14s} {below:>6d}/{far:<5d} {below / max(far, 1):6.1%} "
                  f"{ee_below:>5d}/{ee_far:<5d} {kept:10d} {excess * 1e3:+11.1f} mm "
                  f"{np.median(seconds) * 1e3 if seconds else np.nan:10.1f}   {certified}", flush=True)
            why = "where the nearest possibly-occupied point lies" if name.startswith("ideal") else "flags"
            print(f"{'':37s} {why} of those below rho: "
                  f"{', '.join(f'{k} {v}' for k, v in sorted(flags.items(), key=lambda x: -x[1])) or 'none'}")


if __name__ == "__main__":
    import sys
    from pathlib import Path

    diagnosis = ("_exact" * ("--exact" in sys.argv) + "_calibrated" * ("--calibrated" in sys.argv)
                 + "_fed" * ("--fed" in sys.argv) + "_voxel" * ("--voxel" in sys.argv)
                 + "_ideal" * ("--ideal-only" in sys.argv) + "_zone" * ("--zone" in sys.argv)
                 + "_meshes" * ("--ideal-meshes" in sys.argv) + "_measured" * ("--ideal-measured" in sys.argv))
    if sys.argv.count("--scene") == 1:  # one --scene: that scene's own figures file (the default file holds both)
        diagnosis += "_" + Path(sys.argv[sys.argv.index("--scene") + 1]).stem
    with report(__file__, name=f"probe_memory_robot{diagnosis}" if diagnosis else None):
        main()
