"""A damaged or unwritable numba kernel cache never stops an answer (``depthguard.kernels.jit``): a cache file that cannot
be read is compiled afresh, a cache that cannot be written or a missing cache folder leaves the kernels running
uncached, each with one warning line.

Each case runs a fresh interpreter on one small kernel (the frustum distance: about two seconds to compile) with a
cache folder of its own, never the checkout's."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import depthguard as dg

PACKAGE = Path(dg.__file__).parent
QUERY = ("import json, depthguard as dg; "
         "d, p = dg.frustum_distance([0.0, 0.0, 0.2], [[-0.1, 0.1, -0.1, 0.1]], [0.5, 2.0]); "
         "print(json.dumps([dg.__file__, d.tolist(), p.tolist()]))")
#: The point is 0.3 m in front of the frustum's near plane (z = 0.5), on its axis.
ANSWER = [[0.3], [[0.0, 0.0, 0.5]]]
KERNEL = "depthguard.kernels.frustum.frustum_nearest_many"


def run(code: str, env: dict, cwd) -> tuple[list, list[str]]:
    """Run ``code`` (which prints the query's answer) in a fresh interpreter: its answer and its lines on standard
    error."""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env,
                          cwd=cwd)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1]), done.stderr.strip().splitlines()


def own_cache(folder: Path) -> dict:
    return dict(os.environ, NUMBA_CACHE_DIR=str(folder), PYTHONDONTWRITEBYTECODE="1")


@pytest.fixture(scope="module")
def cached(tmp_path_factory):
    """A cache folder holding the query's kernels, as a first run leaves it."""
    folder = tmp_path_factory.mktemp("cache")
    answer, _ = run(QUERY, own_cache(folder), folder)
    assert answer[1:] == ANSWER
    assert sorted(p.suffix for p in folder.rglob("*.nb?")) == [".nbc", ".nbc", ".nbi", ".nbi"]
    return folder


def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[:len(path.read_bytes()) // 2])


@pytest.mark.parametrize("pattern", ["*.nbc", "*.nbi"], ids=["data", "index"])
def test_a_truncated_cache_file_is_compiled_afresh_with_one_warning(cached, tmp_path, pattern):
    folder = tmp_path / "cache"
    shutil.copytree(cached, folder)
    damaged = sorted(folder.rglob(pattern))
    assert len(damaged) == 2  # the query's kernel and the kernel it calls
    for path in damaged:
        _truncate(path)
    answer, lines = run(QUERY, own_cache(folder), tmp_path)
    assert answer[1:] == ANSWER
    assert len(lines) == 1, lines
    assert KERNEL in lines[0] and "cannot be read" in lines[0] and "frustum" in lines[0], lines[0]
    # ... and written afresh: the next process loads it, silently.
    answer, lines = run(QUERY, own_cache(folder), tmp_path)
    assert answer[1:] == ANSWER and lines == []


def test_no_writable_cache_folder_runs_uncached_with_one_warning(tmp_path):
    """A read-only install: no __pycache__ beside the sources, NUMBA_CACHE_DIR and the user's cache folder cannot be
    made (root ignores permissions, so each is a path under a regular file). numba finds no place for the caches;
    the kernels run uncached, with one warning line."""
    site = tmp_path / "site"
    shutil.copytree(PACKAGE, site / "depthguard", ignore=shutil.ignore_patterns("__pycache__"))
    for folder in [site / "depthguard", *(p for p in (site / "depthguard").rglob("*") if p.is_dir())]:
        (folder / "__pycache__").write_bytes(b"")
    blocker = tmp_path / "blocker"
    blocker.write_bytes(b"")
    env = dict(os.environ, PYTHONPATH=str(site), PYTHONDONTWRITEBYTECODE="1", NUMBA_CACHE_DIR=str(blocker / "numba"),
               XDG_CACHE_HOME=str(blocker / "cache"))
    answer, lines = run(QUERY, env, tmp_path)
    assert answer[0] == str(site / "depthguard" / "__init__.py") and answer[1:] == ANSWER
    assert len(lines) == 1, lines
    assert "no writable folder for the numba kernel caches" in lines[0] and "NUMBA_CACHE_DIR" in lines[0]
    assert not list(tmp_path.rglob("*.nb?"))  # nothing cached anywhere: the next process compiles again


WRITE_FAILS = """
import errno
from numba.core import caching

def full(self, *args):
    raise OSError(errno.ENOSPC, "No space left on device")

caching.IndexDataCacheFile._save_index = caching.IndexDataCacheFile._save_data = full
""" + QUERY.replace("; ", "\n")


def test_a_cache_that_cannot_be_written_leaves_the_kernel_compiled(tmp_path):
    """A full disk when the compiled kernel is saved: the answer comes, with the compile's line and one more."""
    answer, lines = run(WRITE_FAILS, own_cache(tmp_path / "cache"), tmp_path)
    assert answer[1:] == ANSWER
    assert len(lines) == 2, lines
    assert KERNEL in lines[0] and "not in the cache" in lines[0]
    assert "cannot write the cache of numba kernel" in lines[1] and "No space left on device" in lines[1]
