"""A/B of the library against an earlier commit: the same answers, and the time they take, on the same recorded frames.

The lab records scenario B's reach scene (four cameras, or with ``--cameras 2`` its own two; the person reaching in)
once; then the library of each side (``--base``, a commit, checked out into a temporary folder; and this working
tree) answers the same queries on the same frames in a fresh process of its own, one side after the other: the
control points of the robot, fused, self-filtered, with the memory, in four configurations (the defaults; the ``min``
aggregate, which ``live`` and ``replay`` ask since 2026-11-29; a robot zone with hole fills; known solids).
It prints per configuration whether the distances agree bit for bit (else how far apart and where), and the median
time per set (preparation and the first query) of each side with their ratio, and of the later queries on each set
(15, the robot moving 2 mrad a query, as a controller between two sets; their answers are compared too). Both sides
compile their kernels first (a warm-up query on the first set, not timed).

    .venv/bin/python benchmarks/ab_answers.py --base 73482fc [--sets 10] [--cameras 2]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from _common import report

REPO = Path(__file__).resolve().parents[1]

#: The configurations asked of both sides (DistanceMonitor keyword arguments; "static" means the scene's known
#: background as boxes).
CONFIGURATIONS = {
    "defaults": {},
    "min (live's and replay's default)": {"aggregate": "min"},
    "robot zone 6 cm, hole fills": {"robot_zone": 0.06, "invalid": "neighbors"},
    "known solids": {"static": True},
}

WORKER = r"""
import json, sys, time
import numpy as np
LATER = 15
import depthguard as dg
from depthguard.robots import RobotModel
from depthguard.scenes import Box

folder = sys.argv[1]
data = np.load(folder + "/frames.npz")
rig = dg.load_rig(folder + "/rig.yaml")
meta = json.load(open(folder + "/meta.json"))
robot = RobotModel.default()
boxes = [Box(tuple(b["center"]), tuple(b["half_extents"]), np.array(b["R"])) for b in meta["static"]]
out = {}
for label, options in meta["configurations"].items():
    options = dict(options)
    if options.pop("static", False):
        options["static"] = boxes
    monitor = dg.DistanceMonitor(rig, rho=0.4, robot=robot, **options)
    distances, seconds, later = [], [], []
    for k, t in enumerate(meta["times"]):
        frames = {name: dg.depth_image(data[f"{name}_{k}"], rig.cameras[name], timestamp=t) for name in rig.cameras}
        q = data[f"joints_{k}"]
        points = robot.control_point_positions(q)
        start = time.perf_counter()
        prepared = monitor.prepare_set(frames, joints=q, now=t)
        result = prepared.query(points)
        seconds.append(time.perf_counter() - start)
        distances.append(result.distance.tolist())
        for step in range(1, LATER + 1):  # the controller between two sets: the robot moving 2 mrad a query
            moved = robot.control_point_positions(q + 0.002 * step)
            start = time.perf_counter()
            result = prepared.query(moved)
            if k:
                later.append(time.perf_counter() - start)
            distances.append(result.distance.tolist())
    out[label] = {"distances": distances, "seconds": seconds[1:], "later": later}  # set 0 compiled what it needed
