"""The collision test of Henrich & Gecks (design §10): the paper's Tables I-IV row by row, the Fig. 3-5 example
images, and the epipolar bands judged by sampling the tiles' frusta (the projection by the cameras' own model)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import depthguard as dg
from depthguard.collision import (
    BACKGROUND,
    ERROR,
    OBSTACLE,
    POSSIBLE,
    UNKNOWN,
    EpipolarBands,
    TileGrid,
    camera_collisions,
    intersection_image,
    obstacle_image,
    revised_obstacle_images,
    verdict,
)
from depthguard.errors import InputError
from depthguard.transforms import look_at


def _camera(name, eye, target=(0.0, 0.0, 0.5), width=160, height=128, f=140.0):
    """A camera at ``eye`` looking at ``target`` (z up), optical frame REP 103 (x right, y down, z forward)."""
    return dg.PinholeCamera(name, width, height, f, f, (width - 1) / 2, (height - 1) / 2, look_at(eye, target))


# ------------------------------------------------------------------------------------------------- Table I

@pytest.mark.parametrize("foreground, robot, label", [
    (False, False, BACKGROUND),
    (True, False, OBSTACLE),
    (True, True, UNKNOWN),
    (False, True, ERROR),
])
def test_table_1_row(foreground, robot, label):
    assert obstacle_image(np.array([[foreground]]), np.array([[robot]]))[0, 0] == label


def _letters(rows: str, mapping: dict) -> np.ndarray:
    return np.array([[mapping[ch] for ch in row.split()] for row in rows.strip().splitlines()])


def test_figure_3_example():
    """The paper's Fig. 3: difference image and current robot image give the obstacle image. Two cells are blank in
    the scanned figure: the robot image's row 4, column 3 (R: the obstacle image has U there) and the obstacle
    image's row 5, column 3 (E by Table I: background seen where the robot is)."""
    difference = _letters("""
        B B B B B B F F
        B B B B B B B B
        B B B F F F F B
        B B F F F B B B
        B F B F B B F F
        F F F B B B F F
        F F F B B B B B
        F F F B B B B B""", {"B": False, "F": True})
    robot = _letters("""
        B B B B B B B B
        B B B B B B B B
        B B B R R R R B
        B B R R R B B B
        B R R R B B B B
        R R R B B B B B
        R R R B B B B B
        R R R B B B B B""", {"B": False, "R": True})
    expected = _letters("""
        B B B B B B O O
        B B B B B B B B
        B B B U U U U B
        B B U U U B B B
        B U E U B B O O
        U U U B B B O O
        U U U B B B B B
        U U U B B B B B""", {"B": BACKGROUND, "O": OBSTACLE, "U": UNKNOWN, "E": ERROR})
    assert np.array_equal(obstacle_image(difference.astype(bool), robot.astype(bool)), expected)


# ------------------------------------------------------------------------------------------------- Table II

@pytest.mark.parametrize("revised, robot, hit", [
    (BACKGROUND, True, False),
    (OBSTACLE, True, True),
    (POSSIBLE, True, True),
    (BACKGROUND, False, False),
    (OBSTACLE, False, False),
    (POSSIBLE, False, False),
])
def test_table_2_row(revised, robot, hit):
    assert intersection_image(np.array([[revised]], dtype=np.uint8), np.array([[robot]]))[0, 0] == hit


# ------------------------------------------------------------------------------------------------- Table III

def _one_tile_pair():
    """Two 1 x 2 tile grids whose bands are given: camera 0's tile 0 -> camera 1's tile 1, and back."""
    cam = _camera("a", (2.0, 0.0, 0.5), width=2, height=1, f=1.0)
    grids = [TileGrid(cam, 1, 2), TileGrid(cam, 1, 2)]
    band = np.array([[False, True], [True, False]])
    return EpipolarBands.from_dense(grids, {(0, 1): band, (1, 0): band})


@pytest.mark.parametrize("label, other, revised", [
    (BACKGROUND, BACKGROUND, BACKGROUND),
    (OBSTACLE, BACKGROUND, OBSTACLE),
    (UNKNOWN, BACKGROUND, BACKGROUND),   # epipolar line meets no obstacle
    (UNKNOWN, OBSTACLE, POSSIBLE),       # epipolar line meets an obstacle
    (ERROR, BACKGROUND, BACKGROUND),
    (ERROR, OBSTACLE, POSSIBLE),
    (UNKNOWN, UNKNOWN, BACKGROUND),      # an unknown tile is the robot's, not an obstacle
])
def test_table_3_row(label, other, revised):
    bands = _one_tile_pair()
    first = np.array([[label, BACKGROUND]], dtype=np.uint8)
    second = np.array([[BACKGROUND, other]], dtype=np.uint8)  # tile 1: in the band of camera 0's tile 0
    out = revised_obstacle_images([first, second], bands, theta=1)
    assert out[0][0, 0] == revised
    assert out[0][0, 1] == BACKGROUND


def test_table_3_with_more_cameras_counts_c_minus_theta():
    """C = 4: an unknown tile becomes a possible obstacle only when at least C - theta other cameras see an obstacle
    in its band."""
    cam = _camera("a", (2.0, 0.0, 0.5), width=2, height=1, f=1.0)
    grids = [TileGrid(cam, 1, 2) for _ in range(4)]
    dense = {(a, b): np.ones((2, 2), dtype=bool) for a in range(4) for b in range(4) if a != b}
    bands = EpipolarBands.from_dense(grids, dense)
    for seeing in range(4):
        images = [np.array([[UNKNOWN, BACKGROUND]], dtype=np.uint8)]
        images += [np.array([[OBSTACLE if k < seeing else BACKGROUND, BACKGROUND]], dtype=np.uint8) for k in range(3)]
        for theta in range(4):
            out = revised_obstacle_images(images, bands, theta)[0][0, 0]
            assert out == (POSSIBLE if seeing >= 4 - theta else BACKGROUND), (seeing, theta)


# ------------------------------------------------------------------------------------------------- Table IV

