"""Real data: five calibrated views of one static room (the slambook2 RGB-D example) as a rig of depth cameras.

The folder ``slambook2-room`` (see ``data/real/README.md`` in the shared folder; MIT licence, from the
public repository gaoxiang12/slambook2, ``ch5/rgbd``) holds five 640x480 depth images of one static room and the
camera-to-world pose of each. Views 3, 4 and 5 agree best; they stand here for three cameras recording at the same
time, view 3 the depth grid's principal camera. Views 4 and 5 stand 0.71 and 0.94 m in front of it, looking the same
way, so they see little of what view 3 cannot. The poses are approximate: that is the rig's calibration error, which
the fusion margin must cover (design §8: a secondary camera clears a cell only if it saw beyond the cell by its
noise margin plus the fusion margin).

(a) Calibration error. For each ordered pair of views (i, j), every valid pixel of i is back-projected, moved into
    j with the two poses and projected to j's nearest pixel; where j measured too, ``diff = j's depth - the point's
    depth in j``. A small difference (``|diff| < OCCLUSION``) is the same surface seen twice, off by calibration
    error and depth noise; a large negative one is an occlusion (j sees something in front); a large positive one
    means j sees *past* a surface i measured, which cannot happen in a static scene seen by a consistent rig: depth
    edges shifted by the pose error, and mixed ("flying") pixels. What the fusion must cover is how far one camera
    sees past another's surface beyond its own noise margin, ``diff - m(depth)``: :func:`choose_margin` takes its
    ``CHOICE_PERCENTILE`` percentile between the secondary cameras at depths up to ``WORKSPACE_DEPTH``.
(b) Fusion never clears a surface that one camera sees. Points are sampled on the surfaces measured by each
    secondary camera (its valid pixels back-projected, then moved ``SURFACE_OFFSET`` towards it) where the
    principal does not see them: at least ``BEHIND`` metres behind the principal's own measured surface (its gray
    area) or in a principal pixel without a measurement (a hole). The camera that measured a point cannot clear it
    (its measurement lies in the point's cell, less its noise margin); the other secondary camera can, where the
    calibration error puts its measured surface behind the point. A fused distance above ``CLEARED`` marks a wrongly
    cleared surface point. Swept over fusion margins (and two noise models): the fraction of such points cleared,
    per depth and on or off depth edges, and the fraction of the principal's gray area (points 0.1-1 m behind its
    surface) and of its holes that the fusion frees: the cost of the margin.
(c) :func:`main` prints a summary and writes ``summary.json`` and three figures into its output folder.

    python -c "from depthguard_lab.experiments import real_room; real_room.main('out/real-room')"
"""

from __future__ import annotations

import json
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage

import depthguard as dg
from depthguard.io.files import atomic_write, write_whole
from depthguard.depthgrid import DepthGridMap, build_map
from depthguard.transforms import quaternion_to_matrix

#: The data folder beside the checkout (``<repo>/../shared/data/real/slambook2-room``), as tests/conftest.py finds it.
DEFAULT_FOLDER = Path(__file__).resolve().parents[3] / "shared" / "data" / "real" / "slambook2-room"

#: The views' intrinsics, from the source's own program: pixels; depth images in millimetres.
WIDTH, HEIGHT = 640, 480
FX, FY, CX, CY = 518.0, 519.0, 325.5, 253.5
DEPTH_SCALE = 0.001

#: Valid measurement range, metres. The data holds depths from 0.71 to 9.8 m (a Kinect-class structured-light
#: sensor), all inside it.
DEPTH_RANGE = (0.4, 10.0)

#: The rig of this experiment: the views that agree best, and the principal camera.
VIEWS = (3, 4, 5)
PRINCIPAL = 3

#: The depth grid spans the whole room. The default grid ends at 3.72 m; beyond its end every cell counts as
#: occupied, and the fusion could clear nothing there. Cells keep the default depth of 0.01 m.
GRID_D_MAX = 10.0

#: Noise models compared: the library's default (Kinect v1 axial noise, 3 sigma), the model of this sensor; and none,
#: where the fusion margin alone must cover the calibration error.
NOISE_MODELS = {"kinect": dg.NoiseModel(), "none": dg.NoiseModel.none()}

#: (a) A reprojection difference at least this large (metres) is an occlusion or a depth edge, not calibration error.
OCCLUSION = 0.3
#: (a) The README's agreement figure: the fraction of overlapping pixels whose depths agree within this, metres.
AGREEMENT = 0.05
#: (a) Bins of the depth in the target view (metres): the calibration error grows with depth.
DEPTH_BINS = (0.0, 2.0, 3.0, 4.0, 6.0, 10.0)
#: (a) Depths a robot workspace spans in this room, metres (the default depth grid ends at 3.72 m); beyond it the
#: sensor's own noise, not the poses, dominates the disagreement.
WORKSPACE_DEPTH = 4.0
#: (a) The margin is chosen to cover this percentile of how far a secondary camera sees past another's surface
#: beyond its noise margin, rounded up to a swept margin.
CHOICE_PERCENTILE = 99.0

