"""How depthguard's numba kernels are compiled and cached.

Every kernel is decorated with :func:`kernel`: numba's ``njit`` with ``cache=True``, so that a kernel compiles once
and later processes load it from ``__pycache__/*.nbi|*.nbc`` beside its source.

- Stale caches. numba reuses a kernel's cache while its own source file is unchanged. A kernel also holds the code
  of the kernels it calls from other modules (the depth grid's kernels call the single camera's), and numba does not
  track those. Here the caches of a kernel module are stamped with the contents of its own source, of every kernel
  module it imports, and of this file (the compile options): a change in any of them recompiles it, never leaves
  old code running.
- Compiling at run time. A kernel missing from the cache (the first run after an install or an upgrade) compiles
  on its first call, which takes from a second to half a minute. Each such compile logs one warning line on the
  ``depthguard`` logger (standard error unless configured) that names the kernel. ``depthguard warmup``
  (:mod:`depthguard.warmup`) compiles every kernel ahead of time; ``./dev.sh setup`` runs it.
- A damaged cache. A cache file that cannot be read (truncated by a full disk, garbled) is a cache miss: the kernel
  compiles, the file is written afresh, and the compile's warning line names the cache and why it was not used. A
  cache that cannot be written leaves the kernel compiled for this process, with one warning.
- No writable cache folder (a read-only install, no writable ``NUMBA_CACHE_DIR`` or user cache folder): the kernels
  run uncached, compiling on their first call in every process, and one warning says so when they are defined.
"""

from __future__ import annotations

import ast
import functools
import hashlib
import logging
import os
from pathlib import Path

import numba
from numba.core import caching, event
from numba.core.dispatcher import Dispatcher

#: The modules that define numba kernels, each decorated with :func:`kernel`.
KERNEL_MODULES = (
    "depthguard.baselines",
    "depthguard.kernels.capsules",
    "depthguard.kernels.collision",
    "depthguard.kernels.collision_plan",
    "depthguard.kernels.collision_update",
    "depthguard.kernels.depth",
    "depthguard.kernels.depthgrid",
    "depthguard.kernels.depthspace",
    "depthguard.kernels.detectable",
    "depthguard.kernels.freespace",
    "depthguard.kernels.frustum",
)

_PACKAGE = Path(__file__).resolve().parent.parent  # the depthguard package
_LOG = logging.getLogger("depthguard")


def kernel(*, parallel: bool = False, inline: bool = False, error_model: str = "numpy", refcounts: bool = True):
    """numba's ``njit`` as every depthguard kernel uses it: cached on disk, stamped with the sources it depends on,
    and a warning when it compiles at run time.

    Every kernel releases the GIL while it runs (``nogil``): a thread that receives frames (``LiveMonitor``'s
    caller, a ROS or zenoh callback) runs while another prepares a set (``benchmarks/bench_gil.py``). A kernel
    touches no Python object; what two threads may run at once is settled above the kernels (a ``PreparedSet``
    does not change when the next is prepared; ``LiveMonitor`` serialises kernels under numba's workqueue threading
    layer, which cannot run two parallel regions at once).

    ``inline``: numba copies the function's body into each caller instead of compiling it on its own. Each kernel
    compiled on its own costs about half a second, and its code is compiled again into every kernel that calls it,
    so small helpers and functions with one caller are inlined; larger functions with several callers are not
    (a body inlined into several callers, each inlined into several more, multiplies: that once took a minute and
    a half). LLVM still inlines small functions into their callers when it optimises.

    ``refcounts=False``: numba compiles the kernel without reference counting (its ``_nrt=False``). Every array a
    kernel takes, and every view it makes, is then used without counting: sound only for a kernel that allocates
    nothing and returns no array, which numba enforces (such a kernel fails to compile: ``tests/test_warmup.py``);
    its caller holds every array it passes for the whole call. The fused query's
    kernels called per pixel, walk or run (``depthgrid.classify_run`` and the walks above it) are compiled so: with
    counting, each call counted every array of the depth grid's record up and down again (23 increments on
    ``classify_run``'s entry alone), atomic operations that the query's threads contend on, and the first fused
    query took 1.7 times as long (``docs/design.md``, "A new set inside a camera period").
    """
    _install()
    options = {} if refcounts else {"_nrt": False}
    jit = numba.njit(parallel=parallel, error_model=error_model, inline="always" if inline else "never", nogil=True,
                     **options)

    def decorate(py_func):
        dispatcher = jit(py_func)
        if isinstance(dispatcher, Dispatcher):  # not with NUMBA_DISABLE_JIT=1, which returns py_func
            _enable_cache(dispatcher)
        return dispatcher

    return decorate