#: The paper's Table IV (two cameras, theta = 1): camera 1 (obstacle, possible), camera 2 (obstacle, possible), class.
TABLE_IV = [
    (False, False, False, False, "A"), (False, False, False, True, "A"), (False, False, True, False, "A"),
    (False, False, True, True, "A"), (False, True, False, False, "A"), (False, True, False, True, "B"),
    (False, True, True, False, "C"), (False, True, True, True, "C"), (True, False, False, False, "A"),
    (True, False, False, True, "C"), (True, False, True, False, "D"), (True, False, True, True, "D"),
    (True, True, False, False, "A"), (True, True, False, True, "C"), (True, True, True, False, "D"),
    (True, True, True, True, "D"),
]


@pytest.mark.parametrize("o1, p1, o2, p2, klass", TABLE_IV)
def test_table_4_row(o1, p1, o2, p2, klass):
    v = verdict([o1, o2], [p1, p2], theta=1, unseen="free")
    assert v.klass == klass
    # Section 3.5's condition: at least C - theta cameras see an obstacle and every camera sees (a possible) one.
    assert v.collision == ((o1 + o2 >= 1) and (o1 or p1) and (o2 or p2)) == (klass in "CD")
    # Fail-safe (the default): class B, a collision with possible obstacles only, collides too.
    assert verdict([o1, o2], [p1, p2], theta=1).collision == ((o1 or p1) and (o2 or p2)) == (klass in "BCD")


def test_classes_for_four_cameras_follow_section_3_5():
    for flags in itertools.product([False, True], repeat=8):
        ro, rp = flags[:4], flags[4:]
        for theta in range(4):
            v = verdict(ro, rp, theta, unseen="free")
            n = sum(ro)
            if not all(a or b for a, b in zip(ro, rp)):
                assert v.klass == "A"
            elif n < 4 - theta:
                assert v.klass == "B"
            else:
                assert v.klass == ("D" if n == 4 else "C")
            assert v.collision == (n >= 4 - theta and all(a or b for a, b in zip(ro, rp)))
            assert verdict(ro, rp, theta).collision == all(a or b for a, b in zip(ro, rp))
    with pytest.raises(InputError, match="unseen"):
        verdict([True], [True], 0, unseen="maybe")


def test_camera_collisions_are_the_two_predicates():
    revised = np.array([[OBSTACLE, POSSIBLE, BACKGROUND]], dtype=np.uint8)
    assert camera_collisions(revised, np.array([[True, False, False]])) == (True, False)
    assert camera_collisions(revised, np.array([[False, True, True]])) == (False, True)
    assert camera_collisions(revised, np.array([[False, False, True]])) == (False, False)


# ------------------------------------------------------------------------------------------------- epipolar bands

WORKSPACE = np.array([[-0.6, -0.6, 0.0], [0.6, 0.6, 1.2]])


@pytest.fixture(scope="module")
def four_cameras():
    eyes = [(2.5, -1.5, 1.8), (2.5, 1.5, 1.8), (-2.0, 2.0, 1.6), (-2.0, -2.0, 2.2)]
    cameras = [_camera(f"c{k}", eye) for k, eye in enumerate(eyes)]
    # Whole tiles of 8 x 8 pixels for two cameras, fractional ones (10.67 x 10.67) for the others.
    grids = [TileGrid(cam, 16, 20) if k < 2 else TileGrid(cam, 12, 15) for k, cam in enumerate(cameras)]
    return grids, EpipolarBands(grids, WORKSPACE)


def test_bands_hold_every_sampled_point_of_the_tile(four_cameras):
    """Judge: points sampled uniformly in a tile's frustum between the camera's workspace depths, projected into
    another camera by its own model, always land on (or within half a pixel of) a tile of the band; and a band is a
    thin part of the image, not all of it."""
    from depthguard.collision import workspace_depths

    grids, bands = four_cameras
    rng = np.random.default_rng(3)
    widths = []
    for a, b in itertools.permutations(range(4), 2):
        ga, gb = grids[a], grids[b]
        near, far = workspace_depths(ga.camera, WORKSPACE)
        for tile in rng.choice(ga.n_tiles, 40, replace=False):
            r, c = divmod(int(tile), ga.cols)
            u = rng.uniform(ga.col_edges[c], ga.col_edges[c + 1], 300)
            v = rng.uniform(ga.row_edges[r], ga.row_edges[r + 1], 300)
            z = rng.uniform(near, far, 300)
            cam = ga.camera
            points = np.stack([(u - cam.cx) / cam.fx * z, (v - cam.cy) / cam.fy * z, z], axis=1)
            pu, pv, pz = gb.camera.project(gb.camera.world_to_camera(cam.camera_to_world(points)))
            inside = (pz > 0) & (pu >= -0.5) & (pu < gb.camera.width - 0.5) & (pv >= -0.5) & (pv < gb.camera.height - 0.5)
            band = bands.band(a, b, int(tile))
            tile_row, tile_col = gb.tile_of_pixels()  # the tile of the pixel whose footprint holds the point
            cols = tile_col[np.clip(np.floor(pu[inside] + 0.5).astype(int), 0, gb.camera.width - 1)]
            rows = tile_row[np.clip(np.floor(pv[inside] + 0.5).astype(int), 0, gb.camera.height - 1)]
            assert band[rows, cols].all(), (a, b, tile)
            widths.append(band.mean())
    assert np.median(widths) < 0.25, np.median(widths)


def test_a_band_reaching_behind_the_other_camera_sets_every_tile():
    """A tile whose frustum passes behind the other camera's image plane may be seen anywhere by it."""
    front = _camera("front", (2.0, 0.0, 0.5), target=(0.0, 0.0, 0.5))
    inside = _camera("inside", (0.0, 0.0, 0.5), target=(2.0, 0.0, 0.5))  # in the workspace, facing the first
    grids = [TileGrid(front, 4, 5), TileGrid(inside, 4, 5)]
    bands = EpipolarBands(grids, WORKSPACE)
    # Every tile's frustum within the workspace depths (x from 0.6 down to -0.6) crosses x = 0, behind the second
    # camera: every band is the whole image (the sampling test shows bands are thin otherwise).
    assert all(bands.band(0, 1, tile).all() for tile in range(grids[0].n_tiles))