#: (b) A surface point lies at least this far (metres, principal's optical z) behind the principal's own measured
#: surface, so the principal does not see it itself (most of the calibration error is below this, see (a)).
BEHIND = 0.1
#: (b) Surface points are moved this far (metres) from the measured surface towards the camera that measured it: a
#: control point 1 cm in front of a surface only that camera sees.
SURFACE_OFFSET = 0.01
#: (b) Gray-area points lie this far behind the principal's surface (metres, uniform); hole points (principal pixels
#: without a measurement) at a depth uniform in HOLE_DEPTHS (metres).
GRAY_DEPTHS = (0.1, 1.0)
HOLE_DEPTHS = (1.0, 6.0)
#: (b) Sample points lie at least this many pixels inside the principal's image, so that the unseen space beyond its
#: border (fail-safe ``unseen="occupied"``) is farther than CLEARED from them (16 pixels are 3 cm at 1 m).
BORDER = 16
#: (b) A fused distance above this (metres) means the point's cells were cleared: a wrongly cleared surface point,
#: or a freed gray-area point. The surface offset plus a pixel (2-19 mm at 1-10 m).
CLEARED = 0.02
#: (b) Surveillance radius of the fused queries, metres. Whether a distance exceeds CLEARED does not depend on rho as
#: long as rho > CLEARED (aggregate "min"); a small rho keeps the queries fast.
RHO = 0.1
#: (b) The fusion margins swept, metres, and the footprint growths (pixels) compared at the chosen margin.
MARGINS = (0.0, 0.01, 0.02, 0.05, 0.1, 0.2)
FUSION_PIXELS = (0, 1, 2)
#: (b) A surface point whose pixel in the camera that measured it lies within EDGE_WINDOW x EDGE_WINDOW pixels of a
#: depth jump larger than OCCLUSION is on a depth edge: there structured-light sensors report mixed depths between
#: the foreground and the background, surfaces that do not exist.
EDGE_WINDOW = 5
#: (b) Another secondary camera "contests" a surface point if it measured at the point's pixel no more than this
#: (metres) in front of it: it sees the surface or past it, and could clear it.
CONTESTED_SLACK = 0.05


def camera_name(view: int) -> str:
    """The rig's name of view ``view`` (1-5): ``"view3"``."""
    return f"view{view}"


def read_poses(path) -> dict[int, np.ndarray]:
    """The views' poses from ``pose.txt`` (one line per view, ``tx ty tz qx qy qz qw``, camera-to-world):
    view number (1-based) -> T_world_camera, (4, 4) float64, metres."""
    rows = np.loadtxt(path, dtype=np.float64, ndmin=2)
    if rows.shape[1] != 7:
        raise ValueError(f"{path}: expected 7 numbers per line (tx ty tz qx qy qz qw), got {rows.shape[1]}")
    poses = {}
    for view, (tx, ty, tz, qx, qy, qz, qw) in enumerate(rows, start=1):
        T_world_camera = np.eye(4)
        T_world_camera[:3, :3] = quaternion_to_matrix(qx, qy, qz, qw)
        T_world_camera[:3, 3] = (tx, ty, tz)
        poses[view] = T_world_camera
    return poses


def slambook_rig(folder=DEFAULT_FOLDER, views=VIEWS, principal: int = PRINCIPAL, noise: dg.NoiseModel | None = None,
                 depth_range=DEPTH_RANGE) -> tuple[dg.Rig, dict[str, dg.DepthImage]]:
    """The rig of ``views`` of the slambook2 room, and their depth frames.

    Returns (rig, frames): cameras named ``view<k>`` (:func:`camera_name`) in the order of ``views``, the principal
    ``view<principal>``; frames: camera name -> its :class:`depthguard.DepthImage` (uint16 millimetres, 0 = no
    measurement). ``noise``: every camera's noise model (default: the library's, Kinect v1 axial noise).
    """
    folder = Path(folder)
    poses = read_poses(folder / "pose.txt")
    noise = dg.NoiseModel() if noise is None else noise
    cameras = {}
    frames = {}
    for view in views:
        if view not in poses:
            raise ValueError(f"{folder / 'pose.txt'} has no line for view {view} (views 1-{len(poses)})")
        name = camera_name(view)
        camera = dg.PinholeCamera(name, WIDTH, HEIGHT, FX, FY, CX, CY, poses[view], depth_range=depth_range,
                                  depth_scale=DEPTH_SCALE, noise=noise)
        cameras[name] = camera
        frames[name] = dg.load_depth(folder / "depth" / f"{view}.pgm", camera)
    return dg.Rig(cameras, depth_scale=DEPTH_SCALE, principal=camera_name(principal)), frames


def depth_grid(rig: dg.Rig) -> DepthGridMap:
    """The principal's depth grid over the whole room (to ``GRID_D_MAX``)."""
    return build_map(rig, rig.principal, d_max=GRID_D_MAX)


def secondaries(rig: dg.Rig) -> list[str]:
    return [name for name in rig.cameras if name != rig.principal]


