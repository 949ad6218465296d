"""``depthguard warmup`` compiles every kernel the product uses (issue 12): afterwards a new process answers from the
cache and compiles nothing; a kernel that does compile at run time says so; kernel caches know the sources they
inline (``depthguard.kernels.jit``)."""

from __future__ import annotations

import importlib

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import depthguard as dg
from depthguard.kernels import jit
from depthguard.warmup import WORKLOADS
from depthguard.depth import write_depth_png
from depthguard.rendering import Renderer
from depthguard.robots import RobotModel
from depthguard.scenes import Box, render_depth
from depthguard.self_filter import RobotSilhouette
from depthguard.transforms import look_at

PACKAGE = Path(dg.__file__).parent
Q = np.array([0.2, 0.5, 0.0, -1.2, 0.0, 0.6, 0.0])

# Runs in a fresh process: the command line and the Python API on real inputs. Prints, as JSON on its last line, every
# kernel signature they called (depthguard.warmup.loaded_signatures).
PRODUCT_RUNS = r"""
import json, sys
from pathlib import Path
import numpy as np
folder = Path(sys.argv[1])
joints = ",".join(map(str, json.loads((folder / "q.json").read_text())))
from depthguard import cli
import depthguard as dg

single = ["distance", "--rig", str(folder / "rig.yaml"), "--depth", f"principal={folder / 'principal.png'}",
          "--points", str(folder / "points.json"), "--json"]
fused = single + ["--depth", f"second={folder / 'second.png'}"]
robot = ["--robot", "iiwa", "--joints", joints]
for argv in (single + robot, fused + robot, single, fused, single + ["--aggregate", "min", "--invalid", "neighbors"],
             fused + ["--aggregate", "mean", "--invalid", "free"], single + ["--method", "paper"],
             ["distance", "--rig", str(folder / "rig.yaml"), "--depth", f"principal={folder / 'principal.npy'}",
              "--points", str(folder / "one.json")]):
    assert cli.main(argv) == 0, argv
rig = dg.load_rig(folder / "rig.yaml")
points = np.array(json.loads((folder / "points.json").read_text()))
frames = {name: dg.load_depth(folder / f"{name}.png", rig.cameras[name]) for name in rig.cameras}
floats = {name: dg.depth_image(np.load(folder / f"{name}.npy"), rig.cameras[name]) for name in rig.cameras}
for aggregate in ("min", "hybrid"):
    monitor = dg.DistanceMonitor(rig, aggregate=aggregate)
    for pts in (points[:1], points):
        monitor.query({"principal": frames["principal"]}, pts)
        monitor.query(frames, pts)
        monitor.query({"principal": floats["principal"]}, pts)
        monitor.query(floats, pts)
# A hole that invalid="neighbors" fills: every answer measures how near the filled space comes to each point
# (Concessions.fills, a single-camera query of its own; the demo compiled it at run time before).
holed = frames["principal"].data.copy()
holed[30:33, 44:47] = 0
filling = dg.DistanceMonitor(rig, invalid="neighbors")
for pts in (points[:1], points):
    filling.query({**frames, "principal": dg.depth_image(holed, rig.cameras["principal"])}, pts)
dg.frustum_distance([0.0, 0.0, 1.0], [[-0.1, 0.1, -0.1, 0.1]], [0.5, np.inf])
# The monitor as replay and live run it: the free-space memory (a rig with a workspace) beside the robot (its inside,
# and the voxels next to it that no camera sees whole, judged piece by piece), stamped frames with the joints.
from depthguard.robots import RobotModel
q = np.array(json.loads((folder / "q.json").read_text()))
spaced = dg.Rig(rig.cameras, principal="principal", workspace=[[-1.0, -1.0, 0.0], [1.0, 1.0, 1.5]])
iiwa = RobotModel.default()
remembering = dg.DistanceMonitor(spaced, robot=iiwa, aggregate="min")
# And as live --ssm runs it: SSM's detectable space beside the robot.
detecting = dg.DistanceMonitor(spaced, robot=iiwa, aggregate="min", detection_capability=0.06, detectable_voxel=0.03)
for k in range(2):
    stamped = {name: dg.depth_image(frame.data, rig.cameras[name], timestamp=0.1 * k) for name, frame in frames.items()}
    remembering.query(stamped, points, joints=q, now=0.1 * k)
    detecting.prepare_set(stamped, joints=q, now=0.1 * k).detectable_distances(points)
# The collision test's difference images (depthguard collide), intensity and depth.
from depthguard.collision import TileGrid, depth_difference_image, tile_features
grid = TileGrid(rig.cameras["principal"], 6, 8)
reference = np.load(folder / "principal.npy").astype(np.float64)
for image in (frames["principal"].data, floats["principal"].data, reference):
    depth_difference_image(image, reference, grid)
tile_features(np.zeros(rig.cameras["principal"].shape, dtype=np.uint8), grid)
from depthguard.warmup import loaded_signatures
print(json.dumps(loaded_signatures()))
"""