def test_a_camera_that_does_not_see_the_workspace_is_refused():
    away = _camera("away", (-2.0, 0.0, 0.5), target=(-4.0, 0.0, 0.5))
    front = _camera("front", (2.0, 0.0, 0.5), target=(0.0, 0.0, 0.5))
    with pytest.raises(InputError, match="camera 'away'.*workspace"):
        EpipolarBands([TileGrid(front, 4, 5), TileGrid(away, 4, 5)], WORKSPACE)


def test_tiles_partition_the_pixels():
    cam = _camera("c", (2.0, 0.0, 0.5))
    for rows, cols in [(16, 20), (12, 15), (7, 9), (128, 160), (1, 1)]:
        grid = TileGrid(cam, rows, cols)
        tile_row, tile_col = grid.tile_of_pixels()
        assert tile_row.min() == 0 and tile_row.max() == rows - 1 and np.all(np.diff(tile_row) >= 0)
        assert tile_col.min() == 0 and tile_col.max() == cols - 1 and np.all(np.diff(tile_col) >= 0)
        for c in range(cols):  # a tile's pixels are those whose centres lie in [c * tile_w, (c + 1) * tile_w)
            pixels = np.flatnonzero(tile_col == c)
            assert np.all(pixels >= c * grid.tile_w - 1e-9) and np.all(pixels < (c + 1) * grid.tile_w - 1e-9)
            assert grid.col_edges[c] == pixels[0] - 0.5 and grid.col_edges[c + 1] == pixels[-1] + 0.5


@pytest.mark.parametrize("rows, cols", [(0, 4), (4, 0), (True, 4), (4, 2.5), (129, 4), (4, 161)])
def test_bad_tile_grids_are_refused(rows, cols):
    with pytest.raises(InputError, match="camera 'c'"):
        TileGrid(_camera("c", (2.0, 0.0, 0.5)), rows, cols)


def test_bad_inputs_to_the_tables_are_refused():
    bands = _one_tile_pair()
    good = np.zeros((1, 2), dtype=np.uint8)
    with pytest.raises(InputError, match="theta"):
        revised_obstacle_images([good, good], bands, theta=2)
    with pytest.raises(InputError, match="theta"):
        verdict([True], [False], theta=-1)
    with pytest.raises(InputError, match="obstacle image 1"):
        revised_obstacle_images([good, np.zeros((2, 2), dtype=np.uint8)], bands, theta=1)
    with pytest.raises(InputError, match="obstacle images"):
        revised_obstacle_images([good], bands, theta=0)
    with pytest.raises(InputError, match="robot"):
        obstacle_image(np.zeros((2, 2), dtype=bool), np.zeros((2, 3), dtype=bool))
    with pytest.raises(InputError, match="foreground"):
        obstacle_image(np.zeros((2, 2)), np.zeros((2, 2), dtype=bool))


# ------------------------------------------------------------------------------------------------- steps 1-3

def _loop_features(image, grid):
    """The features written tile by tile: mean grey value, balance point's row within the tile (0 .. 1)."""
    out = np.empty((grid.rows, grid.cols, 2))
    for r in range(grid.rows):
        for c in range(grid.cols):
            rows = [v for v in range(grid.camera.height) if r * grid.tile_h <= v < (r + 1) * grid.tile_h]
            cols = [u for u in range(grid.camera.width) if c * grid.tile_w <= u < (c + 1) * grid.tile_w]
            tile = image[np.ix_(rows, cols)].astype(float)
            out[r, c, 0] = tile.mean()
            y = (np.arange(len(rows)) / (len(rows) - 1)) if len(rows) > 1 else np.full(1, 0.5)
            out[r, c, 1] = (tile.sum(axis=1) @ y) / tile.sum() if tile.sum() > 0 else 0.5
    return out


@pytest.mark.parametrize("rows, cols", [(16, 20), (12, 15)])
def test_tile_features_equal_a_tile_by_tile_judge(rows, cols):
    from depthguard.collision import tile_features

    grid = TileGrid(_camera("c", (2.0, 0.0, 0.5)), rows, cols)
    rng = np.random.default_rng(rows)
    image = rng.integers(0, 256, grid.camera.shape).astype(np.uint8)
    image[:20, :30] = 0  # tiles of zeros: balance point 0.5
    assert np.allclose(tile_features(image, grid), _loop_features(image, grid))


def test_reference_median_removes_a_robot_seen_in_fewer_than_half_of_the_images():
    from depthguard.collision import reference_image

    grid = TileGrid(_camera("c", (2.0, 0.0, 0.5)), 16, 20)
    rng = np.random.default_rng(1)
    background = rng.integers(20, 200, grid.camera.shape).astype(np.uint8)
    images = []
    for k in range(5):  # the "robot": a bright block in a different place each time
        image = background.copy()
        image[10 + 20 * k: 40 + 20 * k, 15 * k: 15 * k + 40] = 250
        images.append(image)
    assert np.array_equal(reference_image(images, grid), background.astype(float))


def test_difference_image_finds_an_object_and_closing_only_adds():
    from depthguard.collision import difference_image, robot_tiles, tile_features

    grid = TileGrid(_camera("c", (2.0, 0.0, 0.5)), 16, 20)
    rng = np.random.default_rng(2)
    background = rng.normal(100, 2, grid.camera.shape).clip(0, 255).astype(np.uint8)
    scene = background.copy()
    scene[16:40, 24:32] = 220  # an object over tiles (2-4, 3)
    scene[16:40, 40:48] = 220  # another one column of tiles further: (2-4, 5)
    foreground = difference_image(tile_features(scene, grid), tile_features(background, grid))
    expected = np.zeros((16, 20), dtype=bool)
    expected[2:5, 3] = expected[2:5, 5] = True
    expected[3, 4] = True  # the closing in the 4-neighbourhood fills the gap where both its row neighbours are set
    assert np.array_equal(foreground, expected)
    # A foreground tile on the border stays foreground.
    scene = background.copy()
    scene[:8, :8] = 255
    assert difference_image(tile_features(scene, grid), tile_features(background, grid))[0, 0]
    # The balance point sees a change that keeps the mean: a tile's bright half moved from its top to its bottom.
    top, bottom = background.copy(), background.copy()
    top[64:68, 80:88], bottom[68:72, 80:88] = 250, 250
    top[68:72, 80:88], bottom[64:68, 80:88] = 0, 0
    assert difference_image(tile_features(bottom, grid), tile_features(top, grid))[8, 10]
    # The robot's tile image: a tile with any robot pixel.
    mask = np.zeros(grid.camera.shape, dtype=bool)
    mask[17, 9] = True
    tiles = robot_tiles(mask, grid)
    assert tiles[2, 1] and tiles.sum() == 1


