"""Pick-and-place (design §10, step 8; Henrich & Gecks section 4.1): the tiles a box may be seen in, judged by an
independent polygon test and a ray-cast rendering; the reference image update loop (U, R, E, O) over a scripted
pick-and-place of a KUKA iiwa seen by four cameras, with and without a hand held next to the place."""

from __future__ import annotations

import types

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial import ConvexHull

import depthguard as dg
from depthguard.collision import OBSTACLE, ImageCollisionTest, TileGrid
from depthguard.kernels import collision_update
from depthguard.collision._boxes import NEAR_PLANE, box_tiles, moved_box
from depthguard.collision._update import ReferenceUpdate
from depthguard.errors import InputError
from depthguard.scenes import Box, render_depth
from depthguard.transforms import invert, look_at

#: Grey values of the drawn scene: the robot's padded capsules, the work piece (dark, as the paper's black box), a hand.
ROBOT_GREY, PIECE_GREY, HAND_GREY = 235, 20, 250

WORKSPACE = [[-1.0, -1.0, -0.1], [1.2, 1.0, 1.5]]



def _camera(name, eye, target=(0.2, 0.0, 0.5), width=320, height=256, f=260.0):
    """A camera at ``eye`` looking at ``target`` (z up), optical frame REP 103 (x right, y down, z forward)."""
    return dg.PinholeCamera(name, width, height, f, f, (width - 1) / 2, (height - 1) / 2, look_at(eye, target))


def _rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


# ------------------------------------------------------------------------------------------------- box tiles

def _tiles_naive(grid: TileGrid, box: Box) -> np.ndarray:
    """The judge: the tiles whose footprint meets the convex polygon of the box's projected corners (scipy's hull),
    tested tile by tile: a polygon vertex in the rectangle, a rectangle corner in the polygon, or two edges that
    cross. Every tile when a corner lies within NEAR_PLANE of the camera's plane or behind it."""
    cam = grid.camera
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
    corners = np.asarray(box.center) + (signs * np.asarray(box.half_extents)) @ np.asarray(box.R_world_box).T
    p = cam.world_to_camera(corners)
    if np.any(p[:, 2] <= NEAR_PLANE):
        return np.ones((grid.rows, grid.cols), dtype=bool)
    uv = np.stack([cam.fx * p[:, 0] / p[:, 2] + cam.cx, cam.fy * p[:, 1] / p[:, 2] + cam.cy], axis=1)
    poly = uv[ConvexHull(uv).vertices]

    def inside(point):
        edges = np.roll(poly, -1, axis=0) - poly
        rel = point - poly
        cross = edges[:, 0] * rel[:, 1] - edges[:, 1] * rel[:, 0]
        return np.all(cross >= 0) or np.all(cross <= 0)

    def crosses(a, b, c, d):
        def orient(p, q, r):
            return np.sign((q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]))
        return orient(a, b, c) != orient(a, b, d) and orient(c, d, a) != orient(c, d, b)

    out = np.zeros((grid.rows, grid.cols), dtype=bool)
    for r in range(grid.rows):
        for c in range(grid.cols):
            x0, x1, y0, y1 = grid.col_edges[c], grid.col_edges[c + 1], grid.row_edges[r], grid.row_edges[r + 1]
            rect = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
            out[r, c] = (any(x0 <= u <= x1 and y0 <= v <= y1 for u, v in poly) or any(inside(k) for k in rect) or
                         any(crosses(poly[i], poly[(i + 1) % len(poly)], rect[j], rect[(j + 1) % 4])
                             for i in range(len(poly)) for j in range(4)))
    return out


