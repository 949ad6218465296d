"""Scenario A's report: its run (main: the summary, the timing table) and figures (matplotlib, Agg backend: the paper's
Figs. 6-11 redrawn from depthguard's results)."""

from __future__ import annotations

import json
import os
import platform
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.ticker import FuncFormatter  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402

import depthguard as dg  # noqa: E402
from depthguard.io.files import atomic_write, write_whole  # noqa: E402
from depthguard_lab.experiments import scenario_a as sa  # noqa: E402

COLORS = {"point cloud": "tab:orange", "min": "tab:blue", "mean": "tab:green", "hybrid": "tab:purple",
          "paper min": "tab:gray"}
COMPONENTS = (("x", "tab:red"), ("y", "tab:green"), ("z", "tab:blue"))
VIEW = (35, -100)  # elevation and azimuth of the 3-D panels, degrees
FIGURES = {"point cloud": ("fig7_point_cloud", "Fig. 7: point cloud (Cartesian space), minimum distance"),
           "min": ("fig8_min", "Fig. 8: depth space, minimum distance"),
           "mean": ("fig9_mean", "Fig. 9: depth space, mean distance vector"),
           "hybrid": ("fig10_hybrid", "Fig. 10: depth space, hybrid distance vector")}


def write_all(out, scene, points, truth, truth_direction, exact, noisy, medians, depth, switch_x) -> list[str]:
    """Write every figure of scenario A into ``out``; returns the paths written."""
    files = [overview(out, scene, exact.frame.camera, points, depth)]
    for method in sa.METHODS:
        files.append(method_figure(out, method, scene, points, truth, truth_direction, exact,
                                   switch_x if method == "min" else None))
    files.append(timing_figure(out, points[:, 0], medians))
    files.append(noisy_figure(out, points, truth, noisy))
    return files


def _save(fig, out, name) -> str:
    path = os.path.join(out, f"scenario_a_{name}.png")
    with atomic_write(path, "wb") as f:
        fig.savefig(f, format="png", dpi=110)
    plt.close(fig)
    return path


def _box_faces(box, lower_clip=None, upper_clip=None):
    lo = np.asarray(box.center) - np.asarray(box.half_extents)
    hi = np.asarray(box.center) + np.asarray(box.half_extents)
    if lower_clip is not None:
        lo, hi = np.maximum(lo, lower_clip), np.minimum(hi, upper_clip)
    c = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    quads = [(0, 1, 3, 2), (4, 5, 7, 6), (0, 1, 5, 4), (2, 3, 7, 6), (0, 2, 6, 4), (1, 3, 7, 5)]
    return [c[list(q)] for q in quads]


def _draw_scene_3d(ax, scene):
    table = _box_faces(scene.table, [-0.8, 0.0, -0.02], [0.8, 0.8, sa.TABLE_TOP_Z])
    ax.add_collection3d(Poly3DCollection(table, facecolor="0.85", edgecolor="0.6", alpha=0.35, linewidth=0.5))
    ax.add_collection3d(Poly3DCollection(_box_faces(scene.wall), facecolor="tan", edgecolor="0.4", alpha=0.2,
                                         linewidth=0.5))
    hidden = np.array([[-0.5, 0.37, 0.04], [0.0, 0.37, 0.04], [0.0, 0.37, 0.6], [-0.5, 0.37, 0.6]])
    ax.add_collection3d(Poly3DCollection([hidden], facecolor="tab:red", alpha=0.3, edgecolor="tab:red"))


