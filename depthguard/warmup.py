"""``depthguard warmup``: compile every numba kernel the product uses, for every argument type it passes them, before
the first query needs it (see :mod:`depthguard.kernels.jit` for the caches).

numba compiles a kernel for each combination of argument types it is called with (uint16 and float32 frames are
two). The one honest way to reach every combination the product uses is to run the product's own paths, so
:func:`warm_up` runs small real workloads through the public API on a rig of two 32x24 cameras: frame preparation
(each invalid-pixel policy, with and without a robot rendered, uint16 and float32 frames), single-camera queries
of one point (the serial kernel) and of several (the parallel one), the depth grid's fusion of two cameras with and
without a robot and with a blind secondary camera, the monitor, the frustum distance, the baselines, the capsule
fit, the free-space memory and SSM's detectable space. ``tests/test_warmup.py`` checks that the command line and the monitor call no kernel
signature it does not (:func:`loaded_signatures`).

Once the kernels are cached it takes a few seconds (mostly imports and loading the cached kernels).
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field

import numpy as np
from numba.core import event

from depthguard.kernels import jit


@dataclass
class Compile:
    """One numba compile: the kernel (module.function), its argument types, seconds (including the kernels it called
    that compiled within it), and how deep it was nested in another compile (0: top level)."""

    kernel: str
    args: str
    seconds: float
    depth: int


@dataclass
class WarmupReport:
    """What :func:`warm_up` did: every compile (empty when everything was cached), the seconds it took in all (wall)
    and in how many processes it compiled."""

    compiles: list[Compile] = field(default_factory=list)
    seconds: float = 0.0
    processes: int = 1

    @property
    def top_level(self) -> list[Compile]:
        """The compiles that a workload asked for; the others compiled within them."""
        return [c for c in self.compiles if c.depth == 0]

    @property
    def compile_seconds(self) -> float:
        return sum(c.seconds for c in self.top_level)


class CompileRecorder(event.Listener):
    """Records every numba compile of a depthguard kernel while registered (``with CompileRecorder() as r:``);
    ``progress(kernel)`` is called as a top-level one starts."""

    def __init__(self, progress=None):
        self.compiles: list[Compile] = []
        self._stack: list[tuple[str, str, float]] = []
        self._progress = progress

    def on_start(self, ev):
        dispatcher = ev.data["dispatcher"]
        func = dispatcher.py_func
        name = f"{func.__module__}.{func.__qualname__}"
        if not self._stack and self._progress is not None:
            self._progress(name)
        self._stack.append((name, str(ev.data.get("args", "")), time.perf_counter()))

    def on_end(self, ev):
        name, args, start = self._stack.pop()
        self.compiles.append(Compile(name, args, time.perf_counter() - start, len(self._stack)))

    def __enter__(self):
        event.register("numba:compile", self)
        return self

    def __exit__(self, *exc):
        event.unregister("numba:compile", self)
        return False


def warm_up(progress=None, processes: int | None = None) -> WarmupReport:
    """Run every kernel the product uses once, compiling (and caching) those not in the cache yet.

    Compiling is single-threaded, so after an install or an upgrade (the largest kernels not in the cache) the
    workloads (:data:`WORKLOADS`) run in ``processes`` processes at once (default: one per core, at most one per
    workload), each writing the shared cache; then every workload runs again in this process, which loads what they
    compiled and compiles whatever a race between two processes' writes of one cache index lost. ``processes=1``, or
    a warm cache, runs them here only; more processes than workloads are not started.

    ``progress``: called with a kernel's name as it starts compiling (from the processes: as each workload ends).
    Returns the :class:`WarmupReport` (its compiles from every process; its seconds the wall time).
    """
    start = time.perf_counter()
    compiles = []
    if processes is None:
        processes = min(len(WORKLOADS), len(os.sched_getaffinity(0))) if _cold() else 1
    processes = max(1, min(int(processes), len(WORKLOADS)))  # more than one per workload would idle
    if processes > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor, as_completed

        with ProcessPoolExecutor(processes, mp_context=multiprocessing.get_context("spawn")) as pool:
            for done in as_completed([pool.submit(_run_workload, index) for index in range(len(WORKLOADS))]):
                for compile_ in done.result():
                    compiles.append(compile_)
                    if compile_.depth == 0 and progress is not None:
                        progress(compile_.kernel)
    with jit.quiet_compiles(), CompileRecorder(progress) as recorder:
        _run_workloads()
    return WarmupReport(compiles=compiles + recorder.compiles, seconds=time.perf_counter() - start,
                        processes=processes)


#: Whether this process is one of the warm-up's pool (:func:`_run_workload`), not the process that asked for it.
_IN_POOL = False


def _run_workload(index: int) -> list[Compile]:
    """Run workload ``index`` of :data:`WORKLOADS` (in a process of the warm-up's pool): the compiles it made."""
    global _IN_POOL
    _IN_POOL = True
    with jit.quiet_compiles(), CompileRecorder() as recorder:
        WORKLOADS[index]()
    return recorder.compiles


def loaded_signatures() -> list[str]:
    """Every argument-type signature that this process's kernels have compiled or loaded from the cache so far, as
    sorted ``"module.function (types)"`` strings: what the process has called them with. (A kernel that runs inside
    another shows a signature of its own only if the outer one compiled here, not if it was loaded.) Imports every
    module of :data:`depthguard.kernels.jit.KERNEL_MODULES`."""
    import importlib

    from numba.core.dispatcher import Dispatcher

    found = set()
    for name in jit.KERNEL_MODULES:
        for attribute in vars(importlib.import_module(name)).values():
            if isinstance(attribute, Dispatcher) and attribute.py_func.__module__ == name:
                found.update(f"{name}.{attribute.py_func.__qualname__} {tuple(map(str, signature))}"
                             for signature in attribute.signatures)
    return sorted(found)


def _cold() -> bool:
    """Whether the largest kernels have nothing in the cache for their current sources (after an install or an
    upgrade): then the warm-up compiles in several processes."""
    from depthguard.kernels import depthgrid, depthspace

    for kernel_ in (depthgrid.fused_query_points, depthspace.query_points):
        try:
            if not kernel_._cache._cache_file._load_index():
                return True
        except Exception:  # no cache (NUMBA_DISABLE_JIT, no writable folder) or a numba without these internals
            return False
    return False


def _run_workloads() -> None:
    for group in WORKLOADS:
        group()


def _single_camera() -> None:
    """Frame preparation (each invalid-pixel policy, with and without a robot), single-camera queries (the serial
    kernel for one point, the parallel one for several), the monitor on one camera, the baselines."""
    import depthguard as dg
    from depthguard import baselines

    rig, frames, robot, points = _small_workcell()
    for kind in ("uint16", "float32"):
        images, prepared = _prepared_frames(rig, frames, robot, kind)
        for plain, _, filtered in prepared.values():
            for occupancy in (plain, filtered):
                for pts in (points[:1], points):
                    dg.single_camera_distances(occupancy, pts, 0.3, "hybrid")
                    dg.single_camera_distances(occupancy, pts, 0.3, "min", method="paper")
        monitor = dg.DistanceMonitor(rig, rho=0.3)
        for pts in (points[:1], points):
            monitor.query({"principal": images["principal"]}, pts)
        baselines.cartesian_region_distances(images["principal"], rig.cameras["principal"], points, 0.3)


def _fusion() -> None:
    """The depth grid's fusion of two cameras (with the robot filtered out, without, with a blind secondary camera)
    and the monitor on both (with the free-space memory: :func:`_memory_and_detectable`)."""
    import depthguard as dg
    from depthguard.depthgrid import FusedFrames, build_map, seen_free

    rig, frames, robot, points = _small_workcell()
    grid = build_map(rig, "principal")
    one, several = points[:1], points
    for kind in ("uint16", "float32"):
        images, prepared = _prepared_frames(rig, frames, robot, kind)
        near, far, exit_ = robot["principal"]
        with_robot = FusedFrames(grid, rig, prepared["principal"][2],
                                 {"second": seen_free(images["second"], prepared["second"][2])},
                                 robot_far=far, robot_near=near, robot_exit=exit_)
        without = FusedFrames(grid, rig, prepared["principal"][0],
                              {"second": seen_free(images["second"], prepared["second"][1])})
        blind = FusedFrames(grid, rig, prepared["principal"][0], {"second": None})
        for frames_ in (with_robot, without, blind):
            for pts in (one, several):
                frames_.distances(pts, 0.3, "hybrid")
                frames_.distances(pts, 0.3, "min")
        monitor = dg.DistanceMonitor(rig, rho=0.3)
        for pts in (one, several):
            monitor.query(images, pts)


def _prepared_frames(rig, frames, robot, kind: str):
    """({camera: DepthImage}, {camera: (plain, filled, filtered) OccupancyImage}) of the small workcell's ``kind``
    frames ("uint16" or "float32"): each invalid-pixel policy, with and without the rendered "robot"."""
    import depthguard as dg
    from depthguard.depthgrid import free_image

    images = {name: dg.depth_image(frames[kind][name], rig.cameras[name]) for name in rig.cameras}
    prepared = {}
    for name, camera in rig.cameras.items():
        depth = images[name]
        near, far, _ = robot[name]
        plain = dg.prepare_depth(depth, camera)
        filled = dg.prepare_depth(depth, camera, "neighbors")
        filtered = dg.prepare_depth(depth, camera, "neighbors", robot_near=near, robot_far=far)
        dg.prepare_depth(depth, camera, "free", robot_near=near)
        free_image(depth, camera)
        prepared[name] = (plain, filled, filtered)
    return images, prepared


def _memory_and_detectable() -> None:
    """The free-space memory (design §8a) and SSM's detectable space, alone and in the monitor."""
    import depthguard as dg
    from depthguard.depthgrid import free_image
    from depthguard.freespace import FreeSpaceMemory, seen_free_voxels, squared_distance_transform, voxels_within

    rig, frames, _, points = _small_workcell()
    one, several = points[:1], points
    box = _memory_box()
    # The voxels both cameras see free, two updates (without and with a robot).
    images = {name: dg.depth_image(frames["float32"][name], rig.cameras[name]) for name in rig.cameras}
    cameras = list(rig.cameras.values())
    seen = seen_free_voxels(box, cameras, [free_image(images[c.name], c) for c in cameras], margin=0.01, pad=1)
    memory = FreeSpaceMemory(box)
    memory.update(0.0, seen)
    memory.update(0.1, seen, robot=np.zeros(box.shape, dtype=bool))
    squared_distance_transform(seen)
    # The voxels next to the robot that no camera sees whole, judged piece by piece, as the monitor's memory takes
    # them with a robot: a "link" standing in the box, into which neither camera sees.
    from depthguard.freespace import remember_frames, robot_inside_voxels, robot_voxels

    link = np.array([[0.0, 0.0, 0.3, 0.0, 0.0, 0.7, 0.12]])
    inner = link - [[0.0] * 6 + [0.02]]
    near = np.zeros(box.shape, dtype=bool)
    region = robot_voxels(box, link, box.voxel * math.sqrt(3.0), near)
    remember_frames(FreeSpaceMemory(box), 0.2, cameras, [free_image(images[c.name], c) for c in cameras], [],
                    margin=0.01, pad=1, robot=robot_inside_voxels(box, [inner]), near_robot=near, inner=inner,
                    near_region=region)
    # The monitor with the memory (a rig with a workspace, stamped frames): its sets and their detectable space.
    remembering = _remembering_monitor(rig)
    for k, (stamped, pts) in enumerate(_stamped_sets(rig, frames, (one, several))):
        prepared = remembering.prepare_set(stamped, now=0.1 * k)
        prepared.detectable_distances(pts)
        # Its fused queries: the fused kernels, which _fusion compiles (the memory's kernels are compiled here
        # only). In the pool they are left to the pass that follows it in the asking process, which loads them
        # from the cache: here they would be compiled a second time (about 20 s) while _fusion compiles them.
        if not _IN_POOL:
            prepared.query(pts, now=0.1 * k)
    voxels_within(np.ones(box.shape, dtype=bool), box, several, np.full(len(several), 0.2))
    # Where a ball of the detection capability fits (SSM), with the robot's and a solid's voxels free.
    from depthguard.freespace import DetectableSpace, VoxelBox, robot_voxels, solid_voxels
    from depthguard.scenes import Box

    fine = VoxelBox(box.lo, box.hi, 0.05)
    free = np.zeros(fine.shape, dtype=bool)
    robot_voxels(fine, np.array([[0.0, 0.0, 0.2, 0.0, 0.0, 0.5, 0.1]]), 0.05, free)
    solid_voxels(fine, [Box((0.0, 0.0, 0.1), (0.3, 0.3, 0.1))], free)
    space = DetectableSpace(fine, 0.1)
    space.update(free)
    space.distances(several)


def _geometry_and_collision() -> None:
    """The frustum distance, the collision test (epipolar bands, tile images, difference images, the planner), the
    capsule fit."""
    import depthguard as dg
    from depthguard.robots import enclosing_circle, fit_capsule

    rig = _small_workcell()[0]
    box = _memory_box()
    tangents = np.array([[-0.1, 0.1, -0.1, 0.1], [0.0, 0.2, 0.0, 0.2]])
    dg.frustum_distance([0.0, 0.0, 1.0], tangents, [0.5, np.inf])
    dg.paper_frustum_distance([0.0, 0.0, 1.0], tangents, [0.5, np.inf])
    # The collision test's epipolar bands (design §10), between the small rig's two cameras.
    from depthguard.collision import EpipolarBands, TileGrid

    grids = [TileGrid(camera, 6, 8) for camera in rig.cameras.values()]
    EpipolarBands(grids, [box.lo, box.hi])
    # ... and a capsule projected onto a tile grid (the robot's tile images).
    from depthguard.kernels import collision as collision_kernels

    T = grids[0].camera.T_camera_world
    cam = grids[0].camera
    from depthguard.collision import box_tiles
    from depthguard.scenes import Box

    box_tiles(grids[0], Box.from_bounds(box.lo, box.hi))
    for project in (collision_kernels.capsule_tile_bits, collision_kernels.capsule_tile_bits_parallel):
        project(np.array([[[box.lo, box.hi]]], dtype=np.float64), np.array([0.05]), np.ascontiguousarray(T[:3, :3]),
                np.ascontiguousarray(T[:3, 3]), cam.fx, cam.fy, cam.cx, cam.cy, grids[0].col_edges,
                grids[0].row_edges, grids[0].words, np.zeros((1, grids[0].words), dtype=np.uint64))
    # The collision test's difference images: the tiles' features of intensity images (8 and 16 bits, floats) and the
    # depth variant's changes (uint16 and float frames against a float64 reference in metres).
    from depthguard.collision import (depth_difference_image, tile_features, unexplained_intensity_tiles,
                                      unexplained_tiles)

    for dtype in (np.uint8, np.uint16, np.float32, np.float64):
        tile_features(np.zeros(cam.shape, dtype=dtype), grids[0])
    reference = np.full(cam.shape, 1.0)
    for image in (np.full(cam.shape, 1000, dtype=np.uint16), np.full(cam.shape, 1.0, dtype=np.float32),
                  np.full(cam.shape, 1.0)):
        depth_difference_image(image, reference, grids[0])
        unexplained_tiles(image, reference, np.zeros(cam.shape, dtype=np.float32), grids[0])  # robot_pixels' rule
    for image in (np.zeros(cam.shape, dtype=np.uint8), np.zeros(cam.shape)):  # and its grey rule
        unexplained_intensity_tiles(image, reference, 1.0, np.zeros(cam.shape, dtype=np.float32), grids[0])
    # The wave-propagation planner over a small configuration grid, around a wall.
    from depthguard.collision import ConfigurationGrid, plan_path

    free = np.ones((4, 3), dtype=bool)
    free[1, :2] = False
    plan_path(ConfigurationGrid([-1.0, -1.0], [1.0, 1.0], [4, 3]), free, [-1.0, -1.0], [1.0, -1.0])
    rng = np.random.default_rng(0)
    fit_capsule(rng.normal(size=(40, 3)) * [0.05, 0.05, 0.2], link="warmup", padding=0.01)
    enclosing_circle(rng.normal(size=(20, 2)))


#: The warm-up's workloads, the longest to compile first (each alone from an empty cache, 2026-11-29, two cores:
#: memory and detectable space 42 s, fusion 30 s, geometry and collision 28 s, single camera 17 s), so that on two
#: cores the pool's processes end about together (memory, then single camera; fusion, then collision: about 59 s
#: each, against 42 + 28 s in one when fusion went first): each runs in a process of its own when there are cores for
#: it (:func:`warm_up`); a kernel two of them need is compiled by both.
WORKLOADS = (_memory_and_detectable, _fusion, _geometry_and_collision, _single_camera)


def _memory_box():
    """The small workcell's workspace in voxels of 10 cm."""
    from depthguard.freespace import VoxelBox

    return VoxelBox([-0.5, -0.5, 0.0], [0.5, 0.5, 1.0], 0.1)


def _remembering_monitor(rig):
    """A monitor of the small workcell with the free-space memory and a detectable space."""
    import depthguard as dg

    box = _memory_box()
    return dg.DistanceMonitor(dg.Rig(rig.cameras, principal="principal", workspace=[box.lo, box.hi]), rho=0.3,
                              memory_voxel=0.1, detection_capability=0.06, detectable_voxel=0.03)


def _stamped_sets(rig, frames, point_sets):
    """[(stamped frames, points)]: uint16 and float32 frames stamped 0.1 s apart, each with each set of points."""
    import depthguard as dg

    return [({name: dg.depth_image(frames[kind][name], camera, timestamp=0.1 * k)
              for name, camera in rig.cameras.items()}, pts)
            for k, (kind, pts) in enumerate([(kind, pts) for kind in ("uint16", "float32") for pts in point_sets])]


def _small_workcell():
    """A rig of two 32x24 cameras watching a floor, a wall and a box from two sides, their frames (uint16 with a few
    pixels dropped, and float32), a rendered "robot" in front of the box for each camera (near, far, first exit), and
    three control points near the box (world frame)."""
    import depthguard as dg
    from depthguard.scenes import Box, render_depth
    from depthguard.transforms import look_at

    target = [0.0, 0.0, 0.6]
    eyes = {"principal": [1.5, -2.0, 1.8], "second": [1.5, 2.0, 1.8]}
    cameras = {name: dg.PinholeCamera(name, 32, 24, 26.25, 26.25, 15.5, 11.5, look_at(eye, target),
                                      depth_range=(0.3, 7.0)) for name, eye in eyes.items()}
    rig = dg.Rig(cameras=cameras, principal="principal")
    scene = [Box.from_bounds([-2.0, -3.0, -0.05], [3.0, 3.0, 0.0]), Box.from_bounds([-2.1, -3.0, 0.0],
                                                                                    [-2.0, 3.0, 2.5]),
             Box.from_bounds([-0.2, -0.2, 0.0], [0.2, 0.2, 1.0])]
    frames = {"uint16": {}, "float32": {}}
    robot = {}
    for name, camera in cameras.items():
        metres = render_depth(camera, scene)
        millimetres = np.round(metres * 1000.0).astype(np.uint16)
        millimetres[5:7, 5:8] = 0  # a small hole, filled by the "neighbors" policy
        frames["uint16"][name] = millimetres
        frames["float32"][name] = metres.astype(np.float32)
        near = np.zeros(camera.shape, dtype=np.float32)
        window = (slice(8, 14), slice(12, 20))
        near[window] = np.where(metres[window] > 0, metres[window] - 0.02, 0.0)
        far = np.where(near > 0, near + 0.15, 0.0).astype(np.float32)
        exit_ = np.where(near > 0, near + 0.05, 0.0).astype(np.float32)
        robot[name] = (near, far, exit_)
    points = np.array([[0.0, 0.0, 1.1], [0.3, -0.3, 0.5], [0.1, 0.25, 0.9]])
    return rig, frames, robot, points


