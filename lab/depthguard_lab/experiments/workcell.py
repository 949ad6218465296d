"""Reference scenario B simulated, watched by each depth camera on its own (``depthguard workcell``; the Quick start's
main job before the closed loop, ``depthguard demo``).

A KUKA iiwa traces a vertical hexagon at 0.4 m/s while a person walks in, reaches for the end-effector, carries a
box past the robot, stands between the principal camera and the robot (the 2016 paper's shadow case) and holds a
hand behind the robot as the principal camera sees it (its hidden-hand case). Every frame, each camera's
single-camera distances (design §3-7, robot filtered out) are compared with the exact ground truth, which
covers everything the robot could hit: the person, the box, the table and shelf, and the floor, walls and pedestal.

What it shows: single-camera distances are never above the truth plus the pixel tolerance unless flagged
``robot_blind_spot``; a person between a camera and the robot makes that camera's distances small (false alarms,
the shadow case); the principal camera cannot see the hidden hand. Fusing both cameras is the depth grid's job
(``depthguard.depthgrid``).

    depthguard workcell [--out DIR] [--duration SECONDS]
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

import depthguard as dg
from depthguard.io.files import atomic_write, write_whole
from depthguard.scenes import scene_distance

RHO = 0.4


@dataclass
class Episode:
    """Distances along a simulated episode. Shapes: t frames, m control points, cameras in ``cameras`` order."""

    times: np.ndarray          # (t,) seconds
    control_points: tuple      # (m,) names
    cameras: tuple             # camera names
    truth: np.ndarray          # (t, m) metres: to the nearest obstacle or background surface
    reported: np.ndarray       # (cameras, t, m) metres (inf: nothing within rho)
    blind: np.ndarray          # (cameras, t, m) metres: distance to the camera's robot blind spot (inf: none)
    flags: np.ndarray          # (cameras, t, m) int flag bits
    depth_of_truth: np.ndarray  # (cameras, t, m) metres: optical depth of each control point (for the tolerance)
    fx: np.ndarray             # (cameras,) focal lengths, pixels
    spans: list                # the person's actions: (kind, start, end)
    seconds: float             # wall-clock time of the whole run


def tolerance(episode: Episode) -> np.ndarray:
    """(cameras, t, m) metres: what a distance may exceed the truth by without being wrong. 2.5 pixel footprints at
    the control point's depth (pixel discretisation; see tests/test_judge_pybullet.py) and 1 mm of quantisation."""
    depth = np.maximum(episode.depth_of_truth, 0.1)
    return 2.5 * (depth + RHO) / episode.fx[:, None, None] + 1e-3


def run(workcell=None, duration: float | None = None, seed: int | None = None, progress: bool = True,
        frames=None) -> Episode:
    """Simulate ``workcell`` (default: scenario B) and query every camera on its own, every frame (or the frame
    indices ``frames``; else the first ``duration`` seconds)."""
    from depthguard_lab.simulation import default_workcell, simulate

    workcell = workcell or default_workcell()
    robot = workcell.robot
    cameras = tuple(workcell.rig.cameras)
    # The simulated sensors drop pixels along depth edges, as real ones do, in thin lines around the robot's
    # silhouette; the fail-safe default (invalid="occupied") counts each as an obstacle beside the arm (about 0.1 m).
    # "neighbors" fills such small holes from their surroundings; large holes stay occupied.
    monitors = {name: dg.DistanceMonitor(dg.Rig({name: workcell.rig.cameras[name]}), rho=RHO, aggregate="hybrid",
                                         invalid="neighbors", robot=robot) for name in cameras}
    background = workcell.background_parts()
    if frames is None:
        frames = range(workcell.n_frames if duration is None else
                       min(workcell.n_frames, int(round(duration * workcell.rate))))
    frames = list(frames)
    n = len(frames)
    rows = {key: [] for key in ("times", "truth", "reported", "blind", "flags", "depth")}
    start = time.perf_counter()
    for frame in tqdm(simulate(workcell, seed=seed, frames=frames), total=n, disable=not progress,
                      desc="simulating and watching", unit="frame"):
        points = robot.control_point_positions(frame.joints)
        results = [monitors[c].query({c: frame.depth[c]}, points, joints=frame.joints) for c in cameras]
        record(rows, frame, points, results, workcell, cameras, background)
    seconds = time.perf_counter() - start
    per_camera = {key: np.moveaxis(np.array(rows[key]), 1, 0) for key in ("reported", "blind", "flags", "depth")}
    return Episode(times=np.array(rows["times"]), control_points=robot.control_point_names, cameras=cameras,
                   truth=np.array(rows["truth"]), reported=per_camera["reported"], blind=per_camera["blind"],
                   flags=per_camera["flags"], depth_of_truth=per_camera["depth"],
                   fx=np.array([workcell.rig.cameras[c].fx for c in cameras]),
                   spans=[(s.kind, s.start, s.end) for s in workcell.timeline()], seconds=seconds)


