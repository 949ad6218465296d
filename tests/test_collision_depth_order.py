"""The depth order of the image-based collision test (design §10; issue 27's first step, off by default): a camera
asserts Coll_RO / Coll_RP at a tile only where the future robot's capsule there reaches behind the depth up to which
the camera saw the tile free. Judged by a pixel-by-pixel loop (the tiles' free depth) and by constructed cases that
fail if the order is dropped or reversed; scenario C's judge (tests/test_scenario_c.py) runs with it too."""

from __future__ import annotations

import numpy as np
import pytest

import depthguard as dg
from depthguard.collision import (
    OBSTACLE,
    POSSIBLE,
    RobotProjector,
    TileGrid,
    depth_ordered_collisions,
    tile_free_depth,
)
from depthguard.robots import RobotModel
from depthguard.transforms import look_at


def _camera():
    return dg.PinholeCamera("c", 160, 128, 140.0, 140.0, 79.5, 63.5, look_at((2.5, 0.0, 0.6), (0.0, 0.0, 0.5)),
                            depth_scale=0.001, noise=dg.NoiseModel(a=0.001504, b=-0.00152, c=0.0019, k=3.0))


def test_a_tile_s_free_depth_is_the_least_measured_depth_less_its_margin_and_0_where_a_pixel_is_unmeasured():
    grid = TileGrid(_camera(), 7, 9)  # fractional tiles
    rng = np.random.default_rng(1)
    depth = rng.uniform(0.5, 5.0, grid.camera.shape)
    depth[:20, :30][rng.random((20, 30)) < 0.05] = 0.0  # a few unmeasured pixels, top left
    units = np.rint(depth / 0.001).astype(np.uint16)
    got = tile_free_depth(units, grid)
    metres = units * 0.001
    for r in range(grid.rows):
        for c in range(grid.cols):
            block = metres[grid.first_row[r]: grid.first_row[r + 1], grid.first_col[c]: grid.first_col[c + 1]]
            want = 0.0 if (block == 0).any() else float(np.min(block - grid.camera.noise.margin(block)))
            assert got[r, c] == want
    assert (got == 0).any() and (got > 0).any()


def test_a_capsule_counts_at_a_tile_only_where_it_reaches_behind_the_tile_s_free_depth():
    grid = TileGrid(_camera(), 4, 4)
    revised = np.zeros((4, 4), dtype=np.uint8)
    revised[1, 1] = OBSTACLE
    revised[2, 2] = POSSIBLE
    free = np.full((4, 4), 3.0)
    free[1, 1] = 2.0  # the obstacle measured at 2 m (less its margin)
    free[2, 2] = 2.5  # the current robot's surface, what it hides behind
    cover = np.zeros((4, 4), dtype=bool)
    cover[1, 1] = cover[2, 2] = True
    bits = grid.pack(cover)[None, None]  # one configuration, one capsule over both tiles
    for far, want in [(1.5, (False, False)), (2.2, (True, False)), (2.8, (True, True))]:
        ro, rp = depth_ordered_collisions(revised, free, bits, np.array([[far]]), grid)
        assert (bool(ro[0]), bool(rp[0])) == want, far
    ro, rp = depth_ordered_collisions(revised, np.zeros((4, 4)), bits, np.array([[0.1]]), grid)
    assert ro[0] and rp[0]  # nothing proven free: the images alone decide


def test_each_capsule_s_far_depth_bounds_its_points_depth():
    robot = RobotModel.default()
    grid = TileGrid(_camera(), 16, 20)
    projector = RobotProjector(robot, [grid])
    rng = np.random.default_rng(2)
    q = rng.uniform(robot.lower, robot.upper, (5, robot.n_joints))
    bits, far = projector.capsule_bits(q)
    assert bits.shape[:3] == (1, 5, len(robot.capsules)) and far.shape == (1, 5, len(robot.capsules))
    union = projector.bits(q)
    np.testing.assert_array_equal(np.bitwise_or.reduce(bits, axis=2), union)  # the capsules make the robot image
    T = grid.camera.T_camera_world
    for k in range(5):
        for j, (a, b) in enumerate(robot.capsule_segments(q[k], check=False)):
            radius = robot.capsules[j].radius
            # points of the capsule: along its axis, pushed by its radius in random directions
            s = rng.uniform(0, 1, (200, 1))
            u = rng.normal(size=(200, 3))
            u *= rng.uniform(0, radius, (200, 1)) / np.linalg.norm(u, axis=1, keepdims=True)
            points = a + s * (b - a) + u
            depth = points @ T[2, :3] + T[2, 3]
            assert depth.max() <= far[0, k, j] + 1e-12


