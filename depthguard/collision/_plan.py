"""Collision-free path planning over a discretised configuration space: the wave-propagation planner that Henrich &
Gecks use with their collision test (section 5: "As a simple global planning method, we chose the wave-propagation
algorithm ... Each joint was individually discretized"; their table held 8,192 configurations).

- :class:`ConfigurationGrid` discretises each joint on its own, so that every grid cell is one robot configuration
  and a step moves one joint by one grid value. Choosing the counts so that one step moves the robot by at most a
  given Cartesian distance (the paper's [15]) is left to the caller.
- :func:`wave_propagation` finds a shortest path (fewest steps) over the cells marked free, e.g. the negated
  verdicts of :class:`~depthguard.collision.ConfigurationTable` built on ``grid.configurations()``:
  ``free = ~collision.reshape(grid.shape)``.
- :func:`plan_path` does both: from two joint vectors to the joint positions along the path.

Joints are in one order throughout, the robot's (:attr:`~depthguard.robots.RobotModel.joint_names`); grid values
are in the joints' units (radians; metres for a prismatic joint).
"""

from __future__ import annotations

import numbers

import numpy as np

from depthguard.kernels import collision_plan as plan_kernels
from depthguard.errors import InputError
from depthguard.validation import NOT_A_NUMBER, real_vector, short_repr

#: The most cells a configuration grid (and a free mask) may hold: the wave's work arrays take 8 bytes per cell
#: (128 MiB at the cap), and its flat indices are 32-bit.
MAX_GRID_CELLS = 2**24