def test_box_tiles_are_the_projected_hull_and_hold_the_rendered_box():
    """Random boxes seen by a camera: box_tiles equals the polygon judge tile for tile, holds every tile a ray-cast
    rendering of the box shows, and the kernel's Python body (what NUMBA_DISABLE_JIT runs) gives the same bits."""
    rng = np.random.default_rng(3)
    cam = _camera("c", (2.2, -1.6, 1.6), width=160, height=128, f=130.0)
    grid = TileGrid(cam, 12, 15)  # fractional tiles: 10.67 x 10.67 pixels
    T = cam.T_camera_world
    for k in range(12):
        box = Box(tuple(rng.uniform([-0.4, -0.4, 0.0], [0.8, 0.4, 1.0])), tuple(rng.uniform(0.0, 0.2, 3)),
                  _rotation(rng))
        tiles = box_tiles(grid, box)
        assert np.array_equal(tiles, _tiles_naive(grid, box)), k
        rows, cols = grid.tile_of_pixels()
        shown = np.zeros_like(tiles)
        hit = render_depth(cam, [box]) > 0
        shown[rows[np.nonzero(hit)[0]], cols[np.nonzero(hit)[1]]] = True
        assert not np.any(shown & ~tiles), k
        assert np.array_equal(_box_depth(cam, box), render_depth(cam, [box]))  # the scenes' faster renderer
        corners = np.asarray(box.center) + (np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1)
                                                      for sz in (-1, 1)]) * box.half_extents) @ box.R_world_box.T
        args = (corners[None], np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]), cam.fx, cam.fy,
                cam.cx, cam.cy, NEAR_PLANE, grid.col_edges, grid.row_edges, grid.words)
        compiled, plain = np.zeros((1, grid.words), np.uint64), np.zeros((1, grid.words), np.uint64)
        collision_update.box_tile_bits(*args, compiled)
        collision_update.box_tile_bits.py_func(*args, plain)
        assert np.array_equal(compiled, plain) and np.array_equal(compiled[0], grid.pack(tiles))


def test_a_box_reaching_the_camera_plane_may_be_seen_anywhere_and_one_out_of_view_nowhere():
    cam = _camera("c", (2.2, -1.6, 1.6), width=160, height=128, f=130.0)
    grid = TileGrid(cam, 8, 10)
    eye = cam.T_world_camera[:3, 3]
    assert box_tiles(grid, Box(tuple(eye), (0.05, 0.05, 0.05))).all()  # around the optical centre
    behind = eye - 0.5 * cam.T_world_camera[:3, 2]
    assert box_tiles(grid, Box(tuple(behind), (0.05, 0.05, 0.05))).all()
    beside = eye + 3.0 * cam.T_world_camera[:3, 2] + 5.0 * cam.T_world_camera[:3, 0]
    assert not box_tiles(grid, Box(tuple(beside), (0.05, 0.05, 0.05))).any()
    assert box_tiles(grid, Box((0.2, 0.0, 0.5), (0.0, 0.0, 0.0))).sum() in (1, 2, 4)  # a point: its tile(s)


@pytest.mark.parametrize("box, field", [
    (Box((0.0, 0.0, np.nan), (0.1, 0.1, 0.1)), "box.center"),
    (Box((0.0, 0.0, np.inf), (0.1, 0.1, 0.1)), "box.center"),
    (Box((0.0, 0.0), (0.1, 0.1, 0.1)), "box.center"),
    (Box(("0", 0.0, 0.0), (0.1, 0.1, 0.1)), "box.center"),
    (Box((0.0, 0.0, 0.0), (0.1, -0.1, 0.1)), "box.half_extents"),
    (Box((0.0, 0.0, 0.0), (0.1, 0.1, np.nan)), "box.half_extents"),
    (Box((0.0, 0.0, 0.0), (0.1, 0.1, 0.1), 2.0 * np.eye(3)), "box.R_world_box"),
    (Box((0.0, 0.0, 0.0), (0.1, 0.1, 0.1), -np.eye(3)), "box.R_world_box"),
    (Box((0.0, 0.0, 0.0), (0.1, 0.1, 0.1), np.eye(2)), "box.R_world_box"),
    (Box((0.0, 0.0, 0.0), (0.1, 0.1, 0.1), np.full((3, 3), np.nan)), "box.R_world_box"),
    ((0.0, 0.0, 0.0), "box"),
    (dg.scenes.Sphere((0.0, 0.0, 0.0), 0.1), "box"),
])
def test_box_tiles_refuse_bad_boxes(box, field):
    grid = TileGrid(_camera("c", (2.2, -1.6, 1.6), width=160, height=128, f=130.0), 8, 10)
    with pytest.raises(InputError) as err:
        box_tiles(grid, box)
    assert err.value.field == field


def test_box_tiles_refuse_a_grid_that_is_not_one():
    with pytest.raises(InputError, match="grid"):
        box_tiles("grid", Box((0.0, 0.0, 0.0), (0.1, 0.1, 0.1)))


