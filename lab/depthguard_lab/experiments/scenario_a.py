"""Reference scenario A: the 2015 paper's validation experiment (its section 4, Figs. 6-11; design §12 "A").

One depth camera looks at a table top and a thin vertical wall standing on it. A virtual control point P moves
along y = 0.4, z = 0.2, x in [-0.5, 0.5] m with rho = 0.3 m. The wall's face X = 0 (the paper's "Y-Z surface")
faces the camera; its face Y = 0.37 (the "X-Z surface") is edge-on to the camera and never seen. So:

- the true nearest obstacle is the hidden face for x < 0 (distance 0.03), the wall's vertical edge at (0, 0.37)
  for 0 < x < sqrt(0.16**2 - 0.03**2) = 0.1572 m (distance sqrt(x**2 + 0.03**2)), then the table (0.16);
- the point-cloud approach (pixel centres back-projected) cannot see the hidden face and reports the table
  (about 0.16) for x < -0.157, where the truth is 0.03;
- the depth-space approach counts the space hidden behind each pixel as possibly occupied, so its ``min`` distance
  is at most the truth everywhere (and below 0.03 behind the wall: the gray area).

World frame: z up, metres. The depth image is ray-cast exactly (:func:`depthguard.scenes.render_depth`); a second
run adds Gaussian depth noise of the default noise model and uint16 millimetre quantisation.

:func:`main` writes the plots (the paper's Figs. 7-11 and an overview) and ``summary.json`` and prints a summary;
``depthguard scenario-a`` calls it.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numba
import numpy as np

import depthguard as dg
from depthguard import baselines
from depthguard.validation import check_points
from depthguard.scenes import Box, render_depth, scene_distance
from depthguard.transforms import look_at

#: Radius of the surveillance region, metres (paper section 4).
RHO = 0.3
#: P's line, world frame, metres: y = LINE_Y, z = LINE_Z, x from X_RANGE[0] to X_RANGE[1].
LINE_Y = 0.4
LINE_Z = 0.2
X_RANGE = (-0.5, 0.5)
N_POSITIONS = 201
#: Geometry of the walls, metres (world frame, z up).
TABLE_TOP_Z = 0.04
WALL_X = (-0.5, 0.0)  # the seen face is X = 0
WALL_Y = (0.33, 0.37)  # the hidden face is Y = 0.37
WALL_TOP_Z = 0.6
#: Where the true nearest obstacle switches from the wall's edge to the table: sqrt(0.16**2 - 0.03**2) m.
TRUE_SWITCH_X = math.sqrt((LINE_Z - TABLE_TOP_Z) ** 2 - (LINE_Y - WALL_Y[1]) ** 2)
#: Camera: a Kinect-like 640x480 camera above and in front of the table, looking at the wall.
CAMERA_EYE = (1.5, 0.35, 1.2)
CAMERA_TARGET = (-0.1, 0.35, 0.15)
CAMERA_DEPTH_RANGE = (0.4, 6.0)
#: The paper's times on an Intel i7-2600 (section 4, Fig. 11), seconds per query of one control point.
PAPER_TIMES = {
    "point cloud": {"worst": 70.6e-3},
    "min": {"worst": 1.46e-3, "best": 5.3e-6},
    "mean": {"worst": 3.335e-3},
    "hybrid": {"worst": 3.335e-3},
}
#: The depth-space aggregations and the order in which results, plots and tables list the methods.
AGGREGATES = ("min", "mean", "hybrid")
METHODS = ("point cloud",) + AGGREGATES


@dataclass(frozen=True)
class Scene:
    """Scenario A's world: named solid boxes (world frame, metres)."""

    table: Box
    wall: Box
    floor: Box
    back_wall: Box

    @property
    def primitives(self) -> list[Box]:
        return [self.table, self.wall, self.floor, self.back_wall]


def make_scene() -> Scene:
    """The table top (top face at z = 0.04), the thin vertical wall on it, and a floor and back wall so that every
    pixel hits something."""
    return Scene(
        table=Box.from_bounds([-1.2, -0.6, -0.02], [1.2, 1.5, TABLE_TOP_Z]),
        wall=Box.from_bounds([WALL_X[0], WALL_Y[0], TABLE_TOP_Z], [WALL_X[1], WALL_Y[1], WALL_TOP_Z]),
        floor=Box.from_bounds([-3.0, -3.0, -0.8], [4.0, 4.0, -0.75]),
        back_wall=Box.from_bounds([-2.1, -3.0, -0.75], [-2.0, 4.0, 3.0]),
    )


