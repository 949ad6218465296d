"""The Quick start's main job: a robot doing its task next to a person, in closed loop, three ways.

Scene ``scenario_b_reach.yaml``: a KUKA iiwa traces the 2016 paper's vertical hexagon at 0.4 m/s while a person walks
up, reaches into its end-effector and walks away; four simulated 640x480 depth cameras (Kinect noise, edge dropouts) at 30 Hz,
the four-camera reference layout (``scenario_b_four.yaml``: the scene's two front cameras and two in the back corners;
``cameras=2`` keeps the front two), are fused through the depth grid with the free-space memory; control runs at 500 Hz
(:func:`depthguard_lab.simulation._closed_loop.run_closed_loop`). The same episode is run per mode:

- ``none``: the task alone (the baseline: it shows the collision that would happen);
- ``avoid``: the papers' avoidance (design §9: repulsive velocity at the end-effector, risk-shaped joint
  velocity bounds elsewhere, the task kept through redundancy);
- ``ssm``: speed and separation monitoring (ISO/TS 15066): the task slowed so that the reported distance stays above
  the protective separation distance. It runs in the camera layout SSM needs (:data:`SSM_LAYOUT`,
  ``scenario_b_ssm.yaml``: the four corners and a ceiling camera, time-of-flight-class noise), with the room's solids
  known and distances that leave out what is thinner than its detection capability (``LoopSettings(ssm_capability=
  True, known_solids=True)``): in the other modes' layouts nothing lets it move once it has seen the room
  (``benchmarks/probe_ssm_coverage.py``). ``ssm_cell=False`` (``--ssm-in-layout``) runs it there anyway.

The exact ground truth (coal: the robot's collision meshes against the person and everything else) judges every
run. Per mode it reports (``summary.json``, one object per mode):

- ``collisions``: how many times the robot's meshes came into contact (clearance <= 0, counted once per contact);
- ``clearance_m``: the smallest exact distance between the robot's meshes and any obstacle;
- ``true_min_distance_m``: the smallest exact distance of a control point to an obstacle;
- ``task_error_after_m``: how far the end-effector is from where the task wants it at the end;
- ``obstacles_left_s``, ``task_resumed_after_s``, ``task_error_median_resumed_m``: when every control point was truly
  farther than 0.4 m from every obstacle for good, how many seconds later the task error fell below 1 cm and stayed
  there for 0.1 s, and its median from then on (:func:`resumption`; null where it did not happen);
- ``oscillation_per_s``: reversals per second of the reaction: for ``avoid`` the repulsive velocity's direction
  turning by more than 90 degrees from one control step to the next, for ``ssm`` the speed factor crossing 0.5, for
  ``none`` 0 (it does not react);
- ``loop_hz``: control steps per wall-clock second, the whole loop (camera simulation, self-filtering, fusion,
  distances at every step, the command, the ground truth); ``step_hz``: one control step's distances and command
  alone (1 / its median time);
- ``time_reacting_s``: simulated seconds in which the command was slowed or pushed (task scale or speed factor below
  0.99, or a repulsive velocity);
- per control point, the smallest true and reported distance (from the first usable set of frames on: before it the
  monitor has seen nothing and answers 0).

It writes a plot per mode like the 2016 paper's Fig. 15 (``demo_<mode>.png``: the end-effector's path against the
task's, the distances over time, the repulsive speed and the speed factor), ``summary.json``, and the run with the
papers' avoidance as a recording a user can open in Foxglove or rerun (``bag_avoid/``, an MCAP file: depth images,
joint states, the robot's capsules and control points coloured by distance, the distances over time;
:mod:`depthguard_lab.simulation._loop_bag`; about 0.6 MB per depth image, 150 MB for the whole run).

    depthguard demo [--out DIR] [--duration S] [--mode none|avoid|ssm ...] [--cameras 4|2] [--no-bag]
                    [--ssm-in-layout]
"""

from __future__ import annotations