def module_file(name: str) -> Path:
    """The source file of depthguard module ``name`` (``depthguard.a.b`` -> ``.../depthguard/a/b.py``)."""
    return _PACKAGE.joinpath(*name.split(".")[1:]).with_suffix(".py")


def kernel_dependencies(name: str) -> tuple[str, ...]:
    """The kernel modules whose code kernel module ``name`` holds once compiled: itself and every kernel module it
    imports, transitively (sorted)."""
    found = set()
    todo = [name]
    while todo:
        module = todo.pop()
        if module in found:
            continue
        found.add(module)
        path = module_file(module)
        todo.extend(_imported_kernel_modules(str(path), *_mtime_size(path)))
    return tuple(sorted(found))


@functools.lru_cache(maxsize=None)
def _imported_kernel_modules(path: str, mtime_ns: int, size: int) -> tuple[str, ...]:
    """The kernel modules that file ``path`` imports; memoised on its modification time and size."""
    tree = ast.parse(Path(path).read_bytes(), filename=path)
    names = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.append(node.module)
            names.extend(f"{node.module}.{alias.name}" for alias in node.names)
        elif isinstance(node, ast.Import):
            names.extend(alias.name for alias in node.names)
    return tuple(n for n in names if n in KERNEL_MODULES)


def sources_stamp(path) -> bytes:
    """The stamp of kernel module file ``path``'s caches: a SHA-256 over its source, the sources of the kernel
    modules it imports (:func:`kernel_dependencies`) and this file's."""
    path = Path(path).resolve()
    name = "depthguard." + ".".join(path.relative_to(_PACKAGE).with_suffix("").parts)
    files = [module_file(m) for m in kernel_dependencies(name)] + [Path(__file__).resolve()]
    return _digest(tuple((str(f), *_mtime_size(f)) for f in files))


def _mtime_size(path: Path) -> tuple[int, int]:
    st = os.stat(path)
    return st.st_mtime_ns, st.st_size


@functools.lru_cache(maxsize=None)
def _digest(files: tuple) -> bytes:
    """SHA-256 over the files' contents; memoised on their paths, modification times and sizes."""
    h = hashlib.sha256()
    for path, _, _ in files:
        h.update(path.encode().rsplit(b"/depthguard/", 1)[-1])
        h.update(Path(path).read_bytes())
    return h.digest()


def _is_kernel_file(py_file) -> bool:
    try:
        path = Path(py_file).resolve()
        relative = path.relative_to(_PACKAGE)
    except (OSError, ValueError):
        return False
    return "depthguard." + ".".join(relative.with_suffix("").parts) in KERNEL_MODULES


def _stamped(locator_class):
    """A subclass of one of numba's cache locators that serves depthguard's kernel modules only and stamps their
    caches with :func:`sources_stamp` instead of the file's own contents."""

    class Stamped(locator_class):
        def get_source_stamp(self):
            return sources_stamp(self._py_file)

        @classmethod
        def from_function(cls, py_func, py_file):
            if not _is_kernel_file(py_file):
                return None
            return super().from_function(py_func, py_file)

    Stamped.__name__ = Stamped.__qualname__ = "Depthguard" + locator_class.__name__.lstrip("_")
    return Stamped


class _GuardedCache(caching.FunctionCache):
    """numba's on-disk cache of one kernel, which a damaged file never stops: a cache that cannot be read is a cache
    miss (the compile notice then says why), and one that cannot be written leaves the kernel compiled for this
    process (one warning)."""

    def load_overload(self, sig, target_context):
        try:
            return super().load_overload(sig, target_context)
        except Exception as exc:  # noqa: BLE001 - whatever unpickling or rebuilding a damaged file raises
            _NOTICE.unreadable[self._py_func] = f"its cache in {self.cache_path} cannot be read ({_one_line(exc)})"
            return None

    def save_overload(self, sig, data):
        try:
            super().save_overload(sig, data)
        except Exception:  # noqa: BLE001 - an unreadable index cannot take a new entry: start it afresh
            try:
                self.flush()
                super().save_overload(sig, data)
            except Exception as exc:  # noqa: BLE001 - an unwritable folder, a full disk
                if "unwritable" not in _warned:
                    _warned.add("unwritable")
                    _LOG.warning("depthguard: cannot write the cache of numba kernel %s in %s (%s): it compiles "
                                 "again in every new process", _kernel_name(self._py_func), self.cache_path,
                                 _one_line(exc))