class ConfigurationGrid:
    """Each joint discretised on its own into evenly spaced values; the grid's cells are every combination.

    Args:
        lower, upper: (n,) float, radians (metres for a prismatic joint), each joint's first and last value
            (``lower <= upper``), joints in the robot's order.
        counts: (n,) int >= 1, the number of values per joint. Count 1 is the single value (lower + upper) / 2;
            a larger count is ``np.linspace(lower, upper, count)`` and then needs ``lower < upper``. The grid holds
            ``prod(counts)`` cells, at most :data:`MAX_GRID_CELLS`.

    A cell is an index tuple, one index per joint (``(i_0, ..., i_{n-1})``, each in ``[0, counts[j])``); the cells
    are ordered as numpy's C order (the last joint varies fastest), so that an array of one value per row of
    :meth:`configurations` reshaped to :attr:`shape` is indexed by cell. Each value stands for the joint positions
    within half a step of it (a count-1 joint: its whole range).

    Attributes ``lower``, ``upper`` ((n,) float64) and ``counts`` ((n,) int64) are the arguments, read-only.

    Raises :class:`~depthguard.errors.InputError` naming the field (``lower``, ``upper``, ``counts``) for values that
    are not finite real numbers, ``lower > upper``, counts that are not integers >= 1 (bools refused), lengths that
    differ, or more cells than the cap.
    """

    def __init__(self, lower, upper, counts):
        lower = _joint_vector(lower, None, "lower")
        n = len(lower)
        upper = _joint_vector(upper, n, "upper")
        if np.any(lower > upper):
            j = int(np.argmax(lower > upper))
            raise InputError(f"joint {j}'s upper bound {float(upper[j])!r} is below its lower bound "
                             f"{float(lower[j])!r}", field="upper")
        counts = _counts(counts, n)
        for j in range(n):
            if counts[j] > 1 and not lower[j] < upper[j]:
                raise InputError(f"joint {j} has {counts[j]} values but lower == upper ({float(lower[j])!r}): its "
                                 f"count must be 1", field="counts")
        size = 1
        for c in counts:
            size *= int(c)
        if size > MAX_GRID_CELLS:
            raise InputError(f"the grid {tuple(int(c) for c in counts)} holds {size} cells, more than "
                             f"{MAX_GRID_CELLS}", field="counts")
        self.lower = lower
        self.upper = upper
        self.counts = counts
        for array in (self.lower, self.upper, self.counts):
            array.flags.writeable = False
        self._values = []
        for lo, hi, c in zip(lower, upper, counts):
            values = np.array([(lo + hi) / 2.0]) if c == 1 else np.linspace(lo, hi, int(c))
            values.flags.writeable = False
            self._values.append(values)
        # Per joint: the distance between neighbouring values (a count-1 joint: its range), radians.
        self._steps = np.where(counts > 1, (upper - lower) / np.maximum(counts - 1, 1), upper - lower)

    def __repr__(self) -> str:
        return f"ConfigurationGrid(lower={self.lower.tolist()}, upper={self.upper.tolist()}, " \
               f"counts={self.counts.tolist()})"

    @property
    def n_joints(self) -> int:
        """n, the number of joints."""
        return len(self.counts)

    @property
    def shape(self) -> tuple[int, ...]:
        """(counts[0], ..., counts[n - 1]): the shape of an array of one value per cell."""
        return tuple(int(c) for c in self.counts)

    @property
    def size(self) -> int:
        """K = prod(counts), the number of cells (configurations)."""
        return int(np.prod(self.counts, dtype=np.int64))

    @property
    def values(self) -> list[np.ndarray]:
        """Per joint, its (counts[j],) float64 values in increasing order, radians (read-only)."""
        return list(self._values)

    def configurations(self) -> np.ndarray:
        """(K, n) float64, radians: every cell's joint positions, in C order of the cells (the last joint varies
        fastest): row ``k`` is the cell ``np.unravel_index(k, grid.shape)``."""
        mesh = np.meshgrid(*self._values, indexing="ij")
        return np.stack([m.reshape(-1) for m in mesh], axis=1)

    def configuration(self, index) -> np.ndarray:
        """(n,) float64, radians: the joint positions of cell ``index`` (a tuple of n ints, each in
        ``[0, counts[j])``); InputError naming ``index`` otherwise."""
        index = _check_index(index, self.shape, "index")
        return np.array([values[i] for values, i in zip(self._values, index)])

    def nearest(self, q) -> tuple[int, ...]:
        """The cell whose values are nearest to ``q`` joint by joint (halfway between two values: the higher one).

        ``q``: (n,) float, radians, joints in the grid's order. Refused with InputError naming ``q`` when it is not
        finite or a joint lies outside ``[lower - half a step, upper + half a step]`` (outside every cell).
        """
        return self._nearest(q, "q")

    def _nearest(self, q, field: str) -> tuple[int, ...]:
        q = _joint_vector(q, self.n_joints, field)
        half = self._steps / 2.0
        first = np.array([values[0] for values in self._values]) - half
        last = np.array([values[-1] for values in self._values]) + half
        outside = (q < first) | (q > last)
        if np.any(outside):
            j = int(np.argmax(outside))
            raise InputError(f"joint {j} at {float(q[j])!r} lies outside the grid's cells [{float(first[j])!r}, "
                             f"{float(last[j])!r}]", field=field)
        index = []
        for j in range(self.n_joints):
            if self.counts[j] == 1:
                index.append(0)
            else:
                i = int(np.floor((q[j] - self.lower[j]) / self._steps[j] + 0.5))
                index.append(min(max(i, 0), int(self.counts[j]) - 1))
        return tuple(index)