import dataclasses
import json
from importlib import resources
from pathlib import Path

import numpy as np

from depthguard.errors import InputError

SCENE = "scenario_b_reach.yaml"
#: The camera layouts by number of cameras: the scene's own two, or four (the reference layout: two more in the back
#: corners).
LAYOUTS = {2: None, 4: "scenario_b_four.yaml"}
#: The layout of mode ``ssm``: one that sees its protective separation distance round the arm.
SSM_LAYOUT = "scenario_b_ssm.yaml"

#: A repulsive velocity below this (m/s) counts as none (the papers' sigmoid never quite reaches 0).
REPULSIVE_EPSILON = 1e-3
#: A step whose task scale or speed factor is below this counts as slowed.
SLOWED_BELOW = 0.99
#: The task has resumed when the end-effector is within this of where the task wants it (metres: 1 cm).
RESUMED_WITHIN = 0.01
#: The obstacles have left when every control point is truly farther than this from every obstacle (metres; the
#: avoidance's rho, beyond which nothing acts) for the rest of the run.
LEFT_BEYOND = 0.4
#: ... for at least this long (seconds): a robot stopped on the task's path is passed by it within 1 cm for a moment
#: (at most 0.05 s at 0.4 m/s) without having resumed anything.
RESUMED_HOLD = 0.1


def resumption(log) -> tuple[float | None, float | None, float | None]:
    """When the task resumed after the obstacles left (:class:`~depthguard_lab.simulation._closed_loop.LoopLog`):
    (the time the obstacles left, seconds: from then on every control point is truly farther than
    :data:`LEFT_BEYOND` from every obstacle; the seconds from then until the task error falls below
    :data:`RESUMED_WITHIN` and stays there for :data:`RESUMED_HOLD`; the median task error from then to the end,
    metres). None where it did not happen: the obstacles did not leave, or the task did not come back."""
    near = np.flatnonzero(np.min(log.truth, axis=1) <= LEFT_BEYOND) if len(log.truth) else np.array([], int)
    if len(near) and near[-1] == len(log.truth_steps) - 1:  # still near at the end
        return None, None, None
    step = 0 if not len(near) else int(log.truth_steps[near[-1]]) + 1
    left = float(log.times[min(step, len(log.times) - 1)])
    within = log.task_error[step:] < RESUMED_WITHIN
    hold = int(np.ceil(RESUMED_HOLD / np.median(np.diff(log.times)))) if len(log.times) > 1 else 1
    # runs[k]: how many steps from k on stay within (counted from the end)
    runs = np.zeros(len(within) + 1, dtype=np.int64)
    for k in range(len(within) - 1, -1, -1):
        runs[k] = runs[k + 1] + 1 if within[k] else 0
    back = np.flatnonzero(runs[:-1] >= min(hold, len(within)))
    if not len(back) or not len(within):
        return left, None, None
    first = step + int(back[0])
    return left, float(log.times[first] - left), float(np.median(log.task_error[first:]))


def load_scene(cameras: int = 4):
    """The demo's workcell with ``cameras`` (2 or 4) depth cameras (:data:`LAYOUTS`)."""
    from depthguard_lab.simulation import load_workcell

    if cameras not in LAYOUTS:
        from depthguard.errors import InputError

        raise InputError(f"the demo runs with 2 or 4 cameras, got {cameras!r}", field="cameras")
    folder = Path(str(resources.files("depthguard_lab.simulation")))
    layout = None if LAYOUTS[cameras] is None else folder / LAYOUTS[cameras]
    return load_workcell(folder / SCENE, layout=layout)