def make_camera(noise: dg.NoiseModel | None = None) -> dg.PinholeCamera:
    """The scenario's camera (fx = fy = 525, 640x480) at CAMERA_EYE looking at CAMERA_TARGET; ``noise`` defaults to
    no margin (exact synthetic images)."""
    return dg.PinholeCamera("kinect", 640, 480, 525.0, 525.0, 319.5, 239.5, look_at(CAMERA_EYE, CAMERA_TARGET),
                            depth_range=CAMERA_DEPTH_RANGE, noise=noise if noise is not None else dg.NoiseModel.none())


def control_points(n: int = N_POSITIONS) -> np.ndarray:
    """(n, 3) float64, metres, world frame: P's positions along its line, x increasing."""
    x = np.linspace(X_RANGE[0], X_RANGE[1], n)
    return np.stack([x, np.full(n, LINE_Y), np.full(n, LINE_Z)], axis=1)


def true_nearest(scene: Scene, points_world) -> tuple[np.ndarray, np.ndarray]:
    """Exact distance (n,) metres and unit direction (n, 3) world frame, from the nearest scene point towards each
    point, over all boxes (they are axis-aligned, so the nearest point of a box is the clamped point)."""
    points = np.asarray(points_world, float)
    distance = scene_distance(scene.primitives, points)
    direction = np.zeros_like(points)
    best = np.full(len(points), np.inf)
    for box in scene.primitives:
        lower = np.asarray(box.center) - np.asarray(box.half_extents)
        upper = np.asarray(box.center) + np.asarray(box.half_extents)
        offset = points - np.clip(points, lower, upper)
        d = np.linalg.norm(offset, axis=1)
        take = d < best
        best[take] = d[take]
        direction[take] = offset[take] / np.where(d[take] > 0, d[take], 1.0)[:, None]
    assert np.allclose(best, distance)
    return distance, direction


def render(scene: Scene, camera: dg.PinholeCamera) -> np.ndarray:
    """(480, 640) float32 metres: the exact ray-cast depth image (pixel centres)."""
    return render_depth(camera, scene.primitives)


def noisy_depth(depth_m: np.ndarray, noise: dg.NoiseModel, seed: int = 0) -> np.ndarray:
    """(h, w) uint16 millimetres: ``depth_m`` plus Gaussian noise of standard deviation sigma(d) of ``noise``
    (its margin divided by k), rounded to millimetres (seeded)."""
    rng = np.random.default_rng(seed)
    sigma = noise.margin(depth_m) / noise.k if noise.k > 0 else np.zeros(depth_m.shape)
    noisy = depth_m + rng.normal(size=depth_m.shape) * sigma
    return np.clip(np.round(noisy * 1000.0), 0, np.iinfo(np.uint16).max).astype(np.uint16)


def wall_faces_seen(scene: Scene, camera: dg.PinholeCamera, depth_m: np.ndarray) -> dict[str, int]:
    """Number of pixels whose ray-cast surface point lies on each face of the thin wall.

    Faces: ``"X=0"`` (the paper's Y-Z face, towards the camera), ``"Y=0.37"`` (the X-Z face, hidden), ``"Y=0.33"``,
    ``"X=-0.5"``, ``"top"``. A pixel counts for the wall when its surface point is within 10 µm of the wall box.
    """
    points = camera.camera_to_world(camera.depth_to_points(depth_m.astype(np.float64)).reshape(-1, 3))
    on_wall = points[scene.wall.distance(points) < 1e-5]
    x, y, z = on_wall.T
    gaps = np.stack([np.abs(x - WALL_X[1]), np.abs(y - WALL_Y[1]), np.abs(y - WALL_Y[0]), np.abs(x - WALL_X[0]),
                     np.abs(z - WALL_TOP_Z), np.abs(z - TABLE_TOP_Z)], axis=1)
    names = ("X=0", "Y=0.37", "Y=0.33", "X=-0.5", "top", "bottom")
    face = np.argmin(gaps, axis=1)
    counts = {name: int(np.count_nonzero(face == i)) for i, name in enumerate(names)}
    counts.pop("bottom")  # table pixels touching the wall's foot, not the wall
    return counts