# ------------------------------------------------------------------------------------------------- the scene

def _ik(robot, link, target, yaw):
    """Joints that put the end-effector control point at ``target`` (world, metres) with the end-effector link's z
    axis pointing down (joints 3, 5, 7 at zero; Gauss-Newton from a seed facing ``yaw``)."""
    def joints(x):
        return np.array([x[0], x[1], 0.0, x[2], 0.0, x[3], 0.0])

    def residual(x):
        q = joints(x)
        down = robot.link_poses(q)[link][:3, 2] - (0.0, 0.0, -1.0)
        return np.concatenate([robot.control_point_positions(q)[robot.end_effector_index] - target, 0.3 * down])

    solution = least_squares(residual, [yaw, 0.6, -1.2, 0.9])
    assert np.abs(solution.fun).max() < 1e-6, target
    return joints(solution.x)


def _box_depth(camera, box) -> np.ndarray:
    """render_depth of one box, ray-casting only the pixels within its projected corners' bounding rectangle."""
    depth = np.zeros(camera.shape, dtype=np.float32)
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
    corners = np.asarray(box.center) + (signs * np.asarray(box.half_extents)) @ np.asarray(box.R_world_box).T
    p = camera.world_to_camera(corners)
    if np.any(p[:, 2] <= 0.01):
        return render_depth(camera, [box])
    u = camera.fx * p[:, 0] / p[:, 2] + camera.cx
    v = camera.fy * p[:, 1] / p[:, 2] + camera.cy
    u0, u1 = max(int(np.floor(u.min())), 0), min(int(np.ceil(u.max())) + 1, camera.width)
    v0, v1 = max(int(np.floor(v.min())), 0), min(int(np.ceil(v.max())) + 1, camera.height)
    if u0 >= u1 or v0 >= v1:
        return depth
    vv, uu = np.mgrid[v0:v1, u0:u1].astype(np.float64)
    rays = np.stack([(uu - camera.cx) / camera.fx, (vv - camera.cy) / camera.fy, np.ones_like(uu)], -1).reshape(-1, 3)
    R = camera.T_world_camera[:3, :3]
    directions = rays @ R.T
    t = box.intersect(np.broadcast_to(camera.T_world_camera[:3, 3], directions.shape), directions)
    depth[v0:v1, u0:u1] = np.where(np.isfinite(t), t, 0.0).reshape(v1 - v0, u1 - u0)
    return depth


@pytest.fixture(scope="module")
def scene():
    """Four 320 x 256 cameras around a KUKA iiwa, a textured room; the work piece (a 12 cm cube) lies at A; the
    scripted joints of a pick at A and a place at B (B where the gripped piece is at the place configuration)."""
    from depthguard.robots import RobotModel
    from depthguard.self_filter import RobotSilhouette

    robot = RobotModel.default()
    link = robot.control_points[robot.end_effector_index].link
    eyes = [(2.2, -1.6, 1.6), (2.2, 1.6, 1.6), (-1.8, 1.8, 1.8), (-1.8, -1.8, 1.4)]
    cameras = {f"c{k}": _camera(f"c{k}", eye) for k, eye in enumerate(eyes)}
    rng = np.random.default_rng(11)
    backgrounds = {name: np.kron(rng.integers(40, 160, (32, 40)), np.ones((8, 8))) for name in cameras}
    s = types.SimpleNamespace(robot=robot, link=link, cameras=cameras, rig=dg.Rig(cameras), backgrounds=backgrounds,
                              silhouette=RobotSilhouette(robot, geometry="meshes"))  # the robot as a camera sees it
    s.A = Box((0.0, -0.72, 0.06), (0.06, 0.06, 0.06))
    top_A = np.array([0.0, -0.72, 0.12])
    s.q_A = _ik(robot, link, top_A + (0.0, 0.0, 0.02), -1.57)      # the gripper 2 cm above the piece
    s.up_A = _ik(robot, link, top_A + (0.0, 0.0, 0.25), -1.57)
    s.q_B = _ik(robot, link, np.array([0.0, 0.72, 0.14]), 1.57)
    s.up_B = _ik(robot, link, np.array([0.0, 0.72, 0.37]), 1.57)
    s.home = np.array([0.0, 0.4, 0.0, -0.8, 0.0, 0.4, 0.0])       # between A and B, away from both
    # The piece in the end-effector link's frame at the pick; it moves with the link from then on.
    s.piece_in_link = moved_box(s.A, invert(robot.link_poses(s.q_A)[link]))
    s.B = moved_box(s.piece_in_link, robot.link_poses(s.q_B)[link])
    s.hand = Box((0.15, 0.72, 0.16), (0.05, 0.05, 0.07))            # next to B, in front of it for c0 and c1
    s.q_hand = _ik(robot, link, np.array(s.hand.center), 1.4)       # a configuration through the hand
    poses = [np.array([a, 1.2 * (-1) ** k, 0.0, 0.9 * (-1) ** k, 0.0, 0.8, 0.0])
             for k, a in enumerate(np.linspace(-2.9, 2.9, 9))]
    drawn = [_draw(s, q, [(s.A, PIECE_GREY)])[0] for q in poses]
    s.reference_images = {name: [images[name] for images in drawn] for name in cameras}
    return s


