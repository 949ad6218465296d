"""The wave-propagation planner over a discretised configuration space (Henrich & Gecks, section 5): the numba wave
against a slow breadth-first search written here, the configuration grid's order and nearest cells, bad inputs."""

from __future__ import annotations

import itertools
from collections import deque

import numpy as np
import pytest

from depthguard.kernels import collision_plan
from depthguard.collision._plan import MAX_GRID_CELLS, ConfigurationGrid, plan_path, wave_propagation
from depthguard.errors import InputError


# -- the judges: slow, obvious Python over index tuples ------------------------------------------------------------

def _neighbours(cell, shape):
    """The face neighbours of ``cell`` in the order the planner breaks ties: joint 0 first, step down before up."""
    for d in range(len(shape)):
        for step in (-1, 1):
            i = cell[d] + step
            if 0 <= i < shape[d]:
                yield cell[:d] + (i,) + cell[d + 1:]


def _distances(free, source):
    """Steps from ``source`` to every free cell reachable from it (a dict), by a plain breadth-first search."""
    if not free[source]:
        return {}
    steps = {source: 0}
    queue = deque([source])
    while queue:
        cell = queue.popleft()
        for other in _neighbours(cell, free.shape):
            if free[other] and other not in steps:
                steps[other] = steps[cell] + 1
                queue.append(other)
    return steps


def _judge_path(free, start, goal):
    """The path the planner documents: distances to the goal, then down them from the start taking the first
    neighbour one step nearer (joint 0 first, step down before up). None when there is none."""
    to_goal = _distances(free, goal)
    if start not in to_goal:
        return None
    path = [start]
    while path[-1] != goal:
        path.append(next(c for c in _neighbours(path[-1], free.shape) if to_goal.get(c) == to_goal[path[-1]] - 1))
    return path


def _assert_valid_path(path, free, start, goal):
    assert path[0] == start and path[-1] == goal
    assert all(isinstance(i, int) for cell in path for i in cell)
    assert all(free[cell] for cell in path)
    for a, b in itertools.pairwise(path):
        moved = [abs(x - y) for x, y in zip(a, b)]
        assert sorted(moved) == [0] * (len(a) - 1) + [1], (a, b)


# -- the wave against the judges -------------------------------------------------------------------------------------

SHAPES = [(4, 4, 4, 4, 4, 2), (30, 40), (9,), (5, 6, 7)]


@pytest.mark.parametrize("shape", SHAPES, ids=lambda s: "x".join(map(str, s)))
@pytest.mark.parametrize("obstacles", [0.1, 0.3, 0.5])
def test_wave_finds_a_shortest_path_exactly_when_the_judge_finds_one(shape, obstacles):
    """On random masks (seeded), random start and goal cells (free or not): None exactly when a breadth-first search
    from the start does not reach the goal; otherwise a valid path whose steps are the search's distance, and the
    very path the documented tie-breaking gives."""
    rng = np.random.default_rng([*shape, round(obstacles * 10)])
    found = missing = 0
    for trial in range(16):
        free = rng.random(shape) >= obstacles
        start, goal = (tuple(int(i) for i in rng.integers(0, shape)) for _ in range(2))
        free[start] = free[goal] = True
        from_start = _distances(free, start)
        if trial % 2:  # a goal the start reaches (below the percolation threshold few random ones are)
            reachable = sorted(from_start)
            goal = reachable[rng.integers(len(reachable))]
        if trial % 8 in (2, 4):  # an end in collision
            free[start if trial % 8 == 2 else goal] = False
            from_start = _distances(free, start)
        path = wave_propagation(free, start, goal)
        if goal not in from_start:
            assert path is None
            missing += 1
            continue
        found += 1
        _assert_valid_path(path, free, start, goal)
        assert len(path) - 1 == from_start[goal]
        assert path == _judge_path(free, start, goal)
    assert found > 0 and missing > 0  # both answers exercised


def test_a_wall_splits_the_grid_and_a_gap_lets_the_path_through():
    free = np.ones((10, 12), dtype=bool)
    free[:, 6] = False  # joint 1 cannot pass 6
    assert wave_propagation(free, (0, 0), (9, 11)) is None
    assert wave_propagation(free, (9, 11), (0, 0)) is None
    free[7, 6] = True
    path = wave_propagation(free, (0, 0), (9, 11))
    _assert_valid_path(path, free, (0, 0), (9, 11))
    assert (7, 6) in path
    assert len(path) - 1 == 9 + 11  # the gap lies within the bounding box: no detour
    free[7, 6] = False
    free[9, 6] = True  # at the border: still reachable
    assert len(wave_propagation(free, (0, 0), (0, 11))) - 1 == 2 * 9 + 11