def test_bad_images_are_refused():
    from depthguard.collision import difference_image, reference_image, robot_tiles, tile_features

    grid = TileGrid(_camera("c", (2.0, 0.0, 0.5)), 16, 20)
    with pytest.raises(InputError, match="camera 'c'.*image"):
        tile_features(np.zeros((10, 10)), grid)
    with pytest.raises(InputError, match="image"):
        tile_features(np.full(grid.camera.shape, np.nan), grid)
    with pytest.raises(InputError, match="at least one image"):
        reference_image([], grid)
    with pytest.raises(InputError, match="robot_mask"):
        robot_tiles(np.zeros(grid.camera.shape), grid)
    with pytest.raises(InputError, match="threshold"):
        difference_image(np.zeros((16, 20, 2)), np.zeros((16, 20, 2)), thresholds=(1.0, -1.0))


# ------------------------------------------------------------------------------------------------- the whole test

@pytest.fixture(scope="module")
def iiwa_scene():
    """Four 320 x 256 cameras around a KUKA iiwa; a textured room; images drawn from the robot's padded capsules (its
    render) and exact ray-cast obstacles."""
    from depthguard.collision import ImageCollisionTest
    from depthguard.robots import RobotModel

    robot = RobotModel.default()
    eyes = [(2.2, -1.6, 1.6), (2.2, 1.6, 1.6), (-1.8, 1.8, 1.8), (-1.8, -1.8, 1.4)]
    cameras = {f"c{k}": _camera(f"c{k}", eye, target=(0.2, 0.0, 0.5), width=320, height=256, f=260.0)
               for k, eye in enumerate(eyes)}
    rig = dg.Rig(cameras)
    workspace = [[-1.0, -1.0, -0.1], [1.2, 1.0, 1.5]]
    test = ImageCollisionTest(rig, robot, workspace, tiles=(32, 32), theta=1)
    rng = np.random.default_rng(11)
    backgrounds = {name: np.kron(rng.integers(40, 160, (32, 40)), np.ones((8, 8))) for name in cameras}
    return test, robot, cameras, backgrounds


_SILHOUETTES = {}


def _silhouette(robot, geometry: str = "capsules"):
    """The robot's padded capsules (or its ``geometry``) rendered (OpenGL), one renderer per robot and geometry for
    the module."""
    from depthguard.self_filter import RobotSilhouette

    key = (id(robot), geometry)
    if key not in _SILHOUETTES:
        _SILHOUETTES[key] = (robot, RobotSilhouette(robot, geometry=geometry))
    return _SILHOUETTES[key][1]


def _draw(test, backgrounds, cameras, joints, obstacles=()):
    """Images of the scene: the background, the robot's render at ``joints`` and the obstacles in bright grey."""
    from depthguard.scenes import render_depth

    q = test.robot.joint_vector(joints)
    images = {}
    for name, camera in cameras.items():
        image = backgrounds[name].copy()
        image[_silhouette(test.robot, "meshes").render(camera, q) > 0] = 235  # the robot as a camera sees it
        if obstacles:
            image[render_depth(camera, list(obstacles)) > 0] = 250
        images[name] = image.astype(np.uint8)
    return images


def test_the_whole_test_finds_a_box_in_a_future_configurations_way_and_nothing_without_it(iiwa_scene):
    from depthguard.scenes import Box

    test, robot, cameras, backgrounds = iiwa_scene
    poses = [np.array([a, 0.5, 0.0, -1.4, 0.0, 0.8, 0.0]) for a in (-1.2, -0.6, 0.0, 0.6, 1.2)]
    test.set_reference({name: [_draw(test, backgrounds, cameras, q)[name] for q in poses] for name in cameras})
    now = np.array([0.0, 0.4, 0.0, -1.5, 0.0, 0.8, 0.0])
    future = np.array([0.9, 0.7, 0.0, -1.2, 0.0, 0.8, 0.0])
    # Nothing in the workspace but the robot: its own tiles resolve to background, every configuration is free.
    test.observe(_draw(test, backgrounds, cameras, now), now)
    assert not test.test(now).collision
    assert test.test(now).shell  # free, and it rests on the shell: its image is the current robot's in every camera
    assert not test.test(future).collision
    # A box where the future configuration's end-effector will be: that configuration collides, the current not.
    target = robot.control_point_positions(future)[robot.end_effector_index]
    box = Box.from_bounds(target - 0.08, target + 0.08)
    assert np.linalg.norm(robot.control_point_positions(now)[robot.end_effector_index] - target) > 0.4
    test.observe(_draw(test, backgrounds, cameras, now, [box]), now)
    hit = test.test(future)
    assert hit.collision and hit.klass in "CD", hit
    assert not test.test(now).collision


