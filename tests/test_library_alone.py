"""The library stands alone: a cell installs depthguard without the lab (depthguard_lab), physics engine (pybullet),
plotting library (matplotlib) or progress bars (tqdm), and it answers a fused query without them."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import depthguard as dg
from depthguard.scenes import Box, Sphere, render_depth
from depthguard.transforms import look_at

ROOT = Path(__file__).resolve().parent.parent
LAB_ONLY = ("depthguard_lab", "pybullet", "pybullet_data", "matplotlib", "tqdm")

#: Run in a fresh interpreter: every import of a lab-only package fails, as on a machine that installed the library
#: alone; then every library module is imported and ``depthguard distance`` answers on two cameras.
BLOCKED_RUN = """
import importlib, importlib.abc, pkgutil, sys
BLOCKED = {blocked!r}

class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {{name!r}} (the library alone)")
        return None

sys.meta_path.insert(0, Block())
import depthguard
for module in pkgutil.walk_packages(depthguard.__path__, "depthguard."):
    importlib.import_module(module.name)
loaded = sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED)
assert not loaded, loaded
from depthguard.cli import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.fixture(scope="module")
def two_cameras(tmp_path_factory):
    """A rig of two cameras looking at a ball over a floor, their depth images and two points: files."""
    folder = tmp_path_factory.mktemp("alone")
    cameras = {name: dg.PinholeCamera(name, 160, 120, 131.25, 131.25, 79.5, 59.5, look_at(eye, [0.0, 0.0, 0.3]),
                                      depth_range=(0.3, 6.0))
               for name, eye in (("left", (2.0, 1.0, 1.5)), ("right", (2.0, -1.0, 1.5)))}
    rig = dg.Rig(cameras, principal="left", workspace=[[-1, -1, -0.1], [1, 1, 1.5]])
    dg.save_rig(rig, folder / "rig.yaml")
    scene = [Box.from_bounds([-3, -3, -0.2], [3, 3, 0.0]), Sphere((0.0, 0.0, 0.4), 0.15)]
    for name, camera in cameras.items():
        np.save(folder / f"{name}.npy", render_depth(camera, scene).astype(np.float32))
    (folder / "points.json").write_text(json.dumps([[0.0, 0.0, 0.8], [0.4, 0.3, 0.5]]))
    return folder


def test_the_library_answers_a_fused_query_without_the_lab_or_its_dependencies(two_cameras):
    folder = two_cameras
    argv = ["distance", "--rig", folder / "rig.yaml", "--depth", f"left={folder / 'left.npy'}",
            "--depth", f"right={folder / 'right.npy'}", "--points", folder / "points.json", "--json"]
    run = subprocess.run([sys.executable, "-c", BLOCKED_RUN.format(blocked=LAB_ONLY), *map(str, argv)],
                         capture_output=True, text=True, timeout=600, cwd=folder)
    assert run.returncode == 0, run.stderr[-3000:]
    answers = json.loads(run.stdout)
    # the same answers as this process gives with everything installed; fused, never above the truth
    rig = dg.load_rig(folder / "rig.yaml")
    frames = {name: dg.load_depth(folder / f"{name}.npy", rig.cameras[name]) for name in rig.cameras}
    points = np.array(json.loads((folder / "points.json").read_text()))
    expected = dg.DistanceMonitor(rig).query(frames, points)
    assert [a["distance"] for a in answers] == expected.distance.tolist()
    assert [a["flags"] for a in answers] == [f.names for f in expected.flags]
    assert 0.0 < answers[0]["distance"] <= 0.8 - 0.55 + 1e-3  # above the ball: 0.25 m at most


def test_a_deployment_install_asks_for_no_lab_dependency():
    """The library's own dependencies (pyproject.toml's project.dependencies) name no physics engine, plotting
    library or simulation package: those are the lab's (lab/pyproject.toml) or optional extras."""
    import tomllib

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    names = {dep.split(">")[0].split("=")[0].split("[")[0].strip().lower() for dep in project["dependencies"]}
    assert not names & {"pybullet", "matplotlib", "tqdm", "depthguard-lab"}, names
    lab = tomllib.loads((ROOT / "lab" / "pyproject.toml").read_text())["project"]
    assert "depthguard" in lab["dependencies"] and lab["scripts"]["depthguard-lab"] == "depthguard_lab.cli:main"