def _draw(s, joints, boxes=()):
    """Images of the scene (camera name -> (256, 320) uint8): the background, the robot's padded capsules rendered
    at ``joints`` and the (Box, grey value) ``boxes``, each pixel showing the nearest. Also per camera the
    (height, width) int index of what each pixel shows: -1 background, 0 the robot, k the k-th box."""
    images, shows = {}, {}
    for name, camera in s.cameras.items():
        image = s.backgrounds[name].copy()
        show = np.full(camera.shape, -1)
        nearest = np.full(camera.shape, np.inf)
        layers = [(s.silhouette.render(camera, joints), ROBOT_GREY)]
        layers += [(_box_depth(camera, box), grey) for box, grey in boxes]
        for k, (depth, grey) in enumerate(layers):
            near = (depth > 0) & (depth < nearest)
            image[near], show[near], nearest[near] = grey, k, depth[near]
        images[name], shows[name] = image.astype(np.uint8), show
    return images, shows


def _tiles_showing(shows, layer, grid, name, fraction=0.3) -> np.ndarray:
    """(rows, cols) bool: the tiles of which at least ``fraction`` of the pixels show ``layer``."""
    rows, cols = grid.tile_of_pixels()
    count = np.zeros((grid.rows, grid.cols))
    np.add.at(count, (rows[:, None], cols[None, :]), shows[name] == layer)
    size = np.outer(np.diff(grid.first_row), np.diff(grid.first_col))
    return count >= fraction * size


def _test(s, **options) -> ImageCollisionTest:
    test = ImageCollisionTest(s.rig, s.robot, WORKSPACE, tiles=(32, 32), **options)
    test.set_reference(s.reference_images)
    return test


def _verdicts(s, reference, images, joints, configurations):
    """The verdicts of ``configurations`` against ``images`` seen with ``reference`` (per camera tile features),
    by the paper's rule (theta = 1, class B free) and by the default (theta = C - 1, class B collides)."""
    out = []
    for options in ({"theta": 1, "unseen": "free"}, {}):
        # the reference given as tile features alone (the update's subject): Table I without robot_pixels, which
        # compares pixels with reference images
        test = ImageCollisionTest(s.rig, s.robot, WORKSPACE, tiles=(32, 32), robot_pixels=False, **options)
        test.reference = [np.array(r, copy=True) for r in reference]
        test.observe(images, joints)
        out.append([test.test(q) for q in configurations])
    return out


def _segment(a, b, n):
    return [a + (b - a) * t for t in np.linspace(0.0, 1.0, n + 1)[1:]]


def _pick_and_carry(s, update):
    """The robot comes from home to A, grips the piece, carries it to B: update.step on every set of images."""
    for q in _segment(s.home, s.up_A, 3) + _segment(s.up_A, s.q_A, 2):
        assert update.step(_draw(s, q, [(s.A, PIECE_GREY)])[0], q)  # nothing to update yet
    piece = update.start(s.A, s.q_A)
    assert np.allclose(piece.center, s.piece_in_link.center) and \
        np.allclose(piece.R_world_box, s.piece_in_link.R_world_box)
    update.gripped(piece)
    for q in _segment(s.q_A, s.up_A, 2) + _segment(s.up_A, s.up_B, 4) + _segment(s.up_B, s.q_B, 2):
        carried = moved_box(s.piece_in_link, s.robot.link_poses(q)[s.link])
        update.step(_draw(s, q, [(carried, PIECE_GREY)])[0], q)
    update.released()
    update.start(s.B, s.q_B)