def _project(camera: dg.PinholeCamera, points_world: np.ndarray):
    """Nearest pixels (col, row: (n,) int64, 0 where not inside) of (n, 3) world points (metres) in ``camera``, their
    depth there ((n,) metres) and whether they land inside the image in front of the camera ((n,) bool)."""
    u, v, z = camera.project(camera.world_to_camera(points_world))
    with np.errstate(invalid="ignore"):
        col = np.round(u)
        row = np.round(v)
        inside = (z > 0) & (col >= 0) & (col <= camera.width - 1) & (row >= 0) & (row <= camera.height - 1)
    return np.where(inside, col, 0).astype(np.int64), np.where(inside, row, 0).astype(np.int64), z, inside


def _surface_points(camera: dg.PinholeCamera, frame: dg.DepthImage):
    """Every valid pixel of ``frame`` back-projected: (n, 3) world points, metres."""
    depth = frame.metres()
    row, col = np.nonzero(np.isfinite(depth))
    return camera.camera_to_world(camera.back_project(col, row, depth[row, col]))


# ------------------------------------------------------------------------------------------ (a) calibration error

def reprojection_differences(rig: dg.Rig, frames: dict, source: str, target: str):
    """Reproject ``source``'s valid pixels into ``target``.

    Returns (diff, depth), (m,) float64 metres, for the m points that land inside target's image in front of it on a
    pixel where target measured too: diff = target's measured depth there - the point's depth in target (positive:
    target sees past the point); depth = the point's depth in target."""
    camera = rig.cameras[target]
    col, row, z, inside = _project(camera, _surface_points(rig.cameras[source], frames[source]))
    measured = frames[target].metres()[row, col].astype(np.float64)
    both = inside & np.isfinite(measured)
    return measured[both] - z[both], z[both]


def _error_stats(diff: np.ndarray, depth: np.ndarray, noise: dg.NoiseModel, occlusion: float) -> dict:
    same = np.abs(diff) < occlusion
    stats = dict(pixels=int(diff.size), same_surface=int(same.sum()))
    if same.any():
        small = np.abs(diff[same])
        excess = diff[same] - noise.margin(depth[same])
        stats.update(median=float(np.median(small)), signed_median=float(np.median(diff[same])),
                     **{f"p{q:g}": float(np.percentile(small, q)) for q in (90, 95, 99)},
                     **{f"excess_p{q:g}": float(np.percentile(excess, q)) for q in (95, 99)})
    if diff.size:
        stats.update(occluded_fraction=float(np.mean(diff <= -occlusion)),
                     sees_past_fraction=float(np.mean(diff >= occlusion)))
    return stats


def calibration_error(rig: dg.Rig, frames: dict, occlusion: float = OCCLUSION, bins=DEPTH_BINS,
                      noise: dg.NoiseModel = NOISE_MODELS["kinect"]) -> dict:
    """The reprojection differences of every ordered pair of the rig's cameras (the module's (a)). Metres.

    Returns ``"source->target"`` -> dict: ``pixels`` (overlapping pixels both measured); ``agree_5cm``: the fraction
    of them within AGREEMENT (occlusions included, as the README counts); over the same-surface pixels
    (|diff| < occlusion): ``median``, ``p90``, ``p95``, ``p99`` of |diff|, ``signed_median``, and ``excess_p95``,
    ``excess_p99``: percentiles of diff - noise.margin(depth), how far the target sees past the source's surface
    beyond its noise margin; ``occluded_fraction`` (diff <= -occlusion), ``sees_past_fraction`` (diff >= occlusion);
    ``by_depth``: the same per bin of the depth in the target; ``workspace``: the same up to WORKSPACE_DEPTH.
    """
    result = {}
    for source in rig.cameras:
        for target in rig.cameras:
            if source == target:
                continue
            diff, depth = reprojection_differences(rig, frames, source, target)
            entry = dict(agree_5cm=float(np.mean(np.abs(diff) < AGREEMENT)) if diff.size else 0.0,
                         **_error_stats(diff, depth, noise, occlusion))
            entry["by_depth"] = {_bin_name(lo, hi): _error_stats(diff[(depth >= lo) & (depth < hi)],
                                                                 depth[(depth >= lo) & (depth < hi)], noise, occlusion)
                                 for lo, hi in zip(bins[:-1], bins[1:])}
            near = depth < WORKSPACE_DEPTH
            entry["workspace"] = _error_stats(diff[near], depth[near], noise, occlusion)
            result[f"{source}->{target}"] = entry
    return result


def _bin_name(lo: float, hi: float) -> str:
    return f"{lo:g}-{hi:g} m"