@dataclass(frozen=True)
class Frame:
    """One camera frame of the scenario, ready for every method.

    ``camera``: the camera (its noise model gives the depth-space margin). ``image``: the checked depth image.
    ``occupancy``: what it says is possibly occupied (depth space). ``depth_m``: (h, w) float64 metres with 0 where
    there is no valid measurement, for the point-cloud baseline's window kernel.
    """

    camera: dg.PinholeCamera
    image: dg.DepthImage
    occupancy: dg.OccupancyImage
    depth_m: np.ndarray


def make_frame(camera: dg.PinholeCamera, depth) -> Frame:
    """Prepare ``depth`` ((h, w) float32 metres or uint16 millimetres) of ``camera`` for every method (once per
    frame: the per-query timings exclude this)."""
    image = dg.depth_image(depth, camera)
    return Frame(camera, image, dg.prepare_depth(image, camera), baselines.valid_metres(image, camera))


def query(frame: Frame, method: str, points_world: np.ndarray, rho: float = RHO) -> tuple[np.ndarray, np.ndarray]:
    """Distances (n,) metres and directions (n, 3) world frame (from the obstacle towards the point) of one method.

    ``method``: ``"point cloud"`` (the paper's Cartesian baseline, :func:`baselines.cartesian_region_distances`),
    ``"min"``, ``"mean"``, ``"hybrid"`` (depth space, design), or ``"paper min"`` / ``"paper hybrid"`` (depth space
    with the 2015 paper's formulas, for comparison).
    """
    if method == "point cloud":
        return baselines.cartesian_region_distances(frame.image, frame.camera, points_world, rho)
    formulas, _, aggregate = method.rpartition(" ")
    result = dg.single_camera_distances(frame.occupancy, points_world, rho, aggregate,
                                        method="paper" if formulas == "paper" else "exact")
    return result.distance, result.direction


def timed_query(frame: Frame, method: str, rho: float = RHO):
    """A callable ``f(points)`` answering one query of ``method`` on a prepared frame, for timing.

    ``points``: a checked C-contiguous (n, 3) float64 array (world frame, metres). Depth space: the public call with
    ``check=False`` (the documented hot path). Point cloud: the baseline on the frame's depth converted to metres
    once (per-frame work, which the depth-space timings exclude too).
    """
    if method == "point cloud":
        return lambda points: baselines.cartesian_region_distances(frame.depth_m, frame.camera, points, rho)
    formulas, _, aggregate = method.rpartition(" ")
    paper = "paper" if formulas == "paper" else "exact"
    occupancy = frame.occupancy
    return lambda points: dg.single_camera_distances(occupancy, points, rho, aggregate, method=paper, check=False)


def time_methods(frame: Frame, methods, points_world, repeats: int, threads: int | None = 1) -> dict[str, np.ndarray]:
    """Per-position median seconds of one query of one control point, for each of ``methods`` (see
    :func:`timed_query`); the protocol of :func:`time_queries`. Returns method -> (n,) float64 seconds."""
    return time_queries({m: timed_query(frame, m) for m in methods}, points_world, repeats, threads)


def time_queries(queries: dict, points_world, repeats: int, threads: int | None = 1) -> dict[str, np.ndarray]:
    """Per-position median seconds of ``f(points[i:i+1])`` for each named callable ``f`` of ``queries``.

    Each position is queried ``repeats`` times per callable (after one untimed call), callables interleaved per
    position so that a noisy spell of the machine hits them alike. Returns name -> (n,) float64 seconds.

    ``threads``: numba threads during the timing (restored afterwards); None keeps the current setting. One control
    point is one parallel iteration, so a single thread does all the work either way; with more threads every call
    also waits at the parallel region's barrier for threads that a busy machine may have descheduled (milliseconds
    on a shared 2-core machine), which is the machine's noise, not the method's cost.
    """
    if repeats < 1:
        raise dg.InputError(f"repeats must be at least 1, got {repeats}")
    points = check_points(points_world)
    medians = {name: np.empty(len(points)) for name in queries}
    samples = np.empty(repeats)
    previous = numba.get_num_threads()
    if threads is not None:
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        for i in range(len(points)):
            p = points[i : i + 1]
            for name, fn in queries.items():
                fn(p)
                for k in range(repeats):
                    t = time.perf_counter()
                    fn(p)
                    samples[k] = time.perf_counter() - t
                medians[name][i] = np.median(samples)
    finally:
        numba.set_num_threads(previous)
    return medians