out["__file__"] = dg.__file__
json.dump(out, sys.stdout)
"""


def record(folder: Path, sets: int, cameras: int = 4) -> None:
    """Scenario B's reach scene with four cameras (or its own two): ``sets`` sets of frames from 1.2 s to 3.4 s,
    written to ``folder`` (rig.yaml, frames.npz, meta.json)."""
    from importlib import resources

    import depthguard as dg
    from depthguard_lab.simulation import load_workcell
    from depthguard_lab.simulation._episode import sense_at

    package = resources.files("depthguard_lab.simulation")
    workcell = load_workcell(Path(str(package / "scenario_b_reach.yaml")),
                             layout=Path(str(package / "scenario_b_four.yaml")) if cameras == 4 else None)
    dg.save_rig(workcell.rig, folder / "rig.yaml")
    arrays, times = {}, []
    for k, frame in enumerate(sense_at(workcell, list(np.linspace(1.2, 3.4, sets)))):
        for name, image in frame.depth.items():
            arrays[f"{name}_{k}"] = image.data
        arrays[f"joints_{k}"] = frame.joints
        times.append(float(frame.time))
    np.savez(folder / "frames.npz", **arrays)
    static = [{"center": list(map(float, b.center)), "half_extents": list(map(float, b.half_extents)),
               "R": np.asarray(b.R_world_box, dtype=float).tolist()} for b in workcell.background_parts()]
    (folder / "meta.json").write_text(json.dumps({"times": times, "static": static,
                                                   "configurations": CONFIGURATIONS}))


def answers(library: Path, folder: Path) -> dict:
    """Run the worker with the library in ``library`` (a folder holding the package ``depthguard``)."""
    # Run from the library's folder: "-c" puts the working folder first on sys.path, ahead of the editable install's
    # finder (which would otherwise win over PYTHONPATH and answer with this tree on both sides).
    run = subprocess.run([sys.executable, "-c", WORKER, str(folder)], capture_output=True, text=True, cwd=library,
                         env={"PYTHONPATH": str(library), "PATH": "/usr/bin:/bin"}, timeout=3000)
    if run.returncode != 0:
        sys.exit(f"the library in {library} failed:\n{run.stderr[-3000:]}")
    side = json.loads(run.stdout)
    if Path(side.pop("__file__")).resolve().parent.parent != library.resolve():
        sys.exit(f"the worker did not import the library in {library}")
    return side


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", required=True, help="the commit to compare with (the code before the step)")
    parser.add_argument("--sets", type=int, default=10, help="sets of frames (default 10)")
    parser.add_argument("--cameras", type=int, choices=(2, 4), default=4, help="the scene's cameras (default 4)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="depthguard-ab-") as tmp:
        tmp = Path(tmp)
        frames = tmp / "frames"
        frames.mkdir()
        record(frames, args.sets, args.cameras)
        base = tmp / "base"
        base.mkdir()
        archive = subprocess.run(["git", "-C", str(REPO), "archive", args.base, "depthguard"], capture_output=True,
                                 check=True).stdout
        subprocess.run(["tar", "-x", "-C", str(base)], input=archive, check=True)
        sides = {"base": answers(base, frames), "this tree": answers(REPO, frames)}
    commit = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", args.base], capture_output=True,
                            text=True).stdout.strip()
    print(f"A/B: the library at {commit} (base) against this tree, scenario B's reach scene, "
          f"{args.cameras} cameras, {args.sets} sets, 9 control points, rho 0.4 m, robot filtered, memory on\n")
    print(f"{'configuration':36s} {'same distances':>16s} {'largest difference':>19s} {'base ms/set':>12s} "
          f"{'this ms/set':>12s} {'ratio':>6s} {'base later ms':>14s} {'this later ms':>14s} {'ratio':>6s}")
    for label in CONFIGURATIONS:
        a, b = (np.array(sides[side][label]["distances"]) for side in ("base", "this tree"))
        same = np.array_equal(a, b)
        finite = np.isfinite(a) & np.isfinite(b)
        diff = float(np.max(np.abs(a[finite] - b[finite]))) if finite.any() else 0.0
        mismatched = int(np.count_nonzero(np.isfinite(a) != np.isfinite(b)))
        t_a, t_b = (float(np.median(sides[side][label]["seconds"])) * 1e3 for side in ("base", "this tree"))
        l_a, l_b = (float(np.median(sides[side][label]["later"])) * 1e3 for side in ("base", "this tree"))
        shown = "yes" if same else f"no ({mismatched} inf/finite)" if mismatched else "no"
        print(f"{label:36s} {shown:>16s} {diff:19.3g} {t_a:12.1f} {t_b:12.1f} {t_b / t_a:6.2f} {l_a:14.2f} "
              f"{l_b:14.2f} {l_b / l_a:6.2f}")


if __name__ == "__main__":
    two = any(a == "--cameras=2" or (a == "--cameras" and sys.argv[i + 2:i + 3] == ["2"])
              for i, a in enumerate(sys.argv[1:]))
    with report(__file__, name="ab_answers_2_cameras" if two else None):
        main()