@pytest.fixture(scope="module")
def workcell(tmp_path_factory):
    """Two 96x72 cameras watching the iiwa at Q, a floor, a wall and a box: a rig, uint16 PNG and float32 .npy
    frames of each camera, the robot's control points and joints."""
    folder = tmp_path_factory.mktemp("warmup")
    robot = RobotModel.default()
    cameras = {name: dg.PinholeCamera(name, 96, 72, 78.75, 78.75, 47.5, 35.5, look_at(eye, [0.0, 0.0, 0.6]),
                                      depth_range=(0.3, 6.0))
               for name, eye in (("principal", [1.8, -1.5, 1.6]), ("second", [1.6, 1.8, 1.5]))}
    rig = dg.Rig(cameras, principal="principal")
    scene = [Box.from_bounds([-3, -3, -0.1], [3, 3, 0]), Box.from_bounds([-2.5, -3, 0], [-2.4, 3, 3]),
             Box.from_bounds([0.5, -0.6, 0.0], [0.8, -0.3, 0.5])]
    with Renderer() as renderer:
        silhouette = RobotSilhouette(robot, renderer, geometry="meshes")
        for name, camera in cameras.items():
            room = render_depth(camera, scene)
            arm = silhouette.render(camera, Q)
            depth = np.where(arm > 0, np.minimum(arm, np.where(room > 0, room, np.inf)), room).astype(np.float32)
            write_depth_png(folder / f"{name}.png", np.round(depth * 1000).astype(np.uint16))
            np.save(folder / f"{name}.npy", depth)
    dg.save_rig(rig, folder / "rig.yaml")
    points = robot.control_point_positions(Q)
    (folder / "points.json").write_text(json.dumps(points.tolist() + [[0.65, -0.45, 0.7]]))
    (folder / "one.json").write_text(json.dumps([[0.65, -0.45, 0.7]]))
    (folder / "q.json").write_text(json.dumps(Q.tolist()))
    return folder