def choose_margin(rig: dg.Rig, frames: dict, noise: dg.NoiseModel = NOISE_MODELS["kinect"],
                  pairs=None, percentile: float = CHOICE_PERCENTILE, margins=MARGINS) -> tuple[float, float]:
    """The fusion margin that covers the calibration error of points two cameras both see (the module's (a)).

    Over the same-surface pixels at depths below WORKSPACE_DEPTH of the ordered camera ``pairs`` (default: the
    secondary cameras', the only ones that clear cells), the ``percentile`` of diff - noise.margin(depth): how far
    one camera sees past the other's surface beyond its own noise margin. Returns (that excess in metres, the
    smallest of ``margins`` at least as large)."""
    pairs = pairs or [(a, b) for a in secondaries(rig) for b in secondaries(rig) if a != b]
    excess = []
    for source, target in pairs:
        diff, depth = reprojection_differences(rig, frames, source, target)
        keep = (np.abs(diff) < OCCLUSION) & (depth < WORKSPACE_DEPTH)
        excess.append(diff[keep] - noise.margin(depth[keep]))
    need = float(np.percentile(np.concatenate(excess), percentile))
    return need, min((m for m in margins if m >= need), default=max(margins))


# ---------------------------------------------------------------------------------- (b) what the fusion clears

@dataclass
class SamplePoints:
    """Query points of (b); n points, names are the rig's camera names.

    Attributes:
        points_world: (n, 3) float64, metres, world frame.
        depth: (n,) float64, metres: each point's depth in the principal camera.
        kind: (n,) str: ``"gray"`` (behind the principal's measured surface) or ``"hole"`` (in a principal pixel
            without a measurement).
        seen_by: (n,) str: the secondary camera whose measured surface the point lies on ("" for free-space samples).
        edge: (n,) bool: the point's pixel in ``seen_by`` lies on a depth edge (see EDGE_WINDOW).
        contested: (n,) bool: surface points: another secondary camera measured at the point's pixel no more than
            CONTESTED_SLACK in front of it, so it could clear the point (elsewhere it confirms the point, hidden or
            blind). Free-space samples: some secondary camera measured at least CLEARED past it.
    """

    points_world: np.ndarray
    depth: np.ndarray
    kind: np.ndarray
    seen_by: np.ndarray
    edge: np.ndarray
    contested: np.ndarray

    FIELDS = ("points_world", "depth", "kind", "seen_by", "edge", "contested")

    def __len__(self) -> int:
        return len(self.depth)

    def subset(self, mask) -> "SamplePoints":
        return SamplePoints(*(getattr(self, f)[mask] for f in self.FIELDS))

    @classmethod
    def concatenate(cls, parts) -> "SamplePoints":
        return cls(*(np.concatenate([getattr(p, f) for p in parts]) for f in cls.FIELDS))


def depth_edges(frame: dg.DepthImage, window: int = EDGE_WINDOW, jump: float = OCCLUSION) -> np.ndarray:
    """(h, w) bool: the valid depths within ``window`` x ``window`` pixels of each pixel span more than ``jump``
    metres."""
    depth = frame.metres().astype(np.float64)
    valid = np.isfinite(depth)
    high = ndimage.maximum_filter(np.where(valid, depth, -np.inf), size=window)
    low = ndimage.minimum_filter(np.where(valid, depth, np.inf), size=window)
    with np.errstate(invalid="ignore"):
        return (high - low) > jump


def _measured_past(rig: dg.Rig, frames: dict, name: str, points_world: np.ndarray, past: float) -> np.ndarray:
    """(n,) bool: camera ``name`` measured at each point's nearest pixel at least ``past`` metres behind the point
    (``past`` < 0: at most -past in front of it)."""
    col, row, z, inside = _project(rig.cameras[name], points_world)
    measured = frames[name].metres()[row, col].astype(np.float64)
    with np.errstate(invalid="ignore"):
        return inside & np.isfinite(measured) & (measured >= z + past)


def _principal_pixels(rig: dg.Rig, points_world: np.ndarray, border: int):
    camera = rig.cameras[rig.principal]
    col, row, z, inside = _project(camera, points_world)
    inside &= (col >= border) & (col < camera.width - border) & (row >= border) & (row < camera.height - border)
    inside &= (z > camera.depth_range[0]) & (z < min(camera.depth_range[1], GRID_D_MAX))
    return col, row, z, inside


def secondary_surface_points(rig: dg.Rig, frames: dict, n: int, rng: np.random.Generator, behind: float = BEHIND,
                             offset: float = SURFACE_OFFSET, border: int = BORDER) -> SamplePoints:
    """Up to ``n`` points per secondary camera and kind (gray, hole), uniform over its valid pixels whose surface the
    principal does not see (the module's (b))."""
    depth_principal = frames[rig.principal].metres()
    parts = []
    for name in secondaries(rig):
        camera = rig.cameras[name]
        points_world = _surface_points(camera, frames[name])
        towards = camera.T_world_camera[:3, 3] - points_world
        points_world = points_world + offset * towards / np.linalg.norm(towards, axis=1, keepdims=True)
        col, row, z, inside = _principal_pixels(rig, points_world, border)
        measured = depth_principal[row, col].astype(np.float64)
        with np.errstate(invalid="ignore"):
            kinds = {"gray": inside & (z >= measured + behind), "hole": inside & ~np.isfinite(measured)}
        edges = depth_edges(frames[name])
        for kind, mask in kinds.items():
            index = np.nonzero(mask)[0]
            index = np.sort(rng.choice(index, min(n, index.size), replace=False))
            chosen = points_world[index]
            c, r, _, _ = _project(camera, chosen)
            contested = np.zeros(index.size, dtype=bool)
            for other in secondaries(rig):
                if other != name:
                    contested |= _measured_past(rig, frames, other, chosen, -CONTESTED_SLACK)
            parts.append(SamplePoints(chosen, z[index], np.full(index.size, kind), np.full(index.size, name),
                                      edges[r, c], contested))
    return SamplePoints.concatenate(parts)