def wave_propagation(free, start, goal, *, check: bool = True) -> list[tuple[int, ...]] | None:
    """A shortest path from cell ``start`` to cell ``goal`` over the free cells, by a wave propagated from the goal.

    Args:
        free: n-dimensional bool array (n >= 1, at most :data:`MAX_GRID_CELLS` cells), one per cell of a
            configuration grid (:attr:`ConfigurationGrid.shape`); True = collision-free.
        start, goal: index tuples, n ints each, each in ``[0, free.shape[d])`` (negative indices are refused, not
            counted from the end).
        check: False skips the checks of the arguments (the caller guarantees a bool array and in-range index
            tuples), for a planner called in a loop.

    Returns the cells from ``start`` to ``goal``, both included, as tuples of Python ints: consecutive cells differ
    by one step (±1) of exactly one joint, every cell is free, and no path over the free cells has fewer steps.
    ``[start]`` when start == goal. None when there is no such path:

    - the goal is unreachable from the start over free cells;
    - the start is not free (a robot in collision has no safe path from where it is; getting it out is not this
      planner's job), or the goal is not free.

    The wave: breadth first from the goal over the 2n face neighbours of a cell (one joint one step; no wrap-around
    at a joint's ends), numbering each free cell with its steps to the goal, until the start is numbered. The path
    descends the numbers from the start. Ties (several neighbours one step nearer) go to the first in the order
    joint 0, 1, ..., n - 1 and, per joint, the step down (index - 1) before the step up (index + 1): the same inputs
    always give the same path.

    Raises :class:`~depthguard.errors.InputError` naming ``free``, ``start`` or ``goal`` for a mask that is not a
    non-empty bool array within the cap, or an index tuple of the wrong length, not of ints, or out of range.
    """
    if check:
        free = _check_free(free)
        start = _check_index(start, free.shape, "start")
        goal = _check_index(goal, free.shape, "goal")
    shape = np.array(free.shape, dtype=np.int64)
    strides = np.ones(len(shape), dtype=np.int64)
    for d in range(len(shape) - 2, -1, -1):
        strides[d] = strides[d + 1] * shape[d + 1]
    flat = np.ascontiguousarray(free).reshape(-1)
    if not flat.flags.writeable:  # numba types a read-only array apart: one compiled signature for every caller
        flat = flat.copy()
    path = plan_kernels.shortest_path(flat, shape, strides, int(np.dot(start, strides)), int(np.dot(goal, strides)))
    if len(path) == 0:
        return None
    return list(zip(*(axis.tolist() for axis in np.unravel_index(path, free.shape))))


def plan_path(grid: ConfigurationGrid, free, start_q, goal_q) -> np.ndarray | None:
    """The joint positions along a shortest path over ``grid``'s free cells, from the cell nearest ``start_q`` to
    the cell nearest ``goal_q`` (:meth:`ConfigurationGrid.nearest`, :func:`wave_propagation`).

    Args:
        grid: the :class:`ConfigurationGrid`.
        free: bool array of shape ``grid.shape``, True = the cell's configuration is collision-free.
        start_q, goal_q: (n,) float, radians, joints in the grid's order; each within the grid's cells.

    Returns (m, n) float64, radians: row 0 is the start cell's values, row m - 1 the goal cell's (not ``start_q``
    and ``goal_q`` themselves: the robot moves to the first row before it follows the path); consecutive rows
    differ in one joint by one grid step. None when :func:`wave_propagation` finds no path (including a start or
    goal cell in collision).

    Raises :class:`~depthguard.errors.InputError` naming ``grid``, ``free``, ``start_q`` or ``goal_q``.
    """
    if not isinstance(grid, ConfigurationGrid):
        raise InputError(f"grid must be a ConfigurationGrid, got {type(grid).__name__}", field="grid")
    free = _check_free(free)
    if free.shape != grid.shape:
        raise InputError(f"free has shape {free.shape}, the grid {grid.shape}", field="free")
    start = grid._nearest(start_q, "start_q")
    goal = grid._nearest(goal_q, "goal_q")
    cells = wave_propagation(free, start, goal, check=False)
    if cells is None:
        return None
    return np.array([grid.configuration(cell) for cell in cells]).reshape(len(cells), grid.n_joints)


def _joint_vector(values, n: int | None, field: str) -> np.ndarray:
    """``values`` as a (n,) float64 array of finite numbers (any n >= 1 when ``n`` is None); InputError naming
    ``field`` otherwise."""
    wanted = "n >= 1" if n is None else str(n)
    array = real_vector(values, wanted, field, "radians or metres")
    if array.ndim != 1 or len(array) == 0 or (n is not None and len(array) != n):
        raise InputError(f"expected {wanted} joint values, got shape {array.shape}", field=field)
    if not np.all(np.isfinite(array)):
        raise InputError(f"joint values must be finite, got {short_repr(values)}", field=field)
    return array