def summarize(log, dt: float) -> dict:
    """The figures of one run (:class:`~depthguard_lab.simulation._closed_loop.LoopLog`) listed in the module
    docstring. ``dt``: the control period, seconds."""
    contact = log.clearance <= 0.0
    collisions = int(contact[0]) + int(np.count_nonzero(contact[1:] & ~contact[:-1])) if len(contact) else 0
    duration = len(log.times) * dt
    if log.mode == "avoid":
        r = log.repulsive
        active = np.linalg.norm(r, axis=1) > REPULSIVE_EPSILON
        turned = np.einsum("ij,ij->i", r[1:], r[:-1]) < 0.0
        reversals = int(np.count_nonzero(turned & active[1:] & active[:-1]))
    elif log.mode == "ssm":
        above = log.scale >= 0.5
        reversals = int(np.count_nonzero(above[1:] != above[:-1]))
    else:
        reversals = 0
    reacting = (log.scale < SLOWED_BELOW) | (np.linalg.norm(log.repulsive, axis=1) > REPULSIVE_EPSILON)
    # Before the first set of frames is usable the monitor has seen nothing and answers 0: not counted here.
    seen = np.isfinite(log.data_age)
    reported = log.reported[seen] if seen.any() else np.full_like(log.reported[:1], np.inf)
    left, resumed, error_after = resumption(log)
    return {
        "collisions": collisions,
        "clearance_m": float(np.min(log.clearance)),
        "true_min_distance_m": float(np.min(log.truth)),
        "task_error_after_m": float(log.task_error[-1]),
        "task_error_max_m": float(np.max(log.task_error)),
        "obstacles_left_s": left,
        "task_resumed_after_s": resumed,
        "task_error_median_resumed_m": error_after,
        "oscillation_per_s": reversals / duration if duration > 0 else 0.0,
        "loop_hz": len(log.times) / log.wall_seconds,
        "step_hz": 1.0 / float(np.median(log.step_seconds)),
        "time_reacting_s": float(np.count_nonzero(reacting) * dt),
        "simulated_s": duration,
        "wall_s": log.wall_seconds,
        "frames": log.frames,
        "per_control_point": {"true_min_m": np.min(log.truth, axis=0).tolist()},
        "per_link": surface_minima(log, reported),
    }


def surface_minima(log, reported) -> dict:
    """Link (or the end-effector's control point) -> the smallest reported distance from its surface over the run,
    metres (the distance from each of the loop's points minus its sphere's radius; None: nothing within rho). Empty
    for a log that does not say which robot's points it holds."""
    if log.robot is None:
        return {}
    names = log.robot.control_point_names
    surface = np.min(reported, axis=0) - log.robot.control_point_radii
    out = {}
    for name, value in zip(names, surface):
        link = name.split("/")[0]
        out[link] = min(out.get(link, np.inf), float(value))
    return {link: (max(v, 0.0) if np.isfinite(v) else None) for link, v in out.items()}


def resumed_cell(figures: dict) -> str:
    """The table's "resumed after s" cell, 16 characters: seconds, 'never' (the task did not come back), or '-'
    (the obstacles did not leave)."""
    if figures["obstacles_left_s"] is None:
        return f"{'-':>16s}"
    value = figures["task_resumed_after_s"]
    return f"{'never':>16s}" if value is None else f"{value:16.2f}"