def test_the_warmup_runs_every_kernel_signature_the_product_uses(workcell):
    """The warm-up covers every argument type the product passes its kernels: every kernel signature that the command
    line (one camera and two fused, with and without the robot, uint16 and float32 frames, each policy) and the
    monitor call in a new process is one that the warm-up's workloads call (``loaded_signatures``, whether compiled
    or loaded from the cache), and the product says nothing about compiling.

    Both processes use the suite's own cache, which ``./dev.sh test`` warmed: comparing signatures, not compiles, keeps
    a kernel that another test compiled into that cache from hiding one the warm-up missed. (The warm-up from an
    empty cache, in a process per core, is what ``./dev.sh test`` runs after a fresh clone, and
    ``benchmarks/bench_cold_start.py`` times it.)"""
    warm = subprocess.run([sys.executable, "-c", "import json; from depthguard.warmup import warm_up, "
                           "loaded_signatures; warm_up(); print(json.dumps(loaded_signatures()))"],
                          capture_output=True, text=True, timeout=900)
    assert warm.returncode == 0, warm.stderr[-3000:]
    warmed = set(json.loads(warm.stdout.strip().splitlines()[-1]))
    done = subprocess.run([sys.executable, "-c", PRODUCT_RUNS, str(workcell)], capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    used = json.loads(done.stdout.strip().splitlines()[-1])
    assert len(used) >= 10 and any("fused_query_points" in s for s in used), used
    missed = sorted(set(used) - warmed)
    assert missed == [], f"the warm-up does not run {missed}"
    assert "compiling" not in done.stderr


def test_a_kernel_compiled_at_run_time_says_so(tmp_path):
    """With an empty cache (a cache folder of its own), the first call of a kernel logs one line on standard error
    that names it; the kernels it calls compile within it and add no line."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    code = "import depthguard as dg; dg.frustum_distance([0.0, 0.0, 1.0], [[-0.1, 0.1, -0.1, 0.1]], [0.5, 2.0])"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
    assert done.returncode == 0, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, lines
    assert "depthguard.kernels.frustum.frustum_nearest_many" in lines[0] and "depthguard warmup" in lines[0]
    assert any(tmp_path.rglob("*.nbi"))  # cached where the user asked
    again = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
    assert again.returncode == 0 and again.stderr == ""


def test_every_kernel_module_compiles_through_jit_kernel():
    """Every module that defines numba kernels is listed in jit.KERNEL_MODULES and uses jit.kernel (cached,
    stamped with its dependencies), never numba's njit directly."""
    uses_kernel = set()
    for path in PACKAGE.rglob("*.py"):
        source = path.read_text()
        name = "depthguard." + ".".join(path.relative_to(PACKAGE).with_suffix("").parts)
        assert not re.search(r"\bnjit\b|numba\.jit|from numba import jit", source) or path.name == "jit.py", name
        if re.search(r"^@kernel\(", source, re.M):
            uses_kernel.add(name)
    assert uses_kernel == set(jit.KERNEL_MODULES)


def test_kernels_without_reference_counts_allocate_nothing():
    """The fused query's kernels called per pixel, walk or run are compiled without numba's reference counting
    (``jit.kernel(refcounts=False)``), and no other: sound because such a kernel can neither allocate nor return an
    array, which numba enforces at compile time (checked here, on kernels that would): none can keep an array
    beyond its call."""
    import numba
    import numpy as np
    from numba.core.dispatcher import Dispatcher

    from depthguard.kernels import depthgrid as grid_kernels

    uncounted = set()
    for module in jit.KERNEL_MODULES:
        kernels = importlib.import_module(module)
        uncounted |= {f"{module}.{name}" for name, value in vars(kernels).items()
                      if isinstance(value, Dispatcher) and value.targetoptions.get("_nrt") is False}
    assert uncounted == {f"depthguard.kernels.depthgrid.{name}" for name in (
        "classify_run", "remembered_cells", "occupied_in", "nearest_confirmed", "fused_rows", "fused_region")}
    assert grid_kernels.fused_finish.targetoptions.get("_nrt", True)  # allocates: counted

    @numba.njit(_nrt=False)
    def allocates(n):
        return np.zeros(n).sum()

    @numba.njit(_nrt=False)
    def returns_a_view(a):
        return a[1:]

    with pytest.raises(numba.core.errors.NumbaError):
        allocates(3)
    with pytest.raises(numba.core.errors.NumbaError):
        returns_a_view(np.arange(4.0))


def test_kernel_caches_are_stamped_with_the_sources_they_inline():
    from depthguard.kernels import depthgrid as grid_kernels
    from depthguard.kernels import depthspace as space_kernels

    assert jit.kernel_dependencies("depthguard.kernels.depthgrid") == ("depthguard.kernels.depthgrid",
                                                                         "depthguard.kernels.frustum")
    assert jit.kernel_dependencies("depthguard.kernels.depthspace") == ("depthguard.kernels.depthspace",
                                                                          "depthguard.kernels.frustum")
    assert jit.kernel_dependencies("depthguard.kernels.depth") == ("depthguard.kernels.depth",
                                                                     "depthguard.kernels.frustum")
    # The locator in use is depthguard's, and its stamp covers the depth grid's and the single camera's sources.
    locator = grid_kernels.fused_query_points._cache._impl.locator
    assert type(locator).__name__.startswith("Depthguard")
    stamp = locator.get_source_stamp()
    assert stamp == jit.sources_stamp(grid_kernels.__file__)
    assert stamp != jit.sources_stamp(space_kernels.__file__)
