#!/bin/bash
# The image-based collision test on a 16-core machine with a GPU (the project's lent device machine, no package
# registry): bench_collision.py (the 8,192-configuration table and the four-camera pipeline on scenario C, with and
# without robot_pixels) at NUMBA_NUM_THREADS = 16 and 2, the robot's renders on the GPU (OpenGL through EGL).
# Run from the repository root as `bash benchmarks/device/collision_scaling.sh`, with $OUT a folder for the outputs
# and the folders .gl/ and .devsite/ of benchmarks/device/thread_scaling.sh beside the sources; .devsite/pybullet_data/
# holds xarm/ (scenario C's xArm 6) beside kuka_iiwa/. Its outputs are kept in docs/figures/collision_16_cores.md.
set -u
source benchmarks/device/_env.sh
# the first run compiles the kernels (an empty cache); the figures come from the runs after it
NUMBA_NUM_THREADS=16 timeout 240 python3 benchmarks/bench_collision.py --repeats 5 > $OUT/compile.txt 2>&1; echo "compile rc $? $(( $(date +%s) - T0 )) s"
tail -5 $OUT/compile.txt
for run in 16 2 16b; do NUMBA_NUM_THREADS=${run%b} timeout 120 python3 benchmarks/bench_collision.py --repeats 30 > $OUT/collision$run.txt 2>&1; echo "collision$run rc $? $(( $(date +%s) - T0 )) s"; tail -13 $OUT/collision$run.txt; done