def free_space_points(rig: dg.Rig, frames: dict, n: int, rng: np.random.Generator,
                      border: int = BORDER) -> SamplePoints:
    """``n`` points in what the principal alone calls possibly occupied: its gray area (uniform over its valid
    pixels, GRAY_DEPTHS behind the measured surface) and ``n`` in its holes (uniform over its pixels without a
    measurement, depth uniform in HOLE_DEPTHS); ``border`` pixels inside its image, within the grid."""
    camera = rig.cameras[rig.principal]
    depth = frames[rig.principal].metres()
    parts = []
    for kind in ("gray", "hole"):
        row, col = np.nonzero(np.isfinite(depth) if kind == "gray" else ~np.isfinite(depth))
        keep = (col >= border) & (col < camera.width - border) & (row >= border) & (row < camera.height - border)
        pick = rng.choice(np.count_nonzero(keep), min(n, np.count_nonzero(keep)), replace=False)
        row, col = row[keep][pick], col[keep][pick]
        if kind == "gray":
            z = depth[row, col] + rng.uniform(*GRAY_DEPTHS, row.size)
        else:
            z = rng.uniform(*HOLE_DEPTHS, row.size)
        inside = z < min(camera.depth_range[1], GRID_D_MAX)
        row, col, z = row[inside], col[inside], z[inside]
        points_world = camera.camera_to_world(camera.back_project(col, row, z))
        contested = np.zeros(z.size, dtype=bool)
        for name in secondaries(rig):
            contested |= _measured_past(rig, frames, name, points_world, CLEARED)
        parts.append(SamplePoints(points_world, z, np.full(z.size, kind), np.full(z.size, ""),
                                  np.zeros(z.size, dtype=bool), contested))
    return SamplePoints.concatenate(parts)


def fused_query(rig: dg.Rig, frames: dict, grid: DepthGridMap, points_world: np.ndarray, margin: float,
                pixels: int = 1, rho: float = RHO) -> np.ndarray:
    """(n,) float64 metres: fused distances of (n, 3) world points (metres) through :class:`depthguard.DistanceMonitor`
    (the rig's principal, ``aggregate="min"``, fail-safe policies) with fusion margin ``margin`` metres and footprint
    growth ``pixels``; inf: nothing within ``rho``."""
    monitor = dg.DistanceMonitor(rig, rho=rho, aggregate="min", invalid="occupied", unseen="occupied",
                                 maps={rig.principal: grid}, fusion_margin=margin, fusion_pixels=pixels)
    return monitor.query(frames, points_world).distance


def _fraction(mask: np.ndarray) -> float | None:
    return float(mask.mean()) if mask.size else None


def clearing_row(rig: dg.Rig, frames: dict, grid: DepthGridMap, surface: SamplePoints, free: SamplePoints,
                 margin: float, pixels: int = 1) -> dict:
    """What the fusion clears at one margin: of the secondary-seen surface points (``surface``) the number and
    fraction cleared (fused distance > CLEARED), on and off depth edges, contested, per kind and depth bin; of the
    principal's possibly-occupied samples (``free``) the fraction freed, per kind, overall and where a secondary
    camera saw past them."""
    cleared = fused_query(rig, frames, grid, surface.points_world, margin, pixels) > CLEARED
    freed = fused_query(rig, frames, grid, free.points_world, margin, pixels) > CLEARED
    off = ~surface.edge
    row = dict(margin=float(margin), pixels=int(pixels), surface_points=len(surface), cleared=int(cleared.sum()),
               cleared_fraction=_fraction(cleared), cleared_on_edges=int((cleared & surface.edge).sum()),
               cleared_off_edges=int((cleared & off).sum()), cleared_off_edges_fraction=_fraction(cleared[off]),
               cleared_contested_fraction=_fraction(cleared[surface.contested]),
               cleared_workspace=int((cleared & (surface.depth < WORKSPACE_DEPTH)).sum()),
               cleared_off_edges_workspace=int((cleared & off & (surface.depth < WORKSPACE_DEPTH)).sum()))
    for kind in ("gray", "hole"):
        row[f"cleared_{kind}_fraction"] = _fraction(cleared[surface.kind == kind])
    row["cleared_by_depth"] = {_bin_name(lo, hi): int((cleared & (surface.depth >= lo) & (surface.depth < hi)).sum())
                               for lo, hi in zip(DEPTH_BINS[:-1], DEPTH_BINS[1:])}
    row["cleared_off_edges_by_depth"] = {
        _bin_name(lo, hi): int((cleared & off & (surface.depth >= lo) & (surface.depth < hi)).sum())
        for lo, hi in zip(DEPTH_BINS[:-1], DEPTH_BINS[1:])}
    for kind in ("gray", "hole"):
        mask = free.kind == kind
        row[f"freed_{kind}_fraction"] = _fraction(freed[mask])
        row[f"freed_{kind}_seen_past_fraction"] = _fraction(freed[mask & free.contested])
    return row


