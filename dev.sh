#!/usr/bin/env bash
# depthguard's one entry point for a fresh machine: it sets up everything it needs, then runs a job.
#
#   ./dev.sh demo    set up, then run the main job: the lab's built-in workcell in closed loop (plots + tables in
#                    out/demo)
#   ./dev.sh test    set up, then run the test suite (what CI runs), in two worker processes
#   ./dev.sh bench   set up, then run the benchmarks
#   ./dev.sh setup   only set up
#
# Setup: system packages (when missing, through apt-get), a virtual environment in .venv with the library
# (depthguard, this folder) and the lab beside it (depthguard-lab, ./lab) installed in editable mode with the test
# dependencies. It is skipped when neither pyproject.toml has changed since the last run.
# Then, every time, `depthguard warmup` compiles the numba kernels not cached yet (about a minute after a fresh clone
# or an upgrade of depthguard or numba; a few seconds when everything is cached), so that no query waits for them.
set -euo pipefail
cd "$(dirname "$0")"

# Debian packages the project needs at run time. Rendering (moderngl, headless EGL on Mesa's llvmpipe) opens
# libEGL.so.1 (libegl1, which pulls in Mesa's EGL, libegl-mesa0) and libGL.so.1 (libgl1), and Mesa's software
# rasteriser swrast_dri.so (libgl1-mesa-dri).
SYSTEM_PACKAGES=(libegl1 libgl1 libgl1-mesa-dri)

python_for_venv() {
  for candidate in python3.11 python3 python; do
    if command -v "$candidate" >/dev/null 2>&1 &&
       "$candidate" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)' 2>/dev/null; then
      echo "$candidate"
      return
    fi
  done
  echo "dev.sh: needs Python >= 3.11 on PATH" >&2
  exit 1
}

setup() {
  local missing=()
  for pkg in "${SYSTEM_PACKAGES[@]}"; do
    dpkg -s "$pkg" >/dev/null 2>&1 || missing+=("$pkg")
  done
  if [ ${#missing[@]} -gt 0 ]; then
    local sudo=""
    [ "$(id -u)" -eq 0 ] || sudo="sudo"
    echo "dev.sh: installing system packages: ${missing[*]}"
    $sudo apt-get update -qq && $sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
  fi
  if [ ! -x .venv/bin/python ]; then
    echo "dev.sh: creating .venv"
    "$(python_for_venv)" -m venv .venv
  fi
  local stamp=".venv/.depthguard-installed"
  local want
  want=$(cat pyproject.toml lab/pyproject.toml | sha256sum | cut -d' ' -f1)
  if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
    echo "dev.sh: installing depthguard and depthguard-lab with their dependencies into .venv (log: .venv/pip.log)"
    if ! { .venv/bin/python -m pip install --upgrade pip && .venv/bin/python -m pip install -e '.[test,live]' -e ./lab; } \
        > .venv/pip.log 2>&1; then
      tail -n 30 .venv/pip.log >&2
      echo "dev.sh: pip install failed (full log: .venv/pip.log)" >&2
      exit 1
    fi
    echo "$want" > "$stamp"
  fi
  .venv/bin/depthguard warmup
}

job="${1:-demo}"
shift || true
setup
case "$job" in
  setup) ;;
  demo) exec .venv/bin/depthguard-lab demo "$@" ;;
  # Two worker processes, each module's tests in one of them (its module-scoped set-ups made once); each worker
  # runs numba on one thread (tests/conftest.py).
  test) exec .venv/bin/python -m pytest -q -n 2 --dist loadscope "$@" ;;
  bench)
    for bench in benchmarks/bench_*.py; do
      echo "== $bench"
      .venv/bin/python "$bench" "$@"
    done ;;
  *) echo "usage: ./dev.sh [demo|test|bench|setup]" >&2; exit 2 ;;
esac
