"""Ready in seconds (issue 12): compile time of every kernel from an empty cache, the warm-up when everything is
cached, and the first answers of new processes after the warm-up.

It copies the committed package (``git archive HEAD``: no numba caches, as a fresh clone) into a temporary folder and
runs it from there with this virtual environment, each step a new process:

1. ``depthguard warmup`` with an empty cache: what ``./dev.sh setup`` does after a fresh clone (compile time of all
   kernels, and the slowest ones), after the baseline in the same run: the same in one process (``--processes 1``,
   as the warm-up compiled before it used a process per core);
2. ``depthguard warmup`` again: what every later ``./dev.sh`` command pays;
3. ``depthguard simulate`` writes a short recording of scenario B (two cameras, the iiwa);
4. ``depthguard distance`` on its first frame, one camera and then both fused, with the robot filtered out: seconds
   from the process's start to its answer.

    .venv/bin/python benchmarks/bench_cold_start.py [--without-warmup] [--llvm-opt N]

``--without-warmup`` also times the first answers from an empty cache (what the first query costs when nothing was
compiled ahead: minutes). ``--llvm-opt N`` also times the baseline with LLVM's optimisation level N (numba's
``NUMBA_OPT``, 3 by default; 0-3), after it in the same run: how much of the compile time is LLVM's.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from _common import report

REPO = Path(__file__).resolve().parents[1]


def run(argv, cwd, label, module="depthguard.cli", env=None):
    """Run ``python -m MODULE ARGV`` (the library's command line, or the lab's, ``depthguard_lab.cli``) from the
    copy, with ``env`` (dict) added to the environment; (wall seconds, CPU seconds, stdout)."""
    env = dict(os.environ, PYTHONPATH=str(cwd), **(env or {}))
    env.pop("NUMBA_CACHE_DIR", None)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", module, *map(str, argv)], cwd=cwd, env=env,
                          capture_output=True, text=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        sys.exit(f"{label} failed ({done.returncode}):\n{done.stderr[-3000:]}")
    cpu = after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime
    return wall, cpu, done.stdout


def fresh_copy(folder: Path) -> Path:
    folder.mkdir(parents=True)
    archive = subprocess.run(["git", "-C", str(REPO), "archive", "HEAD", "depthguard"], capture_output=True,
                             check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive, check=True)
    return folder


def first_answers(copy: Path, sim: Path):
    joints = (sim / "joint_states.csv").read_text().splitlines()[1].split(",", 1)[1]
    points = copy / "points.csv"
    points.write_text("x,y,z\n0.5,0.0,1.0\n0.3,0.2,0.8\n")
    base = ["distance", "--rig", sim / "rig.yaml", "--depth", f"principal={sim / 'depth/principal/000000.png'}",
            "--points", points, "--robot", "iiwa", "--joints", joints, "--json"]
    single = run(base, copy, "single camera")
    fused = run(base + ["--depth", f"second={sim / 'depth/second/000000.png'}"], copy, "fused")
    return single, fused


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--without-warmup", action="store_true", help="also time the first answers from an empty "
                                                                      "cache")
    parser.add_argument("--llvm-opt", type=int, choices=range(4), help="also the baseline at this NUMBA_OPT")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="depthguard-cold-") as tmp:
        tmp = Path(tmp)
        sim = tmp / "sim"
        rows = []
        if args.without_warmup:
            cold = fresh_copy(tmp / "cold")
            run(["simulate", "--out", sim, "--duration", "0.1"], cold, "simulate", "depthguard_lab.cli")
            for p in cold.rglob("*.nb[ic]"):
                p.unlink()
            (s_wall, s_cpu, _), (f_wall, f_cpu, _) = first_answers(cold, sim)
            rows += [("first single-camera answer, empty cache, no warm-up", s_wall, s_cpu),
                     ("then the first fused answer, no warm-up", f_wall, f_cpu)]
        baseline = fresh_copy(tmp / "baseline")
        wall, cpu, _ = run(["warmup", "--processes", "1"], baseline, "warmup in one process")
        rows.append(("baseline: warmup --processes 1, empty cache", wall, cpu))
        if args.llvm_opt is not None:
            wall, cpu, _ = run(["warmup", "--processes", "1"], fresh_copy(tmp / "opt"), "warmup at another NUMBA_OPT",
                               env={"NUMBA_OPT": str(args.llvm_opt)})
            rows.append((f"the same at NUMBA_OPT={args.llvm_opt} (LLVM's optimisation; 3 above)", wall, cpu))
        copy = fresh_copy(tmp / "clone")
        wall, cpu, out = run(["warmup"], copy, "warmup")
        rows.append((f"depthguard warmup, empty cache ({os.cpu_count()} cores; x{rows[-1][1] / wall:.2f} faster)",
                     wall, cpu))
        slowest = [line for line in out.splitlines() if re.match(r"\s+[\d.]+ s\s+depthguard\.", line)]
        summary = next(line for line in out.splitlines() if "kernel signatures in" in line)
        wall, cpu, _ = run(["warmup"], copy, "warmup again")
        rows.append(("depthguard warmup, everything cached", wall, cpu))
        if not sim.exists():
            run(["simulate", "--out", sim, "--duration", "0.1"], copy, "simulate", "depthguard_lab.cli")
        (s_wall, s_cpu, _), (f_wall, f_cpu, _) = first_answers(copy, sim)
        rows += [("first single-camera answer after the warm-up (new process)", s_wall, s_cpu),
                 ("first fused answer after the warm-up (new process)", f_wall, f_cpu)]
    print(f"{'step':64s} {'wall s':>7s} {'CPU s':>7s}")
    for label, wall, cpu in rows:
        print(f"{label:64s} {wall:7.1f} {cpu:7.1f}")
    print(f"\n{summary.strip()}")
    for line in slowest:
        print(line)
    print("\nGoals: each first answer within 5 s of the process's start; every kernel compiled within 30 s.")


if __name__ == "__main__":
    with report(__file__):
        main()