def test_the_wave_does_not_wrap_around_a_joints_ends():
    free = np.zeros((1, 6), dtype=bool)
    free[0, [0, 1, 4, 5]] = True
    assert wave_propagation(free, (0, 0), (0, 5)) is None


def test_ties_go_to_the_lowest_joint_and_the_step_down_first():
    free = np.ones((3, 3), dtype=bool)
    assert wave_propagation(free, (0, 0), (2, 2)) == [(0, 0), (1, 0), (2, 0), (2, 1), (2, 2)]
    assert wave_propagation(free, (2, 2), (0, 0)) == [(2, 2), (1, 2), (0, 2), (0, 1), (0, 0)]
    assert wave_propagation(free, (1, 1), (1, 1)) == [(1, 1)]
    free[1, 1] = False  # around a pillar: down and up joint 0 are equally short
    assert wave_propagation(free, (1, 0), (1, 2)) == [(1, 0), (0, 0), (0, 1), (0, 2), (1, 2)]


def test_an_end_in_collision_has_no_path():
    free = np.ones((4, 4), dtype=bool)
    free[0, 0] = False
    assert wave_propagation(free, (0, 0), (3, 3)) is None
    assert wave_propagation(free, (3, 3), (0, 0)) is None
    assert wave_propagation(free, (0, 0), (0, 0)) is None


def test_any_bool_layout_gives_the_same_path_and_the_mask_is_left_alone():
    """A Fortran-ordered, a strided and a read-only mask plan like their C-ordered copy; numpy index arrays and
    ``check=False`` too; the mask is not written."""
    rng = np.random.default_rng(4)
    free = rng.random((12, 14)) >= 0.25
    free[0, 0] = free[11, 13] = True
    expected = wave_propagation(free, (0, 0), (11, 13))
    assert expected is not None
    fortran = np.asfortranarray(free)
    strided = np.ones((24, 14), dtype=bool)
    strided[::2] = free
    readonly = free.copy()
    readonly.flags.writeable = False
    before = free.copy()
    for mask in (fortran, strided[::2], readonly):
        assert wave_propagation(mask, (0, 0), (11, 13)) == expected
    assert wave_propagation(free, np.array([0, 0]), np.array([11, 13], dtype=np.uint8)) == expected
    assert wave_propagation(free, (0, 0), (11, 13), check=False) == expected
    assert np.array_equal(free, before)


def test_the_kernel_body_runs_as_python():
    """The kernel's Python body (what NUMBA_DISABLE_JIT=1 runs; coverage sees it) gives the compiled kernel's path,
    and its empty answer when the goal is walled in."""
    rng = np.random.default_rng(5)
    shape = np.array([5, 4, 6], dtype=np.int64)
    strides = np.array([24, 6, 1], dtype=np.int64)
    free = rng.random(120) >= 0.2
    free[0] = free[119] = True
    walled = np.ones(120, dtype=bool)
    walled[[118, 113, 95]] = False  # the goal's three neighbours
    for mask, length in ((free, None), (walled, 0)):
        compiled = collision_plan.shortest_path(mask, shape, strides, 0, 119)
        plain = collision_plan.shortest_path.py_func(mask, shape, strides, 0, 119)
        assert np.array_equal(compiled, plain)
        assert len(compiled) == (length if length is not None else 4 + 3 + 5 + 1) or length is None
    assert len(collision_plan.shortest_path(free, shape, strides, 0, 119)) > 0


@pytest.mark.parametrize("free, start, goal, field", [
    (np.ones((3, 3), dtype=np.uint8), (0, 0), (2, 2), "free"),  # 0/1 integers are not a bool mask
    (np.ones((3, 3)), (0, 0), (2, 2), "free"),
    (np.array(True), (), (), "free"),
    (np.ones((3, 0), dtype=bool), (0, 0), (0, 0), "free"),
    (np.ma.masked_array(np.ones((3, 3), dtype=bool)), (0, 0), (2, 2), "free"),
    ("free", (0, 0), (2, 2), "free"),
    (np.ones((3, 3), dtype=bool), (0,), (2, 2), "start"),
    (np.ones((3, 3), dtype=bool), (0, 0, 0), (2, 2), "start"),
    (np.ones((3, 3), dtype=bool), (0, 3), (2, 2), "start"),
    (np.ones((3, 3), dtype=bool), (-1, 0), (2, 2), "start"),
    (np.ones((3, 3), dtype=bool), (0.0, 0), (2, 2), "start"),
    (np.ones((3, 3), dtype=bool), (True, 0), (2, 2), "start"),
    (np.ones((3, 3), dtype=bool), "00", (2, 2), "start"),
    (np.ones((3, 3), dtype=bool), 0, (2, 2), "start"),
    (np.ones((3, 3), dtype=bool), np.zeros((1, 2), dtype=int), (2, 2), "start"),
    (np.ones((3, 3), dtype=bool), (0, 0), (2, 9), "goal"),
    (np.ones((3, 3), dtype=bool), (0, 0), (2, np.nan), "goal"),
])
def test_wave_propagation_refuses_bad_inputs(free, start, goal, field):
    with pytest.raises(InputError) as error:
        wave_propagation(free, start, goal)
    assert error.value.field == field