def method_figure(out, method, scene, points, truth, truth_direction, run, switch_x=None) -> str:
    """The paper's Figs. 7-10 for one method: distance vectors in space [left], distance and direction components
    against x [right]."""
    name, title = FIGURES[method]
    x = points[:, 0]
    distance, direction = run.distance[method], run.direction[method]
    fig = plt.figure(figsize=(14, 6.2))
    grid = fig.add_gridspec(2, 2, width_ratios=(1.2, 1.0), hspace=0.3, wspace=0.16, left=0.02, right=0.97)
    ax3 = fig.add_subplot(grid[:, 0], projection="3d")
    _draw_scene_3d(ax3, scene)
    ax3.plot(x, points[:, 1], points[:, 2], color="red", linewidth=1.5, label="P's line")
    step = 8
    finite = np.isfinite(distance)
    sel = np.arange(0, len(x), step)
    sel = sel[finite[sel]]
    obstacle = points[sel] - distance[sel, None] * direction[sel]
    ax3.quiver(obstacle[:, 0], obstacle[:, 1], obstacle[:, 2], *(points[sel] - obstacle).T, color=COLORS[method],
               arrow_length_ratio=0.15, linewidth=0.9, label="distance vectors (obstacle → P)")
    ax3.set(xlim=(-0.8, 0.8), ylim=(0.0, 0.8), zlim=(0.0, 0.6), xlabel="x [m]", ylabel="y [m]", zlabel="z [m]")
    ax3.set_box_aspect((1.6, 0.8, 0.6), zoom=1.25)
    ax3.view_init(elev=VIEW[0], azim=VIEW[1])
    ax3.legend(loc="upper left", fontsize=8)
    ax3.set_title("red face: Y = 0.37, hidden from the camera", fontsize=9)

    ax = fig.add_subplot(grid[0, 1])
    ax.plot(x, truth, "k--", linewidth=1.2, label="true distance")
    ax.plot(x, distance, color=COLORS[method], linewidth=1.6, label=f"{method}")
    ax.axvline(sa.TRUE_SWITCH_X, color="k", linestyle=":", linewidth=1)
    ax.annotate(f"true switch\nx = {sa.TRUE_SWITCH_X:.4f}", (sa.TRUE_SWITCH_X, 0.01), xytext=(4, 0),
                textcoords="offset points", fontsize=8)
    if method == "min" and "paper min" in run.distance:
        ax.plot(x, run.distance["paper min"], color=COLORS["paper min"], linewidth=1.0,
                label="min with the paper's formulas (window, depth filter)")
    if switch_x is not None:
        ax.axvline(switch_x, color=COLORS[method], linestyle="--", linewidth=0.8,
                   label=f"{method} direction switches, x = {switch_x:.4f}")
    if method == "point cloud":
        ax.axvspan(sa.X_RANGE[0], -sa.TRUE_SWITCH_X, color="tab:red", alpha=0.08,
                   label="hidden face nearest but unseen")
    ax.set(ylabel="distance [m]", xlim=sa.X_RANGE, ylim=(0.0, sa.RHO))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    ax.set_title(title, fontsize=10)

    ax = fig.add_subplot(grid[1, 1], sharex=ax)
    for k, (label, color) in enumerate(COMPONENTS):
        ax.plot(x, direction[:, k], color=color, linewidth=1.5, label=f"{label}")
        ax.plot(x, truth_direction[:, k], color=color, linestyle=":", linewidth=1.0)
    ax.axvline(sa.TRUE_SWITCH_X, color="k", linestyle=":", linewidth=1)
    ax.set(xlabel="x of P [m]", ylabel="unit direction (world)", ylim=(-1.1, 1.1))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower left", ncol=3, title="solid: method, dotted: truth", title_fontsize=8)
    ax.set_title("direction components, from the obstacle towards P", fontsize=9)
    return _save(fig, out, name)


