#!/bin/bash
# Thread scaling of the per-set work on a 16-core machine that has no package registry (the project's lent device
# machine): bench_frame_budget (budget, shadow) and bench_detectable_space at NUMBA_NUM_THREADS = 1, 4, 8, 16.
# Run from the repository root as `bash benchmarks/device/thread_scaling.sh`, with $OUT a folder for the outputs and
# two folders beside the sources, made on a machine with the registries (both git-ignored, carried to the device):
#   .gl/      libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2 libvulkan1 (.deb, apt-get download): EGL for
#             moderngl on the NVIDIA driver;
#   .devsite/ site312.tar.xz: `pip install --target` of pin trimesh moderngl pydantic rosbags for CPython 3.12
#             (manylinux wheels, no numpy; headers and static libraries removed: 37 MB), and pybullet_data/ holding
#             only kuka_iiwa/ and an __init__.py whose getDataPath() returns its folder.
# The device's own numba, numpy and scipy are used; the sources run from the checkout (PYTHONPATH), not installed.
# Its outputs are kept in docs/figures/thread_scaling_16_cores.md.
set -u
source benchmarks/device/_env.sh
NUMBA_NUM_THREADS=16 timeout 200 python3 benchmarks/bench_frame_budget.py --only budget --repeats 15 > $OUT/budget16.txt 2>&1; echo "budget16 rc $? $(( $(date +%s) - T0 )) s"
tail -30 $OUT/budget16.txt
for t in 16 1 4; do NUMBA_NUM_THREADS=$t timeout 120 python3 benchmarks/bench_detectable_space.py --sets 12 > $OUT/detect$t.txt 2>&1; echo "detect$t rc $? $(( $(date +%s) - T0 )) s"; done
tail -14 $OUT/detect16.txt; tail -14 $OUT/detect1.txt
for t in 4 8; do NUMBA_NUM_THREADS=$t timeout 90 python3 benchmarks/bench_frame_budget.py --only budget --repeats 10 > $OUT/budget$t.txt 2>&1; echo "budget$t rc $? $(( $(date +%s) - T0 )) s"; done
NUMBA_NUM_THREADS=16 timeout 90 python3 benchmarks/bench_frame_budget.py --only shadow > $OUT/shadow16.txt 2>&1; echo "shadow rc $? $(( $(date +%s) - T0 )) s"