def test_wave_propagation_refuses_a_mask_above_the_cap():
    big = np.lib.stride_tricks.as_strided(np.ones(1, dtype=bool), shape=(MAX_GRID_CELLS + 1,), strides=(0,))
    with pytest.raises(InputError) as error:
        wave_propagation(big, (0,), (1,))
    assert error.value.field == "free"


# -- the configuration grid ------------------------------------------------------------------------------------------

def test_grid_values_and_configurations_in_c_order():
    """Count 1 is the middle of the range, others np.linspace; configurations() row k is the cell
    np.unravel_index(k, shape), so a per-row result reshaped to the grid's shape is indexed by cell."""
    grid = ConfigurationGrid([-1.0, 0.5, -2.0, 0.0], [1.0, 1.5, 2.0, 0.3], [3, 1, 5, 2])
    assert grid.shape == (3, 1, 5, 2) and grid.size == 30 and grid.n_joints == 4
    assert np.array_equal(grid.values[0], [-1.0, 0.0, 1.0])
    assert np.array_equal(grid.values[1], [1.0])
    assert np.allclose(grid.values[2], [-2.0, -1.0, 0.0, 1.0, 2.0], rtol=0, atol=1e-15)
    assert np.array_equal(grid.values[3], [0.0, 0.3])
    configurations = grid.configurations()
    assert configurations.shape == (30, 4) and configurations.dtype == np.float64
    per_row = configurations @ np.array([1.0, 10.0, 100.0, 1000.0])  # any per-configuration result
    by_cell = per_row.reshape(grid.shape)
    for k, cell in enumerate(np.ndindex(grid.shape)):
        assert np.array_equal(configurations[k], grid.configuration(cell))
        assert by_cell[cell] == per_row[k]
        assert np.array_equal([grid.values[j][i] for j, i in enumerate(cell)], configurations[k])
    with pytest.raises(ValueError):
        grid.values[0][0] = 5.0  # read-only


def test_nearest_round_trips_and_rounds_to_the_nearest_value():
    grid = ConfigurationGrid([-1.0, 0.0, -0.5], [1.0, 1.0, 0.5], [5, 3, 1])
    for cell in np.ndindex(grid.shape):
        assert grid.nearest(grid.configuration(cell)) == cell
    rng = np.random.default_rng(2)
    steps = np.array([0.5, 0.5, 1.0])  # a count-1 joint's cell spans its range
    for _ in range(200):
        q = rng.uniform([-1.25, -0.25, -0.5], [1.25, 1.25, 0.5])
        cell = grid.nearest(q)
        centre = grid.configuration(cell)
        assert np.all(np.abs(q - centre) <= steps / 2 + 1e-12)
    assert grid.nearest([-0.75, 0.25, 0.0]) == (1, 1, 0)  # halfway: the higher value
    assert grid.nearest([1.25, 1.25, 0.5]) == (4, 2, 0)  # at the outer edge of the last cells
    assert grid.nearest([-1.25, -0.25, -0.5]) == (0, 0, 0)


@pytest.mark.parametrize("q", [[1.26, 0.0, 0.0], [0.0, -0.26, 0.0], [0.0, 0.0, 0.51], [np.nan, 0.0, 0.0],
                               [np.inf, 0.0, 0.0], [0.0, 0.0], [0.0, 0.0, 0.0, 0.0], ["0", 0.0, 0.0],
                               [True, 0.0, 0.0], [[0.0, 0.0, 0.0]]])
def test_nearest_refuses_what_lies_outside_every_cell_or_is_not_a_joint_vector(q):
    grid = ConfigurationGrid([-1.0, 0.0, -0.5], [1.0, 1.0, 0.5], [5, 3, 1])
    with pytest.raises(InputError) as error:
        grid.nearest(q)
    assert error.value.field == "q"


@pytest.mark.parametrize("index", [(5, 0, 0), (0, 0, -1), (0, 0), (0.0, 0, 0), "000", None])
def test_configuration_refuses_bad_cells(index):
    grid = ConfigurationGrid([-1.0, 0.0, -0.5], [1.0, 1.0, 0.5], [5, 3, 1])
    with pytest.raises(InputError) as error:
        grid.configuration(index)
    assert error.value.field == "index"