def required_margin(rows: list[dict], key: str = "cleared_off_edges") -> float | None:
    """The smallest swept margin from which on no surface point counted by ``key`` is cleared (None: none)."""
    rows = sorted(rows, key=lambda r: r["margin"])
    for k, row in enumerate(rows):
        if all(r[key] == 0 for r in rows[k:]):
            return row["margin"]
    return None


# ------------------------------------------------------------------------------------------------------- (c) main

def run(folder=DEFAULT_FOLDER, samples: int = 4000, seed: int = 0, margins=MARGINS) -> tuple[dict, dict]:
    """The whole experiment. Returns (summary, arrays): the summary in plain Python types (as ``summary.json``), and
    what the figures need. ``samples``: surface points per secondary camera and kind, and free-space points per
    kind."""
    started = time.perf_counter()
    summary: dict = {"data": str(folder), "views": list(VIEWS), "principal": camera_name(PRINCIPAL)}
    rig, frames = slambook_rig(folder)
    grid = depth_grid(rig)
    summary["rig"] = {name: {"position": [round(float(x), 4) for x in camera.T_world_camera[:3, 3]],
                             "valid_fraction": frames[name].valid_fraction(),
                             "median_depth": float(np.nanmedian(frames[name].metres()))}
                      for name, camera in rig.cameras.items()}
    summary["grid"] = {"d_min": grid.d_min, "delta_d": grid.delta_d, "n_cells": grid.n_cells, "d_max": grid.d_max}

    t = time.perf_counter()
    calibration = calibration_error(rig, frames)
    need, chosen = choose_margin(rig, frames)
    everywhere_need, everywhere = choose_margin(rig, frames, pairs=[(a, b) for a in rig.cameras for b in rig.cameras
                                                                     if a != b])
    summary["calibration_error"] = calibration
    summary["chosen_margin"] = {
        "margin": chosen, "noise_model": "kinect (the library default, 3 sigma)",
        "rule": f"p{CHOICE_PERCENTILE:g} of (diff - noise margin) over same-surface pixels of the secondary cameras "
                f"(|diff| < {OCCLUSION} m, depth < {WORKSPACE_DEPTH} m), rounded up to a swept margin",
        "excess_percentile": need,
        "all_pairs_excess_percentile": everywhere_need, "all_pairs_margin": everywhere}
    summary["seconds_calibration"] = time.perf_counter() - t

    t = time.perf_counter()
    sweeps = {}
    samples_info = {}
    arrays = {"calibration": {}, "frames": {n: f.metres() for n, f in frames.items()}}
    for pair in ((camera_name(3), camera_name(4)), (camera_name(4), camera_name(5)), (camera_name(5), camera_name(3))):
        arrays["calibration"][pair] = reprojection_differences(rig, frames, *pair)
    for noise_name, noise in NOISE_MODELS.items():
        rig_n, frames_n = slambook_rig(folder, noise=noise)
        grid_n = depth_grid(rig_n)
        rng = np.random.default_rng(seed)
        surface = secondary_surface_points(rig_n, frames_n, samples, rng)
        free = free_space_points(rig_n, frames_n, samples, rng)
        samples_info[noise_name] = _sample_info(surface, free)
        rows = [clearing_row(rig_n, frames_n, grid_n, surface, free, m) for m in margins]
        sweeps[noise_name] = {"rows": rows, "required_margin": required_margin(rows),
                              "required_margin_workspace": required_margin(rows, "cleared_off_edges_workspace")}
        if noise_name == "kinect":
            sweeps[noise_name]["pixels_at_chosen_margin"] = [
                clearing_row(rig_n, frames_n, grid_n, surface, free, chosen, p) for p in FUSION_PIXELS]
    summary["samples"] = samples_info
    summary["sweeps"] = sweeps
    summary["seconds_fusion"] = time.perf_counter() - t
    summary["settings"] = dict(behind=BEHIND, surface_offset=SURFACE_OFFSET, cleared=CLEARED, rho=RHO,
                               border=BORDER, gray_depths=list(GRAY_DEPTHS), hole_depths=list(HOLE_DEPTHS),
                               edge_window=EDGE_WINDOW, occlusion=OCCLUSION, workspace_depth=WORKSPACE_DEPTH,
                               samples=samples, seed=seed, fusion_pixels=1, aggregate="min", invalid="occupied",
                               unseen="occupied", depth_range=list(DEPTH_RANGE))
    summary["seconds"] = time.perf_counter() - started
    return summary, arrays