@pytest.mark.parametrize("images", ["intensity", "depth"])
@pytest.mark.parametrize("robot_pixels", [True, False])
def test_an_object_where_the_robot_stood_in_every_reference_image_is_not_taken_for_the_room(iiwa_scene, images,
                                                                                           robot_pixels):
    """Where the robot covered a pixel in every reference image, the reference holds the robot (nothing else was
    seen there). Once the robot has left such pixels, whatever they show counts as a change: here an object of the
    robot's shape, grey level and depth standing exactly where it stood, which matches the reference pixel for pixel.
    Without that rule (``unreferenced`` cleared) the configuration the robot stood in tests free. With or without
    the robot's render (``robot_pixels``: its pixels; else its projected tiles)."""
    from depthguard.collision import ImageCollisionTest

    _, robot, cameras, backgrounds = iiwa_scene
    rig = dg.Rig(cameras)
    stood = np.array([0.0, 0.5, 0.0, -1.4, 0.0, 0.8, 0.0])
    now = np.array([2.2, 0.5, 0.0, -1.4, 0.0, 0.8, 0.0])
    meshes = _silhouette(robot, "meshes")

    def picture(*poses):
        """Per camera, the room with the robot's meshes drawn at each of ``poses`` (grey 235, or their depth)."""
        out = {}
        for name, camera in cameras.items():
            if images == "intensity":
                image = backgrounds[name].astype(np.uint8)
                for q in poses:
                    image[meshes.render(camera, q) > 0] = 235
            else:
                image = np.full(camera.shape, 4.0, dtype=np.float32)
                for q in poses:
                    depth = meshes.render(camera, q)
                    image = np.where((depth > 0) & (depth < image), depth, image).astype(np.float32)
            out[name] = image
        return out

    def verdict_where_it_stood(rule: bool):
        test = ImageCollisionTest(rig, robot, [[-1.0, -1.0, -0.1], [1.2, 1.0, 1.5]], tiles=(32, 32), images=images,
                                  robot_pixels=robot_pixels)
        reference = picture(stood)
        test.set_reference({name: [reference[name]] * 3 for name in cameras}, joints=[stood] * 3)
        assert all(mask is not None and mask.sum() > 100 for mask in test.unreferenced)
        if not rule:
            test.unreferenced = None
        test.observe(picture(stood, now), now)  # the robot has moved on; the object stands where it stood
        return test.test(stood)

    assert verdict_where_it_stood(True).collision
    assert not verdict_where_it_stood(False).collision  # what the rule is for: the reference matches the object


@pytest.mark.parametrize("workspace", [
    [[0, 0, 0], [1, 1]], [[0, 0, 0], [np.nan, 1, 1]], [[0, 0, 0], [np.inf, 1, 1]], [[1, 0, 0], [0, 1, 1]], "box", None,
    [[-1e300, 0, 0], [1e300, 1, 1]],
])
def test_bad_workspaces_are_refused(workspace):
    cam = _camera("c", (2.0, 0.0, 0.5))
    with pytest.raises(InputError, match="workspace"):
        EpipolarBands([TileGrid(cam, 4, 5), TileGrid(cam, 4, 5)], workspace)


def test_the_whole_test_refuses_what_it_cannot_use(iiwa_scene):
    test, robot, cameras, backgrounds = iiwa_scene
    for thresholds in [(1.0,), (1.0, np.nan), (1.0, -1.0), ("a", 1.0), "12"]:
        with pytest.raises(InputError, match="thresholds"):
            type(test)(dg.Rig(cameras), robot, [[-1, -1, -0.1], [1, 1, 1.5]], tiles=(8, 8), thresholds=thresholds)
    with pytest.raises(InputError, match="every camera"):
        test.observe({"c0": backgrounds["c0"]}, np.zeros(7))
    with pytest.raises(InputError, match="theta"):
        type(test)(dg.Rig(cameras), robot, [[-1, -1, -0.1], [1, 1, 1.5]], tiles=(8, 8), theta=4)


def test_the_configuration_table_gives_every_verdict_the_slow_test_gives(iiwa_scene):
    """ConfigurationTable: the verdicts of many configurations at once, from bitsets, equal ImageCollisionTest.test
    on each (the judge: its per-configuration render and tile sets), with and without the box."""
    from depthguard.collision import ConfigurationTable
    from depthguard.scenes import Box

    test, robot, cameras, backgrounds = iiwa_scene
    poses = [np.array([a, 0.5, 0.0, -1.4, 0.0, 0.8, 0.0]) for a in (-1.2, -0.6, 0.0, 0.6, 1.2)]
    test.set_reference({name: [_draw(test, backgrounds, cameras, q)[name] for q in poses] for name in cameras})
    rng = np.random.default_rng(8)
    now = np.array([0.0, 0.4, 0.0, -1.5, 0.0, 0.8, 0.0])
    configurations = now + rng.uniform(-1.0, 1.0, (24, 7)) * [1.2, 0.5, 0.8, 0.6, 1.0, 0.6, 1.0]
    table = ConfigurationTable(test, configurations)
    future = configurations[3]
    target = robot.control_point_positions(future)[robot.end_effector_index]
    classes = set()
    for obstacles in ([], [Box.from_bounds(target - 0.08, target + 0.08)]):
        test.observe(_draw(test, backgrounds, cameras, now, obstacles), now)
        collision, klass = table.verdicts()
        for k, q in enumerate(configurations):
            v = test.test(q)
            assert (collision[k], klass[k]) == (v.collision, v.klass), k
        classes |= set(klass.tolist())
    assert collision[3] and len(classes) >= 2, classes


def test_a_configuration_table_refuses_bad_configurations(iiwa_scene):
    from depthguard.collision import ConfigurationTable

    test = iiwa_scene[0]
    for bad in (np.zeros((3, 6)), np.full((2, 7), np.nan), np.zeros(7)):
        with pytest.raises(InputError, match="configurations"):
            ConfigurationTable(test, bad)


# ------------------------------------------------------------------------------------ the robot's tile images

def test_projected_capsules_cover_every_tile_their_render_covers(iiwa_scene):
    """Step 3 without rendering: the analytic projection of the padded capsules sets every tile in which the capsules'
    render (OpenGL, tests/judge) shows a pixel, and not many more (a projection that set every tile would fail)."""
    from depthguard.collision import robot_tiles

    test, robot, cameras, _ = iiwa_scene
    rng = np.random.default_rng(5)
    covered = extra = 0
    for _ in range(12):
        q = rng.uniform(robot.lower, robot.upper)
        for grid, tiles in zip(test.grids, test.robot_image(q)):
            rendered = robot_tiles(_silhouette(robot).render(grid.camera, q) > 0.0, grid)
            assert not np.any(rendered & ~tiles), grid.camera.name
            covered += rendered.sum()
            extra += (tiles & ~rendered).sum()
    assert covered > 500 and extra < 0.5 * covered, (covered, extra)