@pytest.mark.parametrize("lower, upper, counts, field", [
    ([np.nan, 0.0], [1.0, 1.0], [2, 2], "lower"),
    ([-np.inf, 0.0], [1.0, 1.0], [2, 2], "lower"),
    ([0.0, 0.0], [1.0, np.inf], [2, 2], "upper"),
    ([], [], [], "lower"),
    ("01", [1.0, 1.0], [2, 2], "lower"),
    ([[0.0, 0.0]], [1.0, 1.0], [2, 2], "lower"),
    ([0.0, 0.0], [1.0], [2, 2], "upper"),
    ([0.0, 2.0], [1.0, 1.0], [2, 2], "upper"),
    ([0.0, True], [1.0, 1.0], [2, 2], "lower"),
    ([0.0, 0.0], [1.0, 1.0], [2, 0], "counts"),
    ([0.0, 0.0], [1.0, 1.0], [2, -3], "counts"),
    ([0.0, 0.0], [1.0, 1.0], [2, True], "counts"),
    ([0.0, 0.0], [1.0, 1.0], [2, 2.0], "counts"),
    ([0.0, 0.0], [1.0, 1.0], np.array([2.0, 2.0]), "counts"),
    ([0.0, 0.0], [1.0, 1.0], np.array([True, True]), "counts"),
    ([0.0, 0.0], [1.0, 1.0], [2], "counts"),
    ([0.0, 0.0], [1.0, 1.0], "22", "counts"),
    ([0.0, 0.0], [1.0, 1.0], None, "counts"),
    ([0.0, 1.0], [1.0, 1.0], [2, 2], "counts"),  # lower == upper with two values
    ([0.0, 0.0], [1.0, 1.0], [2**12, 2**12 + 1], "counts"),  # above the cap
    ([0.0, 0.0], [1.0, 1.0], [10**30, 1], "counts"),
])
def test_grid_refuses_bad_inputs(lower, upper, counts, field):
    with pytest.raises(InputError) as error:
        ConfigurationGrid(lower, upper, counts)
    assert error.value.field == field


def test_grid_accepts_a_point_joint_and_the_cap():
    grid = ConfigurationGrid([0.0, 0.3], [1.0, 0.3], np.array([2**12, 1], dtype=np.uint16))
    assert grid.shape == (4096, 1) and grid.values[1].tolist() == [0.3]
    assert grid.nearest([0.5, 0.3])[1] == 0
    with pytest.raises(InputError):
        grid.nearest([0.5, 0.3 + 1e-9])
    assert ConfigurationGrid([0.0, 0.0], [1.0, 1.0], [2**12, 2**12]).size == MAX_GRID_CELLS


# -- planning in joint space ----------------------------------------------------------------------------------------

def test_plan_path_gives_the_joint_positions_of_the_cells_on_the_wave_path():
    grid = ConfigurationGrid([-1.0, -2.0, 0.0], [1.0, 2.0, 0.6], [9, 8, 4])
    rng = np.random.default_rng(7)
    free = rng.random(grid.shape) >= 0.3
    start_q, goal_q = np.array([-0.98, -1.9, 0.05]), np.array([0.97, 1.95, 0.55])
    start, goal = grid.nearest(start_q), grid.nearest(goal_q)
    assert (start, goal) == ((0, 0, 0), (8, 7, 3))
    free[start] = free[goal] = True
    cells = wave_propagation(free, start, goal)
    assert cells is not None
    joints = plan_path(grid, free, start_q, goal_q)
    assert joints.shape == (len(cells), 3) and joints.dtype == np.float64
    assert np.array_equal(joints, np.array([grid.configuration(c) for c in cells]))
    steps = np.array([0.25, 4.0 / 7.0, 0.2])
    moves = np.abs(np.diff(joints, axis=0)) / steps
    assert np.allclose(np.sort(moves, axis=1), [0.0, 0.0, 1.0])
    free[goal] = False
    assert plan_path(grid, free, start_q, goal_q) is None
    free[goal] = True
    one = plan_path(grid, free, start_q, start_q + 0.01)
    assert np.array_equal(one, grid.configuration(start)[None])


@pytest.mark.parametrize("change, field", [
    (dict(grid=np.zeros((3, 3))), "grid"),
    (dict(free=np.ones((3, 4), dtype=bool)), "free"),
    (dict(free=np.ones((3, 3), dtype=int)), "free"),
    (dict(start_q=[0.0, 1.6]), "start_q"),
    (dict(start_q=[0.0]), "start_q"),
    (dict(goal_q=[np.nan, 0.0]), "goal_q"),
])
def test_plan_path_refuses_bad_inputs(change, field):
    arguments = dict(grid=ConfigurationGrid([-1.0, -1.0], [1.0, 1.0], [3, 3]), free=np.ones((3, 3), dtype=bool),
                     start_q=[-1.0, -1.0], goal_q=[1.0, 1.0])
    arguments.update(change)
    with pytest.raises(InputError) as error:
        plan_path(**arguments)
    assert error.value.field == field