def overview(out, scene, camera, points, depth) -> str:
    """The paper's Fig. 6: the depth image with P's line, and a top and a side view of the walls and camera."""
    fig = plt.figure(figsize=(14, 6.5))
    grid = fig.add_gridspec(2, 2, width_ratios=(1.15, 1.0), hspace=0.3, wspace=0.22, left=0.04, right=0.98,
                            top=0.94, bottom=0.08)
    ax = fig.add_subplot(grid[:, 0])
    axes = [ax, fig.add_subplot(grid[0, 1]), fig.add_subplot(grid[1, 1])]
    shown = np.where(depth > 0, depth, np.nan)
    image = ax.imshow(shown, cmap="gray_r", interpolation="nearest")
    fig.colorbar(image, ax=ax, fraction=0.035, pad=0.02, label="depth [m] (lighter = nearer)")
    u, v, _ = camera.project(camera.world_to_camera(points))
    ax.plot(u, v, color="red", linewidth=1.5, label="P's line (projected)")
    ax.annotate("x = -0.5", (u[0], v[0]), color="red", fontsize=8, xytext=(8, 0), textcoords="offset points")
    ax.annotate("x = 0.5", (u[-1], v[-1]), color="red", fontsize=8, xytext=(8, 0), textcoords="offset points")
    face = camera.world_to_camera(np.array([[0, 0.33, 0.04], [0, 0.37, 0.04], [0, 0.37, 0.6], [0, 0.33, 0.6],
                                            [0, 0.33, 0.04]], float))
    fu, fv, _ = camera.project(face)
    ax.plot(fu, fv, color="tab:green", linewidth=1.0, label="wall face X = 0 (seen)")
    ax.legend(fontsize=8, loc="lower right")
    ax.set_title("depth image (640x480, fx = fy = 525)", fontsize=10)

    eye, target = np.array(sa.CAMERA_EYE), np.array(sa.CAMERA_TARGET)
    for ax, (i, j), label in ((axes[1], (0, 1), "top view (x-y)"), (axes[2], (0, 2), "side view (x-z)")):
        for box, color in ((scene.table, "0.85"), (scene.wall, "tan")):
            lo = np.asarray(box.center) - np.asarray(box.half_extents)
            hi = np.asarray(box.center) + np.asarray(box.half_extents)
            ax.add_patch(plt.Rectangle((lo[i], lo[j]), hi[i] - lo[i], hi[j] - lo[j], facecolor=color,
                                       edgecolor="0.4", linewidth=0.6))
        ax.plot(points[:, i], points[:, j], color="red", linewidth=2, label="P's line")
        ax.plot(*eye[[i, j]], "k^", markersize=8, label="camera")
        ax.annotate("", target[[i, j]], eye[[i, j]], arrowprops=dict(arrowstyle="->", color="k", linewidth=0.8))
        ax.set(xlabel=f"{'xyz'[i]} [m]", ylabel=f"{'xyz'[j]} [m]", aspect="equal")
        ax.set_title(label, fontsize=10)
        ax.grid(alpha=0.3)
    ax = axes[1]
    ax.plot([0, 0], [0.33, 0.37], color="tab:green", linewidth=3, label="face X = 0 (seen)")
    ax.plot([-0.5, 0], [0.37, 0.37], color="tab:red", linewidth=3, label="face Y = 0.37 (hidden)")
    ax.set(xlim=(-1.3, 1.8), ylim=(-0.2, 0.9))
    ax.legend(fontsize=8, loc="lower right", framealpha=1.0)
    ax = axes[2]
    ax.plot([0, 0], [0.04, 0.6], color="tab:green", linewidth=3)
    ax.set(xlim=(-1.3, 1.8), ylim=(-0.2, 1.4))
    return _save(fig, out, "overview")


def timing_figure(out, x, medians) -> str:
    """The paper's Fig. 11: time per query of one control point along the motion (log scale) and worst / median /
    best per method beside the paper's times."""
    fig, (left, right) = plt.subplots(1, 2, figsize=(13, 4.8), gridspec_kw={"width_ratios": (1.4, 1.0)})
    for m, t in medians.items():
        left.semilogy(x, t * 1e3, color=COLORS[m], linewidth=1.2, label=m)
    plain = FuncFormatter(lambda value, _: f"{value:g}")
    left.yaxis.set_major_formatter(plain)
    left.yaxis.set_minor_formatter(plain)
    left.set(xlabel="x of P [m]", ylabel="time per query [ms] (median per position)", xlim=sa.X_RANGE)
    left.grid(alpha=0.3, which="both")
    left.legend(fontsize=8)
    left.set_title("one control point, prepared frame, 1 numba thread", fontsize=10)

    table = sa.timing_table(medians)
    names = list(table)
    stats = ("worst", "median", "best")
    width = 0.25
    for k, stat in enumerate(stats):
        values = [table[m][stat] * 1e3 for m in names]
        right.bar(np.arange(len(names)) + (k - 1) * width, values, width, label=f"this machine, {stat}",
                  color=["0.25", "0.55", "0.8"][k])
    for i, m in enumerate(names):
        for stat, marker in (("worst", "rv"), ("best", "r^")):
            value = sa.PAPER_TIMES.get(m, {}).get(stat)
            if value is not None:
                right.plot(i + (-1 if stat == "worst" else 1) * width, value * 1e3, marker, markersize=7)
    right.plot([], [], "rv", label="paper worst (i7-2600)")
    right.plot([], [], "r^", label="paper best")
    right.set_yscale("log")
    right.set_xticks(np.arange(len(names)), names)
    right.set(ylabel="time per query [ms]")
    right.grid(alpha=0.3, axis="y", which="both")
    right.legend(fontsize=7)
    right.set_title("Fig. 11: worst / median / best over the motion", fontsize=10)
    fig.tight_layout()
    return _save(fig, out, "fig11_timing")