# ------------------------------------------------------------------------------------------------- the update

def test_the_gripped_piece_is_part_of_the_robot(scene):
    """While carrying, the piece's tiles at the gripper are the robot's: every camera sees the current configuration
    free (class A), alone and moving on with the piece. The bare robot's test (test.observe) sees the piece as an
    obstacle glued to the gripper: every camera sees the configuration meet (possible) obstacles (class B, a
    collision by the default rule)."""
    s = scene
    test = _test(s, theta=1, unseen="free")
    update = ReferenceUpdate(test)
    update.start(s.A, s.q_A)
    update.gripped(s.piece_in_link)
    q = s.up_B
    carried = moved_box(s.piece_in_link, s.robot.link_poses(q)[s.link])
    assert np.allclose(update.piece_at(q).center, carried.center)
    images = _draw(s, q, [(carried, PIECE_GREY)])[0]
    update.step(images, q)
    piece_tiles = [box_tiles(grid, carried) for grid in test.grids]
    assert all(np.array_equal(r, t | p) for r, t, p in zip(update.robot_image(q), test.robot_image(q), piece_tiles))
    assert update.test(q).klass == "A"
    assert update.test_motion([q, s.q_B]).klass == "A"
    test.observe(images, q)
    assert test.test(q).klass != "A"
    update.released()
    assert update.piece_at(q) is None
    assert all(np.array_equal(r, t) for r, t in zip(update.robot_image(q), test.robot_image(q)))


def test_the_update_frees_the_pick_and_the_place_once_the_robot_has_left(scene):
    """Without the update the tiles at A (the piece gone) and at B (the piece new) stay foreground and the
    configurations that reach A and B collide; with it, once the robot has left, A and B read as background and
    both configurations are free, by the paper's rule and by the default."""
    s = scene
    test = _test(s, theta=1, unseen="free")
    initial = [r.copy() for r in test.reference]
    update = ReferenceUpdate(test)
    grids = test.grids
    U_A = [box_tiles(grid, s.A) for grid in grids]
    U_B = [box_tiles(grid, s.B) for grid in grids]
    _pick_and_carry(s, update)
    assert all(np.array_equal(u & b, b) and not np.any(u & ~(a | b)) for u, a, b in zip(update.pending, U_A, U_B))
    assert sum(int((u & a & ~b).sum()) for u, a, b in zip(update.pending, U_A, U_B)) < \
        sum(int((a & ~b).sum()) for a, b in zip(U_A, U_B))  # A's update ran during the carry
    leave = _segment(s.q_B, s.up_B, 2) + _segment(s.up_B, s.home, 4) + [s.home] * 3
    for q in leave:
        done = update.step(_draw(s, q, [(s.B, PIECE_GREY)])[0], q)
        assert not any(np.any(e & ~(a | b)) for e, a, b in zip(update.absorbed, U_A, U_B))  # only U is updated
    assert done and update.done
    final = _draw(s, s.home, [(s.B, PIECE_GREY)])[0]
    with_update = _verdicts(s, test.reference, final, s.home, [s.q_A, s.q_B])
    without = _verdicts(s, initial, final, s.home, [s.q_A, s.q_B])
    for rule in range(2):
        assert [v.collision for v in without[rule]] == [True, True], without[rule]
        assert [v.collision for v in with_update[rule]] == [False, False], with_update[rule]
    test.observe(final, s.home)
    assert not any(np.any(r == OBSTACLE) for r in test.revised)
    test.reference = initial  # without the update: A and B are obstacles in every camera
    test.observe(final, s.home)
    assert all(np.any((r == OBSTACLE) & a) and np.any((r == OBSTACLE) & b) for r, a, b in zip(test.revised, U_A, U_B))