def _sample_info(surface: SamplePoints, free: SamplePoints) -> dict:
    return {"surface_points": len(surface),
            "surface_by_kind": {k: int((surface.kind == k).sum()) for k in ("gray", "hole")},
            "surface_on_edges_fraction": _fraction(surface.edge),
            "surface_contested_fraction": _fraction(surface.contested),
            "surface_by_depth": {_bin_name(lo, hi): int(((surface.depth >= lo) & (surface.depth < hi)).sum())
                                 for lo, hi in zip(DEPTH_BINS[:-1], DEPTH_BINS[1:])},
            "free_points": {k: int((free.kind == k).sum()) for k in ("gray", "hole")},
            "free_seen_past_fraction": {k: _fraction(free.contested[free.kind == k]) for k in ("gray", "hole")}}


def main(out: str = "out/real-room", folder=None, samples: int = 4000, seed: int = 0) -> int:
    """Run the experiment on the slambook2 room: print a summary, write ``summary.json`` and the figures into ``out``
    (created if needed). Returns 0, or 2 if the data folder is missing."""
    folder = Path(folder) if folder is not None else DEFAULT_FOLDER
    if not (folder / "pose.txt").is_file():
        print(f"real-room: no slambook2-room data at {folder} (expected pose.txt and depth/1-5.pgm)", file=sys.stderr)
        return 2
    out = Path(out)
    os.makedirs(out, exist_ok=True)
    summary, arrays = run(folder, samples=samples, seed=seed)
    files = _plots(out, summary, arrays)
    summary["files"] = sorted([p.name for p in files] + ["summary.json"])
    write_whole(out / "summary.json", json.dumps(summary, indent=2))
    _print_summary(summary, out)
    return 0


def _pct(x) -> str:
    return "-" if x is None else f"{100 * x:.2f} %"


def _print_summary(s: dict, out: Path) -> None:
    print("slambook2 room: views 3, 4, 5 as a rig of three depth cameras, principal view3 (views 4 and 5 stand "
          "0.71 and 0.94 m in front of it)")
    for name, info in s["rig"].items():
        print(f"  {name}: valid {100 * info['valid_fraction']:.1f} %, median depth {info['median_depth']:.2f} m")
    print(f"\n(a) Calibration error: reprojected depth differences, same surface = |diff| < {OCCLUSION} m, metres")
    print("  pair            agree<5cm  median    p90    p95    p99   occluded  sees-past | <4 m: median   p95  "
          "excess p99")
    for pair, e in s["calibration_error"].items():
        w = e["workspace"]
        print(f"  {pair:15s} {100 * e['agree_5cm']:6.1f} %  {e['median']:.3f}  {e['p90']:.3f}  {e['p95']:.3f}  "
              f"{e['p99']:.3f}  {100 * e['occluded_fraction']:5.1f} %  {100 * e['sees_past_fraction']:5.1f} %  | "
              f"     {w['median']:.3f}  {w['p95']:.3f}  {w['excess_p99']:+.3f}")
    print("  by depth in the target (view4->view5): " + "; ".join(
        f"{k}: median {v['median']:.3f}, p95 {v['p95']:.3f}" for k, v in
        s["calibration_error"]["view4->view5"]["by_depth"].items() if "median" in v))
    c = s["chosen_margin"]
    print(f"  chosen fusion margin: {c['margin']} m (with the Kinect noise margin): a secondary camera sees past the "
          f"other's surface by at most\n  {c['excess_percentile']:.3f} m beyond its noise margin for "
          f"{CHOICE_PERCENTILE:g} % of same-surface pixels below {WORKSPACE_DEPTH} m "
          f"(all camera pairs: {c['all_pairs_excess_percentile']:.3f} m -> {c['all_pairs_margin']} m)")
    print(f"\n(b) Secondary-seen surface points the principal does not see (>= {BEHIND} m behind its surface or in its "
          f"holes), {SURFACE_OFFSET} m in front of the surface;\n    cleared = fused distance > {CLEARED} m "
          f"(rho {RHO} m, aggregate min, invalid/unseen occupied, 1-pixel footprint growth)")
    for noise_name, sweep in s["sweeps"].items():
        info = s["samples"][noise_name]
        print(f"  noise model {noise_name}: {info['surface_points']} surface points "
              f"({100 * info['surface_on_edges_fraction']:.1f} % on depth edges, "
              f"{100 * info['surface_contested_fraction']:.1f} % contested by the other secondary); "
              f"{info['free_points']['gray']} gray-area and {info['free_points']['hole']} hole points")
        print("    margin   cleared            off edges   off edges <4 m | gray freed  (seen past)  holes freed")
        for r in sweep["rows"]:
            print(f"    {r['margin']:5.2f}  {r['cleared']:5d} {_pct(r['cleared_fraction']):>9s}   "
                  f"{r['cleared_off_edges']:6d}       {r['cleared_off_edges_workspace']:6d}      | "
                  f"{_pct(r['freed_gray_fraction']):>9s}  ({_pct(r['freed_gray_seen_past_fraction'])})  "
                  f"{_pct(r['freed_hole_fraction']):>9s}")
        print(f"    required margin (no surface point off depth edges cleared from it on): "
              f"{_margin(sweep['required_margin'])} over the room, {_margin(sweep['required_margin_workspace'])} "
              f"below {WORKSPACE_DEPTH} m")
        if "pixels_at_chosen_margin" in sweep:
            print("    footprint growth at the chosen margin: " + ", ".join(
                f"{r['pixels']} px: {r['cleared']} cleared ({r['cleared_off_edges']} off edges), gray freed "
                f"{_pct(r['freed_gray_fraction'])}" for r in sweep["pixels_at_chosen_margin"]))
    print(f"\nFiles in {out.resolve()}: {', '.join(s['files'])} ({s['seconds']:.1f} s: calibration "
          f"{s['seconds_calibration']:.1f} s, fusion sweeps {s['seconds_fusion']:.1f} s)")