def noisy_figure(out, points, truth, run) -> str:
    """The same motion on a noisy, millimetre-quantised image: distances of every method and the direction
    components of the point cloud and of depth-space min."""
    x = points[:, 0]
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.6), sharex=True)
    ax = axes[0]
    ax.plot(x, truth, "k--", linewidth=1.2, label="true distance")
    for m in sa.METHODS:
        style = dict(linestyle="--", label="hybrid (= min)") if m == "hybrid" else dict(label=m)
        ax.plot(x, run.distance[m], color=COLORS[m], linewidth=1.3, **style)
    ax.axvline(sa.TRUE_SWITCH_X, color="k", linestyle=":", linewidth=1)
    ax.set(xlabel="x of P [m]", ylabel="distance [m]", ylim=(0, sa.RHO), xlim=sa.X_RANGE)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    ax.set_title("noisy image: distances", fontsize=10)
    for ax, m in zip(axes[1:], ("point cloud", "min")):
        for k, (label, color) in enumerate(COMPONENTS):
            ax.plot(x, run.direction[m][:, k], color=color, linewidth=1.2, label=label)
        ax.axvline(sa.TRUE_SWITCH_X, color="k", linestyle=":", linewidth=1)
        ax.set(xlabel="x of P [m]", ylabel="unit direction (world)", ylim=(-1.1, 1.1))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="lower left", ncol=3)
        ax.set_title(f"noisy image: {m} direction", fontsize=10)
    fig.suptitle("Gaussian depth noise sigma(d) of the default noise model, uint16 millimetres; depth space uses "
                 "the 3-sigma margin", fontsize=10)
    fig.tight_layout()
    return _save(fig, out, "noisy")


def main(out: str = "out/scenario-a", repeats: int = 20) -> int:
    """Run scenario A: write the plots and ``summary.json`` into ``out`` (created if needed), print a summary.

    ``repeats``: timing repetitions per control-point position (the per-position median is kept). Returns 0.
    """
    started = time.perf_counter()
    os.makedirs(out, exist_ok=True)
    scene = sa.make_scene()
    points = sa.control_points()
    x = points[:, 0]
    truth, truth_direction = sa.true_nearest(scene, points)

    camera = sa.make_camera()
    depth = sa.render(scene, camera)
    faces = sa.wall_faces_seen(scene, camera, depth)
    exact = sa.run_methods("noise-free", sa.make_frame(camera, depth), points, sa.METHODS + ("paper min",))
    exact_facts = sa.facts(exact, x, truth)

    noisy_camera = sa.make_camera(dg.NoiseModel())
    noisy = sa.run_methods("noisy", sa.make_frame(noisy_camera, sa.noisy_depth(depth, noisy_camera.noise)), points)
    noisy_facts = sa.facts(noisy, x, truth)

    medians = sa.time_methods(exact.frame, sa.METHODS, points, repeats)
    table = sa.timing_table(medians)

    files = write_all(out, scene, points, truth, truth_direction, exact, noisy, medians, depth,
                      switch_x=exact_facts["min_direction_switch_x"])
    summary = {
        "scenario": "A (Flacco et al. 2015, section 4)",
        "rho": sa.RHO,
        "line": {"y": sa.LINE_Y, "z": sa.LINE_Z, "x": list(sa.X_RANGE), "positions": len(points)},
        "camera": {"eye": list(sa.CAMERA_EYE), "target": list(sa.CAMERA_TARGET), "width": camera.width,
                   "height": camera.height, "fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy,
                   "depth_range": list(camera.depth_range)},
        "wall_face_pixels": faces,
        "noise_free": exact_facts,
        "noisy": {"noise": "Gaussian sigma(d) of the default NoiseModel, uint16 mm, margin 3 sigma", **noisy_facts},
        "timing_seconds": table,
        "timing": {"repeats_per_position": repeats,
                   "statistic": "median per position, then worst/median/best over positions",
                   "query": "one control point, prepared frame", "numba_threads": 1,
                   "machine": platform.processor() or platform.machine(), "cpus": os.cpu_count()},
        "paper_timing_seconds": sa.PAPER_TIMES,
        "files": sorted(os.path.basename(f) for f in files),
    }
    write_whole(os.path.join(out, "summary.json"), json.dumps(summary, indent=2))

    _print_summary(out, faces, exact_facts, noisy_facts, table, repeats, len(points), time.perf_counter() - started)
    return 0