def _counts(counts, n: int) -> np.ndarray:
    """``counts`` as a (n,) int64 array of integers >= 1; InputError naming ``counts`` otherwise (bools, floats and
    strings are refused, not converted)."""
    if isinstance(counts, (str, bytes)) or isinstance(counts, np.ma.MaskedArray):
        raise InputError(f"expected {n} integers >= 1, got {short_repr(counts)}", field="counts")
    if isinstance(counts, (list, tuple)):
        for c in counts:
            if isinstance(c, (bool, np.bool_)) or not isinstance(c, numbers.Integral):
                raise InputError(f"expected {n} integers >= 1, got {short_repr(c)} among them", field="counts")
    try:
        array = np.asarray(counts)
    except NOT_A_NUMBER:
        raise InputError(f"expected {n} integers >= 1, got {short_repr(counts)}", field="counts") from None
    if array.dtype.kind not in "iu":
        raise InputError(f"expected {n} integers >= 1, got {short_repr(counts)} (dtype {array.dtype})",
                         field="counts")
    if array.shape != (n,):
        raise InputError(f"expected {n} counts (one per joint), got shape {array.shape}", field="counts")
    if np.any(array < 1):
        raise InputError(f"every count must be >= 1, got {array.tolist()}", field="counts")
    if np.any(array > MAX_GRID_CELLS):
        raise InputError(f"a count above {MAX_GRID_CELLS} exceeds the grid's cap, got {array.tolist()}",
                         field="counts")
    return array.astype(np.int64)


def _check_free(free) -> np.ndarray:
    """``free`` as a bool ndarray with n >= 1 dimensions and 1 to :data:`MAX_GRID_CELLS` cells; InputError naming
    ``free`` otherwise (0/1 integers are refused: a verdict label array passed by mistake must not plan)."""
    if isinstance(free, np.ma.MaskedArray):
        raise InputError("free must be a plain bool array, not a masked array", field="free")
    try:
        array = np.asarray(free)
    except NOT_A_NUMBER:
        raise InputError(f"free must be a bool array, got {short_repr(free)}", field="free") from None
    if array.dtype != np.bool_:
        raise InputError(f"free must be a bool array (True = collision-free), got dtype {array.dtype}", field="free")
    if array.ndim < 1 or array.size == 0:
        raise InputError(f"free must have at least one dimension and one cell, got shape {array.shape}",
                         field="free")
    if array.size > MAX_GRID_CELLS:
        raise InputError(f"free holds {array.size} cells, more than {MAX_GRID_CELLS}", field="free")
    return array


def _check_index(index, shape: tuple[int, ...], field: str) -> tuple[int, ...]:
    """``index`` as a tuple of ``len(shape)`` Python ints, each in ``[0, shape[d])``; InputError naming ``field``
    otherwise (bools, floats and negative indices are refused)."""
    if isinstance(index, np.ndarray):
        if index.ndim != 1:
            raise InputError(f"expected {len(shape)} indices, got an array of shape {index.shape}", field=field)
        index = index.tolist()
    if isinstance(index, (str, bytes)) or not isinstance(index, (list, tuple)):
        raise InputError(f"expected a tuple of {len(shape)} indices, got {short_repr(index)}", field=field)
    if len(index) != len(shape):
        raise InputError(f"expected {len(shape)} indices (one per joint), got {len(index)}", field=field)
    for d, (i, n) in enumerate(zip(index, shape)):
        if isinstance(i, (bool, np.bool_)) or not isinstance(i, numbers.Integral):
            raise InputError(f"index {d} must be an integer, got {short_repr(i)}", field=field)
        if not 0 <= i < n:
            raise InputError(f"index {d} is {int(i)}, outside [0, {n})", field=field)
    return tuple(int(i) for i in index)