def test_the_depth_order_is_off_by_default_asked_by_a_bool_and_only_with_depth_images():
    import pytest

    from depthguard.collision import ImageCollisionTest
    from depthguard.errors import InputError

    camera = _camera()
    rig = dg.Rig({"c": camera, "d": dg.PinholeCamera("d", 160, 128, 140.0, 140.0, 79.5, 63.5,
                                                     look_at((0.0, 2.5, 0.6), (0.0, 0.0, 0.5)), depth_scale=0.001)})
    robot = RobotModel.default()
    workspace = [[-1.0, -1.0, 0.0], [1.0, 1.0, 1.5]]
    assert not ImageCollisionTest(rig, robot, workspace, tiles=(8, 8), images="depth").depth_order
    assert ImageCollisionTest(rig, robot, workspace, tiles=(8, 8), images="depth", depth_order=True).depth_order
    assert not ImageCollisionTest(rig, robot, workspace, tiles=(8, 8), depth_order=True).depth_order  # intensity
    with pytest.raises(InputError) as error:
        ImageCollisionTest(rig, robot, workspace, tiles=(8, 8), images="depth", depth_order="yes")
    assert error.value.field == "depth_order"


def test_unexplained_tiles_count_the_changed_pixels_the_rendered_robot_cannot_explain():
    """Against a pixel loop: a pixel counts when it changed (depth_difference_image's rule) and no robot is rendered
    within a pixel of it, or it measured nearer than the nearest such robot surface by more than the tolerance and
    the noise margin there; a tile when more than the fraction of its pixels count."""
    from depthguard.collision import unexplained_tiles

    grid = TileGrid(_camera(), 7, 9)
    cam = grid.camera
    rng = np.random.default_rng(3)
    shape = cam.shape
    reference = rng.uniform(1.0, 4.0, shape)
    reference[rng.random(shape) < 0.03] = 0.0
    now = reference.copy()
    moved = rng.random(shape) < 0.5
    now[moved] = rng.uniform(0.5, 4.0, int(moved.sum()))
    now[rng.random(shape) < 0.03] = 0.0
    near = np.where(rng.random(shape) < 0.4, rng.uniform(0.8, 4.0, shape), 0.0).astype(np.float32)
    near[:40, :60] = 0.0  # a stretch without the robot
    got = unexplained_tiles(now, reference, near, grid, (0.05, 0.25), tolerance=0.02)
    h, w = shape
    counts = np.zeros((grid.rows, grid.cols))
    for v in range(h):
        r = np.searchsorted(grid.first_row, v, side="right") - 1
        for u in range(w):
            c = np.searchsorted(grid.first_col, u, side="right") - 1
            d, ref = now[v, u], reference[v, u]
            if (d > 0) == (ref > 0) and (d == 0 or abs(d - ref) <= max(0.05, float(cam.noise.margin(ref)))):
                continue
            window = near[max(v - 1, 0): v + 2, max(u - 1, 0): u + 2]
            if (window > 0).any():
                d_r = float(window[window > 0].min())
                if d == 0 or d >= d_r - 0.02 - float(cam.noise.margin(d_r)):
                    continue
            counts[r, c] += 1
    pixels = np.outer(np.diff(grid.first_row), np.diff(grid.first_col))
    np.testing.assert_array_equal(got, counts / pixels > 0.25)
    assert got.any() and not got.all()
    some = rng.random(got.shape) < 0.5  # only the tiles asked for are looked at; the others are False
    np.testing.assert_array_equal(unexplained_tiles(now, reference, near, grid, (0.05, 0.25), 0.02, tiles=some),
                                  got & some)


def test_unexplained_intensity_tiles_count_the_changed_pixels_outside_the_robots_silhouette():
    """Against a pixel loop: a pixel counts when its grey value over the gain is more than 12 levels from the
    reference's and no robot is rendered within a pixel of it; a tile when more than a quarter of its pixels count."""
    from depthguard.collision import unexplained_intensity_tiles

    grid = TileGrid(_camera(), 7, 9)
    shape = grid.camera.shape
    rng = np.random.default_rng(5)
    reference = rng.uniform(0, 255, shape)
    image = np.where(rng.random(shape) < 0.6, rng.integers(0, 256, shape), np.rint(reference * 1.1)).clip(0, 255)
    image = image.astype(np.uint8)
    near = np.where(rng.random(shape) < 0.05, 2.0, 0.0).astype(np.float32)
    near[:60, :80] = 0.0
    got = unexplained_intensity_tiles(image, reference, 1.1, near, grid)
    h, w = shape
    counts = np.zeros((grid.rows, grid.cols))
    for v in range(h):
        r = np.searchsorted(grid.first_row, v, side="right") - 1
        for u in range(w):
            c = np.searchsorted(grid.first_col, u, side="right") - 1
            if abs(image[v, u] / 1.1 - reference[v, u]) > 12.0 and not (near[max(v - 1, 0): v + 2,
                                                                             max(u - 1, 0): u + 2] > 0).any():
                counts[r, c] += 1
    pixels = np.outer(np.diff(grid.first_row), np.diff(grid.first_col))
    np.testing.assert_array_equal(got, counts / pixels > 0.25)
    assert got.any() and not got.all()
    float_image = unexplained_intensity_tiles(image.astype(np.float64), reference, 1.1, near, grid)
    np.testing.assert_array_equal(float_image, got)