def _margin(m) -> str:
    return "more than the largest swept margin" if m is None else f"{m} m"


def _plots(out: Path, s: dict, arrays: dict) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.0), layout="constrained")
    for ax, (name, depth) in zip(axes, arrays["frames"].items()):
        image = ax.imshow(np.ma.masked_invalid(depth), cmap="viridis", vmin=0.5, vmax=8.0)
        image.cmap.set_bad("black")
        info = s["rig"][name]
        ax.set_title(f"{name}{' (principal)' if name == s['principal'] else ''}: valid "
                     f"{100 * info['valid_fraction']:.0f} %, median {info['median_depth']:.2f} m", fontsize=10)
        ax.set_axis_off()
    fig.colorbar(image, ax=axes, shrink=0.8, label="depth [m] (black: no measurement)")
    path = out / "depth_images.png"
    with atomic_write(path, "wb") as f:
        fig.savefig(f, format="png", dpi=90)
    plt.close(fig)
    written.append(path)

    fig, (left, right) = plt.subplots(1, 2, figsize=(14, 4.8))
    bins = np.linspace(-OCCLUSION, OCCLUSION, 121)
    for (source, target), (diff, depth) in arrays["calibration"].items():
        left.hist(diff[np.abs(diff) < OCCLUSION], bins=bins, histtype="step", lw=1.3, density=True,
                  label=f"{source} -> {target}")
    left.set_xlabel("target's depth - reprojected depth [m] (> 0: target sees past the source's surface)")
    left.set_ylabel("density")
    left.set_title("Reprojection differences, same surface (|diff| < 0.3 m)")
    left.legend(fontsize=9)
    left.grid(alpha=0.3)
    centres = [(lo + hi) / 2 for lo, hi in zip(DEPTH_BINS[:-1], DEPTH_BINS[1:])]
    for pair in ("view4->view5", "view5->view4", "view3->view4"):
        by = s["calibration_error"][pair]["by_depth"]
        right.plot(centres, [v.get("p95", np.nan) for v in by.values()], "o-", label=f"{pair}: p95 |diff|")
    depth = np.linspace(0.5, 9.5, 100)
    right.plot(depth, NOISE_MODELS["kinect"].margin(depth), "k--", label="Kinect noise margin m(d) (3 sigma)")
    right.set_ylim(0, OCCLUSION)
    right.set_xlabel("depth in the target [m]")
    right.set_ylabel("metres")
    right.set_title("Calibration error grows with depth (beyond 4 m the 0.3 m cut truncates it)", fontsize=10)
    right.legend(fontsize=9)
    right.grid(alpha=0.3)
    fig.tight_layout()
    path = out / "calibration_error.png"
    with atomic_write(path, "wb") as f:
        fig.savefig(f, format="png", dpi=90)
    plt.close(fig)
    written.append(path)

    fig, (left, right) = plt.subplots(1, 2, figsize=(13, 4.5))
    for noise_name, colour in zip(s["sweeps"], ("tab:blue", "tab:orange")):
        rows = s["sweeps"][noise_name]["rows"]
        margins = [r["margin"] for r in rows]
        left.plot(margins, [100 * r["cleared_fraction"] for r in rows], "o-", color=colour,
                  label=f"noise {noise_name}: all")
        left.plot(margins, [100 * r["cleared_off_edges_fraction"] for r in rows], "s--", color=colour,
                  label=f"noise {noise_name}: off depth edges")
        right.plot(margins, [100 * r["freed_gray_fraction"] for r in rows], "o-", color=colour,
                   label=f"noise {noise_name}: gray area")
        right.plot(margins, [100 * r["freed_hole_fraction"] for r in rows], "s--", color=colour,
                   label=f"noise {noise_name}: principal's holes")
    left.axvline(s["chosen_margin"]["margin"], color="grey", ls=":", label="chosen margin")
    left.set_xlabel("fusion margin [m]")
    left.set_ylabel("secondary-seen surface points cleared [%]")
    left.set_title("What must stay occupied")
    right.set_xlabel("fusion margin [m]")
    right.set_ylabel("principal's possibly-occupied samples freed [%]")
    right.set_title("What fusion frees (the margin's cost)")
    for ax in (left, right):
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    path = out / "margin_sweep.png"
    with atomic_write(path, "wb") as f:
        fig.savefig(f, format="png", dpi=90)
    plt.close(fig)
    written.append(path)
    return written