def plot(log, mode_summary: dict, path: Path, control_points, rho: float) -> None:
    """The run's Fig. 15: end-effector path (in the plane of the task's path) against the task's; per control step the smallest reported
    distance (clipped at rho) and per truth sample the smallest true distance and the robot's clearance; the
    repulsive speed and the speed factor."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from depthguard.io.files import atomic_write

    fig, axes = plt.subplots(3, 1, figsize=(9, 10), gridspec_kw={"height_ratios": [1.2, 1, 0.8]})
    ax = axes[0]
    # The plane of the task's path: the two world axes along which the reference moves most.
    a, b = sorted(np.argsort(np.ptp(log.ee_ref, axis=0))[-2:])
    ax.plot(log.ee_ref[:, a], log.ee_ref[:, b], "k--", lw=1, label="task (reference)")
    ax.plot(log.ee[:, a], log.ee[:, b], "C0", lw=1.5, label="end-effector")
    ax.set_xlabel(f"world {'xyz'[a]} (m)")
    ax.set_ylabel(f"world {'xyz'[b]} (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(loc="best", fontsize=8)
    ax.set_title(f"mode {log.mode}: {mode_summary['collisions']} collisions, clearance "
                 f"{mode_summary['clearance_m']:.3f} m, task error at the end {mode_summary['task_error_after_m']:.3f} m")
    ax = axes[1]
    reported = np.minimum(np.min(log.reported, axis=1), rho)
    ax.plot(log.times, reported, "C1", lw=1, label=f"reported, nearest control point (clipped at rho = {rho:g} m)")
    truth_t = log.times[log.truth_steps]
    ax.plot(truth_t, np.min(log.truth, axis=1), "C2", lw=1.5, label="true, nearest control point")
    ax.plot(truth_t, log.clearance, "C3", lw=1, label="true clearance of the robot's meshes")
    ax.axhline(0.0, color="k", lw=0.5)
    ax.set_ylabel("distance (m)")
    ax.legend(loc="best", fontsize=8)
    ax = axes[2]
    ax.plot(log.times, np.linalg.norm(log.repulsive, axis=1), "C4", lw=1, label="repulsive speed (m/s)")
    ax.plot(log.times, log.scale, "C5", lw=1, label="task scale / speed factor")
    ax.set_xlabel("time (s)")
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    with atomic_write(path, "wb") as f:
        fig.savefig(f, format=Path(path).suffix[1:].lower() or None, dpi=90)  # as savefig(path) picks it
    plt.close(fig)


BAG_MODE = "avoid"  # the run written as a recording


def ssm_scene():
    """(workcell, settings) of mode ``ssm`` in :data:`SSM_LAYOUT`."""
    from depthguard_lab.simulation import load_workcell
    from depthguard_lab.simulation._closed_loop import LoopSettings

    folder = resources.files("depthguard_lab.simulation")
    workcell = load_workcell(Path(str(folder / SCENE)), layout=Path(str(folder / SSM_LAYOUT)))
    return workcell, LoopSettings(ssm_capability=True, known_solids=True)


def main(out="out/demo", duration: float | None = None, modes=None, progress: bool = True, bag: bool = True,
         cameras: int = 4, ssm_cell: bool = True) -> int:
    """Run the scene once per mode, print a table, write the plots and summary.json into ``out`` (and, with
    ``bag``, the ``avoid`` run as a recording in ``out/bag_avoid``, replacing an earlier one). ``ssm_cell``: mode
    ``ssm`` in :data:`SSM_LAYOUT` (else in the others' layout)."""
    from depthguard.io.files import write_whole
    from depthguard_lab.simulation._closed_loop import MODES, LoopSettings, run_closed_loop

    modes = list(MODES) if not modes else list(dict.fromkeys(modes))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    workcell = load_scene(cameras)
    settings = LoopSettings()
    dt = 1.0 / settings.control_rate
    span = workcell.duration if duration is None else min(duration, workcell.duration)
    cameras = list(workcell.rig.cameras)
    print(f"{SCENE}: a KUKA iiwa traces a vertical hexagon at 0.4 m/s while a person reaches into its end-effector\n"
          "and walks away; "
          f"{len(cameras)} simulated 640x480 depth cameras ({', '.join(cameras)}) at {workcell.rate:g} Hz fused "
          f"through the depth grid; control at {settings.control_rate:g} Hz; {span:g} s simulated per mode;\n"
          "judged by the exact distances between the robot's meshes and the obstacles (coal).")
    if ssm_cell and "ssm" in modes:
        ssm_workcell, ssm_settings = ssm_scene()
        print(f"Mode ssm in {SSM_LAYOUT} ({', '.join(ssm_workcell.rig.cameras)}; time-of-flight noise), the room's "
              "solids known, regions thinner than\nthe detection capability left out (--ssm-in-layout: in the one "
              "above); refused where its distances can hide more than ISO 13855's 70 mm.")
    print()
    rho = {mode: settings.ssm_rho if mode == "ssm" else settings.avoidance.rho for mode in modes}
    results, logs, bags = {}, {}, []
    refused = {}
    for mode in modes:
        record = bag and mode == BAG_MODE
        cell, cell_settings = (ssm_workcell, ssm_settings) if mode == "ssm" and ssm_cell else (workcell, settings)
        try:
            log = run_closed_loop(cell, mode, duration=span, settings=cell_settings, progress=progress,
                                  keep_frames=record)
        except InputError as error:
            if error.field != "detection_capability":
                raise
            refused[mode] = str(error)  # SSM that cannot be sound in this cell: said, not run
            continue
        if record:
            import shutil

            from depthguard_lab.simulation._loop_bag import write_loop_bag

            folder = out / f"bag_{mode}"
            if folder.is_dir() and (folder / "metadata.yaml").is_file():
                shutil.rmtree(folder)  # this command's own earlier recording
            bags.append(write_loop_bag(folder, workcell, log, rho[mode]))
            log = dataclasses.replace(log, captures=())
        logs[mode] = log
        results[mode] = summarize(log, dt)
        results[mode]["cameras"] = list(cell.rig.cameras)
    for mode in results:
        plot(logs[mode], results[mode], out / f"demo_{mode}.png", workcell.robot.control_point_names, rho[mode])
    summary = {"scene": SCENE, "cameras": cameras, "control_hz": settings.control_rate, "camera_hz": workcell.rate,
               "control_points": list(workcell.robot.control_point_names), "modes": results,
               "refused": refused}
    write_whole(out / "summary.json", json.dumps(summary, indent=2))
    print(f"\n{'mode':6s} {'collisions':>10s} {'clearance m':>12s} {'true min m':>11s} {'reacting s':>11s} "
          f"{'task error end m':>17s} {'resumed after s':>16s} {'oscillation /s':>15s} {'loop Hz':>8s} "
          f"{'step Hz':>8s}")
    # reacting s: slowed (task scale or speed factor < 0.99, the joints' limits included) or pushed away
    for mode, r in results.items():
        print(f"{mode:6s} {r['collisions']:10d} {r['clearance_m']:12.3f} {r['true_min_distance_m']:11.3f} "
              f"{r['time_reacting_s']:11.2f} {r['task_error_after_m']:17.3f} {resumed_cell(r)} "
              f"{r['oscillation_per_s']:15.2f} "
              f"{r['loop_hz']:8.0f} {r['step_hz']:8.0f}")
    for mode, reason in refused.items():
        print(f"{mode:6s} refused: {reason}")
    ran = list(results)
    print("\nper control point, smallest true distance over the run (m; the control points' centres to the obstacles):")
    names = list(workcell.robot.control_point_names)
    print(f"  {'point':14s} " + " ".join(f"{mode:>10s}" for mode in ran))
    for j, name in enumerate(names):
        print(f"  {name:14s} " + " ".join(f"{results[mode]['per_control_point']['true_min_m'][j]:10.3f}"
                                          for mode in ran))
    print("per link, smallest reported distance from its surface (m; the loop measures from spheres covering every "
          "moving\nlink, none more than Z_r beyond it; '-': nothing within rho; from frames 1/30 to 2/30 s old):")
    links = list(dict.fromkeys(link for mode in ran for link in results[mode]["per_link"]))
    for link in links:
        cells = [results[mode]["per_link"].get(link) for mode in ran]
        print(f"  {link:18s} " + " ".join(f"{'-' if v is None else f'{v:.3f}':>10s}" for v in cells))
    print(f"\nPlots: {', '.join(str(out / f'demo_{m}.png') for m in results)}; numbers: {out / 'summary.json'}")
    for folder in bags:
        print(f"Recording (open the .mcap file in Foxglove or rerun; `depthguard replay {folder} --out RESULTS.csv` "
              f"runs it through the monitor again): {folder}")
    return 0