def _enable_cache(dispatcher) -> None:
    """Cache ``dispatcher`` on disk, as numba's ``Dispatcher.enable_caching`` does, in a :class:`_GuardedCache`.
    Where no folder can hold the cache (numba raises "no locator available"), the kernel runs uncached, and the first
    such kernel of the process logs one warning."""
    try:
        dispatcher._cache = _GuardedCache(dispatcher.py_func)
    except (RuntimeError, OSError) as exc:
        _NOTICE.uncached.add(dispatcher.py_func)
        if "uncached" not in _warned:
            _warned.add("uncached")
            _LOG.warning("depthguard: no writable folder for the numba kernel caches (%s): depthguard's kernels run "
                         "uncached, compiling on their first call in every process. Set NUMBA_CACHE_DIR to a writable "
                         "folder and run `depthguard warmup`.", _one_line(exc))


def _kernel_name(py_func) -> str:
    return f"{py_func.__module__}.{py_func.__qualname__}"


def _one_line(exc: Exception) -> str:
    text = " ".join(str(exc).split())[:200]
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


class _CompileNotice(event.Listener):
    """Logs a warning when a depthguard kernel compiles (it was not in the cache, or its cache could not be read);
    nested compiles of the kernels it calls are part of the same one. An uncached kernel compiles without one (the
    warning that no cache folder is writable said so)."""

    def __init__(self):
        self.depth = 0
        self.quiet = 0  # > 0 while depthguard warmup compiles on purpose
        self.unreadable = {}  # kernel (py_func) -> where its cache is and why it could not be read, until it compiles
        self.uncached = set()  # kernels (py_func) without a cache folder

    def on_start(self, ev):
        self.depth += 1
        dispatcher = ev.data["dispatcher"]
        unreadable = self.unreadable.pop(dispatcher.py_func, None)
        if self.depth > 1 or self.quiet or dispatcher.py_func in self.uncached:
            return
        module = getattr(dispatcher.py_func, "__module__", "") or ""
        if module.split(".")[0] != "depthguard":
            return
        if unreadable is not None:
            _LOG.warning("depthguard: compiling numba kernel %s: %s; it is written afresh once compiled.",
                         _kernel_name(dispatcher.py_func), unreadable)
            return
        _LOG.warning("depthguard: compiling numba kernel %s.%s (not in the cache: first run after an install or an "
                     "upgrade; it is cached once compiled). `depthguard warmup` compiles every kernel ahead of time.",
                     module, dispatcher.py_func.__qualname__)

    def on_end(self, ev):
        self.depth -= 1


_NOTICE = _CompileNotice()
_installed = False
_warned: set[str] = set()  # the warnings given once per process: "uncached" (no cache folder), "unwritable"


def _install() -> None:
    """Register the stamped cache locators and the compile notice, once per process."""
    global _installed
    if _installed:
        return
    _installed = True
    event.register("numba:compile", _NOTICE)
    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)
    classes = getattr(impl, "_locator_classes", None)
    if classes is None:
        _LOG.warning("depthguard: this numba version's cache locators are unknown to depthguard: kernel caches are "
                     "stamped with their own source only")
        return
    # numba's own order: a cache folder the user chose, __pycache__ beside the source, a per-user folder.
    ours = []
    for name in ("UserProvidedCacheLocator", "InTreeCacheLocator", "UserWideCacheLocator"):
        base = getattr(caching, name, None) or getattr(caching, "_" + name, None)
        if base is not None:
            ours.append(_stamped(base))
    classes[:0] = ours


def uncached_kernels() -> int:
    """How many kernels defined so far run uncached (no writable folder for their caches)."""
    return len(_NOTICE.uncached)


class quiet_compiles:
    """Within this context, kernels compile without the run-time warning (``depthguard warmup`` reports them)."""

    def __enter__(self):
        _NOTICE.quiet += 1
        return self

    def __exit__(self, *exc):
        _NOTICE.quiet -= 1
        return False
