"""Large per-set arrays reused from one set of frames to the next.

A set's row-minimum tables (12 MB a 640x480 camera), a watched detectable space's block arrays (2 bytes a voxel) and
the depth grid's cell classes (a byte a cell, 130 MB for a 640x480 principal, of which a set touches a few) are made
anew for every set. Above glibc's largest mmap threshold (32 MB) each such array is mapped afresh and every
page it touches faults in again, which on this project's machines cost 10-100 ms a set. :func:`reusable` hands out
an array that an earlier owner no longer holds (its contents are whatever that owner left: the caller writes before
it reads), and takes it back when its new owner is garbage collected.
"""

from __future__ import annotations

import threading
import weakref

import numpy as np

#: Spare arrays kept per (shape, dtype): a live monitor holds a set being queried and one being prepared.
SPARES = 3

_spares: dict[tuple, list[np.ndarray]] = {}
_generation: dict[tuple, int] = {}  # per kind, raised by drop_spares: arrays handed out before are not taken back
_lock = threading.Lock()


def _key(shape: tuple, dtype) -> tuple:
    """The kind of an array: (shape as ints, dtype string)."""
    return tuple(int(n) for n in shape), np.dtype(dtype).str


def reusable(shape: tuple, dtype, owner, new=np.empty) -> np.ndarray:
    """An uninitialised C-contiguous array of ``shape`` and ``dtype``, given back to the spares when ``owner`` (any
    object that supports weak references) is collected: the array must not outlive it. ``new(shape, dtype)`` makes
    one when no spare is left (``np.zeros`` for one that starts zeroed: its pages come from the operating system as
    they are first touched); a spare holds what its last owner left in it."""
    key = _key(shape, dtype)
    with _lock:
        spares = _spares.setdefault(key, [])
        array = spares.pop() if spares else None
        generation = _generation.get(key, 0)
    if array is None:
        array = new(key[0], dtype=key[1])
    weakref.finalize(owner, _give_back, key, array, generation)
    return array


def _give_back(key: tuple, array: np.ndarray, generation: int) -> None:
    with _lock:
        spares = _spares.setdefault(key, [])
        if len(spares) < SPARES and generation == _generation.get(key, 0):
            spares.append(array)


def drop_spares(shape: tuple, dtype) -> None:
    """Forget the arrays of ``shape`` and ``dtype``: the spares now, and those in use when their owners give them
    back; their memory goes back to the operating system once nothing holds them, and the next :func:`reusable` of
    that kind makes a new one."""
    key = _key(shape, dtype)
    with _lock:
        _spares.pop(key, None)
        _generation[key] = _generation.get(key, 0) + 1