def timing_table(medians: dict[str, np.ndarray]) -> dict[str, dict[str, float]]:
    """method -> {"worst", "median", "best"} seconds over the positions of the per-position medians."""
    return {m: {"worst": float(t.max()), "median": float(np.median(t)), "best": float(t.min())}
            for m, t in medians.items()}


def format_time(seconds: float | None) -> str:
    """``1.46 ms``, ``5.3 µs``, or ``-`` for None."""
    if seconds is None:
        return "-"
    if seconds >= 1e-3:
        return f"{seconds * 1e3:.3g} ms"
    return f"{seconds * 1e6:.3g} µs"


def format_timing_table(table: dict[str, dict[str, float]], paper: dict | None = PAPER_TIMES) -> list[str]:
    """The timing table as lines of text; with ``paper``, the paper's worst and best times in extra columns."""
    width = max([len("method")] + [len(m) for m in table])
    head = f"  {'method':{width}s} {'worst':>10s} {'median':>10s} {'best':>10s}"
    if paper:
        head += f"   {'paper worst':>11s} {'paper best':>10s}"
    lines = [head]
    for m, row in table.items():
        line = f"  {m:{width}s} {format_time(row['worst']):>10s} {format_time(row['median']):>10s} " \
               f"{format_time(row['best']):>10s}"
        if paper:
            ref = paper.get(m, {})
            line += f"   {format_time(ref.get('worst')):>11s} {format_time(ref.get('best')):>10s}"
        lines.append(line)
    return lines


def is_vertical(direction: np.ndarray) -> np.ndarray:
    """(n,) bool: the direction (n, 3) points more up than sideways (the table below, not the wall beside)."""
    return np.abs(direction[:, 2]) > np.linalg.norm(direction[:, :2], axis=1)


def direction_switch(frame: Frame, method: str, x: np.ndarray, direction: np.ndarray,
                     tolerance: float = 1e-4) -> float | None:
    """x (metres) where ``method``'s direction turns from horizontal (the wall) to vertical (the table), for x > 0.

    Found on the sampled line first, then refined by bisection to ``tolerance``. None when it does not switch.
    """
    vertical = is_vertical(direction)
    candidates = np.nonzero((x[:-1] >= 0.0) & ~vertical[:-1] & vertical[1:])[0]
    if len(candidates) == 0:
        return None
    lo, hi = float(x[candidates[0]]), float(x[candidates[0] + 1])
    while hi - lo > tolerance:
        mid = 0.5 * (lo + hi)
        _, d = query(frame, method, np.array([[mid, LINE_Y, LINE_Z]]))
        if is_vertical(d)[0]:
            hi = mid
        else:
            lo = mid
    return 0.5 * (lo + hi)


@dataclass(frozen=True)
class Run:
    """The results of every method along the line on one frame."""

    label: str
    frame: Frame
    distance: dict[str, np.ndarray]
    direction: dict[str, np.ndarray]


def run_methods(label: str, frame: Frame, points_world: np.ndarray, methods=METHODS) -> Run:
    distance, direction = {}, {}
    for m in methods:
        distance[m], direction[m] = query(frame, m, points_world)
    return Run(label, frame, distance, direction)


def facts(run: Run, x: np.ndarray, truth: np.ndarray) -> dict:
    """The numbers scenario A must show, for one run (distances in metres)."""
    hidden = x < -TRUE_SWITCH_X
    excess = {m: float(np.max(run.distance[m] - truth)) for m in ("min", "hybrid", "paper min") if m in run.distance}
    worst = {m: float(x[np.argmax(run.distance[m] - truth)]) for m in excess}
    switch = direction_switch(run.frame, "min", x, run.direction["min"])
    return {
        "min_direction_switch_x": switch,
        "true_switch_x": TRUE_SWITCH_X,
        "hidden_face_region": f"x < {-TRUE_SWITCH_X:.4f}",
        "hidden_face_point_cloud_distance": [float(run.distance["point cloud"][hidden].min()),
                                             float(run.distance["point cloud"][hidden].max())],
        "hidden_face_min_distance": [float(run.distance["min"][hidden].min()),
                                     float(run.distance["min"][hidden].max())],
        "hidden_face_true_distance": float(truth[hidden].max()),
        "max_excess_over_truth": excess,
        "max_excess_at_x": worst,
        "hybrid_equals_min": bool(np.array_equal(run.distance["hybrid"], run.distance["min"])),
    }