KNOWN_SOLIDS_WITHOUT_OPENGL = """
import importlib.abc, sys

class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] == "moderngl":
            raise ModuleNotFoundError("No module named 'moderngl' (no OpenGL here)")
        return None

sys.meta_path.insert(0, Block())
import numpy as np
import depthguard as dg
from depthguard.scenes import Box, render_depth
from depthguard.transforms import look_at

camera = dg.PinholeCamera("cam", 160, 120, 131.25, 131.25, 79.5, 59.5, look_at([2.0, 0.0, 1.2], [0.0, 0.0, 0.0]),
                          depth_range=(0.3, 6.0))
floor = Box.from_bounds([-3, -3, -0.1], [3, 3, 0.0])
frame = dg.depth_image(render_depth(camera, [floor]), camera)
plain = dg.DistanceMonitor(dg.Rig({"cam": camera})).query({"cam": frame}, [[0.0, 0.0, 0.3]])
known = dg.DistanceMonitor(dg.Rig({"cam": camera}), static=[floor]).query({"cam": frame}, [[0.0, 0.0, 0.3]])
assert known.distance[0] > plain.distance[0] + 0.05, (plain.distance, known.distance)
assert "moderngl" not in sys.modules
print("ok")
"""


def test_known_solids_need_no_opengl():
    """A known static solid is pure geometry (each pixel's ray against the box): a monitor with known solids and
    no robot answers where moderngl cannot even be imported, and the floor stops being an obstacle."""
    run = subprocess.run([sys.executable, "-c", KNOWN_SOLIDS_WITHOUT_OPENGL], capture_output=True, text=True,
                         timeout=600)
    assert run.returncode == 0 and run.stdout.strip() == "ok", run.stderr[-3000:]


def test_a_fresh_virtual_environment_with_the_library_alone_answers_a_fused_query(two_cameras, tmp_path):
    """The deployment install itself: a new virtual environment (no site packages of this one), ``pip install .``
    from the package registries (pip's cache makes it quick after ./dev.sh), and its own ``depthguard distance`` on
    two cameras: the same answers as this process gives. What pip installed there, every dependency resolved by pip
    itself transitively, holds the library's own (numpy, numba, pin) and no physics engine, plotting library,
    progress bars, the lab, open3d or torch. The kernels run as plain Python there (``NUMBA_DISABLE_JIT=1``:
    compiling them afresh would add a minute to the suite; the kernel-cache tests compile in fresh processes), which
    gives the same numbers bit for bit."""
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    python = venv / "bin" / "python"
    # From a copy of the sources: pip builds in the tree, and a stale build/ folder there would go into the wheel.
    source = tmp_path / "source"
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(".git", ".venv", "build", "out", "*.egg-info",
                                                                 "__pycache__", "lab", "tests", "benchmarks"))
    install = subprocess.run([str(python), "-m", "pip", "install", "--quiet", str(source)], capture_output=True,
                             text=True, timeout=1200)
    assert install.returncode == 0, install.stderr[-3000:]
    listed = subprocess.run([str(python), "-m", "pip", "list", "--format=json"], capture_output=True, text=True,
                            timeout=300, check=True)
    names = {item["name"].lower() for item in json.loads(listed.stdout)}
    assert "depthguard" in names and {"numpy", "numba", "pin"} <= names, names
    assert not names & {"pybullet", "matplotlib", "tqdm", "depthguard-lab", "open3d", "torch"}, names
    folder = two_cameras
    argv = ["distance", "--rig", folder / "rig.yaml", "--depth", f"left={folder / 'left.npy'}",
            "--depth", f"right={folder / 'right.npy'}", "--points", folder / "points.json", "--json"]
    env = {"PATH": str(venv / "bin"), "HOME": str(tmp_path), "NUMBA_DISABLE_JIT": "1"}
    run = subprocess.run([str(venv / "bin" / "depthguard"), *map(str, argv)], capture_output=True, text=True,
                         timeout=1200, cwd=tmp_path, env=env)
    assert run.returncode == 0, run.stderr[-3000:]
    answers = json.loads(run.stdout)
    rig = dg.load_rig(folder / "rig.yaml")
    frames = {name: dg.load_depth(folder / f"{name}.npy", rig.cameras[name]) for name in rig.cameras}
    expected = dg.DistanceMonitor(rig).query(frames, np.array(json.loads((folder / "points.json").read_text())))
    assert [a["distance"] for a in answers] == expected.distance.tolist()
    assert [a["flags"] for a in answers] == [f.names for f in expected.flags]
