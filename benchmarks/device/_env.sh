# Sourced by the device scripts (benchmarks/device/*.sh), from the repository root: unpacks .gl/ (EGL for moderngl on
# the NVIDIA driver) and .devsite/ (the packages the device lacks), sets PYTHONPATH to the sources, and prints the
# machine, the libraries and the OpenGL renderer; $OUT/lscpu.txt holds lscpu. T0: the start, for elapsed times.
for f in .gl/*.deb; do dpkg -x $f /; done; ldconfig
mkdir -p /tmp/site && tar -xJf .devsite/site312.tar.xz -C /tmp/site
export PYTHONPATH=$PWD:$PWD/lab:$PWD/.devsite:/tmp/site:/tmp/site/cmeel.prefix/lib/python3.12/site-packages
export NUMBA_CACHE_DIR=/tmp/nc PYTHONUNBUFFERED=1
[ -e /usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json ] && export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
nproc; lscpu > $OUT/lscpu.txt; grep -m1 "model name" /proc/cpuinfo
python3 -c "import numba, numpy, scipy; print('numba', numba.__version__, 'numpy', numpy.__version__, 'scipy', scipy.__version__)"
python3 -c "from depthguard.rendering import Renderer; r = Renderer(); print('GL', r._gl.renderer_name)" 2>&1 | tail -3
T0=$(date +%s)
