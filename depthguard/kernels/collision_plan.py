"""Numba kernel of the wave-propagation planner (Henrich & Gecks, section 5): a breadth-first wave over a discretised
configuration space, flattened in C order. It trusts its inputs; ``depthguard/collision/_plan.py`` checks them."""

import numpy as np

from depthguard.kernels.jit import kernel


@kernel()
def shortest_path(free, shape, strides, start, goal):
    """The cells of a shortest path from ``start`` to ``goal`` over the free cells, as flat indices.

    Args:
        free: (N,) bool, C-contiguous: the n-dimensional grid of cells flattened in C order (True = collision-free).
        shape: (n,) int64, the grid's shape (N = prod(shape) < 2**31).
        strides: (n,) int64, the grid's C-order strides in cells (``strides[d] = prod(shape[d + 1:])``).
        start, goal: int, flat cell indices in [0, N).

    Returns (m,) int64: the flat indices of the path from ``start`` to ``goal``, both included (m - 1 steps, each
    moving one joint by one cell); empty when ``start`` or ``goal`` is not free or the goal cannot be reached.

    The wave: breadth first from the goal over the 2n face neighbours (no wrap-around at a joint's ends), numbering
    each free cell with its number of steps to the goal; it stops once the start is numbered (every cell nearer the
    goal than the start is numbered by then). The path descends the numbers from the start; of the neighbours one
    step nearer the goal it takes the first in the order joint 0, 1, ..., n - 1, and per joint the step down (index
    - 1) before the step up (index + 1).
    """
    size = free.shape[0]
    n = shape.shape[0]
    if not free[start] or not free[goal]:
        return np.empty(0, dtype=np.int64)
    # wave: steps to the goal of a numbered cell, -1 for a free cell not numbered yet, -2 for a cell in collision.
    wave = np.empty(size, dtype=np.int32)
    for cell in range(size):
        wave[cell] = -1 if free[cell] else -2
    queue = np.empty(size, dtype=np.int32)
    index = np.empty(n, dtype=np.int64)
    wave[goal] = 0
    queue[0] = goal
    head = 0
    tail = 1
    while head < tail and wave[start] < 0:
        cell = np.int64(queue[head])
        head += 1
        number = wave[cell] + 1
        rest = cell  # the cell's index per joint, by one division per joint
        for d in range(n - 1, 0, -1):
            above = rest // shape[d]
            index[d] = rest - above * shape[d]
            rest = above
        index[0] = rest
        for d in range(n):
            if index[d] > 0:
                neighbour = cell - strides[d]
                if wave[neighbour] == -1:
                    wave[neighbour] = number
                    queue[tail] = neighbour
                    tail += 1
            if index[d] < shape[d] - 1:
                neighbour = cell + strides[d]
                if wave[neighbour] == -1:
                    wave[neighbour] = number
                    queue[tail] = neighbour
                    tail += 1
    if wave[start] < 0:
        return np.empty(0, dtype=np.int64)
    steps = wave[start]
    path = np.empty(steps + 1, dtype=np.int64)
    cell = np.int64(start)
    path[0] = cell
    for k in range(1, steps + 1):
        wanted = wave[cell] - 1
        following = np.int64(-1)
        for d in range(n):
            at = (cell // strides[d]) % shape[d]
            if at > 0 and wave[cell - strides[d]] == wanted:
                following = cell - strides[d]
                break
            if at < shape[d] - 1 and wave[cell + strides[d]] == wanted:
                following = cell + strides[d]
                break
        cell = following  # a numbered cell other than the goal always has a neighbour one step nearer
        path[k] = cell
    return path