def test_the_swept_piece_covers_every_tile_it_passes(scene):
    """test_motion with a gripped piece: every tile the piece's box shows at any of 40 configurations per segment of
    the motion is in the future image of the camera (judged one tile and camera at a time: that camera's revised
    image holds an obstacle in that tile only, every other camera's is all obstacle, so the default rule reports a
    collision iff the camera's future image holds the tile)."""
    s = scene
    test = _test(s)
    update = ReferenceUpdate(test)
    update.gripped(s.piece_in_link)
    path = np.array([s.q_A, s.up_A, s.up_B])
    dense = np.concatenate([a + (b - a) * np.linspace(0.0, 1.0, 41)[:, None] for a, b in zip(path[:-1], path[1:])])
    everywhere = [np.full((g.rows, g.cols), OBSTACLE, dtype=np.uint8) for g in test.grids]
    checked = 0
    for c, grid in enumerate(test.grids):
        tiles = np.zeros((grid.rows, grid.cols), dtype=bool)
        for q in dense:
            tiles |= box_tiles(grid, moved_box(s.piece_in_link, s.robot.link_poses(q)[s.link]))
        tiles &= ~np.logical_or.reduce([test.projector.swept_images(path[k:k + 2])[c] for k in range(2)])
        for r, k in np.argwhere(tiles):
            revised = [image.copy() for image in everywhere]
            revised[c][:] = 0
            revised[c][r, k] = OBSTACLE
            test.revised = revised
            assert update.test_motion(path).collision, (test.names[c], r, k)
            checked += 1
    assert checked >= 8  # tiles only the piece covers, in the four cameras together
    update.released()
    test.revised = revised
    assert not update.test_motion(path).collision  # without the piece the robot does not reach the last tile