def test_a_balls_projected_bounds_are_its_tangents():
    """The slopes a/z of the tangents to a ball equal the extremes over densely sampled points of its surface."""
    from depthguard.kernels.collision import _ball_slopes

    for a, z, rho in [(0.3, 1.5, 0.1), (-0.8, 0.9, 0.4), (0.0, 2.0, 0.05), (1.5, 0.7, 0.6)]:
        angles = np.linspace(0.0, 2 * np.pi, 200_001)
        slopes = (a + rho * np.cos(angles)) / (z + rho * np.sin(angles))
        lo, hi = _ball_slopes(a, z, rho)
        # Never inside the sampled extremes (the bound holds), and within the samples' spacing of them (exact).
        assert lo <= slopes.min() + 1e-12 and hi >= slopes.max() - 1e-12
        assert slopes.min() - lo < 1e-8 * abs(slopes).max() and hi - slopes.max() < 1e-8 * abs(slopes).max()


def test_swept_samples_move_no_point_of_the_robot_more_than_x_max(iiwa_scene):
    """Step 7's sampling: between two consecutive samples no vertex of the robot's collision meshes (nor its capsule
    ends) moves more than x_max (judge: forward kinematics of the samples); the joint reaches bound what they must."""
    from depthguard.collision import RobotProjector

    test, robot, _, _ = iiwa_scene
    projector = RobotProjector(robot, test.grids, x_max=0.03)
    rng = np.random.default_rng(3)
    path = rng.uniform(robot.lower * 0.7, robot.upper * 0.7, (3, 7))
    samples = projector.samples(path)
    assert len(samples) > 20 and np.allclose(samples[0], path[0]) and np.allclose(samples[-1], path[-1])
    vertices = {link: mesh.vertices for link, mesh in robot.collision_meshes.items()}

    def points(q):
        poses = robot.link_poses(q)
        return np.concatenate([v @ poses[link][:3, :3].T + poses[link][:3, 3] for link, v in vertices.items()])

    worst = 0.0
    previous = points(samples[0])
    for q in samples[1:]:
        now = points(q)
        worst = max(worst, float(np.linalg.norm(now - previous, axis=1).max()))
        previous = now
    assert 0.3 * projector.x_max < worst <= projector.x_max, worst


def test_a_swept_volume_holds_every_intermediate_configuration(iiwa_scene):
    """The swept volume's tiles hold the tiles of configurations sampled 20 times more densely than its own samples
    (each at its unwidened capsules), in every camera."""
    test, robot, _, _ = iiwa_scene
    rng = np.random.default_rng(4)
    path = rng.uniform(robot.lower * 0.6, robot.upper * 0.6, (2, 7))
    swept = test.projector.swept_images(path)
    samples = test.projector.samples(path)
    s = np.linspace(0.0, 1.0, 20 * len(samples))[:, None]
    dense = test.projector.bits(path[0] + s * (path[1] - path[0]))
    for c, grid in enumerate(test.grids):
        union = np.bitwise_or.reduce(dense[c], axis=0)
        held = grid.pack(swept[c])
        assert not np.any(union & ~held), grid.camera.name
    assert all(image.sum() < image.size for image in swept)


def test_a_motion_between_two_free_configurations_collides_with_a_box_between_them(iiwa_scene):
    """test_motion: both ends of a motion are clear of a box that the end-effector passes through on the way; the
    swept volume finds it, the two end configurations do not (the paper's rule: with the default, fail-safe one the
    ends meet possible obstacles in every camera, class B, and collide too)."""
    from depthguard.collision import ImageCollisionTest
    from depthguard.scenes import Box

    shared, robot, cameras, backgrounds = iiwa_scene
    # The paper's rule and Table I (robot_pixels=False): the box shares tiles with the start's robot image in three
    # cameras, an obstacle there with robot_pixels, which makes the start collide too.
    test = ImageCollisionTest(dg.Rig(cameras), robot, [[-1.0, -1.0, -0.1], [1.2, 1.0, 1.5]], tiles=(32, 32), theta=1,
                              unseen="free", robot_pixels=False)
    poses = [np.array([a, 0.5, 0.0, -1.4, 0.0, 0.8, 0.0]) for a in (-1.2, -0.6, 0.0, 0.6, 1.2)]
    test.set_reference({name: [_draw(test, backgrounds, cameras, q)[name] for q in poses] for name in cameras})
    start = np.array([-1.8, 0.7, 0.0, -1.2, 0.0, 0.8, 0.0])
    end = np.array([1.8, 0.7, 0.0, -1.2, 0.0, 0.8, 0.0])
    middle = robot.control_point_positions((start + end) / 2)[robot.end_effector_index]
    box = Box.from_bounds(middle - 0.06, middle + 0.06)
    test.observe(_draw(test, backgrounds, cameras, start, [box]), start)
    assert not test.test(start).collision and not test.test(end).collision
    assert test.test_motion([start, end]).collision
    assert test.test_motion([start]).collision == test.test(start).collision
    shared.set_reference({name: [_draw(shared, backgrounds, cameras, q)[name] for q in poses] for name in cameras})
    shared.observe(_draw(shared, backgrounds, cameras, start, [box]), start)
    # the default: class B without robot_pixels; with them the box, sharing tiles with the start's robot image, is an
    # obstacle in three cameras (class C): a collision either way
    assert shared.test_motion([start, end]).collision and shared.test(start).klass in "BC"


@pytest.mark.parametrize("x_max", [0.0, -0.01, np.nan, np.inf, True, "2 cm", 0.9])
def test_bad_x_max_is_refused(iiwa_scene, x_max):
    from depthguard.collision import RobotProjector

    test, robot = iiwa_scene[:2]
    with pytest.raises(InputError, match="x_max"):
        RobotProjector(robot, test.grids, x_max=x_max)


def test_bad_motions_are_refused(iiwa_scene):
    test, robot = iiwa_scene[:2]
    for bad in (np.zeros((2, 6)), np.full((2, 7), np.nan), np.full((2, 7), 9.0), "path"):
        with pytest.raises(InputError):
            test.projector.swept_images(bad)


# ------------------------------------------------------------------------------------------- the depth variant