def test_table_i_makes_an_unexplained_foreground_tile_under_the_robot_an_obstacle():
    from depthguard.collision import ERROR, UNKNOWN, obstacle_image

    foreground = np.array([[True, True, False], [True, False, False]])
    robot = np.array([[True, True, True], [False, False, False]])
    unexplained = np.array([[True, False, True], [True, False, False]])
    assert obstacle_image(foreground, robot).tolist() == [[UNKNOWN, UNKNOWN, ERROR], [OBSTACLE, 0, 0]]
    assert obstacle_image(foreground, robot, unexplained).tolist() == [[OBSTACLE, UNKNOWN, ERROR], [OBSTACLE, 0, 0]]


def test_the_pixel_rule_names_what_it_refuses():
    from depthguard.collision import ImageCollisionTest, unexplained_intensity_tiles, unexplained_tiles

    grid = TileGrid(_camera(), 4, 5)
    shape = grid.camera.shape
    depth, near = np.ones(shape), np.zeros(shape, dtype=np.float32)
    with pytest.raises(dg.InputError) as error:
        unexplained_tiles(depth, depth, np.zeros((3, 3), dtype=np.float32), grid)
    assert error.value.field == "near" and error.value.camera == "c"
    with pytest.raises(dg.InputError) as error:
        unexplained_tiles(depth, depth, near, grid, tiles=np.ones((4, 4), dtype=bool))
    assert error.value.field == "tiles"
    with pytest.raises(dg.InputError) as error:
        unexplained_intensity_tiles(np.zeros(shape, dtype=np.uint8), np.zeros((2, 2)), 1.0, near, grid)
    assert error.value.field == "reference"
    for thresholds in ((np.nan, 0.25), (0.05, np.inf), (-0.1, 0.25), (0.05,), "ab"):
        with pytest.raises(dg.InputError) as error:
            unexplained_tiles(depth, depth, near, grid, thresholds)
        assert error.value.field == "thresholds"
    for tolerance in (np.nan, np.inf, -0.01, 1e300, "2 cm", True):
        with pytest.raises(dg.InputError) as error:
            unexplained_tiles(depth, depth, near, grid, tolerance=tolerance)
        assert error.value.field == "tolerance"
    grey_image = np.zeros(shape, dtype=np.uint8)
    for grey, fraction, field in ((np.nan, 0.25, "grey"), (-1.0, 0.25, "grey"), (12.0, np.nan, "fraction"),
                                  (12.0, 1.5, "fraction"), (12.0, "a", "fraction")):
        with pytest.raises(dg.InputError) as error:
            unexplained_intensity_tiles(grey_image, np.zeros(shape), 1.0, near, grid, grey, fraction)
        assert error.value.field == field
    # a gain that is not a number: no estimate of the light, every tile counts (the conservative answer)
    assert unexplained_intensity_tiles(grey_image, np.zeros(shape), "bright", near, grid).all()
    # no estimate of the light: every tile asked for counts (the conservative answer)
    assert unexplained_intensity_tiles(np.zeros(shape, dtype=np.uint8), np.zeros(shape), float("nan"), near,
                                       grid).all()
    with pytest.raises(dg.InputError) as error:
        ImageCollisionTest(dg.Rig({"c": grid.camera}), RobotModel.default(), [[-1, -1, 0], [1, 1, 2]],
                           robot_pixels="yes")
    assert error.value.field == "robot_pixels"
    test = ImageCollisionTest(dg.Rig({"c": grid.camera}), RobotModel.default(), [[-1, -1, 0], [1, 1, 2]],
                              tiles=(4, 5))
    test.reference = [np.zeros((4, 5, 2))]  # tile features set by hand: no reference images to compare pixels with
    with pytest.raises(dg.InputError) as error:
        test.observe({"c": np.zeros(shape, dtype=np.uint8)}, np.zeros(7))
    assert error.value.field == "reference" and test.revised is None


def test_the_reference_leaves_out_the_robots_pixels_when_given_them():
    """reference_image(pixels=...): each pixel's median over the images whose robot does not cover it; over all of
    them where every image's does (judged pixel by pixel)."""
    from depthguard.collision import reference_image

    grid = TileGrid(_camera(), 4, 5)
    rng = np.random.default_rng(8)
    images = [rng.uniform(0, 255, grid.camera.shape) for _ in range(5)]
    masks = [rng.random(grid.camera.shape) < 0.6 for _ in range(5)]
    got = reference_image(images, grid, pixels=masks)
    stack, covered = np.stack(images), np.stack(masks)
    for v, u in zip(*np.nonzero(np.ones(grid.camera.shape, dtype=bool))):
        keep = ~covered[:, v, u] if not covered[:, v, u].all() else np.ones(5, dtype=bool)
        assert got[v, u] == np.median(stack[keep, v, u])
    with pytest.raises(dg.InputError) as error:
        reference_image(images, grid, pixels=masks[:2])
    assert error.value.field == "pixels"