def test_a_camera_whose_light_cannot_be_estimated_holds_the_update(scene):
    """A camera three times darker than its reference (its light gain outside config.LIGHT_GAIN_RANGE) sees every
    tile as foreground: it updates nothing, and since its unexplained foreground lies along every band, no other
    camera does either. With the light back the update completes."""
    s = scene
    test = _test(s)
    update = ReferenceUpdate(test)
    update.start(s.A, s.home)
    images = _draw(s, s.home)[0]  # the piece has gone from A
    dark = dict(images, c1=(images["c1"] // 3).astype(np.uint8))
    before = [r.copy() for r in test.reference]
    assert not update.step(dark, s.home)
    assert np.isnan(test.gains[1]) and all(u.any() for u in update.pending)
    assert all(np.array_equal(r, b) for r, b in zip(test.reference, before))
    assert update.step(images, s.home)


def _depth_images(s, joints, boxes) -> dict:
    """Per camera, float32 depth images (metres, 0: nothing) of the robot's render at ``joints``, a floor under
    everything and ``boxes``."""
    floor = Box((0.0, 0.0, -0.05), (3.0, 3.0, 0.05))
    out = {}
    for name, camera in s.cameras.items():
        layers = [s.silhouette.render(camera, joints), render_depth(camera, [floor] + boxes)]
        stack = np.stack([np.where(d > 0, d, np.inf) for d in layers])
        nearest = stack.min(axis=0)
        out[name] = np.where(np.isfinite(nearest), nearest, 0.0).astype(np.float32)
    return out


def test_the_update_takes_what_the_robot_always_hid_into_the_reference(scene):
    """Reference images with the robot reaching A in every one: the pixels it covered are unreferenced
    (``ImageCollisionTest.unreferenced``: any change there counts). An update area round the whole arm there (a
    region the user declares, as a piece's): once the robot has left and the update absorbs a tile, its pixels hold
    the room and are referenced again; the others stay unreferenced."""
    s = scene
    test = ImageCollisionTest(s.rig, s.robot, WORKSPACE, tiles=(32, 32), images="depth")
    drawn = _depth_images(s, s.q_A, [s.A])
    test.set_reference({name: [drawn[name]] * 3 for name in s.cameras}, joints=[s.q_A] * 3)
    before = [mask.copy() for mask in test.unreferenced]
    update = ReferenceUpdate(test)
    arm = s.robot.control_point_positions(s.q_A)
    update.start(Box.from_bounds(arm.min(axis=0) - 0.2, arm.max(axis=0) + 0.2), s.q_A)
    absorbed = [np.zeros((grid.rows, grid.cols), dtype=bool) for grid in test.grids]  # absorbed over the steps
    for _ in range(3):
        update.step(_depth_images(s, s.home, []), s.home)  # the piece taken away, the robot home
        absorbed = [a | b for a, b in zip(absorbed, update.absorbed)]
    cleared = 0
    for c, grid in enumerate(test.grids):
        rows, cols = grid.tile_of_pixels()
        pixels = absorbed[c][rows[:, None], cols[None, :]]
        now = test.unreferenced[c] if test.unreferenced[c] is not None else np.zeros_like(before[c])
        assert np.array_equal(now, before[c] & ~pixels)
        cleared += int(np.count_nonzero(before[c] & pixels))
    assert cleared > 0  # the robot stood over A's tiles in the reference, and the update cleared them


def test_the_depth_variant_updates_the_reference_depth_image(scene):
    """images="depth": the reference is a depth image (metres) and the update replaces the pixels of its tiles. The
    piece moved from A to B (a floor under everything); once updated, the configurations reaching A and B are free;
    a hand next to B is not absorbed."""
    s = scene

    def depth(joints, boxes):
        return _depth_images(s, joints, boxes)

    poses = [np.array([a, 1.2 * (-1) ** k, 0.0, 0.9 * (-1) ** k, 0.0, 0.8, 0.0])
             for k, a in enumerate(np.linspace(-2.9, 2.9, 5))]
    test = ImageCollisionTest(s.rig, s.robot, WORKSPACE, tiles=(32, 32), images="depth")
    drawn = [depth(q, [s.A]) for q in poses]
    test.set_reference({name: [d[name] for d in drawn] for name in s.cameras}, joints=poses)
    update = ReferenceUpdate(test)
    update.start(s.A, s.q_A)
    update.start(s.B, s.q_B)
    now = depth(s.home, [s.B, s.hand])
    update.step(now, s.home)
    assert not update.done
    update.step(depth(s.home, [s.B]), s.home)
    assert update.done
    update.step(depth(s.home, [s.B]), s.home)
    assert not test.test(s.q_A).collision and not test.test(s.q_B).collision
    update.step(now, s.home)
    assert test.test(s.q_hand).collision


def test_a_hand_next_to_the_place_is_never_absorbed(scene):
    """A hand (a bright box) held next to B while the update runs: some cameras see it in front of the placed piece,
    inside their update area, others see it outside theirs. No tile showing it is ever absorbed; while it is there
    the update waits, its tiles stay obstacles and a configuration through it collides; after it has gone the
    update completes, and when it comes back every camera sees it again."""
    s = scene
    test = _test(s, theta=1, unseen="free")
    update = ReferenceUpdate(test)
    grids = test.grids
    _pick_and_carry(s, update)
    leave = _segment(s.q_B, s.up_B, 2) + _segment(s.up_B, s.home, 4) + [s.home] * 4
    scene_now = [(s.B, PIECE_GREY), (s.hand, HAND_GREY)]
    inside = False
    for q in leave:
        images, shows = _draw(s, q, scene_now)
        hand = [_tiles_showing(shows, 2, grid, name) for grid, name in zip(grids, test.names)]
        pending = [u.copy() for u in update.pending]
        assert not update.step(images, q)
        for c in range(len(grids)):
            assert not np.any(update.absorbed[c] & hand[c]), (q, test.names[c])
            assert np.all(test.revised[c][hand[c] & ~update.robot_image(q)[c]] == OBSTACLE)
            inside |= bool(np.any(pending[c] & hand[c]))
    assert inside  # the hand was seen inside an update area: only O kept it from being absorbed
    v = [verdicts[0] for verdicts in _verdicts(s, test.reference, images, s.home, [s.q_hand])]
    assert v[0].collision and v[1].collision, v
    # The hand goes: the update completes, B is free.
    for q in [s.home] * 4:
        done = update.step(_draw(s, q, [(s.B, PIECE_GREY)])[0], q)
    assert done
    assert not update.test(s.q_B).collision
    # The hand comes back: every camera that shows it sees it as an obstacle, and the configuration through it
    # collides, by the paper's rule and by the default.
    images, shows = _draw(s, s.home, scene_now)
    update.step(images, s.home)
    for c, (grid, name) in enumerate(zip(grids, test.names)):
        hand = _tiles_showing(shows, 2, grid, name)
        assert hand.any() and np.all(test.revised[c][hand] == OBSTACLE), name
    v = [verdicts[0] for verdicts in _verdicts(s, test.reference, images, s.home, [s.q_hand])]
    assert v[0].collision and v[1].collision, v


def test_the_update_refuses_what_it_cannot_use(scene):
    s = scene
    test = ImageCollisionTest(s.rig, s.robot, WORKSPACE, tiles=(8, 8))
    with pytest.raises(InputError, match="test"):
        ReferenceUpdate("test")
    one = ImageCollisionTest(dg.Rig({"c0": s.cameras["c0"]}), s.robot, WORKSPACE, tiles=(8, 8))
    with pytest.raises(InputError, match="two cameras"):
        ReferenceUpdate(one)
    update = ReferenceUpdate(test)
    with pytest.raises(InputError, match="reference"):
        update.step({name: s.backgrounds[name].astype(np.uint8) for name in s.cameras}, s.home)
    with pytest.raises(InputError) as err:
        update.start(Box((0.0, 0.0, np.nan), (0.1, 0.1, 0.1)), s.home)
    assert err.value.field == "piece.center"
    with pytest.raises(InputError, match="joints"):
        update.start(s.A, s.home[:6])
    with pytest.raises(InputError, match="joints"):
        update.start(s.A, np.full(7, np.nan))
    assert update.done  # nothing was added by the refused calls
    with pytest.raises(InputError) as err:
        update.gripped(Box((0.0, 0.0, 0.0), (0.1, -0.1, 0.1)))
    assert err.value.field == "piece_in_gripper.half_extents"
    with pytest.raises(InputError) as err:
        update.gripped("piece")
    assert err.value.field == "piece_in_gripper"
    test.set_reference({name: [s.backgrounds[name].astype(np.uint8)] for name in s.cameras})
    with pytest.raises(InputError, match="every camera"):
        update.step({"c0": s.backgrounds["c0"].astype(np.uint8)}, s.home)
    with pytest.raises(InputError, match="revised"):
        ReferenceUpdate(ImageCollisionTest(s.rig, s.robot, WORKSPACE, tiles=(8, 8))).test(s.home)
    update.step({name: s.backgrounds[name].astype(np.uint8) for name in s.cameras}, s.home)
    with pytest.raises(InputError, match="foreground"):
        update.possible_obstacles([np.zeros((8, 8), dtype=bool)] * 3, [np.zeros((8, 8), dtype=bool)] * 4)
    with pytest.raises(InputError, match="robot_now"):
        update.possible_obstacles([np.zeros((8, 8), dtype=bool)] * 4, [np.zeros((8, 8))] * 4)
    update.gripped(s.piece_in_link)
    with pytest.raises(InputError, match="path"):
        update.test_motion(np.zeros((2, 6)))
    with pytest.raises(InputError, match="chunk"):
        update.test_motion([s.home, s.up_B], chunk=0)


def test_a_configuration_table_with_the_gripped_piece_gives_the_updates_verdicts(scene):
    """ConfigurationTable(piece=...): every configuration's tiles include the gripped piece's, and the verdicts equal
    ReferenceUpdate.test's, configuration by configuration; the piece changes some verdicts."""
    from depthguard.collision import ConfigurationTable

    s = scene
    test = _test(s, theta=1, unseen="free")
    update = ReferenceUpdate(test)
    update.gripped(s.piece_in_link)
    hand = [(s.hand, 250)]
    update.step(_draw(s, s.up_B, [(moved_box(s.piece_in_link, s.robot.link_poses(s.up_B)[s.link]), PIECE_GREY)]
                      + hand)[0], s.up_B)
    rng = np.random.default_rng(21)
    configurations = np.vstack([s.q_hand, s.q_B, s.home, s.up_A,
                                s.up_B + rng.uniform(-0.6, 0.6, (16, 7)) * [1.0, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5]])
    configurations = np.clip(configurations, s.robot.lower, s.robot.upper)
    with_piece = ConfigurationTable(test, configurations, piece=s.piece_in_link)
    bare = ConfigurationTable(test, configurations)
    assert np.all(with_piece.bits >= bare.bits) and np.any(with_piece.bits != bare.bits)
    collision, klass = with_piece.verdicts()
    for k, q in enumerate(configurations):
        v = update.test(q)
        assert (collision[k], klass[k]) == (v.collision, v.klass), k
    assert collision[0]  # through the hand
    assert not np.array_equal(klass, bare.verdicts()[1])