@pytest.mark.parametrize("rows, cols", [(16, 20), (12, 15)])
def test_depth_difference_image_equals_a_pixel_by_pixel_judge(rows, cols):
    """The depth variant's changed pixels per tile (a numba kernel) against numpy, pixel by pixel: measured in one
    image only, or beyond max(threshold, the noise margin) apart; uint16 in depth_scale units and float metres."""
    from depthguard.collision import depth_difference_image

    camera = dg.PinholeCamera("d", 160, 128, 140.0, 140.0, 79.5, 63.5, np.eye(4), depth_scale=0.001)
    grid = TileGrid(camera, rows, cols)
    rng = np.random.default_rng(6)
    reference = rng.uniform(0.5, 4.0, camera.shape) * (rng.random(camera.shape) > 0.1)
    now_m = np.where(reference > 0, reference + rng.normal(0.0, 0.01, camera.shape), 0.0)  # noise, mostly within
    now_m[40:70, 30:90] = np.maximum(reference[40:70, 30:90] - rng.uniform(0.0, 0.4, (30, 60)), 0.3)  # an object
    now_m = np.where(rng.random(camera.shape) < 0.03, 0.0, now_m)  # dropouts
    now_units = np.rint(now_m * 1000.0).astype(np.uint16)
    for image, metres in ((now_units, now_units * 0.001), (now_m.astype(np.float32), now_m.astype(np.float32))):
        for thresholds in ((0.05, 0.1), (0.02, 0.3)):
            margin = np.maximum(thresholds[0], camera.noise.margin(reference))
            seen, ref_seen = metres > 0, reference > 0
            changed = (seen != ref_seen) | (seen & ref_seen & (np.abs(metres.astype(np.float64) - reference) > margin))
            fraction = np.array([[changed[grid.first_row[r]:grid.first_row[r + 1],
                                          grid.first_col[c]:grid.first_col[c + 1]].mean() for c in range(cols)]
                                 for r in range(rows)])
            expected = fraction > thresholds[1]
            from scipy import ndimage
            expected = expected | ndimage.binary_closing(expected, structure=np.array([[0, 1, 0], [1, 1, 1],
                                                                                          [0, 1, 0]], dtype=bool))
            got = depth_difference_image(image, reference, grid, thresholds)
            assert np.array_equal(got, expected), (image.dtype, thresholds)
            assert 0 < got.sum() < got.size


# ------------------------------------------------------------------------------------ the Bayes tile classifier

