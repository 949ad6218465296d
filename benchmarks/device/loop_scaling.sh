#!/bin/bash
# The closed loop's distance queries per set (bench_loop_queries.py) on a 16-core machine (the project's lent device
# machine, no package registry) at NUMBA_NUM_THREADS = 16, 4 and 2. Run from the repository root as
# `bash benchmarks/device/loop_scaling.sh`, with $OUT a folder for the outputs and the folders .gl/ and .devsite/ of
# benchmarks/device/thread_scaling.sh beside the sources. Not run yet (no machine was lent when it was written): its
# outputs are to go to docs/figures/loop_queries_16_cores.md.
set -u
source benchmarks/device/_env.sh
# the first run compiles the kernels (an empty cache); the figures come from the runs after it
NUMBA_NUM_THREADS=16 timeout 300 python3 benchmarks/bench_loop_queries.py --sets 2 > $OUT/compile.txt 2>&1; echo "compile rc $? $(( $(date +%s) - T0 )) s"
tail -3 $OUT/compile.txt
for t in 16 4 2; do NUMBA_NUM_THREADS=$t timeout 150 python3 benchmarks/bench_loop_queries.py --sets 12 > $OUT/loop$t.txt 2>&1; echo "loop$t rc $? $(( $(date +%s) - T0 )) s"; tail -6 $OUT/loop$t.txt; done