def record(rows: dict, frame, points, results, workcell, cameras, background) -> None:
    """Append one simulated frame to ``rows``: its time, the exact truth at ``points`` (the frame's obstacles and
    the ``background`` primitives), and per result its distances, blind distances and flags, and per camera the
    points' optical depths (for the tolerance)."""
    rows["times"].append(frame.time)
    rows["truth"].append(np.minimum(frame.truth.distance, scene_distance(background, points)))
    rows["reported"].append([r.distance for r in results])
    rows["blind"].append([r.blind_distance for r in results])
    rows["flags"].append([[int(f) for f in r.flags] for r in results])
    rows["depth"].append([workcell.rig.cameras[c].world_to_camera(points)[:, 2] for c in cameras])


def summary(episode: Episode) -> dict:
    """Per camera and per action of the person: the smallest true and reported distances, false alarms (reported
    below rho while the truth is at least rho plus the tolerance), unflagged misses (reported above the truth plus
    the tolerance without ``robot_blind_spot``; must be 0) and how often the blind spot was flagged."""
    tol = tolerance(episode)
    blind_flag = int(dg.Flag.ROBOT_BLIND_SPOT)
    out = {"cameras": {}, "frames": len(episode.times), "seconds": episode.seconds, "rho": RHO}
    for k, camera in enumerate(episode.cameras):
        reported, flags = episode.reported[k], episode.flags[k]
        above = reported > episode.truth + tol[k]
        flagged = (flags & blind_flag) != 0
        conservative = np.minimum(reported, episode.blind[k])
        per_span = {}
        for kind, start, end in episode.spans:
            rows = (episode.times >= start) & (episode.times < end)
            if not rows.any():
                continue
            truth, rep = episode.truth[rows], reported[rows]
            far = truth >= RHO + tol[k][rows]
            per_span[f"{kind} {start:.1f}-{end:.1f} s"] = {
                "min_truth": float(truth.min()),
                "min_reported": float(rep.min()),
                "false_alarm_fraction": float(np.mean(rep[far] < RHO)) if far.any() else 0.0,
            }
        out["cameras"][camera] = {
            "unflagged_misses": int(np.count_nonzero(above & ~flagged)),
            "largest_unflagged_excess_m": float(np.max(np.where(~flagged, reported - episode.truth, -np.inf),
                                                           initial=-np.inf)),
            "blind_spot_flagged_fraction": float(flagged.mean()),
            "conservative_misses": int(np.count_nonzero(conservative > episode.truth + tol[k])),
            "false_alarm_fraction": float(np.mean(reported[episode.truth >= RHO + tol[k]] < RHO)),
            "by_action": per_span,
        }
    return out