def test_the_bayes_classifier_learns_two_classes_and_leans_towards_foreground_below_one_half():
    from depthguard.collision import BayesTileClassifier

    rng = np.random.default_rng(9)
    background = np.abs(rng.normal([0.5, 0.01], [0.4, 0.01], (4000, 2)))
    foreground = np.abs(rng.normal([25.0, 0.15], [12.0, 0.1], (400, 2)))
    x = np.concatenate([background, foreground])
    y = np.concatenate([np.zeros(len(background), bool), np.ones(len(foreground), bool)])
    classifier = BayesTileClassifier(0.5).fit(x[::2], y[::2])
    got = classifier.foreground(x[1::2])
    assert np.mean(got == y[1::2]) > 0.97 and got[y[1::2]].mean() > 0.95
    leaning = BayesTileClassifier(0.05).fit(x[::2], y[::2]).foreground(x[1::2])
    assert np.all(leaning >= got) and leaning.sum() > got.sum()  # a lower threshold only adds foreground
    assert classifier.foreground(x.reshape(2, -1, 2)).shape == (2, len(x) // 2)


def test_labelled_tiles_label_by_a_tenth_of_the_pixels_and_leave_out_mixed_and_excluded_tiles():
    from depthguard.collision import labelled_tiles

    camera = dg.PinholeCamera("c", 40, 30, 40.0, 40.0, 19.5, 14.5, np.eye(4))
    grid = TileGrid(camera, 3, 4)  # 10 x 10 pixel tiles
    truth = np.zeros(camera.shape, dtype=bool)
    truth[0:10, 0:10] = True          # tile (0, 0): all
    truth[10:12, 10:15] = True        # tile (1, 1): 10 of 100 pixels
    truth[20, 30] = True              # tile (2, 3): 1 pixel (mixed: left out)
    features = np.zeros((3, 4, 2))
    features[..., 0] = np.arange(12).reshape(3, 4)
    exclude = np.zeros((3, 4), dtype=bool)
    exclude[0, 3] = True
    x, y = labelled_tiles(features, np.zeros((3, 4, 2)), truth, grid, exclude=exclude)
    assert len(x) == 10 and y.sum() == 2
    assert sorted(x[y, 0].tolist()) == [0.0, 5.0] and 11.0 not in x[:, 0] and 3.0 not in x[:, 0]


def test_the_whole_test_with_a_bayes_classifier_finds_the_box(iiwa_scene):
    from depthguard.collision import BayesTileClassifier, ImageCollisionTest, labelled_tiles, light_gain, tile_features
    from depthguard.scenes import Box, render_depth

    shared, robot, cameras, backgrounds = iiwa_scene
    poses = [np.array([a, 0.5, 0.0, -1.4, 0.0, 0.8, 0.0]) for a in (-1.2, -0.6, 0.0, 0.6, 1.2)]
    now = np.array([0.0, 0.4, 0.0, -1.5, 0.0, 0.8, 0.0])
    future = np.array([0.9, 0.7, 0.0, -1.2, 0.0, 0.8, 0.0])
    target = robot.control_point_positions(future)[robot.end_effector_index]
    box = Box.from_bounds(target - 0.08, target + 0.08)
    training_box = Box.from_bounds(target + [-0.5, 0.3, -0.08], target + [-0.34, 0.46, 0.08])
    references = {name: [_draw(shared, backgrounds, cameras, q)[name] for q in poses] for name in cameras}
    shared.set_reference(references, joints=poses)
    # training: a frame with another box, labelled by its exact render
    frame = _draw(shared, backgrounds, cameras, now, [training_box])
    x, y = [], []
    for c, (name, grid) in enumerate(zip(shared.names, shared.grids)):
        features = tile_features(frame[name], grid)
        truth = render_depth(cameras[name], [training_box]) > 0
        xs, ys = labelled_tiles(features, shared.reference[c], truth, grid, light_gain(features, shared.reference[c]),
                                shared.robot_image(now)[c])
        x.append(xs)
        y.append(ys)
    classifier = BayesTileClassifier().fit(np.concatenate(x), np.concatenate(y))
    test = ImageCollisionTest(dg.Rig(cameras), robot, [[-1.0, -1.0, -0.1], [1.2, 1.0, 1.5]], tiles=(32, 32),
                              theta=1, unseen="free", classifier=classifier)
    test.set_reference(references, joints=poses)
    test.observe(_draw(test, backgrounds, cameras, now), now)
    assert not test.test(future).collision
    test.observe(_draw(test, backgrounds, cameras, now, [box]), now)
    assert test.test(future).collision


@pytest.mark.parametrize("threshold", [0.0, 1.0, -0.1, True, "0.2", np.nan])
def test_a_bayes_classifier_refuses_bad_thresholds(threshold):
    from depthguard.collision import BayesTileClassifier

    with pytest.raises(InputError, match="threshold"):
        BayesTileClassifier(threshold)


def test_a_bayes_classifier_refuses_what_it_cannot_learn_from():
    from depthguard.collision import BayesTileClassifier

    classifier = BayesTileClassifier()
    with pytest.raises(InputError, match="fit"):
        classifier.foreground(np.zeros((3, 2)))
    with pytest.raises(InputError, match="at least 3"):
        classifier.fit(np.zeros((10, 2)), np.array([True, True] + [False] * 8))
    for x, y in ((np.zeros((10, 3)), np.zeros(10, bool)), (np.zeros((10, 2)), np.zeros(10)),
                 (np.full((10, 2), np.nan), np.zeros(10, bool))):
        with pytest.raises(InputError, match="distances"):
            classifier.fit(x, y)


def test_a_refused_set_of_images_leaves_no_answer_behind(iiwa_scene):
    test, robot, cameras, backgrounds = iiwa_scene
    poses = [np.array([a, 0.5, 0.0, -1.4, 0.0, 0.8, 0.0]) for a in (-1.2, -0.6, 0.0, 0.6, 1.2)]
    test.set_reference({name: [_draw(test, backgrounds, cameras, q)[name] for q in poses] for name in cameras})
    now = poses[2]
    good = _draw(test, backgrounds, cameras, now)
    test.observe(good, now)
    assert test.test(now).klass in "ABCD" and len(test.gains) == 4
    with pytest.raises(InputError):
        test.observe({**good, "c2": good["c2"][:-1]}, now)
    with pytest.raises(InputError, match="observe"):
        test.test(now)
    assert test.gains == []


def test_a_dark_tiles_balance_point_is_not_compared():
    """On a near-black tile a few grey levels of noise put the balance point anywhere: only the mean is compared
    there; on a brighter tile the same shift of the balance point makes it foreground."""
    from depthguard.collision import BALANCE_MIN_MEAN, difference_image, feature_distances

    reference = np.array([[[2.0, 0.5], [100.0, 0.5]]])
    now = np.array([[[2.5, 0.9], [100.0, 0.9]]])
    distances = feature_distances(now, reference)
    assert distances[0, 0, 1] == 0.0 and distances[0, 1, 1] == pytest.approx(0.4)
    assert BALANCE_MIN_MEAN > 2.5
    assert difference_image(now, reference).tolist() == [[False, True]]


def test_future_configurations_leave_the_base_out(iiwa_scene):
    """The base never moves: a future configuration's tiles are its moving links' (the base stays inside the robot's
    own volume); the current robot image keeps every link."""
    test, robot = iiwa_scene[:2]
    moving = robot.moving_links()
    assert moving.tolist() == [False] + [True] * 7
    q = np.array([0.3, 0.5, 0.0, -1.4, 0.0, 0.8, 0.0])
    everything = test.robot_image(q)
    future = test.robot_image(q, future=True)
    for all_tiles, moving_tiles in zip(everything, future):
        assert np.all(all_tiles >= moving_tiles) and all_tiles.sum() > moving_tiles.sum()


def test_a_bayes_classifier_calls_what_it_cannot_measure_foreground():
    from depthguard.collision import BayesTileClassifier

    rng = np.random.default_rng(1)
    x = np.concatenate([np.abs(rng.normal(0.5, 0.3, (50, 2))), np.abs(rng.normal(30.0, 5.0, (50, 2)))])
    classifier = BayesTileClassifier(0.5).fit(x, np.arange(100) >= 50)
    assert classifier.foreground(np.array([[np.nan, 0.0], [0.0, np.inf], [0.1, 0.0]])).tolist() == [True, True, False]


def test_a_configuration_table_refuses_more_configurations_than_its_cap(iiwa_scene, monkeypatch):
    from depthguard import config
    from depthguard.collision import ConfigurationTable

    monkeypatch.setattr(config, "MAX_TABLE_CONFIGURATIONS", 8)
    with pytest.raises(InputError, match="at most 8"):
        ConfigurationTable(iiwa_scene[0], np.zeros((9, 7)))
    assert ConfigurationTable(iiwa_scene[0], np.zeros((8, 7))).bits.shape[1] == 8


def test_a_motion_needing_more_samples_than_the_cap_is_refused(iiwa_scene, monkeypatch):
    from depthguard import config

    test, robot = iiwa_scene[:2]
    path = np.array([robot.lower * 0.5, robot.upper * 0.5])
    n = len(test.projector.samples(path))
    monkeypatch.setattr(config, "MAX_MOTION_SAMPLES", n - 2)
    with pytest.raises(InputError, match="at most"):
        test.projector.samples(path)


def test_a_tile_images_pixels_take_their_tiles_values():
    """TileGrid.pixels against a pixel loop over tile_of_pixels, on uneven tiles."""
    from depthguard.collision import TileGrid

    grid = TileGrid(_camera("c", (2.0, 0.0, 1.0), width=37, height=23), 5, 7)
    tiles = np.random.default_rng(3).random((5, 7)) < 0.5
    rows, cols = grid.tile_of_pixels()
    expected = np.array([[tiles[rows[v], cols[u]] for u in range(37)] for v in range(23)])
    assert np.array_equal(grid.pixels(tiles), expected) and expected.any() and not expected.all()
