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
for f in .gl/*.deb; do dpkg -x $f /; done; ldconfig
mkdir -p /tmp/site && tar -xJf .devsite/site312.tar.xz -C /tmp/site
export PYTHONPATH=$PWD:$PWD/lab:$PWD/.devsite:/tmp/site:/tmp/site/cmeel.prefix/lib/python3.12/site-packages
export NUMBA_CACHE_DIR=/tmp/nc PYTHONUNBUFFERED=1
[ -e /usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json ] && export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
nproc; lscpu > $OUT/lscpu.txt; grep -m1 "model name" /proc/cpuinfo
python3 -c "import numba, numpy, scipy; print('numba', numba.__version__, 'numpy', numpy.__version__, 'scipy', scipy.__version__)"
python3 -c "from depthguard.rendering import Renderer; r = Renderer(); print('GL', r._gl.renderer_name)" 2>&1 | tail -3
T0=$(date +%s)
NUMBA_NUM_THREADS=16 timeout 200 python3 benchmarks/bench_frame_budget.py --only budget --repeats 15 > $OUT/budget16.txt 2>&1; echo "budget16 rc $? $(( $(date +%s) - T0 )) s"
tail -30 $OUT/budget16.txt
for t in 16 1 4; do NUMBA_NUM_THREADS=$t timeout 120 python3 benchmarks/bench_detectable_space.py --sets 12 > $OUT/detect$t.txt 2>&1; echo "detect$t rc $? $(( $(date +%s) - T0 )) s"; done
tail -14 $OUT/detect16.txt; tail -14 $OUT/detect1.txt
for t in 4 8; do NUMBA_NUM_THREADS=$t timeout 90 python3 benchmarks/bench_frame_budget.py --only budget --repeats 10 > $OUT/budget$t.txt 2>&1; echo "budget$t rc $? $(( $(date +%s) - T0 )) s"; done
NUMBA_NUM_THREADS=16 timeout 90 python3 benchmarks/bench_frame_budget.py --only shadow > $OUT/shadow16.txt 2>&1; echo "shadow rc $? $(( $(date +%s) - T0 )) s"
