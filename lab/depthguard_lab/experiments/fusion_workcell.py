"""The workcell experiment of the depth grid: one depth camera against two fused through the depth grid, in reference scenario
B's shadow and hidden-hand cases (the 2016 paper's Figs. 8, 9, 12 and 13, with numbers).

Each layout (scene file) is simulated and, every frame, the control points' distances are computed three ways:
the principal camera alone, the second camera alone (the single-camera method, design §3-7, robot filtered
out) and both fused through the principal camera's depth grid (design §8). Each is compared with the exact
ground truth of :mod:`depthguard_lab.experiments.workcell` (the person, the box, the table and shelf, the floor, walls
and pedestal).

Two layouts are packaged. ``scenario_b.yaml`` is the reference scene: both cameras on the robot's front side, so a
region right behind the links is hidden from both and fusion counts it as occupied. ``scenario_b_across.yaml``
puts the second camera across the robot from the principal camera (the 2016 paper: "a correct positioning of the
cameras is crucial").

What it counts, per layout, method and case (``shadow``, ``hidden_hand``), over (frame, control point) pairs:

- false alarms: the reported distance is below rho while the truth is at least rho plus the tolerance;
- misses: the reported distance, taken as rho when it is larger ("nothing within rho" is right when the truth is
  beyond rho), is above the truth plus the tolerance. A single camera may miss only what hides behind the robot,
  and then flags ``robot_blind_spot``; the fused result must never miss.

    depthguard fusion-workcell [--out DIR] [--scene SCENE.yaml ...] [--all-frames]
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from tqdm import tqdm

import depthguard as dg
from depthguard.io.files import atomic_write, write_whole
from depthguard.errors import InputError
from depthguard_lab.experiments import workcell as single

RHO = single.RHO
#: The person's actions this experiment is about, in the order they happen.
CASES = ("shadow", "hidden_hand")
#: Seconds simulated before and after each case by default.
MARGIN = 0.5
#: The names of the fused results among the methods (the others are camera names): without and with the free-space
#: memory (design §8a).
FUSED = "fused"
FUSED_MEMORY = "fused+memory"
FUSED_METHODS = (FUSED, FUSED_MEMORY)
#: The packaged layouts, in the package's simulation folder, and those run by default: the published two-camera
#: layout and the four-camera reference layout.
SCENES = ("scenario_b.yaml", "scenario_b_across.yaml", "scenario_b_four.yaml")
DEFAULT_SCENES = ("scenario_b.yaml", "scenario_b_four.yaml")
#: "Useful": the share of (frame, control point) pairs truly farther than rho + USEFUL_MARGIN that are
#: reported below rho.
USEFUL_MARGIN = 0.05


@dataclass
class Episode:
    """Distances along one layout's episode. Shapes: t frames, m control points, k methods in ``methods`` order
    (each camera alone, the rig's principal camera first, then ``"fused"``)."""

    layout: str                # the scene's name (its file name without .yaml)
    times: np.ndarray          # (t,) seconds
    control_points: tuple      # (m,) names
    methods: tuple             # (k,) camera names, then FUSED and FUSED_MEMORY
    eyes: dict                 # camera name -> (3,) its optical centre, metres, world frame
    truth: np.ndarray          # (t, m) metres: to the nearest obstacle or background surface
    reported: np.ndarray       # (k, t, m) metres (inf: nothing within rho)
    blind: np.ndarray          # (k, t, m) metres: distance to a single camera's robot blind spot (inf: none; fused)
    flags: np.ndarray          # (k, t, m) int flag bits
    tolerance: np.ndarray      # (k, t, m) metres a distance may exceed the truth by without being wrong
    spans: list                # the person's actions: (kind, start, end)
    seconds: float             # wall-clock time of the simulation and the queries


def case_frames(workcell, margin: float = MARGIN) -> list[int]:
    """Frame indices of the shadow and hidden-hand cases, ``margin`` seconds before and after each."""
    times = workcell.times()
    keep = np.zeros(len(times), dtype=bool)
    for span in workcell.timeline():
        if span.kind in CASES:
            keep |= (times >= span.start - margin) & (times < span.end + margin)
    if not keep.any():
        raise InputError(f"the scene has no {' or '.join(CASES)} action", field="people")
    return [int(i) for i in np.flatnonzero(keep)]


def methods_of(rig) -> tuple[str, ...]:
    """The methods compared on ``rig``: each camera alone (the principal camera first; with more than two cameras,
    the principal camera only), then the cameras fused without and with the free-space memory."""
    if len(rig.cameras) < 2:
        raise InputError(f"fusion needs at least two depth cameras, the scene has {', '.join(rig.cameras)}",
                         field="cameras")
    for name in FUSED_METHODS:
        if name in rig.cameras:
            raise InputError(f"a camera is named {name!r}, the name of a fused result; rename it", field="cameras")
    principal = rig.principal or next(iter(rig.cameras))
    others = tuple(name for name in rig.cameras if name != principal) if len(rig.cameras) == 2 else ()
    return (principal,) + others + FUSED_METHODS


def run(workcell=None, layout: str | None = None, frames=None, duration: float | None = None,
        seed: int | None = None, progress: bool = True) -> Episode:
    """Simulate ``workcell`` (default: scenario B) and query each camera alone and all of them fused, every frame
    of ``frames`` (indices; default: the shadow and hidden-hand cases, :func:`case_frames`), or of the first
    ``duration`` seconds when that is given."""
    from depthguard_lab.simulation import default_workcell, simulate

    layout = layout or ("scenario_b" if workcell is None else "workcell")
    workcell = workcell or default_workcell()
    robot = workcell.robot
    methods = methods_of(workcell.rig)
    cameras = methods[:-len(FUSED_METHODS)]
    # Single cameras as in the demo (workcell.run). invalid="neighbors" fills the sensor's small dropouts along the
    # robot's edges; large holes stay occupied. The fused monitor uses the same policy for the principal camera.
    options = dict(rho=RHO, aggregate="hybrid", invalid="neighbors", robot=robot)
    monitors = {name: dg.DistanceMonitor(dg.Rig({name: workcell.rig.cameras[name]}), **options) for name in cameras}
    fused = dg.DistanceMonitor(workcell.rig, memory=False, **options)
    remembering = dg.DistanceMonitor(workcell.rig, memory=True, **options)
    background = workcell.background_parts()
    if duration is not None:
        frames = range(min(workcell.n_frames, int(round(duration * workcell.rate))))
    elif frames is None:
        frames = case_frames(workcell)
    frames = list(frames)
    rows = {key: [] for key in ("times", "truth", "reported", "blind", "flags", "depth")}
    start = time.perf_counter()
    for frame in tqdm(simulate(workcell, seed=seed, frames=frames), total=len(frames), disable=not progress,
                      desc=f"{layout}: simulating, one camera and two", unit="frame"):
        points = robot.control_point_positions(frame.joints)
        results = [monitors[c].query({c: frame.depth[c]}, points, joints=frame.joints) for c in cameras]
        every = dict(frame.depth)
        results.append(fused.query(every, points, joints=frame.joints))
        results.append(remembering.query(every, points, joints=frame.joints, now=frame.time))
        single.record(rows, frame, points, results, workcell, cameras, background)
    seconds = time.perf_counter() - start
    per_method = {key: np.moveaxis(np.array(rows[key]), 1, 0) for key in ("reported", "blind", "flags", "depth")}
    # Each camera alone: the demo's tolerance (2.5 pixel footprints at the point's depth, 1 mm). Fused: the larger
    # of the cameras' (the principal's pixels make the grid's cells, the others' pixels clear them).
    singles = single.tolerance(SimpleNamespace(depth_of_truth=per_method["depth"],
                                               fx=np.array([workcell.rig.cameras[c].fx for c in cameras])))
    fused_tolerance = singles.max(axis=0, keepdims=True)
    tolerance = np.concatenate([singles] + [fused_tolerance] * len(FUSED_METHODS))
    return Episode(layout=layout, times=np.array(rows["times"]), control_points=robot.control_point_names,
                   methods=methods, eyes={c: workcell.rig.cameras[c].T_world_camera[:3, 3].copy() for c in cameras},
                   truth=np.array(rows["truth"]), reported=per_method["reported"], blind=per_method["blind"],
                   flags=per_method["flags"], tolerance=tolerance,
                   spans=[(s.kind, s.start, s.end) for s in workcell.timeline()], seconds=seconds)


def case_rows(episode: Episode, kind: str) -> np.ndarray:
    """(t,) bool: the frames within any span of action ``kind``."""
    rows = np.zeros(len(episode.times), dtype=bool)
    for name, start, end in episode.spans:
        if name == kind:
            rows |= (episode.times >= start) & (episode.times < end)
    return rows


def counts(episode: Episode, k: int, rows: np.ndarray) -> dict:
    """Method ``k`` over the frames ``rows``: false alarms and misses among the (frame, control point) pairs.

    - ``false_alarms``: pairs whose truth is at least rho + tolerance (``far_pairs``) reported below rho;
    - ``misses``: pairs whose min(reported, rho) is above truth + tolerance, split into ``flagged_misses``
      (``robot_blind_spot`` set: a single camera says it cannot see there) and ``unflagged_misses``;
    - ``largest_excess_m``: the largest min(reported, rho) - truth;
    - ``useful_alarm_fraction``: among the pairs truly farther than rho + USEFUL_MARGIN, the share reported below
      rho (the measure of usefulness);
    - ``remembered``: pairs whose answer rests on the free-space memory (flag ``remembered``).
    """
    truth, reported, tol = episode.truth[rows], episode.reported[k][rows], episode.tolerance[k][rows]
    flagged = (episode.flags[k][rows] & int(dg.Flag.ROBOT_BLIND_SPOT)) != 0
    far = truth >= RHO + tol
    alarms = far & (reported < RHO)
    far_useful = truth >= RHO + USEFUL_MARGIN
    useful_alarms = far_useful & (reported < RHO)
    above = np.minimum(reported, RHO) > truth + tol
    return {"pairs": int(truth.size), "far_pairs": int(far.sum()), "false_alarms": int(alarms.sum()),
            "false_alarm_fraction": float(alarms.sum() / far.sum()) if far.any() else 0.0,
            "misses": int(above.sum()), "flagged_misses": int((above & flagged).sum()),
            "unflagged_misses": int((above & ~flagged).sum()),
            "largest_excess_m": float(np.max(np.minimum(reported, RHO) - truth, initial=-np.inf)),
            "min_truth": float(truth.min(initial=np.inf)), "min_reported": float(reported.min(initial=np.inf)),
            "useful_far_pairs": int(far_useful.sum()),
            "useful_alarm_fraction": float(useful_alarms.sum() / far_useful.sum()) if far_useful.any() else 0.0,
            "remembered": int(((episode.flags[k][rows] & int(dg.Flag.REMEMBERED)) != 0).sum())}


def summary(episodes: list[Episode]) -> dict:
    """Per layout, method and case: :func:`counts`, which flags were set, and the share of the principal camera's
    false alarms in the shadow case that fusion removes, without and with the memory (``false_alarms_removed``,
    ``false_alarms_removed_with_memory``; None when it has none)."""
    out = {"rho": RHO, "layouts": {}}
    for episode in episodes:
        methods = {}
        for k, method in enumerate(episode.methods):
            flags = episode.flags[k]
            methods[method] = {
                "all_frames": counts(episode, k, np.ones(len(episode.times), dtype=bool)),
                "by_case": {kind: counts(episode, k, case_rows(episode, kind)) for kind in CASES},
                "flagged_fraction": {flag.name.lower(): float(np.mean((flags & int(flag)) != 0)) for flag in dg.Flag
                                     if np.any((flags & int(flag)) != 0)},
            }
        principal = methods[episode.methods[0]]["by_case"]["shadow"]["false_alarms"]
        fused = methods[FUSED]["by_case"]["shadow"]["false_alarms"]
        remembered = methods[FUSED_MEMORY]["by_case"]["shadow"]["false_alarms"]
        out["layouts"][episode.layout] = {
            "frames": len(episode.times), "seconds": episode.seconds,
            "eyes": {c: [round(float(x), 3) for x in eye] for c, eye in episode.eyes.items()},
            "cases": {kind: [[start, end] for name, start, end in episode.spans if name == kind] for kind in CASES},
            "methods": methods,
            "false_alarms_removed": None if principal == 0 else 1.0 - fused / principal,
            "false_alarms_removed_with_memory": None if principal == 0 else 1.0 - remembered / principal,
        }
    return out


def plot(episode: Episode, out: Path) -> list[Path]:
    """One PNG per case: the smallest distance over the control points against time (truth, each camera alone,
    fused) above each control point's distance (truth, the principal camera alone, fused), as in the 2016 paper's
    Figs. 8, 9, 12 and 13."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    top = 0.6
    clip = lambda d: np.where(np.isfinite(d), np.minimum(d, top), np.nan)  # noqa: E731 (inf: nothing within rho)
    principal, fused, memory = 0, episode.methods.index(FUSED), episode.methods.index(FUSED_MEMORY)
    styles = {principal: dict(color="tab:red", lw=1.2), fused: dict(color="tab:blue", lw=1.6),
              memory: dict(color="tab:purple", lw=1.2, ls="-.")}
    blind_flag = int(dg.Flag.ROBOT_BLIND_SPOT)
    written = []
    for kind in CASES:
        rows = np.zeros(len(episode.times), dtype=bool)
        spans = [(start, end) for name, start, end in episode.spans if name == kind]
        for start, end in spans:
            rows |= (episode.times >= start - MARGIN) & (episode.times < end + MARGIN)
        if not rows.any():
            continue
        times = episode.times[rows]
        fig = plt.figure(figsize=(15, 12))
        grid = fig.add_gridspec(4, 3, height_ratios=[1.4, 1, 1, 1])
        ax = fig.add_subplot(grid[0, :])
        for start, end in spans:
            ax.axvspan(start, end, color="#eeeeee", lw=0)
        ax.plot(times, clip(episode.truth[rows].min(axis=1)), "k-", lw=2, label="truth")
        for k, method in enumerate(episode.methods):
            label = {fused: "fused (depth grid)", memory: "fused, with memory"}.get(k, f"{method} alone")
            style = styles.get(k, dict(color="tab:green", lw=1.0, ls="--"))
            ax.plot(times, clip(episode.reported[k][rows].min(axis=1)), label=label, **style)
        ax.axhline(RHO, color="grey", ls=":", lw=0.8)
        ax.set_ylim(0, top)
        ax.set_ylabel("smallest distance [m]")
        ax.set_title("smallest over the control points")
        ax.legend(loc="lower left", fontsize=9)
        ax.grid(alpha=0.3)
        for j, name in enumerate(episode.control_points[:9]):
            ax = fig.add_subplot(grid[1 + j // 3, j % 3], sharex=fig.axes[0])
            ax.plot(times, clip(episode.truth[rows, j]), "k-", lw=1.5)
            for k in (principal, fused, memory):
                ax.plot(times, clip(episode.reported[k][rows, j]), **styles[k])
            flagged = (episode.flags[principal][rows, j] & blind_flag) != 0
            ax.plot(times[flagged], np.zeros(flagged.sum()), "|", color="tab:red", ms=4,
                    label=f"{episode.methods[principal]} alone: robot_blind_spot")
            ax.axhline(RHO, color="grey", ls=":", lw=0.8)
            ax.set_ylim(0, top)
            ax.set_title(name, fontsize=9)
            ax.grid(alpha=0.3)
            if j == 0 and flagged.any():
                ax.legend(loc="lower left", fontsize=8)
            if j >= 6:
                ax.set_xlabel("time [s]")
        fig.suptitle(f"{episode.layout}, {kind.replace('_', ' ')} case (shaded): distance against time, rho = {RHO} m "
                     "(distances above 0.6 m and 'nothing within rho' drawn at the top or not at all)")
        fig.tight_layout()
        path = out / f"{episode.layout}_{kind}.png"
        with atomic_write(path, "wb") as f:
            fig.savefig(f, format="png", dpi=80)
        plt.close(fig)
        written.append(path)
    return written


def scene_paths(names=SCENES) -> list[Path]:
    """The packaged layouts' scene files (``names``: file names, default all)."""
    from importlib import resources

    folder = resources.files("depthguard_lab.simulation")
    return [Path(str(folder.joinpath(name))) for name in names]


def main(out="out/fusion-workcell", duration: float | None = None, scenes=None, progress: bool = True,
         all_frames: bool = False) -> int:
    """Run every layout (``scenes``: scene files, default DEFAULT_SCENES), print the table, write one plot per
    case and layout and summary.json into ``out``. By default only the cases' frames (:func:`case_frames`) are
    simulated; ``all_frames`` simulates the whole episode, ``duration`` its first seconds."""
    from depthguard_lab.simulation import load_workcell

    paths = [Path(p) for p in scenes] if scenes else scene_paths(DEFAULT_SCENES)
    if len({path.stem for path in paths}) < len(paths):
        raise InputError(f"two scene files share a name ({', '.join(str(p) for p in paths)}): plots and summary are "
                         "keyed by the file name", field="scenes")
    workcells = [load_workcell(path) for path in paths]  # a bad scene file fails before any work
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    print("Reference scenario B, the 2016 paper's shadow and hidden-hand cases: depth cameras alone (robot "
          "filtered out)\nagainst all of them fused through the principal camera's depth grid, without and with the "
          f"free-space memory;\nrho = {RHO} m, hybrid, invalid='neighbors'. False alarm: reported < rho while the "
          "truth >= rho + tolerance;\nuseful: the share of pairs truly farther than rho + "
          f"{USEFUL_MARGIN:g} m reported below rho (the goal: at most 10 % with two cameras,\n5 % with four). "
          "Miss: min(reported, rho) > truth + tolerance; flagged: with robot_blind_spot.\n")
    episodes, plots = [], []
    for path, workcell in zip(paths, workcells):
        frames = range(workcell.n_frames) if all_frames else None
        episode = run(workcell, layout=path.stem, frames=frames, duration=duration, progress=progress)
        episodes.append(episode)
        plots += plot(episode, out)
    result = summary(episodes)
    write_whole(out / "summary.json", json.dumps(result, indent=2))
    for layout, figures in result["layouts"].items():
        eyes = "; ".join(f"{c} at ({', '.join(f'{x:g}' for x in eye)})" for c, eye in figures["eyes"].items())
        print(f"{layout}: {eyes}; {figures['frames']} frames in {figures['seconds']:.1f} s")
        print(f"  {'case':12s} {'method':13s} {'min truth':>9s} {'min rep.':>9s} {'false alarms':>17s} "
              f"{'useful':>7s} {'misses (flagged)':>17s} {'remembered':>10s}")
        for kind in CASES:
            for method, numbers in figures["methods"].items():
                row = numbers["by_case"][kind]
                alarms = f"{row['false_alarms']}/{row['far_pairs']} {row['false_alarm_fraction']:6.1%}"
                print(f"  {kind:12s} {method:13s} {row['min_truth']:9.3f} {row['min_reported']:9.3f} {alarms:>17s} "
                      f"{row['useful_alarm_fraction']:7.1%} {row['misses']:>8d} ({row['flagged_misses']}) "
                      f"{row['remembered']:>10d}")
        removed, with_memory = figures["false_alarms_removed"], figures["false_alarms_removed_with_memory"]
        removed = "n/a (the principal camera alone has none)" if removed is None else \
            f"{removed:.1%} (with memory {with_memory:.1%})"
        misses = [figures["methods"][m]["all_frames"]["misses"] for m in FUSED_METHODS]
        print(f"  shadow case, false alarms removed by fusion: {removed}; fused misses over all frames: {misses[0]} "
              f"(with memory {misses[1]})\n")
    print("Plots: " + ", ".join(str(p) for p in plots) + f"; numbers: {out / 'summary.json'}")
    return 0
