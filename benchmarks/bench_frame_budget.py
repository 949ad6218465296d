"""The per-frame budget (issue 8, "Ready in time"): what a new set of frames costs before queries are served, step
by step, and what the monitor sustains with live cameras.

Scene: bench_depth_grid.py's workcell (a room, a person reaching towards the robot, the KUKA iiwa rendered from its
meshes), 640x480 cameras from its EYES (1: principal; 2: + second; 4: + third, fourth), a rig whose workspace box
holds the robot and the person's reach, 9 control points (the robot's), rho = 0.4 m, hybrid, the robot
self-filtered, the free-space memory on unless said otherwise. The real monitor path: every set of frames is new
DepthImage objects, stamped 1/30 s apart, the robot's joints moving 2 mrad per joint per frame, passed to
DistanceMonitor.query (which prepares them inline, as depthguard does today).

1. Per new set of frames, time until its first query is served, split by step (the monitor's own functions wrapped
   with timers, in this benchmark only), for 1, 2 and 4 cameras; memory on and off. Goals (issue 38): <= 20 ms with
   two cameras, <= 30 ms with four, on this 2-core machine.
2. Thread scaling: the same with numba at 1 and at 2 threads.
3. Memory: the monitor's arrays (bytes) and the resident memory it adds (a child process, so that nothing else
   allocated in this one blurs it).
4. Sustained rate: cameras at 30 Hz (wall clock), queries as fast as they come in one thread of control, each new
   set of frames prepared by the query that first sees it. Goals: >= 500 queries/s with two cameras, >= 300 with
   four; the age of the data when answered (median, worst).
5. A still scene (issue 38): the robot at rest, one person walking past it at 1 m/s; per new set, the same step
   table for two and four cameras. Goal: <= 12 ms.
6. Later queries in a shadow scene (a person 1.2 m from the principal camera, between it and the robot): queries/s
   on the same frames after the first. Goal: >= 500 with two cameras. Baseline in the same run: the principal
   camera alone.

This machine is shared and noisy: medians, with min / max where it matters.

    .venv/bin/python benchmarks/bench_frame_budget.py [--repeats 10] [--seconds 3]
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import os
import subprocess
import sys
import tempfile
import time

import numba
import numpy as np

sys.path.insert(0, os.path.dirname(__file__))

import depthguard as dg  # noqa: E402
import depthguard._answer as answer_module  # noqa: E402
import depthguard._monitor as monitor_module  # noqa: E402
import depthguard.depthgrid as depthgrid  # noqa: E402
import depthguard.freespace as freespace  # noqa: E402
from depthguard.depthgrid import FusedFrames, grid_range  # noqa: E402
from depthguard.kernels import depthgrid as grid_kernels  # noqa: E402
from depthguard.freespace import FreeSpaceMemory  # noqa: E402
from depthguard.kernels import freespace as memory_kernels  # noqa: E402
from depthguard.freespace import _near  # noqa: E402
from depthguard.rendering import Renderer  # noqa: E402
from depthguard.robots import RobotModel  # noqa: E402
from depthguard.scenes import Box, render_depth
from depthguard_lab.simulation import standing_person  # noqa: E402
from depthguard.self_filter import RobotSilhouette  # noqa: E402
from bench_depth_grid import EYES, cameras  # noqa: E402
from _common import nearer, report

WORKSPACE = [[-1.2, -1.5, 0.0], [1.8, 1.5, 2.0]]  # the robot (base at the origin) and the person's reach
RHO = 0.4
FPS = 30.0
Q0 = np.array([0.3, 0.6, 0.0, -1.2, 0.0, 0.8, 0.0])
STEP = 0.002  # rad per joint per frame (and per query between frames): every joint at ~1 rad/s at 500 Hz
POOL = 30  # pre-rendered frame sets, played forwards and backwards so that the joints move smoothly
LATER = 15  # queries per frame after the first (500 Hz control, 30 Hz cameras)
SETS = {1: ["principal"], 2: ["principal", "second"], 4: ["principal", "second", "third", "fourth"]}
GOAL_NEW_SET_MS = {2: 20.0, 4: 30.0}
GOAL_STILL_MS = 12.0
WALK = 12  # the still scene's person positions, 1/30 s apart at 1 m/s
GOAL_RATE = {2: 500.0, 4: 300.0}
GOAL_LATER_RATE = 500.0

ROOM = [Box.from_bounds([-2.3, -3.1, -0.05], [4, 3.1, 0.0]), Box.from_bounds([-2.4, -3.1, 0.0], [-2.3, 3.1, 2.5]),
        Box.from_bounds([-2.3, 3.0, 0.0], [4, 3.1, 2.5]), Box.from_bounds([-2.3, -3.1, 0.0], [4, -3.0, 2.5])]


# ---------------------------------------------------------------------------------------------------- the scenes


def shadow_person(robot):
    """A person standing on the line from the principal camera's eye to the robot's control points' centre, 1.2 m
    from the eye, facing the robot."""
    eye = np.array(EYES["principal"], dtype=float)
    centre = robot.control_point_positions(Q0).mean(axis=0)
    along = (centre - eye) / np.linalg.norm(centre - eye)
    spot = eye + 1.2 * along
    return standing_person((spot[0], spot[1]), facing=math.atan2(along[1], along[0]), reach=0.0), spot


class Scene:
    """A static room and person per camera (rendered once: the primitive renderer takes seconds a camera), and the
    robot at any joint positions composited in front (its meshes, by OpenGL: milliseconds)."""

    def __init__(self, all_cameras, robot, person, renderer):
        self.cameras = all_cameras
        self.robot = robot
        self.silhouette = RobotSilhouette(robot, renderer, geometry="meshes", padding=0.0)
        self.background = {name: render_depth(camera, ROOM + person) for name, camera in all_cameras.items()}

    def raw(self, q, names):
        """uint16 millimetres per camera: the room, the person and the robot at ``q``."""
        out = {}
        for name in names:
            room = self.background[name]
            arm = self.silhouette.render(self.cameras[name], q)
            depth = nearer(arm, room)
            out[name] = np.round(depth * 1000).astype(np.uint16)
        return out

    def pool(self, names, count=POOL):
        """[(q, control points, {camera: uint16 array})] with q = Q0 + STEP * k."""
        return [(Q0 + STEP * k, self.robot.control_point_positions(Q0 + STEP * k), self.raw(Q0 + STEP * k, names))
                for k in range(count)]


def pool_index(i, n=POOL):
    """Frame i of a pool of n played forwards then backwards (0, 1, ..., n-1, n-2, ..., 1, 0, 1, ...)."""
    period = max(2 * n - 2, 1)
    k = i % period
    return k if k < n else period - k


def new_frames(raw, all_cameras, timestamp):
    """New DepthImage objects (the monitor prepares each new object again)."""
    return {name: dg.depth_image(data, all_cameras[name], timestamp=timestamp) for name, data in raw.items()}


def make_rig(all_cameras, names):
    return dg.Rig({n: all_cameras[n] for n in names}, principal="principal", workspace=WORKSPACE)


def make_monitor(all_cameras, names, robot, memory=True):
    return dg.DistanceMonitor(make_rig(all_cameras, names), rho=RHO, aggregate="hybrid", robot=robot, memory=memory)


# ------------------------------------------------------------------------------------------ timing the monitor's steps


class StepTimer:
    """Wraps the functions the monitor calls with timers that add up each step's own wall and CPU time (a wrapped
    call inside another counts for its own step, not its caller's). CPU time is the whole process's (every thread:
    numba's, llvmpipe's). Used in this benchmark only; :meth:`restore` unwraps."""

    def __init__(self):
        self.spent: dict[str, np.ndarray] = {}
        self._stack: list[np.ndarray] = []
        self._undo: list[tuple[object, str, object]] = []

    def wrap(self, owner, attr, step):
        original = owner.__dict__.get(attr) if isinstance(owner, type) else getattr(owner, attr, None)
        if original is None:  # renamed since: its time counts for its caller
            return
        timer = self

        def timed(*args, **kwargs):
            name = step(args) if callable(step) else step
            timer._stack.append(np.zeros(2))
            start = np.array([time.perf_counter(), time.process_time()])
            try:
                return original(*args, **kwargs)
            finally:
                elapsed = np.array([time.perf_counter(), time.process_time()]) - start
                inner = timer._stack.pop()
                timer.spent[name] = timer.spent.get(name, 0.0) + elapsed - inner
                if timer._stack:
                    timer._stack[-1] += elapsed

        setattr(owner, attr, timed)
        self._undo.append((owner, attr, original))

    def restore(self):
        for owner, attr, original in reversed(self._undo):
            setattr(owner, attr, original)
        self._undo.clear()

    def take(self) -> dict[str, np.ndarray]:
        spent, self.spent = self.spent, {}
        return spent


def _query_step(args):
    """The first query on a FusedFrames classifies the cells it needs; later ones reuse them."""
    frames = args[0]
    served = frames.__dict__.get("_bench_served", False)
    frames.__dict__["_bench_served"] = True
    return "first query: fused (cell classification)" if not served else "later query: fused"


STEPS = [  # (step, owner, attribute), in the order the monitor calls them
    ("check frame (validate, copy)", monitor_module, "checked_frame"),
    ("check frame (validate, copy)", monitor_module, "depth_image"),
    ("self-filter: render robot near", RobotSilhouette, "render"),
    ("self-filter: render robot far", RobotSilhouette, "render_far"),
    ("prepare depth (occupancy, holes, robot)", monitor_module, "prepare_depth"),
    ("free depths (seen_free)", depthgrid, "seen_free"),
    ("memory: row-min tables", memory_kernels, "row_min_tables"),
    ("memory: seen-free voxels", freespace, "seen_free_voxels"),
    ("memory: seen-free voxels", memory_kernels, "seen_free_voxels"),
    ("memory: voxels next to the robot, in pieces", memory_kernels, "certify_mixed_voxels"),
    ("memory: distance transform", memory_kernels, "grown_possibly_occupied"),
    ("memory: distance transform", memory_kernels, "last_axis_of_mask"),
    ("memory: distance transform", memory_kernels, "middle_axis"),
    ("memory: distance transform", memory_kernels, "first_axis"),
    ("memory: update (arrival times)", memory_kernels, "advance_arrival"),
    ("memory: update (arrival times)", FreeSpaceMemory, "update"),
    ("memory: free_at", monitor_module.DistanceMonitor, "_remembered_free"),
    ("self-filter: render first exit", RobotSilhouette, "render_first_exit"),
    ("fusion set-up: erosion", grid_kernels, "erode_free"),
    ("fusion set-up: principal arrays", grid_kernels, "principal_arrays"),
    ("fusion set-up: copies, allocations", FusedFrames, "__init__"),
    ("first query: fused (cell classification)", FusedFrames, "distances"),
    ("remembered flag", _near, "voxels_within"),
    ("single-camera query", answer_module, "single_camera_distances"),
    ("build map (first set only)", depthgrid, "build_map"),
]
OTHER = "other (plan, Python, result)"
ORDER = list(dict.fromkeys([s for s, _, _ in STEPS] + [OTHER]))


def instrument() -> StepTimer:
    timer = StepTimer()
    for step, owner, attr in STEPS:
        timer.wrap(owner, attr, _query_step if attr == "distances" else step)
    return timer


def serve_new_set(monitor, pool, all_cameras, i, timer=None):
    """Set of frames i of ``pool`` as new DepthImage objects, stamped i / 30 s, queried once with the robot's control
    points: (wall seconds, process CPU seconds, {step: (wall, CPU) seconds})."""
    q, points, raw = pool[pool_index(i, len(pool))]
    t = i / FPS
    frames = new_frames(raw, all_cameras, t)
    if timer is not None:
        timer.take()
    cpu = time.process_time()
    start = time.perf_counter()
    monitor.query(frames, points, joints=q, now=t, check=False)
    wall = time.perf_counter() - start
    cpu = time.process_time() - cpu
    steps = timer.take() if timer is not None else {}
    steps[OTHER] = np.array([wall, cpu]) - sum(steps.values(), np.zeros(2))
    return wall, cpu, steps


def run_sets(all_cameras, names, robot, pool, sets, memory=True, warmup=3):
    """Serve ``warmup`` + ``sets`` new sets of frames with a new monitor (to load and compile everything)."""
    monitor = make_monitor(all_cameras, names, robot, memory)
    for i in range(warmup + sets):
        serve_new_set(monitor, pool, all_cameras, i)
    del monitor
    gc.collect()


def spread(values, scale=1e3, digits=1):
    if len(values) == 0:
        return "n/a"
    v = np.asarray(values) * scale
    return f"{np.min(v):.{digits}f} / {np.median(v):.{digits}f} / {np.max(v):.{digits}f}"


def step_medians(runs, which):
    """Median seconds per step over the sets (which: 0 wall, 1 CPU)."""
    return {step: float(np.median([r[2].get(step, np.zeros(2))[which] for r in runs])) for step in ORDER}


def source_state() -> str:
    """The commit and the library files changed in the working tree (others edit this checkout meanwhile)."""
    here = os.path.dirname(os.path.abspath(__file__))
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=here, capture_output=True, text=True,
                              check=True).stdout.strip()
        changed = subprocess.run(["git", "status", "--porcelain", "--", "../depthguard"], cwd=here,
                                 capture_output=True, text=True, check=True).stdout.split("\n")
    except (OSError, subprocess.CalledProcessError):
        return "(git not available)"
    changed = [line[3:] for line in changed if line.strip()]
    return f"commit {head}" + (f", library files changed in the working tree: {', '.join(changed)}" if changed else "")


def load():
    return "load average " + " / ".join(f"{x:.1f}" for x in os.getloadavg()) + " (1 / 5 / 15 min)"


# --------------------------------------------------------------------------------------------- 1 and 2: the budget


def budget(all_cameras, robot, pools, repeats):
    threads = numba.get_num_threads()
    print(f"\n1. per new set of 640x480 frames: the query that prepares it, until served (KUKA iiwa self-filtered, 9 "
          f"control points, rho = {RHO} m, hybrid); {repeats} sets per configuration after 3 not counted, the "
          f"configurations interleaved set by set so that the machine's load falls on all alike; {load()}")
    configs = [(n, memory, t) for n in SETS for memory, t in ((True, threads), (False, threads), (True, 1))]
    monitors = {c: make_monitor(all_cameras, SETS[c[0]], robot, c[1]) for c in configs}
    runs = {c: [] for c in configs}
    timer = instrument()
    try:
        for i in range(3 + repeats):
            for c in configs:
                numba.set_num_threads(c[2])
                run = serve_new_set(monitors[c], pools[c[0]], all_cameras, i, timer)
                if i >= 3:
                    runs[c].append(run)
    finally:
        numba.set_num_threads(threads)
        timer.restore()
    del monitors
    gc.collect()
    wall = {c: step_medians(runs[c], 0) for c in configs}
    cpu = {c: step_medians(runs[c], 1) for c in configs}
    print(f"  memory on; medians, ms; wall at {threads} numba threads (the default), wall at 1 thread, and the CPU "
          "time of the process (all threads) at 1 thread")
    print(f"  {'':42s}" + "".join(f" | {f'{n} camera' + ('s' if n > 1 else ''):^22s}" for n in SETS))
    print(f"  {'step':42s}" + f" | {f'{threads} thr':>6s} {'1 thr':>6s} {'CPU 1':>6s} " * len(SETS))
    for step in ORDER:
        cells = [(wall[(n, True, threads)][step], wall[(n, True, 1)][step], cpu[(n, True, 1)][step]) for n in SETS]
        if any(v > 0 for row in cells for v in row) or step == OTHER:
            print(f"  {step:42s}" + "".join(f" | {a * 1e3:6.2f} {b * 1e3:6.2f} {c * 1e3:6.2f} " for a, b, c in cells))

    def total(c, which=0):
        return np.median([r[which] for r in runs[c]]) * 1e3

    print(f"  {'total (median of the sets)':42s}" + "".join(
        f" | {total((n, True, threads)):6.1f} {total((n, True, 1)):6.1f} {total((n, True, 1), 1):6.1f} "
        for n in SETS))
    print(f"  {'memory off: total':42s}" + "".join(
        f" | {total((n, False, threads)):6.1f} {'':6s} {'':6s} " for n in SETS))
    print(f"  noise, total wall min / median / max, ms ({threads} threads):")
    for n in SETS:
        print(f"    {n} camera(s): memory on {spread([r[0] for r in runs[(n, True, threads)]])}, memory off "
              f"{spread([r[0] for r in runs[(n, False, threads)]])}; at 1 thread, memory on "
              f"{spread([r[0] for r in runs[(n, True, 1)]])}")
    met = lambda v, goal: "met" if v <= goal else "NOT met"  # noqa: E731
    for n, goal in GOAL_NEW_SET_MS.items():
        on, one, cpu_one, off = (total((n, True, threads)), total((n, True, 1)), total((n, True, 1), 1),
                                 total((n, False, threads)))
        print(f"  goal <= {goal:g} ms for {n} cameras (memory on): {on:.1f} ms at {threads} threads "
              f"({met(on, goal)}), {one:.1f} ms at 1 thread ({met(one, goal)}), CPU {cpu_one:.1f} ms "
              f"({met(cpu_one, goal)}); memory off: {off:.1f} ms ({met(off, goal)})")

    print(f"\n2. thread scaling, memory on (numba threads; llvmpipe renders with its own threads either way): median "
          f"total wall, ms; {load()}")
    print(f"  {'cameras':>7s} {'1 thread':>9s} {f'{threads} threads':>10s} {'ratio':>6s}  CPU, all threads: "
          f"{'1 thread':>9s} {f'{threads} threads':>10s}")
    for n in SETS:
        a, b = total((n, True, 1)), total((n, True, threads))
        print(f"  {n:7d} {a:9.1f} {b:10.1f} {a / b:6.2f}  {'':17s} {total((n, True, 1), 1):9.1f} "
              f"{total((n, True, threads), 1):10.1f}")
    print(f"  two cameras, by step (wall medians, ms):")
    print(f"    {'step':42s} {'1 thread':>9s} {f'{threads} threads':>10s} {'ratio':>6s}")
    for step in ORDER:
        a, b = wall[(2, True, 1)][step], wall[(2, True, threads)][step]
        if a > 0 or b > 0:
            print(f"    {step:42s} {a * 1e3:9.2f} {b * 1e3:10.2f} {a / b if b > 0 else float('nan'):6.2f}")
    return wall


# --------------------------------------------------------------------------------------------------- 3: memory


def vm(field):
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1]) * 1024
    return 0


def state_bytes(monitor) -> dict[str, int]:
    """Bytes of the numpy arrays the monitor holds, by part (each buffer counted once)."""
    seen: set[int] = set()
    parts: dict[str, int] = {}

    def walk(obj, part, depth=0):
        if depth > 6 or id(obj) in seen:
            return
        seen.add(id(obj))
        if isinstance(obj, np.ndarray):
            base = obj
            while isinstance(base.base, np.ndarray):
                base = base.base
            if id(base) in seen and base is not obj:
                return
            seen.add(id(base))
            parts[part] = parts.get(part, 0) + base.nbytes
        elif isinstance(obj, dict):
            for value in obj.values():
                walk(value, part, depth + 1)
        elif isinstance(obj, (list, tuple)):
            for value in obj:
                walk(value, part, depth + 1)
        elif hasattr(obj, "__dict__") and type(obj).__module__.startswith("depthguard"):
            for key, value in vars(obj).items():
                if key in ("_monitor", "camera", "rig", "robot", "_silhouette"):
                    continue
                sub = "fused frames: cell classes (zeroed pages, touched lazily)" if key == "_cells" else part
                walk(value, sub, depth + 1)

    walk(monitor.memory, "free-space memory (arrival times, work space)")
    walk(monitor._free_now, "memory masks (free now, remembered only)")
    walk(monitor.maps, "depth grid maps")
    walk(monitor._prepared, "prepared frames (copy, occupancy, robot renders, free depths)")
    walk(monitor._fused_frames, "fused frames (eroded free images, principal arrays)")
    return parts


def memory_child(path, sets):
    """Run in a child process with a fixed mmap threshold (freed big arrays go back to the system): the resident
    memory a monitor adds, per camera count, after a warm-up monitor has loaded every kernel."""
    robot = RobotModel.default()
    all_cameras = cameras(list(EYES))
    data = np.load(path)
    pools = {n: [(data["q"][k], robot.control_point_positions(data["q"][k]),
                  {name: data[f"{name}_{k}"] for name in SETS[n]}) for k in range(len(data["q"]))] for n in SETS}
    for n in SETS:  # load and compile everything first
        run_sets(all_cameras, SETS[n], robot, pools[n], 2, True, warmup=1)
    report = {}
    for n in SETS:
        gc.collect()
        before = vm("VmRSS")
        try:
            with open("/proc/self/clear_refs", "w") as f:  # resets the peak (VmHWM) to the current RSS
                f.write("5")
            peak_ok = True
        except OSError:
            peak_ok = False
        monitor = make_monitor(all_cameras, SETS[n], robot, True)
        made = vm("VmRSS")
        for i in range(sets):
            q, points, raw = pools[n][pool_index(i, len(pools[n]))]
            frames = new_frames(raw, all_cameras, i / FPS)
            monitor.query(frames, points, joints=q, now=i / FPS, check=False)
            for k in range(1, LATER + 1):  # the same frames again, the points moving
                monitor.query(frames, points + 0.002 * k, now=i / FPS, check=False)
            if i == 0:
                first = vm("VmRSS")
        gc.collect()
        after = vm("VmRSS")
        report[n] = {"made": made - before, "first": first - before, "after": after - before,
                     "peak": (vm("VmHWM") - before) if peak_ok else None, "parts": state_bytes(monitor)}
        del monitor
        gc.collect()
    print(json.dumps(report))


def memory_report(pool4, sets):
    print(f"\n3. memory used (a child process at 1 numba thread, big arrays mmapped so that freed memory goes back; "
          f"after a warm-up monitor loaded every kernel; memory on; MB = 1e6 bytes); {load()}")
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "pool.npz")
        arrays = {"q": np.array([q for q, _, _ in pool4])}
        for k, (_, _, raw) in enumerate(pool4):
            for name, data in raw.items():
                arrays[f"{name}_{k}"] = data
        np.savez(path, **arrays)
        env = dict(os.environ, MALLOC_MMAP_THRESHOLD_="65536", NUMBA_NUM_THREADS="1")
        done = subprocess.run([sys.executable, __file__, "--memory-child", path, "--sets", str(sets)], env=env,
                              capture_output=True, text=True)
    if done.returncode != 0:
        print("  the memory child failed:\n" + done.stderr[-2000:])
        return
    report = {int(k): v for k, v in json.loads(done.stdout.strip().splitlines()[-1]).items()}
    mb = lambda b: f"{b / 1e6:.0f}" if b is not None else "n/a"  # noqa: E731
    print(f"  resident memory added, MB {'1 camera':>9s} {'2 cameras':>10s} {'4 cameras':>10s}")
    for label, key in (("monitor made (GL context, meshes)", "made"), ("after the first set (map built)", "first"),
                       (f"after {sets} sets of {LATER + 1} queries", "after"), ("peak", "peak")):
        print(f"    {label:40s} " + " ".join(f"{mb(report[n][key]):>{w}s}" for n, w in zip(SETS, (9, 10, 10))))
    print("  arrays the monitor holds, MB:")
    parts = list(dict.fromkeys(p for n in SETS for p in report[n]["parts"]))
    for part in parts:
        print(f"    {part:62s} " + " ".join(f"{report[n]['parts'].get(part, 0) / 1e6:>{w}.1f}"
                                            for n, w in zip(SETS, (6, 7, 7))))
    print(f"    {'total':62s} " + " ".join(f"{sum(report[n]['parts'].values()) / 1e6:>{w}.1f}"
                                          for n, w in zip(SETS, (6, 7, 7))))
    print("  (goal of issue 8: the memory <= 256 MB)")


# ----------------------------------------------------------------------------------------- 4: the sustained rate


def sustained(all_cameras, robot, pool, names, seconds):
    """Cameras at 30 Hz on the wall clock and queries as fast as they come, one thread of control."""
    monitor = make_monitor(all_cameras, names, robot, True)
    offsets = [[robot.control_point_positions(q + STEP * j) for j in range(64)] for q, _, _ in pool]
    # the first set builds the map and loads everything: not counted
    q, points, raw = pool[0]
    monitor.query(new_frames(raw, all_cameras, 0.0), points, joints=q, now=0.0, check=False)
    period = 1.0 / FPS
    start = time.perf_counter()
    clock = lambda: time.perf_counter() - start + 1.0  # noqa: E731  (capture clock, after the warm-up frame's)
    first_capture = clock()
    k = -1
    frames = capture = None
    since = 0
    latency_new, latency_later, ages = [], [], []
    dropped = 0
    while clock() - first_capture < seconds:
        now = clock()
        latest = int((now - first_capture) / period)  # the newest frame set that has arrived
        new = latest != k
        if new:
            dropped += max(latest - k - 1, 0) if k >= 0 else 0
            k = latest
            capture = first_capture + k * period
            q, _, raw = pool[pool_index(k + 1, len(pool))]
            frames = new_frames(raw, all_cameras, capture)
            since = 0
        points = offsets[pool_index(k + 1, len(pool))][min(since, 63)]
        t0 = time.perf_counter()
        monitor.query(frames, points, joints=q if new else None, now=clock(), check=False)
        t1 = time.perf_counter()
        ages.append(clock() - capture)
        (latency_new if new else latency_later).append(t1 - t0)
        since += 1
    elapsed = clock() - first_capture
    del monitor
    gc.collect()
    return {"rate": (len(latency_new) + len(latency_later)) / elapsed, "sets": len(latency_new), "dropped": dropped,
            "elapsed": elapsed, "new": np.array(latency_new), "later": np.array(latency_later),
            "ages": np.array(ages)}


def sustained_live(all_cameras, robot, pool, names, seconds):
    """The same timeline through depthguard.LiveMonitor: each new set of frames is submitted (prepared on its worker
    thread) and every query answers at once from the latest prepared set."""
    live = dg.LiveMonitor(make_rig(all_cameras, names), rho=RHO, aggregate="hybrid", robot=robot)
    try:
        offsets = [[robot.control_point_positions(q + STEP * j) for j in range(64)] for q, _, _ in pool]
        q, points, raw = pool[0]
        live.submit(new_frames(raw, all_cameras, 0.0), joints=q, now=0.0)
        live.wait(600)  # the first set builds the map: not counted
        period = 1.0 / FPS
        start = time.perf_counter()
        clock = lambda: time.perf_counter() - start + 1.0  # noqa: E731
        first_capture = clock()
        k, since = -1, 0
        latency, ages = [], []
        while clock() - first_capture < seconds:
            latest = int((clock() - first_capture) / period)
            if latest != k:
                k = latest
                q, _, raw = pool[pool_index(k + 1, len(pool))]
                live.submit(new_frames(raw, all_cameras, first_capture + k * period), joints=q, now=clock())
                since = 0
            points = offsets[pool_index(k + 1, len(pool))][min(since, 63)]
            t0 = time.perf_counter()
            live.query(points)
            latency.append(time.perf_counter() - t0)
            if live.latest_time is not None and live.latest_time >= first_capture:
                ages.append(clock() - live.latest_time)
            since += 1
        elapsed = clock() - first_capture
        return {"rate": len(latency) / elapsed, "latency": np.array(latency), "ages": np.array(ages),
                "prepared": live.prepared - 1, "dropped": live.dropped, "sets": k + 1}
    finally:
        live.close()


def sustained_report(all_cameras, robot, pools, seconds):
    threads = numba.get_num_threads()
    print(f"\n4. sustained: cameras at {FPS:g} Hz (wall clock), queries of 9 points as fast as they come (the robot "
          f"moving {STEP * 1e3:g} mrad per joint per query), each new set of frames prepared inline by the query that "
          f"first sees it, memory on, {seconds:g} s each; age = answer time - capture time; {load()}")
    print(f"  {'cameras':>7s} {'threads':>7s} {'queries/s':>9s} {'goal':>5s} {'sets':>5s} {'dropped':>7s} "
          f"{'age med ms':>10s} {'age worst':>9s} {'new-set query ms min/med/max':>29s} "
          f"{'later ms min/med/max':>21s}")
    out = {}
    for n in SETS:
        for t in (threads, 1):
            numba.set_num_threads(t)
            try:
                r = out[(n, t)] = sustained(all_cameras, robot, pools[n], SETS[n], seconds)
            finally:
                numba.set_num_threads(threads)
            goal = GOAL_RATE.get(n)
            print(f"  {n:7d} {t:7d} {r['rate']:9.0f} {('>=' + str(int(goal))) if goal else '':>5s} {r['sets']:5d} "
                  f"{r['dropped']:7d} {np.median(r['ages']) * 1e3:10.1f} {np.max(r['ages']) * 1e3:9.1f} "
                  f"{spread(r['new']):>29s} {spread(r['later'], digits=2):>21s}")
    print("  (later n/a: every query met a new set of frames, its preparation taking longer than a frame period)")
    print(f"  the same through LiveMonitor (frames prepared on a worker thread, {threads} numba threads; queries never "
          "wait for a set):")
    print(f"  {'cameras':>7s} {'queries/s':>9s} {'goal':>5s} {'sets':>5s} {'prepared':>8s} {'age med ms':>10s} "
          f"{'age worst':>9s} {'query ms min/med/max':>22s}")
    for n in SETS:
        r = out[(n, "live")] = sustained_live(all_cameras, robot, pools[n], SETS[n], seconds)
        goal = GOAL_RATE.get(n)
        ages = r["ages"] if len(r["ages"]) else np.array([np.nan])
        print(f"  {n:7d} {r['rate']:9.0f} {('>=' + str(int(goal))) if goal else '':>5s} {r['sets']:5d} "
              f"{r['prepared']:8d} {np.median(ages) * 1e3:10.1f} {np.max(ages) * 1e3:9.1f} "
              f"{spread(r['latency'], digits=2):>22s}")
    for n, goal in GOAL_RATE.items():
        rates = [out[(n, t)]["rate"] for t in (threads, 1)]
        ages = out[(n, threads)]["ages"]
        print(f"  goal >= {goal:g} queries/s with {n} cameras: {rates[0]:.0f} at {threads} threads, {rates[1]:.0f} "
              f"at 1 ({'met' if max(rates) >= goal else 'NOT met'}); data age at {threads} threads: median "
              f"{np.median(ages) * 1e3:.0f} ms, worst {np.max(ages) * 1e3:.0f} ms")
    return out


# ------------------------------------------------------------------------------------------- 5: the still scene


def still_pool(all_cameras, robot, renderer, names):
    """[(Q0, control points, {camera: uint16 millimetres})]: the room and the robot at rest at Q0, and one person
    walking at 1 m/s past the robot (WALK positions 1/30 s apart, 1.3-1.7 m from its base), arms down."""
    silhouette = RobotSilhouette(robot, renderer, geometry="meshes", padding=0.0)
    still = {}
    for name in names:
        room = render_depth(all_cameras[name], ROOM)
        arm = silhouette.render(all_cameras[name], Q0)
        still[name] = nearer(arm, room)
    points = robot.control_point_positions(Q0)
    pool = []
    for k in range(WALK):
        person = standing_person((1.3, -0.6 + k / FPS), facing=np.pi)
        raw = {}
        for name in names:
            body = render_depth(all_cameras[name], person)
            depth = nearer(body, still[name])
            raw[name] = np.round(depth * 1000).astype(np.uint16)
        pool.append((Q0.copy(), points, raw))
    return pool


def still_report(all_cameras, robot, pools, still, repeats):
    """Per new set, the still scene against the moving robot's (the budget's scene), interleaved set by set."""
    threads = numba.get_num_threads()
    print(f"\n5. a still scene: the robot at rest, one person walking past it at 1 m/s (1.3 m from its base); per new "
          f"set of frames, the query that prepares it, until served; against the budget's scene (the robot moving "
          f"{STEP * 1e3:g} mrad per joint per set) in the same run, configurations interleaved set by set; "
          f"{repeats} sets after 3 not counted; memory on, {threads} numba threads; {load()}")
    configs = [(n, scene) for n in (2, 4) for scene in ("still", "moving")]
    monitors = {c: make_monitor(all_cameras, SETS[c[0]], robot) for c in configs}
    runs = {c: [] for c in configs}
    timer = instrument()
    try:
        for i in range(3 + repeats):
            for c in configs:
                pool = still[c[0]] if c[1] == "still" else pools[c[0]]
                run = serve_new_set(monitors[c], pool, all_cameras, i, timer)
                if i >= 3:
                    runs[c].append(run)
    finally:
        timer.restore()
    del monitors
    gc.collect()
    wall = {c: step_medians(runs[c], 0) for c in configs}
    print(f"  wall medians, ms")
    print(f"  {'step':42s}" + "".join(f" | {f'{n} cameras, {scene}':>18s}" for n, scene in configs))
    for step in ORDER:
        cells = [wall[c][step] for c in configs]
        if any(v > 0 for v in cells) or step == OTHER:
            print(f"  {step:42s}" + "".join(f" | {v * 1e3:18.2f}" for v in cells))
    totals = {c: np.median([r[0] for r in runs[c]]) * 1e3 for c in configs}
    print(f"  {'total (median of the sets)':42s}" + "".join(f" | {totals[c]:18.1f}" for c in configs))
    for n in (2, 4):
        value = totals[(n, "still")]
        print(f"  goal <= {GOAL_STILL_MS:g} ms for a still scene, {n} cameras: {value:.1f} ms "
              f"({'met' if value <= GOAL_STILL_MS else 'NOT met'}; the moving robot's {totals[(n, 'moving')]:.1f} ms, "
              f"x{value / totals[(n, 'moving')]:.2f})")


# ------------------------------------------------------------------------------------------ 6: the shadow scene


def shadow_report(all_cameras, robot, scene, pools, repeats):
    threads = numba.get_num_threads()
    silhouette_pixels = scene.silhouette.render(all_cameras["principal"], Q0) > 0
    behind = scene.background["principal"]
    hidden = silhouette_pixels & (behind > 0) & (behind < scene.silhouette.render(all_cameras["principal"], Q0))
    print(f"\n6. later queries in a shadow scene: a person 1.2 m from the principal camera on its line to the robot "
          f"(in front of {hidden.sum() / max(silhouette_pixels.sum(), 1):.0%} of the robot's pixels in the principal);"
          f" per set of frames, the first query then {LATER} more on the same frames with the robot moving "
          f"{STEP * 1e3:g} mrad per joint per query; {repeats} sets after 3 not counted, configurations interleaved; "
          f"{load()}")
    configs = [(n, memory, t) for n in SETS for memory, t in ((True, threads), (False, threads), (True, 1))]
    monitors = {c: make_monitor(all_cameras, SETS[c[0]], robot, c[1]) for c in configs}
    first = {c: [] for c in configs}
    later = {c: [] for c in configs}
    later_cpu = {c: [] for c in configs}
    below = {c: [] for c in configs}
    counted = {c: [] for c in configs}  # obstacle pixels a point's answer aggregates (hybrid: all within rho)
    try:
        for i in range(3 + repeats):
            for c in configs:
                numba.set_num_threads(c[2])
                monitor = monitors[c]
                q, _, raw = pools[c[0]][pool_index(i, len(pools[c[0]]))]
                t = i / FPS
                frames = new_frames(raw, all_cameras, t)
                steps = [robot.control_point_positions(q + STEP * j) for j in range(LATER + 1)]
                start = time.perf_counter()
                monitor.query(frames, steps[0], joints=q, now=t, check=False)
                if i >= 3:
                    first[c].append(time.perf_counter() - start)
                for points in steps[1:]:
                    cpu = time.process_time()
                    start = time.perf_counter()
                    result = monitor.query(frames, points, now=t, check=False)
                    if i >= 3:
                        later[c].append(time.perf_counter() - start)
                        later_cpu[c].append(time.process_time() - cpu)
                        below[c].append(int(np.sum(result.distance < RHO)))
                        counted[c].append(float(np.median(result.count)))
    finally:
        numba.set_num_threads(threads)
    del monitors
    gc.collect()
    print(f"  {'cameras':>7s} {'memory':>6s} {'threads':>7s} {'new set ms':>10s} {'later ms min/med/max':>21s} "
          f"{'later q/s':>9s} {'later CPU ms':>12s} {'points < rho':>12s} {'obstacle px/point':>17s}")
    rates = {}
    for c in configs:
        n, memory, t = c
        rates[c] = 1.0 / np.median(later[c])
        print(f"  {n:7d} {'on' if memory else 'off':>6s} {t:7d} {np.median(first[c]) * 1e3:10.1f} "
              f"{spread(later[c], digits=2):>21s} {rates[c]:9.0f} {np.median(later_cpu[c]) * 1e3:12.2f} "
              f"{np.median(below[c]):10.0f}/9 {np.median(counted[c]):17.0f}")
    best = max(rates[(2, True, threads)], rates[(2, True, 1)])
    print(f"  goal >= {GOAL_LATER_RATE:g} later queries/s with two cameras (memory on): "
          f"{rates[(2, True, threads)]:.0f} at {threads} threads, {rates[(2, True, 1)]:.0f} at 1 "
          f"({'met' if best >= GOAL_LATER_RATE else 'NOT met'}); memory off {rates[(2, False, threads)]:.0f}; "
          f"baseline, the principal camera alone: {rates[(1, True, threads)]:.0f}")


# -------------------------------------------------------------------------------------------------------- main


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=10, help="new sets of frames timed per configuration")
    parser.add_argument("--seconds", type=float, default=3.0, help="wall-clock seconds of each sustained run")
    parser.add_argument("--memory-child", help=argparse.SUPPRESS)
    parser.add_argument("--sets", type=int, default=10, help=argparse.SUPPRESS)
    parser.add_argument("--only", choices=("budget", "memory", "sustained", "still", "shadow"), action="append",
                        help="run only these sections (repeatable; default: all)")
    args = parser.parse_args(argv)
    run = set(args.only or ("budget", "memory", "sustained", "still", "shadow"))
    if args.memory_child:
        memory_child(args.memory_child, args.sets)
        return

    started = time.perf_counter()
    robot = RobotModel.default()
    all_cameras = cameras(list(EYES))
    rig = make_rig(all_cameras, list(EYES))
    ranges = ", ".join(f"{n} {lo:.2f}-{hi:.2f} m" for n in EYES for lo, hi in [grid_range(rig, n)])
    renderer = Renderer()
    print(f"workspace {WORKSPACE}; grid ranges: {ranges}; the monitor self-filters with its default geometry (padded "
          "hulls), the frames were rendered from the meshes")
    print(f"code: {source_state()}")
    print(f"{os.cpu_count()} cores; numba {numba.__version__}, {numba.config.NUMBA_NUM_THREADS} threads; OpenGL: "
          f"{renderer.gl_renderer}; {load()}")
    print("rendering the scenes' backgrounds (the primitive renderer: seconds a camera) ...", flush=True)
    workcell = Scene(all_cameras, robot, standing_person((0.95, 0.35), facing=np.pi * 1.1, reach=0.9), renderer)
    person, spot = shadow_person(robot)
    shadow = Scene(all_cameras, robot, person, renderer)
    pools = {4: workcell.pool(SETS[4])}
    pools.update({n: [(q, p, {name: raw[name] for name in SETS[n]}) for q, p, raw in pools[4]] for n in (1, 2)})
    shadow_pool = shadow.pool(SETS[4], 3 + max(2, args.repeats // 2))
    shadow_pools = {n: [(q, p, {name: raw[name] for name in SETS[n]}) for q, p, raw in shadow_pool] for n in SETS}
    still = still_pool(all_cameras, robot, renderer, SETS[4]) if "still" in run else []
    still = {n: [(q, p, {name: raw[name] for name in SETS[n]}) for q, p, raw in still] for n in SETS}
    print(f"  done in {time.perf_counter() - started:.0f} s; shadow person at ({spot[0]:.2f}, {spot[1]:.2f})")
    for n in SETS:  # load / compile every kernel before anything is timed
        run_sets(all_cameras, SETS[n], robot, pools[n], 1, True, warmup=1)
        run_sets(all_cameras, SETS[n], robot, pools[n], 1, False, warmup=1)
    print(f"numba threading layer: {numba.threading_layer()}")

    if "budget" in run:
        budget(all_cameras, robot, pools, args.repeats)
    if "memory" in run:
        memory_report(pools[4][:8], 10)
    if "sustained" in run:
        sustained_report(all_cameras, robot, pools, args.seconds)
    if "still" in run:
        still_report(all_cameras, robot, pools, still, args.repeats)
    if "shadow" in run:
        shadow_report(all_cameras, robot, shadow, shadow_pools, max(2, args.repeats // 2))
    print(f"\n(run took {time.perf_counter() - started:.0f} s)")


if __name__ == "__main__":
    with report(__file__):
        main()