def plot(episode: Episode, out: Path) -> list[Path]:
    """Distance over time per control point and camera against the truth; one PNG per camera and an overview."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = {"walk": "#eeeeee", "reach": "#fde0c5", "carry": "#e0ecf8", "shadow": "#e6dcf2",
               "hidden_hand": "#dcefdc", "stand": "#f5f5dc"}
    written = []

    def shade(ax):
        for kind, start, end in episode.spans:
            ax.axvspan(start, end, color=colours.get(kind, "#f0f0f0"), lw=0)

    blind_flag = int(dg.Flag.ROBOT_BLIND_SPOT)
    for k, camera in enumerate(episode.cameras):
        fig, axes = plt.subplots(3, 3, figsize=(15, 10), sharex=True, sharey=True)
        for j, ax in enumerate(axes.ravel()[: len(episode.control_points)]):
            shade(ax)
            ax.plot(episode.times, np.minimum(episode.truth[:, j], 0.6), "k-", lw=1.2, label="truth")
            reported = episode.reported[k, :, j]
            ax.plot(episode.times, np.where(np.isfinite(reported), reported, np.nan), "-", color="tab:blue",
                    lw=1.2, label=f"{camera}, single camera")
            flagged = (episode.flags[k, :, j] & blind_flag) != 0
            ax.plot(episode.times[flagged], np.minimum(episode.blind[k, flagged, j], 0.6), ".", color="tab:red",
                    ms=2, label="blind spot distance (flagged)")
            ax.axhline(RHO, color="grey", ls=":", lw=0.8)
            ax.set_title(episode.control_points[j], fontsize=10)
            ax.set_ylim(0, 0.6)
            ax.grid(alpha=0.3)
        for ax in axes[-1]:
            ax.set_xlabel("time [s]")
        for ax in axes[:, 0]:
            ax.set_ylabel("distance [m]")
        axes[0, 0].legend(fontsize=8, loc="upper left")
        fig.suptitle(f"Scenario B, camera '{camera}' alone: distance of each control point (rho = {RHO} m; "
                     "shading: walk, reach, carry, shadow, hidden hand)")
        fig.tight_layout()
        path = out / f"workcell_{camera}.png"
        with atomic_write(path, "wb") as f:
            fig.savefig(f, format="png", dpi=90)
        plt.close(fig)
        written.append(path)

    fig, ax = plt.subplots(figsize=(12, 4.5))
    shade(ax)
    ax.plot(episode.times, np.minimum(episode.truth.min(axis=1), 0.6), "k-", lw=1.5, label="truth (nearest point)")
    for k, camera in enumerate(episode.cameras):
        ax.plot(episode.times, np.minimum(episode.reported[k].min(axis=1), 0.6), lw=1.2, label=f"{camera} alone")
    for kind, start, end in episode.spans:
        ax.text((start + end) / 2, 0.57, kind.replace("_", " "), ha="center", fontsize=9)
    ax.axhline(RHO, color="grey", ls=":", lw=0.8)
    ax.set_ylim(0, 0.6)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("smallest distance over the 9 control points [m]")
    ax.legend(loc="lower left", fontsize=9)
    ax.grid(alpha=0.3)
    ax.set_title("Scenario B: the robot's smallest distance, truth and each single camera")
    fig.tight_layout()
    path = out / "workcell_overview.png"
    with atomic_write(path, "wb") as f:
        fig.savefig(f, format="png", dpi=100)
    plt.close(fig)
    written.append(path)
    return written


def main(out="out/workcell", duration: float | None = None, progress: bool = True) -> int:
    """Run, print the summary table, write plots and summary.json into ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    print("Reference scenario B (Flacco & De Luca 2016): KUKA iiwa tracing a vertical hexagon at 0.4 m/s, a person "
          "walking in,\nreaching, carrying a box, standing in the principal camera's shadow and hiding a hand behind "
          "the robot;\ntwo 640x480 depth cameras 4 m apart, each used on its own (robot filtered out), rho = "
          f"{RHO} m, hybrid,\ninvalid='neighbors' (small holes, like the sensor's dropouts along the robot's edges, "
          "take the depth around them).\n")
    episode = run(duration=duration, progress=progress)
    result = summary(episode)
    plots = plot(episode, out)
    write_whole(out / "summary.json", json.dumps(result, indent=2))
    print(f"\n{result['frames']} frames in {result['seconds']:.1f} s "
          f"({result['frames'] / result['seconds']:.1f} frames/s: simulation of both cameras, self-filtering and "
          "queries)\n")
    for camera, figures in result["cameras"].items():
        print(f"camera '{camera}' alone:")
        print(f"  {'action':26s} {'min truth':>10s} {'min reported':>13s} {'false alarms':>13s}")
        for action, row in figures["by_action"].items():
            print(f"  {action:26s} {row['min_truth']:10.3f} {row['min_reported']:13.3f} "
                  f"{row['false_alarm_fraction']:13.1%}")
        excess = figures["largest_unflagged_excess_m"]
        largest = "every result flagged" if excess == -np.inf else f"largest unflagged distance - truth " \
                                                                     f"{excess * 1e3:+.1f} mm"
        print(f"  above truth + tolerance without the blind-spot flag: {figures['unflagged_misses']} ({largest}); "
              f"min(distance, blind distance) above it: {figures['conservative_misses']}")
        print(f"  blind spot flagged on {figures['blind_spot_flagged_fraction']:.0%} of control-point frames\n")
    print("Plots: " + ", ".join(str(p) for p in plots) + f"; numbers: {out / 'summary.json'}")
    return 0
