"""The lab's ideal memory (issue 35's bound, ``depthguard_lab.experiments.ideal_memory``) does what its docstring
says on scenario B's first frame: the robot's inside and what a camera's exact ray passes are never possibly
occupied (on the measured frames: what the measured ray passes, a dropout passing nothing), everything else is at
start-up, and with the cameras blind the possibly-occupied space grows at v_max."""

import numpy as np
import pytest

from depthguard_lab.experiments import fusion_workcell as fw
from depthguard_lab.experiments.ideal_memory import IdealMemory, measured_depths
from depthguard_lab.simulation import load_workcell, simulate


@pytest.fixture(scope="module")
def start():
    workcell = load_workcell(fw.scene_paths(("scenario_b.yaml",))[0])
    frame = next(iter(simulate(workcell, seed=0, frames=range(1))))
    return workcell, frame


def exact_seen(ideal, workcell, frame, noise_margin, measured=False, calibration=0.0, pad=0):
    """The grid points some camera's exact ray passes before its first surface (less the noise margin); with
    ``measured``, its measured depth (noise, dropouts), where a pixel without a measurement sees nothing; with
    ``calibration`` (metres) and ``pad`` (pixels), by that much more, on every pixel within pad of the point's (one
    beyond the image's edge sees nothing)."""
    seen = np.zeros(len(ideal.points), bool)
    depths = measured_depths(frame.depth) if measured else frame.depth_exact
    for name, camera in workcell.rig.cameras.items():
        depth = depths[name]
        local = camera.world_to_camera(ideal.points)
        z = local[:, 2]
        u = np.rint(camera.fx * local[:, 0] / np.maximum(z, 1e-9) + camera.cx)
        v = np.rint(camera.fy * local[:, 1] / np.maximum(z, 1e-9) + camera.cy)
        for p in np.flatnonzero((z > 1e-3) & (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height)):
            reach = np.inf
            for r in range(int(v[p]) - pad, int(v[p]) + pad + 1):
                for c in range(int(u[p]) - pad, int(u[p]) + pad + 1):
                    if not (0 <= r < camera.height and 0 <= c < camera.width):
                        reach = 0.0
                        continue
                    d = float(depth[r, c])
                    here = (0.0 if measured else np.inf) if d == 0.0 else \
                        d - (float(camera.noise.margin(d)) if noise_margin else 0.0) - calibration
                    reach = min(reach, here)
            seen[p] |= z[p] < reach
    return seen.reshape(ideal.shape)


@pytest.mark.parametrize("noise_margin, measured, calibration, pad",
                         [(False, False, 0.0, 0), (True, False, 0.0, 0), (True, True, 0.0, 0), (True, True, 0.01, 1)])
def test_the_ideal_memory_at_start_up_and_blind(start, noise_margin, measured, calibration, pad):
    workcell, frame = start
    ideal = IdealMemory(workcell, spacing=0.1, noise_margin=noise_margin, measured=measured, calibration=calibration,
                        pad=pad)
    depths = measured_depths(frame.depth) if measured else frame.depth_exact
    ideal.update(frame.time, frame.joints, depths, frame.label)
    robot = ideal.inside_robot(frame.joints)
    seen = exact_seen(ideal, workcell, frame, noise_margin, measured, calibration, pad)
    if pad:  # the margins see less
        assert seen.sum() < exact_seen(ideal, workcell, frame, noise_margin, measured).sum()
    assert robot.sum() >= 3 and 0.3 < seen.mean() < 0.99  # the test says something
    if measured:  # the sensor's dropouts see nothing free: fewer points seen than on the exact frames
        assert seen.sum() < exact_seen(ideal, workcell, frame, noise_margin).sum()
    assert not np.any(ideal.possibly & (robot | ideal.solid))
    # Seen free now is not possibly occupied, unless a camera sees a surface that is not the robot's in that cell.
    assert not np.any(ideal.possibly & seen & ~ideal.surfaces) and np.mean(ideal.surfaces[seen]) < 0.1
    # Everything else is possibly occupied at start-up.
    np.testing.assert_array_equal(ideal.possibly[~seen & ~robot & ~ideal.solid], True)
    # One second later with every camera blind (a surface 1 cm in front of each), the possibly-occupied space has grown
    # by v_max * 1 s = 2 m: every point not inside the robot or a solid within 2 m of it is possibly occupied.
    blind = {name: np.full_like(depth, 0.01) for name, depth in frame.depth_exact.items()}
    labels = {name: np.full_like(label, -1) for name, label in frame.label.items()}
    before = ideal.possibly.copy()
    ideal.update(frame.time + 1.0, frame.joints, blind, labels)
    grid = ideal.points.reshape(*ideal.shape, 3)
    sources = grid[before]
    far = ~before & ~robot & ~ideal.solid
    for point in grid[far][::7]:
        reached = np.min(np.linalg.norm(sources - point, axis=1)) <= 2.0
        assert not reached or ideal.possibly[tuple(np.round((point - ideal.lo) / ideal.spacing - 0.5).astype(int))]