def _print_summary(out, faces, exact, noisy, table, repeats, n, elapsed) -> None:
    def at(x):
        return "nowhere" if x is None else f"x = {x:.4f} m"

    excess = exact["max_excess_over_truth"]
    cloud = exact["hidden_face_point_cloud_distance"]
    seen = exact["hidden_face_min_distance"]
    noisy_cloud = noisy["hidden_face_point_cloud_distance"]
    print("Scenario A (Flacco et al. 2015, section 4): one 640x480 depth camera, a table top at z = 0.04 m and a "
          "thin wall.\n"
          f"The camera sees the wall's face X = 0 ({faces['X=0']} pixels), not its face Y = 0.37 "
          f"({faces['Y=0.37']} pixels).\n"
          f"Control point P: y = {sa.LINE_Y}, z = {sa.LINE_Z}, x from {sa.X_RANGE[0]} to {sa.X_RANGE[1]} m ({n} positions), "
          f"rho = {sa.RHO} m.\n")
    print("Noise-free image:")
    print(f"  min's nearest obstacle turns from the wall to the table at {at(exact['min_direction_switch_x'])} "
          f"(true: {sa.TRUE_SWITCH_X:.4f} m)")
    print(f"  behind the wall (x < {-sa.TRUE_SWITCH_X:.3f}): truth 0.030 m; depth-space min "
          f"{seen[0]:.3f}-{seen[1]:.3f} m; point cloud {cloud[0]:.3f}-{cloud[1]:.3f} m (blind)")
    print(f"  depth-space distance - truth, largest: min {excess['min'] * 1e3:+.2f} mm, hybrid "
          f"{excess['hybrid'] * 1e3:+.2f} mm: never above the truth")
    print(f"  the paper's formulas instead: {excess['paper min'] * 1e3:+.1f} mm at x = "
          f"{exact['max_excess_at_x']['paper min']:.3f} (their depth filter skips the wall, > rho in front of P)")
    print("Noisy image (Gaussian sigma(d), uint16 mm, 3-sigma margin):")
    print(f"  min switch at {at(noisy['min_direction_switch_x'])}; min - truth at most "
          f"{noisy['max_excess_over_truth']['min'] * 1e3:+.2f} mm; point cloud behind the wall "
          f"{noisy_cloud[0]:.3f}-{noisy_cloud[1]:.3f} m")
    print(f"\nTime per query of one control point on a prepared frame, 1 numba thread (median of {repeats} repeats "
          f"per position,\nthen worst / median / best over the {n} positions; the paper's on an i7-2600):")
    for line in sa.format_timing_table(table):
        print(line)
    print(f"\nPlots (overview, Figs. 7-11, noisy run) and summary.json in {os.path.abspath(out)}/ ({elapsed:.1f} s)")