def test_opened_is_the_union_of_the_balls_that_fit():
    """``opened`` against its definition, ball by ball: a True point is kept exactly when some grid ball of the
    radius (centre on a grid point, the grid points within the radius) holds it and lies in the mask (the grid's
    outside counts as in it: a ball may reach beyond the grid)."""
    from depthguard_lab.experiments.ideal_memory import opened

    rng = np.random.default_rng(3)
    mask = np.zeros((14, 12, 10), dtype=bool)
    mask[1:9, 2:10, 1:8] = True  # a block a ball of radius 2 fits in, its corners not
    mask[10:12, :, :] = True  # a slab 2 thick: no ball of radius 2
    mask |= rng.random(mask.shape) < 0.1
    radius = 2.0
    offsets = np.argwhere(np.ones((5, 5, 5), bool)) - 2
    offsets = offsets[(offsets ** 2).sum(1) <= radius ** 2]
    twin = np.zeros_like(mask)
    for centre in np.argwhere(mask):
        ball = centre + offsets
        inside = np.all((ball >= 0) & (ball < mask.shape), axis=1)
        ball = ball[inside]
        if mask[tuple(ball.T)].all():
            twin[tuple(ball.T)] = True
    assert twin[1:9, 2:10, 1:8].sum() > 100 and not twin[10:12, 2:-2, 2:-2].any()  # the test says something
    np.testing.assert_array_equal(opened(mask, radius), twin)


def test_an_opened_memory_keeps_only_balls_of_d_and_answers_within_its_box(start):
    """With ``opening`` the possibly-occupied points are the opening of those without it, and ``nearest`` is the
    distance to the nearest of them, at most to the box's side."""
    from depthguard_lab.experiments.ideal_memory import opened

    workcell, frame = start
    box = ((-0.6, -0.6, -0.5), (0.9, 0.6, 1.2))
    plain = IdealMemory(workcell, spacing=0.04, bounds=box)
    open_ = IdealMemory(workcell, spacing=0.04, bounds=box, opening=0.08)
    for ideal in (plain, open_):
        ideal.update(frame.time, frame.joints, frame.depth_exact, frame.label)
    np.testing.assert_array_equal(open_.possibly, opened(plain.possibly, 0.04 / 0.04))
    assert 0 < open_.possibly.sum() < plain.possibly.sum()  # the opening removed some, not all
    points = np.array([[0.3, 0.0, 0.5], [0.0, 0.3, 0.9], [0.85, 0.0, 0.0]])
    where = open_.points[open_.possibly.reshape(-1)]
    side = np.minimum(points - open_.lo, open_.hi - points).min(axis=1)
    brute = np.minimum(np.linalg.norm(where[None] - points[:, None], axis=2).min(axis=1), side)
    np.testing.assert_allclose(open_.nearest(points), brute, atol=1e-12)


def test_with_nothing_possibly_occupied_nothing_arrives(start):
    """A grid wholly inside a known solid (the pedestal) holds no possibly-occupied point, and nothing can arrive
    there: every arrival time stays infinite (a distance transform with no source would give finite ones)."""
    workcell, frame = start
    ideal = IdealMemory(workcell, spacing=0.02, bounds=((-0.12, -0.12, -0.45), (0.12, 0.12, -0.05)))
    ideal.update(frame.time, frame.joints, frame.depth_exact, frame.label)
    assert ideal.solid.all() and not ideal.possibly.any()
    assert np.all(np.isinf(ideal.arrival))
