"""The depth grid (design §8): the map, the fused query against its brute-force twin, the corrected
confirmation rule, and fusion's bounds (never above the truth, never below the principal camera alone)."""

import numpy as np
import pytest

import depthguard as dg
import naive
from depthguard.depthgrid import FusedFrames, MapError, build_map, free_image, fused_distances, load_map, save_map
from depthguard.rendering import Renderer, primitive_mesh, MeshInstance
from depthguard.scenes import Box, Capsule, Sphere, render_depth, scene_distance
from depthguard.transforms import look_at

ROOM = [Box.from_bounds([-4, -4, -0.1], [4, 4, 0]), Box.from_bounds([-3, -4, 0], [-2.9, 4, 3]),
        Box.from_bounds([-4, -3, 0], [4, -2.9, 3])]


def rig(width=160, height=120, noise=None, second=(0.0, 2.5, 1.4)):
    f = 131.25 * width / 160
    cams = {n: dg.PinholeCamera(n, width, height, f, f, (width - 1) / 2, (height - 1) / 2,
                                look_at(eye, [0, 0, 0.6]), depth_range=(0.3, 6.0),
                                noise=noise or dg.NoiseModel.none())
            for n, eye in (("p", [2.5, 0.0, 1.4]), ("s", second))}
    return dg.Rig(cams, principal="p")


def frames(r, scene, holes=None):
    depth = render_depth(r.cameras["p"], scene)
    if holes is not None:
        depth[holes] = 0
    principal = dg.prepare_depth(dg.depth_image(depth, r.cameras["p"]), r.cameras["p"])
    second = free_image(dg.depth_image(render_depth(r.cameras["s"], scene), r.cameras["s"]), r.cameras["s"])
    return principal, {"s": second}


def test_map_round_trip_refusal_and_no_code(tmp_path):
    r = rig()
    grid = build_map(r)
    lo, hi = r.cameras["p"].depth_range  # the grid spans the principal's range (no workspace), in 1 cm cells
    assert grid.principal == "p" and grid.secondaries == ("s",) and grid.d_min == lo
    assert grid.delta_d == 0.01 and grid.n_cells == round((hi - lo) / 0.01)
    assert grid.corners.shape == (1, 121, 161, 3)
    save_map(grid, tmp_path / "map.npz")
    again = load_map(tmp_path / "map.npz", r)
    assert np.array_equal(again.corners, grid.corners) and again.d_min == grid.d_min
    moved = dg.Rig({"p": r.cameras["p"], "s": r.cameras["s"].replace(T_world_camera=look_at([0.1, 2.5, 1.4],
                                                                                                  [0, 0, 0.6]))},
                   principal="p")
    with pytest.raises(MapError, match="another rig"):
        load_map(tmp_path / "map.npz", moved)
    # A file holding a pickled object is refused without unpickling it.
    np.savez(tmp_path / "evil.npz", header=np.array([object()], dtype=object), corners=grid.corners,
             offsets=grid.offsets)
    with pytest.raises(MapError):
        load_map(tmp_path / "evil.npz", r)
    (tmp_path / "junk.npz").write_bytes(b"not a map")
    with pytest.raises(MapError):
        load_map(tmp_path / "junk.npz")
    with pytest.raises(dg.InputError, match="secondary"):
        build_map(dg.Rig({"p": r.cameras["p"]}))


def test_map_corners_project_like_the_cameras():
    r = rig()
    grid = build_map(r)
    p, s = r.cameras["p"], r.cameras["s"]
    rng = np.random.default_rng(0)
    for _ in range(20):
        u, v = rng.integers(0, 160), rng.integers(0, 120)
        z = rng.uniform(0.5, 4.0)
        corner = p.back_project(u - 0.5, v - 0.5, z)
        h = grid.corners[0, v, u] * z + grid.offsets[0]
        us, vs, zs = s.project(s.world_to_camera(p.camera_to_world(corner[None])))
        assert np.allclose([h[0] / h[2], h[1] / h[2], h[2]], [us[0], vs[0], zs[0]], atol=1e-9)


def scenes():
    rng = np.random.default_rng(3)
    yield ROOM + [Capsule((1.4, 0.0, 0.2), (1.4, 0.0, 1.5), 0.2)]  # a person between p and the origin
    for _ in range(3):
        prims = list(ROOM)
        for _ in range(4):
            c = rng.uniform([-0.8, -0.8, 0.2], [1.6, 0.8, 1.2])
            prims.append(Sphere(tuple(c), rng.uniform(0.05, 0.2)) if rng.random() < 0.5 else
                         Box(tuple(c), tuple(rng.uniform(0.05, 0.25, 3))))
        yield prims


@pytest.mark.parametrize("index", range(4))
def test_fused_kernel_equals_brute_force_twin(index):
    scene = list(scenes())[index]
    r = rig(40, 30)
    grid = build_map(r)
    rng = np.random.default_rng(index)
    holes = rng.random((30, 40)) < 0.05
    principal, frees = frames(r, scene, holes)
    points = rng.uniform([-0.5, -0.6, 0.1], [1.3, 0.6, 1.3], (6, 3))
    reference = naive.fused_query_reference(grid, principal, [frees["s"]], [0.3], points, 0.4, "occupied")
    for aggregate in ("min", "hybrid", "mean"):
        result = fused_distances(grid, r, principal, frees, points, 0.4, aggregate)
        assert_equals_twin(result, reference[aggregate])


def assert_equals_twin(result, twin):
    """A fused result against :func:`naive.fused_query_reference`'s answer: distances, directions, counts, invalid
    counts, flags; no region between links is left unchecked (the twin has no robot_exit): blind distances inf."""
    naive.assert_same_answers(result, twin.distance, twin.direction, twin.count, twin.invalid_count, twin.flags,
                              np.full(len(twin.distance), np.inf), twin.tied)


@pytest.mark.parametrize("index", range(4))
def test_fusion_is_bounded_by_the_truth_and_by_the_principal_alone(index):
    """Fused distances are at most the true distance (plus the pixel tolerance) and at least the principal's own
    single-camera distance: fusion only removes false occupancy."""
    scene = list(scenes())[index]
    r = rig()
    grid = build_map(r)
    principal, frees = frames(r, scene)
    rng = np.random.default_rng(10 + index)
    points = rng.uniform([-0.6, -0.8, 0.1], [1.6, 0.8, 1.4], (60, 3))
    points = points[scene_distance(scene, points) > 0]
    truth = scene_distance(scene, points)
    fused = fused_distances(grid, r, principal, frees, points, 0.4, "min")
    single = dg.single_camera_distances(principal, points, 0.4, "min")
    depth = r.cameras["p"].world_to_camera(points)[:, 2]
    tolerance = 2.5 * (depth + 0.4) / r.cameras["p"].fx
    near = truth < 0.4
    assert np.all(fused.distance[near] <= truth[near] + tolerance[near])
    assert np.all(fused.distance >= single.distance - 1e-12)


def test_shadow_is_removed_and_the_hidden_side_found():
    scene = ROOM + [Capsule((1.4, 0.0, 0.2), (1.4, 0.0, 1.5), 0.2)]
    r = rig()
    principal, frees = frames(r, scene)
    grid = build_map(r)
    points = np.array([[0.0, 0.0, 0.6], [0.3, 0.1, 0.8], [0.9, 0.0, 0.8]])  # behind the person as p sees it
    single = dg.single_camera_distances(principal, points, 0.4, "min")
    fused = fused_distances(grid, r, principal, frees, points, 0.4, "min")
    truth = scene_distance(scene, points)
    assert np.all(single.distance[:2] == 0)  # the shadow
    assert np.all(np.isinf(fused.distance[:2]))  # the truth is beyond rho: 0.6 and 0.8
    assert truth[2] - 0.06 < fused.distance[2] <= truth[2]  # the person's back, which p cannot see


def test_corrected_rule_confirms_a_cell_the_papers_rule_clears():
    """A small ball hidden from the principal camera sits in one of its gray cells; the second camera sees the ball,
    its measured surface inside the cell. The papers' rule (j confirms only if its depth < the cell's near depth)
    declares the cell free and misses the ball; the corrected rule (j must see beyond the cell's far depth)
    confirms it, and the fused distance does not exceed the true one."""
    r = rig()
    grid = build_map(r)
    p, s = r.cameras["p"], r.cameras["s"]
    plate = Box.from_bounds([1.45, -0.3, 0.3], [1.5, 0.3, 1.3])  # hides the region behind it from p
    u, v = 80, 60
    k = int((2.0 - grid.d_min) / grid.delta_d)
    # A ball whose surface, as s sees it, lies inside cell k of pixel (u, v): 3 mm before the cell's centre.
    z_centre = grid.d_min + (k + 0.5) * grid.delta_d
    centre_world = p.camera_to_world(p.back_project(u, v, z_centre)[None])[0]
    away_from_s = centre_world - s.T_world_camera[:3, 3]
    away_from_s /= np.linalg.norm(away_from_s)
    ball = Sphere(tuple(centre_world + (0.03 - 0.003) * away_from_s), 0.03)
    scene = ROOM + [plate, ball]
    principal, frees = frames(r, scene)
    assert principal.z_start[v, u] < 1.5  # p sees the plate, not the ball
    z0, z1 = grid.d_min + k * grid.delta_d, grid.d_min + (k + 1) * grid.delta_d
    # The papers' rule: j confirms iff its depth at the cell's pixel < the cell's near depth in j.
    centre = p.camera_to_world(p.back_project(u, v, (z0 + z1) / 2)[None])
    us, vs, _ = s.project(s.world_to_camera(centre))
    near_depth_j = min(s.world_to_camera(p.camera_to_world(p.back_project(u + du, v + dv, z0)[None]))[0, 2]
                       for du in (-0.5, 0.5) for dv in (-0.5, 0.5))
    measured = frees["s"][int(round(vs[0])), int(round(us[0]))]
    papers_confirm = measured < near_depth_j
    ours_clears = naive.camera_clears_reference(grid.corners[0], grid.offsets[0], frees["s"], 0.3, z0, z1, u, v,
                                                0.02, 1)
    assert not papers_confirm and not ours_clears
    P = centre_world + np.array([0.0, 0.0, 0.15])
    fused = fused_distances(grid, r, principal, frees, P[None], 0.4, "min")
    assert fused.distance[0] <= scene_distance([ball], P[None])[0] + 0.01


def test_a_blind_secondary_clears_nothing():
    scene = ROOM + [Capsule((1.4, 0.0, 0.2), (1.4, 0.0, 1.5), 0.2)]
    r = rig()
    principal, frees = frames(r, scene)
    grid = build_map(r)
    points = np.array([[0.0, 0.0, 0.6], [0.9, 0.0, 0.8]])
    blind = fused_distances(grid, r, principal, {"s": None}, points, 0.4, "min")
    single = dg.single_camera_distances(principal, points, 0.4, "min")
    assert np.allclose(blind.distance, single.distance)
    assert all(dg.Flag.STALE_CAMERA in f for f in blind.flags)


def test_fused_kernel_equals_twin_behind_a_robot():
    """Case (iv): a capsule arm filtered out of the principal frame; the space behind it (from where its body ends,
    plus the self-filter's slack) is checked with the second camera."""
    arm = [Capsule((0.0, 0.0, 0.0), (0.0, 0.0, 0.7), 0.08), Capsule((0.0, 0.0, 0.7), (0.3, 0.3, 0.9), 0.06)]
    hand = Sphere((-0.25, 0.05, 0.6), 0.05)  # behind the arm as p sees it
    r = rig(40, 30)
    grid = build_map(r)
    p, s = r.cameras["p"], r.cameras["s"]
    padded = [Capsule(c.p0, c.p1, c.radius + 0.02) for c in arm]
    with Renderer() as renderer:
        meshes = [renderer.add_mesh(*primitive_mesh(c, 32), closed=True) for c in padded]
        instances = [MeshInstance(m, np.eye(4)) for m in meshes]
        robot_near = renderer.render_depth(p, instances)
        robot_far = renderer.render_depth_max(p, instances)
    scene = ROOM + arm + [hand]
    principal = dg.prepare_depth(dg.depth_image(render_depth(p, scene), p), p, robot_near=robot_near)
    assert principal.robot_pixels > 20
    frees = {"s": free_image(dg.depth_image(render_depth(s, scene), s), s)}
    points = np.array([[0.0, 0.0, 0.35], [0.0, 0.0, 0.6], [0.15, 0.15, 0.8], [-0.1, 0.0, 0.5]])
    slack = 0.02 + p.noise.margin(robot_far.astype(np.float64))
    reference = naive.fused_query_reference(grid, principal, [frees["s"]], [0.3], points, 0.4, "occupied",
                                            robot_far=robot_far, robot_slack=slack)
    for aggregate in ("min", "hybrid", "mean"):
        result = fused_distances(grid, r, principal, frees, points, 0.4, aggregate, robot_far=robot_far)
        assert_equals_twin(result, reference[aggregate])
    # The hand hidden from p but seen by s counts; the single camera could only flag it.
    truth = scene_distance([hand], points)
    fused = fused_distances(grid, r, principal, frees, points, 0.4, "min", robot_far=robot_far)
    assert fused.distance[3] <= truth[3] + 0.02


def robot_scene_frames(width=80, height=60, torso=False, second=(0.0, 2.5, 1.4)):
    """A capsule arm filtered out of the principal frame (case iv), a hand behind it, a few holes: the rig, map,
    principal frame, the second camera's free image and the principal's robot_far. ``torso``: a box between the
    principal camera and the arm hides the arm's middle (a person in front of the robot). ``second``: where the second
    camera stands (it looks at the arm)."""
    arm = [Capsule((0.0, 0.0, 0.0), (0.0, 0.0, 0.7), 0.08), Capsule((0.0, 0.0, 0.7), (0.3, 0.3, 0.9), 0.06)]
    r = rig(width, height, second=second)
    p, s = r.cameras["p"], r.cameras["s"]
    padded = [Capsule(c.p0, c.p1, c.radius + 0.02) for c in arm]
    with Renderer() as renderer:
        instances = [MeshInstance(renderer.add_mesh(*primitive_mesh(c, 32), closed=True), np.eye(4)) for c in padded]
        robot_near = renderer.render_depth(p, instances)
        robot_far = renderer.render_depth_max(p, instances)
    scene = ROOM + arm + [Sphere((-0.25, 0.05, 0.6), 0.05), Capsule((1.4, 0.3, 0.2), (1.4, 0.3, 1.5), 0.2)]
    if torso:
        scene = scene + [Box.from_bounds([1.1, -0.25, 0.3], [1.25, 0.1, 0.75])]
    depth = render_depth(p, scene)
    depth[np.random.default_rng(5).random(depth.shape) < 0.03] = 0
    principal = dg.prepare_depth(dg.depth_image(depth, p), p, robot_near=robot_near, robot_far=robot_far)
    frees = {"s": free_image(dg.depth_image(render_depth(s, scene), s), s)}
    return r, build_map(r), principal, frees, robot_far, robot_near


@pytest.mark.parametrize("aggregate", ["min", "hybrid", "mean"])
def test_cells_kept_for_the_frame_change_no_answer(aggregate):
    """A FusedFrames keeps the cells its queries classified, and the runs of cells found free, for later queries on
    the same frames. Whatever came before, a query's answer is the one a fresh FusedFrames gives."""
    r, grid, principal, frees, robot_far, robot_near = robot_scene_frames()
    rng = np.random.default_rng(7)
    points = rng.uniform([-0.5, -0.6, 0.1], [1.3, 0.6, 1.3], (12, 3))
    points[:4] = [[0.0, 0.0, 0.35], [0.0, 0.0, 0.6], [0.15, 0.15, 0.8], [-0.1, 0.0, 0.5]]  # on the arm

    def fresh(pts):
        return FusedFrames(grid, r, principal, frees, robot_far=robot_far, robot_near=robot_near).distances(
            pts, 0.4, aggregate)

    kept = FusedFrames(grid, r, principal, frees, robot_far=robot_far, robot_near=robot_near)
    for order in (rng.permutation(12), rng.permutation(12)):
        for i in order:  # one point at a time, in random orders: each sees what the earlier ones left
            again = kept.distances(points[i:i + 1], 0.4, aggregate)
            alone = fresh(points[i:i + 1])
            assert again.distance[0] == alone.distance[0] and again.count[0] == alone.count[0], i
            assert np.allclose(again.direction, alone.direction, atol=1e-12)
    together = kept.distances(points, 0.4, aggregate)
    assert np.allclose(together.distance, fresh(points).distance, rtol=1e-12, atol=0)
    assert (kept._cells > 0).sum() > 100  # the cache was used


def test_cells_of_earlier_frames_are_cleared_when_their_array_is_reused():
    """The cell classes' array (a byte a cell, mostly untouched) passes from one set's FusedFrames to the next once
    the first is collected: the next starts with every cell unknown, and answers as on an array of its own."""
    from depthguard import buffers
    from depthguard.kernels import depthgrid as K

    r, grid, principal, frees, robot_far, robot_near = robot_scene_frames()
    points = np.array([[0.0, 0.0, 0.35], [0.15, 0.15, 0.8], [0.6, 0.2, 0.9], [1.0, 0.0, 0.7]])
    first = FusedFrames(grid, r, principal, frees, robot_far=robot_far, robot_near=robot_near)
    first.distances(points, 0.4, "hybrid")
    assert (first._cells > 0).sum() > 100 and first._touched.sum() > 10
    assert np.any(first._free_run != K.NO_FREE_RUN)
    used = first._cells.base
    del first
    _, _, principal2, frees2, _, _ = robot_scene_frames(torso=True)
    again = FusedFrames(grid, r, principal2, frees2, robot_far=robot_far, robot_near=robot_near)
    assert again._cells.base is used  # reused, not new
    assert not again._cells.any() and not again._touched.any()
    assert np.all(again._free_run == K.NO_FREE_RUN) and np.all(again._behind_run == K.NO_FREE_RUN)
    reused = again.distances(points, 0.4, "hybrid")
    del again
    with buffers._lock:
        buffers._spares.clear()
    own = FusedFrames(grid, r, principal2, frees2, robot_far=robot_far, robot_near=robot_near)
    assert own._cells.base is not used
    expected = own.distances(points, 0.4, "hybrid")
    assert np.array_equal(reused.distance, expected.distance) and reused.flags == expected.flags


def test_cell_arrays_are_renewed_every_so_many_sets(monkeypatch):
    """Every config.CELL_CACHE_RENEWAL sets the cell array is made anew (the pages earlier sets touched go back to
    the operating system), the one in use when it comes back included."""
    from depthguard import config

    r, grid, principal, frees, robot_far, robot_near = robot_scene_frames()

    def arrays(renewal: int) -> int:
        """How many distinct cell arrays 9 sets used, each set's frames made while the last one's still live."""
        monkeypatch.setattr(config, "CELL_CACHE_RENEWAL", renewal)
        seen = []  # held, so that no two arrays are the same object by a reused id
        frames = None
        for _ in range(9):
            frames = FusedFrames(grid, r, principal, frees, robot_far=robot_far, robot_near=robot_near)
            frames.distances(np.array([[0.0, 0.0, 0.35]]), 0.4, "min")
            if not any(frames._cells.base is array for array in seen):
                seen.append(frames._cells.base)
        return len(seen)

    assert arrays(10**9) <= 3  # two alternate (a spare of an earlier test's may come in once)
    assert arrays(3) >= 5  # a new pair every third set


def test_remembered_cells_are_the_cells_whose_corner_box_lies_in_free_voxels():
    """remembered_cells against a twin written from its definition: a cell counts free by the memory exactly when
    every voxel that the box of its 8 corners (each pixel corner's ray at the cell's two depths, through the camera's
    own model) touches is free, and none when that box leaves the voxels. Random voxels (one in 25 not free), random
    pixels and runs; cases whose box ends within 1e-6 m of a voxel face are left out (the kernel grows the box by
    1e-9 m against rounding, the twin does not)."""
    from depthguard.freespace import VoxelBox
    from depthguard.kernels import depthgrid as K

    r, grid, principal, frees, robot_far, robot_near = robot_scene_frames(64, 48)
    p = r.cameras["p"]
    box = VoxelBox([-0.9, -0.8, -0.1], [1.5, 0.8, 1.6], 0.08)
    rng = np.random.default_rng(12)
    free = rng.random(box.shape) < 0.96
    frames = FusedFrames(grid, r, principal, frees, robot_far=robot_far, robot_near=robot_near,
                         remembered=(free, box))
    state = frames.kernel_state()
    rotation, origin = p.T_world_camera[:3, :3], p.T_world_camera[:3, 3]
    compared = certified = 0
    for _ in range(400):
        u, v = int(rng.integers(0, p.width)), int(rng.integers(0, p.height))
        k_a = int(rng.integers(0, grid.n_cells - 1))
        k_b = min(k_a + int(rng.integers(0, 64)), grid.n_cells - 1)
        bits = int(K.remembered_cells(u, v, k_a, k_b, state))
        for i in range(k_b - k_a + 1):
            depths = grid.d_min + (k_a + i + np.array([0.0, 1.0])) * grid.delta_d
            corners = np.array([[(u - 0.5 + du - p.cx) / p.fx * z, (v - 0.5 + dv - p.cy) / p.fy * z, z]
                                for z in depths for du in (0, 1) for dv in (0, 1)]) @ rotation.T + origin
            lo = (corners.min(axis=0) - box.lo) / box.voxel
            hi = (corners.max(axis=0) - box.lo) / box.voxel
            if np.any(np.abs(np.concatenate([lo, hi]) - np.round(np.concatenate([lo, hi]))) * box.voxel < 1e-6):
                continue
            first, last = np.floor(lo).astype(int), np.floor(hi).astype(int)
            inside = np.all(first >= 0) and np.all(last < np.array(box.shape))
            twin = bool(inside and free[first[0]:last[0] + 1, first[1]:last[1] + 1, first[2]:last[2] + 1].all())
            assert bool(bits >> i & 1) == twin, (u, v, k_a + i)
            compared += 1
            certified += twin
    assert compared > 5000 and 0.1 * compared < certified < 0.9 * compared


BESIDE, BEHIND = (0.0, 2.5, 1.4), (-2.5, 0.6, 1.6)  # second cameras: beside the principal, behind the arm


@pytest.mark.parametrize("aggregate, torso, second, size", [
    ("hybrid", False, BESIDE, 80), ("hybrid", True, BESIDE, 80), ("hybrid", True, BESIDE, 160),
    ("hybrid", True, BEHIND, 160), ("min", True, BEHIND, 160)])
def test_later_queries_of_moving_points_equal_a_fresh_query(aggregate, torso, second, size):
    """Later queries answer from the runs of cells earlier ones found free (``distance_by_runs``, ``nearest_by_run``:
    the nearest occupied cell is the one just past a run's end, or nothing is in reach), without walking the cells.
    Points that move a little between queries, as a robot's do between frames, in the shadow of a person in front of
    the principal camera and behind the arm, get exactly a fresh FusedFrames' answer at every step; with the second
    camera beside the principal (it clears the space between the torso and the arm), or behind the arm, where at
    160x120 it clears the space right behind it (so that every cell in reach behind the arm is known free for some
    pixels)."""
    r, grid, principal, frees, robot_far, robot_near = robot_scene_frames(size, size * 3 // 4, torso=torso,
                                                                          second=second)
    if torso:  # the arm's middle is hidden: its gray area ends where the robot starts, its back is checked too
        hidden = (robot_near > 0) & (principal.z_start < robot_near - 0.1)
        assert hidden.sum() > 50
    start = np.array([[0.0, 0.0, 0.35], [0.0, 0.0, 0.6], [0.15, 0.15, 0.8],  # on the arm
                      [0.7, 0.2, 0.8], [0.9, 0.4, 0.5], [-0.4, 0.1, 0.6],  # between the person and the arm, behind it
                      [0.3, -0.1, 0.45], [0.35, 0.05, 0.5], [0.25, -0.05, 0.55],  # just in front of the arm
                      [0.95, -0.05, 0.5], [0.85, -0.1, 0.6], [1.0, 0.0, 0.4]])  # just behind the torso
    kept = FusedFrames(grid, r, principal, frees, robot_far=robot_far, robot_near=robot_near)
    for step in range(8):
        points = start + step * np.array([0.004, -0.003, 0.002])
        again = kept.distances(points, 0.4, aggregate)
        alone = FusedFrames(grid, r, principal, frees, robot_far=robot_far, robot_near=robot_near).distances(
            points, 0.4, aggregate)
        assert np.array_equal(again.count, alone.count), step
        np.testing.assert_allclose(again.distance, alone.distance, rtol=1e-12, atol=0, err_msg=str(step))
        np.testing.assert_allclose(again.direction, alone.direction, rtol=0, atol=1e-12, err_msg=str(step))
        assert again.flags == alone.flags
    assert np.isfinite(alone.distance).sum() >= 3 and (alone.count > 1).sum() >= 3 or aggregate == "min"


def test_nearest_by_run_equals_the_walk_on_random_pixels():
    """``nearest_by_run`` (the answer from a pixel's known free run, one evaluation of g per end) against
    ``nearest_confirmed`` (the walk over the cells, frustum_nearest on the occupied ones) on one pixel of a real
    FusedFrames whose cell classes, free run, certain part and segment are drawn at random: wherever the run decides
    the answer, both give the same squared distance and depth. Every branch is drawn: the cells just past the run's
    ends, the certain part (a surface's own cell, and the grid's near end), the grid's far end, and a nearest point
    outside the run in a cell known occupied (the answer itself)."""
    from depthguard.kernels import depthgrid as K

    r, grid, principal, frees, robot_far, robot_near = robot_scene_frames(40, 30)
    frames = FusedFrames(grid, r, principal, frees, robot_far=robot_far, robot_near=robot_near)
    camera = r.cameras["p"]
    rng = np.random.default_rng(11)
    d_min, delta_d, n = grid.d_min, grid.delta_d, grid.n_cells
    decided = dict(left_cell=0, right_cell=0, certain=0, grid_end=0, nothing=0, own=0)
    for trial in range(4000):
        u, v = int(rng.integers(0, 40)), int(rng.integers(0, 30))
        draw = rng.random(n)  # 0: not classified yet (nearest_confirmed classifies it), 1: free, 2: occupied
        cells = np.where(draw < 0.1, 0, np.where(draw < 0.4, 2, 1)).astype(np.uint8)
        run_lo = int(rng.integers(0, n))
        run_hi = min(n - 1, run_lo + int(rng.integers(0, 40)))
        cells[run_lo:run_hi + 1] = 1
        frames._cells[v, u] = cells
        frames._touched[v, u] = 1  # for whoever reuses the array
        runs = np.full(camera.shape, K.NO_FREE_RUN, dtype=np.int64)
        runs[v, u] = (run_lo << 32) | run_hi
        state = frames.kernel_state(runs, runs.copy())
        a0, a1 = (u - 0.5 - camera.cx) / camera.fx, (u + 0.5 - camera.cx) / camera.fx
        b0, b1 = (v - 0.5 - camera.cy) / camera.fy, (v + 0.5 - camera.cy) / camera.fy
        z_run = d_min + delta_d * (rng.uniform(run_lo, run_hi + 1) if rng.random() < 0.7 else rng.uniform(0, n))
        tx, ty = rng.uniform(a0 - 0.02, a1 + 0.02), rng.uniform(b0 - 0.02, b1 + 0.02)
        Z = z_run + rng.normal(0, 0.02)
        X, Y = tx * Z, ty * Z
        lo = z_run - rng.uniform(0.0, 0.5) if rng.random() < 0.8 else d_min - rng.uniform(0, 0.1)
        certain_to = lo + (rng.uniform(0, z_run - lo) if rng.random() < 0.5 else 0.0)
        hi = z_run + rng.uniform(0.0, 0.5) if rng.random() < 0.8 else d_min + n * delta_d + rng.uniform(0, 0.2)
        rho = 0.4
        bound2 = rho * rho if rng.random() < 0.7 else rng.uniform(0.0001, 0.04)
        d2, z = K.frustum_nearest(X, Y, Z, a0, a1, b0, b1, lo, hi)
        if not d2 < bound2:
            continue
        got2, got_z, ok = K.nearest_by_run(X, Y, Z, a0, a1, b0, b1, d2, z, lo, certain_to, hi, bound2, u, v, d_min,
                                           delta_d, n, frames._cells, runs)
        if not ok:
            continue
        want2, want_z = K.nearest_confirmed(X, Y, Z, rho, a0, a1, b0, b1, lo, certain_to, hi, bound2, u, v, state, runs)
        assert got2 == pytest.approx(want2, rel=1e-9, abs=1e-15), trial
        if np.isfinite(want2):
            assert got_z == pytest.approx(want_z, rel=0, abs=1e-9), trial
            if got2 == d2 and got_z == z:
                decided["own"] += 1
                continue
            k = min(int((got_z - d_min) / delta_d), n - 1) if got_z >= d_min else -1
            if got_z <= max(certain_to, min(d_min, hi) if lo < d_min else certain_to) and got_z < z:
                decided["certain"] += 1
            elif got_z >= d_min + n * delta_d:
                decided["grid_end"] += 1
            elif got_z < z:
                decided["left_cell"] += 1
            else:
                decided["right_cell"] += 1
        else:
            decided["nothing"] += 1
    assert all(count >= 10 for count in decided.values()), decided


def test_threads_and_row_chunks_change_no_answer(monkeypatch):
    import numba

    from depthguard import config

    r, grid, principal, frees, robot_far, robot_near = robot_scene_frames()
    points = np.random.default_rng(8).uniform([-0.5, -0.6, 0.1], [1.3, 0.6, 1.3], (10, 3))
    answers = []
    previous = numba.get_num_threads()
    for threads, chunks in ((1, 1), (2, 1), (2, 4), (1, 3)):
        numba.set_num_threads(threads)
        monkeypatch.setattr(config, "FUSION_ROW_CHUNKS", chunks)
        for aggregate in ("min", "hybrid"):
            result = fused_distances(grid, r, principal, frees, points, 0.4, aggregate, robot_far=robot_far)
            answers.append((aggregate, result.distance, result.count))
    numba.set_num_threads(previous)
    for aggregate, distance, count in answers:
        first = next(a for a in answers if a[0] == aggregate)
        assert np.allclose(distance, first[1], rtol=1e-12, atol=0) and np.array_equal(count, first[2])


def test_fused_kernel_equals_twin_with_robot_far_and_holes():
    r, grid, principal, frees, robot_far, robot_near = robot_scene_frames(40, 30)
    p = r.cameras["p"]
    points = np.random.default_rng(9).uniform([-0.5, -0.6, 0.1], [1.3, 0.6, 1.3], (6, 3))
    slack = 0.02 + p.noise.margin(robot_far.astype(np.float64))
    hidden_arm = np.isinf(principal.blind) & (robot_far > 0) & (principal.z_start < robot_near)
    assert hidden_arm.sum() >= 3  # the person hides part of the arm from p
    for near in (None, robot_near):  # with robot_near, the arm's body hidden behind the person is not an obstacle
        reference = naive.fused_query_reference(grid, principal, [frees["s"]], [0.3], points, 0.4, "occupied",
                                                robot_far=robot_far, robot_slack=slack, robot_near=near)
        for aggregate in ("min", "hybrid", "mean"):
            result = fused_distances(grid, r, principal, frees, points, 0.4, aggregate, robot_far=robot_far,
                                     robot_near=near)
            assert_equals_twin(result, reference[aggregate])


def test_space_between_two_links_is_checked():
    """Two links one behind the other along the principal camera's rays, a ball in the gap between them, which the
    second camera sees. Without robot_exit (where each ray first leaves the robot's padded geometry) the depth grid
    takes the space up to where the geometry ends for the robot and misses the ball; with it, the gap is checked like
    the space behind the robot (design §11a): the ball is found. With the links' capsules (robot_shell), the second
    link's shell counts as that link, so that the link itself is no obstacle to a point beside it."""
    links = [Capsule((0.5, 0.0, 0.3), (0.5, 0.0, 1.0), 0.06), Capsule((-0.3, 0.0, 0.3), (-0.3, 0.0, 1.0), 0.06)]
    ball = Sphere((0.1, 0.0, 0.62), 0.035)  # in the gap, hidden from p by the nearer link
    r = rig(160, 120)
    p, s = r.cameras["p"], r.cameras["s"]
    padded = [Capsule(c.p0, c.p1, c.radius + 0.02) for c in links]
    shell = np.array([c.p0 + c.p1 + (c.radius,) for c in padded])
    with Renderer() as renderer:
        instances = [MeshInstance(renderer.add_mesh(*primitive_mesh(c, 32), closed=True), np.eye(4)) for c in padded]
        near = renderer.render_depth(p, instances)
        far = renderer.render_depth_max(p, instances)
        exit_ = renderer.render_depth_first_exit(p, instances)
    grid = build_map(r)
    assert np.all(exit_[far > 0] <= far[far > 0] + 1e-6) and np.any(exit_ < far - 0.3)  # the rays leave A first

    def fused(scene, P, **robot):
        principal = dg.prepare_depth(dg.depth_image(render_depth(p, scene), p), p, robot_near=near, robot_far=far)
        frees = {"s": free_image(dg.depth_image(render_depth(s, scene), s), s)}
        return fused_distances(grid, r, principal, frees, P, 0.4, "min", robot_far=far, robot_near=near, **robot)

    P = np.array([[0.1, 0.0, 0.75]])
    truth = scene_distance([ball], P)[0]
    tolerance = 2.5 * (p.world_to_camera(P)[0, 2] + 0.4) / p.fx
    with_ball = ROOM + links + [ball]
    assert fused(with_ball, P).distance[0] > truth + tolerance  # without robot_exit: the gap taken for the robot
    for robot in ({"robot_exit": exit_}, {"robot_exit": exit_, "robot_shell": shell}):
        checked = fused(with_ball, P, **robot)
        assert checked.distance[0] <= truth + tolerance, robot.keys()
        assert dg.Flag.ROBOT_BLIND_SPOT not in checked.flags[0]
    # Without the ball: the cells of a ray through both links' axes that lie inside B's shell (its padded capsule
    # grown by the tolerance) count as B with its capsule, and stay occupied without it (the second camera sees B's
    # surface, not through it); the cells of the gap outside every shell are cleared by the second camera either way.
    from depthguard.kernels import depthgrid as K

    uu, vv, _ = p.project(p.world_to_camera(np.array([[-0.3, 0.0, 0.65]])))
    u, v = int(round(float(uu[0]))), int(round(float(vv[0])))
    principal = dg.prepare_depth(dg.depth_image(render_depth(p, ROOM + links), p), p, robot_near=near, robot_far=far)
    frees = {"s": free_image(dg.depth_image(render_depth(s, ROOM + links), s), s)}
    classes = {}
    for name, robot in (("alone", {}), ("shell", {"robot_shell": shell})):
        frames = FusedFrames(grid, r, principal, frees, robot_far=far, robot_near=near, robot_exit=exit_, **robot)
        k_lo = int((exit_[v, u] + 0.02 - grid.d_min) / grid.delta_d) + 1
        k_hi = int((far[v, u] - grid.d_min) / grid.delta_d) - 1
        for k in range(k_lo, k_hi + 1, 32):
            K.classify_run(u, v, k, min(k + 31, k_hi), frames.kernel_state())
        depths = grid.d_min + (np.arange(k_lo, k_hi + 1) + 0.5) * grid.delta_d
        classes[name] = frames._cells[v, u, k_lo:k_hi + 1].copy()  # the next frames reuse the array
    ray = p.T_world_camera[:3, :3] @ np.array([(u - p.cx) / p.fx, (v - p.cy) / p.fy, 1.0])
    points = p.T_world_camera[:3, 3] + depths[:, None] * ray  # the cells' centres, world frame
    to_b = np.hypot(points[:, 0] + 0.3, points[:, 1]) - 0.08  # from B's padded surface (its axis is vertical)
    inside_b = to_b < -0.01
    assert inside_b.sum() >= 5
    assert np.all(classes["shell"][inside_b] == 1) and np.all(classes["alone"][inside_b] == 2)
    gap = (to_b > 0.1) & (np.hypot(points[:, 0] - 0.5, points[:, 1]) - 0.08 > 0.1)
    assert gap.sum() >= 10 and np.all(classes["alone"][gap] == 1) and np.all(classes["shell"][gap] == 1)


def test_seen_free_fills_edge_dropouts_and_nothing_else():
    """A secondary camera's free depths from its prepared frame: its measurements minus their noise margin (as
    free_image), the thin lines sensors drop along depth edges filled from the nearest surface around them under
    "neighbors", and nothing where a large hole stays unmeasured or the policy is "occupied"."""
    from depthguard.depthgrid import seen_free

    r = rig(80, 60)
    s = r.cameras["s"]
    depth = render_depth(s, ROOM + [Capsule((0.0, 0.0, 0.2), (0.0, 0.0, 1.2), 0.2)])
    holes = np.zeros(depth.shape, bool)
    holes[20:40, 30] = True  # a one-pixel line
    holes[45:55, 5:25] = True  # a large hole
    depth[holes] = 0
    image = dg.depth_image(depth, s)
    reference = free_image(image, s)
    filled = seen_free(image, dg.prepare_depth(image, s, "neighbors"))
    kept = seen_free(image, dg.prepare_depth(image, s, "occupied"))
    assert np.array_equal(filled[~holes], reference[~holes]) and np.array_equal(kept, reference)
    line = holes.copy()
    line[45:55, 5:25] = False
    assert np.all(filled[line] > 0)
    around = np.minimum(reference[line.nonzero()[0], 29], reference[line.nonzero()[0], 31])
    assert np.all(filled[line] <= around + 1e-6)  # never farther than the surface around the line
    assert np.all(filled[45:55, 5:25] == 0)


# --------------------------------------------------------------------------- the kernels as plain Python

def tiny_fused_answers() -> dict:
    """Small fused queries through :class:`FusedFrames`, every kernel path once: two 32x24 cameras, the room, a
    person and an arm self-filtered out of the principal frame (with where its rays leave a link, so that the space
    between links is reported), holes under every invalid policy, the three aggregates, unseen space occupied and
    free, a blind secondary camera, remembered free space, a grid shorter than the camera's range, and a second query
    on the same frames (the cells kept). Returns, per case, the distances, directions, counts, invalid counts, flag
    bits and blind distances, in plain Python types (floats as they are: JSON keeps them exactly, inf included)."""
    from depthguard.depthgrid import seen_free
    from depthguard.freespace import VoxelBox

    r, grid, _, frees, robot_far, robot_near = robot_scene_frames(32, 24)
    p, s = r.cameras["p"], r.cameras["s"]
    rng = np.random.default_rng(3)
    depth = render_depth(p, ROOM + [Capsule((1.4, 0.3, 0.2), (1.4, 0.3, 1.5), 0.2)])
    depth[rng.random(depth.shape) < 0.08] = 0
    robot_exit = robot_near.copy()  # every ray of the arm leaves a link at once: the space between links is reported
    points = np.concatenate([[[0.0, 0.0, 0.35], [0.0, 0.0, 0.6], [-0.1, 0.0, 0.5], [-3.2, 0.0, 0.5],  # arm, wall
                              [3.0, 0.0, 1.4], [1.2, 0.3, 0.9]],  # behind the principal camera, at the person
                             rng.uniform([-0.5, -0.6, 0.1], [1.3, 0.6, 1.3], (4, 3))])
    box = VoxelBox([-0.6, -0.7, 0.0], [1.4, 0.7, 1.4], 0.1)
    free = np.ones(box.shape, bool)
    free[:, :, 5:8] = False  # all free but a slab
    remembered = (free, box)
    second = dg.depth_image(render_depth(s, ROOM), s)
    answers = {}

    def record(name, result):
        answers[name] = dict(distance=result.distance.tolist(), direction=result.direction.tolist(),
                             count=result.count.tolist(), invalid_count=result.invalid_count.tolist(),
                             flags=[int(f) for f in result.flags], blind_distance=result.blind_distance.tolist())

    for invalid in ("occupied", "neighbors", "free"):
        principal = dg.prepare_depth(dg.depth_image(depth, p), p, invalid, robot_near=robot_near, robot_far=robot_far)
        secondaries = {"s": seen_free(second, dg.prepare_depth(second, s, invalid))}
        frames = FusedFrames(grid, r, principal, secondaries, robot_far=robot_far, robot_near=robot_near,
                             robot_exit=robot_exit)
        for aggregate in ("min", "mean", "hybrid"):
            for unseen in ("occupied", "free"):
                record(f"{invalid} {aggregate} {unseen}", frames.distances(points, 0.4, aggregate, unseen))
        record(f"{invalid} again", frames.distances(points[::-1], 0.3, "min"))  # the cells kept from above
        record(f"{invalid} remembered", FusedFrames(grid, r, principal, secondaries, robot_far=robot_far,
                                                    robot_near=robot_near, remembered=remembered).distances(points))
    record("blind secondary", FusedFrames(grid, r, principal, {"s": None}, robot_far=robot_far).distances(points))
    short = build_map(r, d_max=2.6)  # beyond its end every cell is occupied, and regions leaving it are flagged
    record("short grid", FusedFrames(short, r, principal, secondaries, robot_far=robot_far).distances(points))
    record("free image", fused_distances(grid, r, principal, frees, points, 0.4, "hybrid", robot_far=robot_far))
    return answers


def test_depth_grid_kernels_run_as_python_with_jit_disabled():
    """NUMBA_DISABLE_JIT=1 in a child process runs the depth grid's kernels' bodies as plain Python (so coverage sees
    them): :func:`tiny_fused_answers` there gives exactly what the compiled kernels give here (floats to 1e-12)."""
    import json
    import os
    import subprocess
    import sys

    tests = os.path.dirname(os.path.abspath(__file__))
    script = (f"import json, sys; sys.path.insert(0, {tests!r}); import test_depth_grid; "
              "print(json.dumps(test_depth_grid.tiny_fused_answers()))")
    done = subprocess.run([sys.executable, "-c", script], env=dict(os.environ, NUMBA_DISABLE_JIT="1"),
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-3000:]
    plain = json.loads(done.stdout.splitlines()[-1])
    compiled = json.loads(json.dumps(tiny_fused_answers()))
    assert plain.keys() == compiled.keys()
    checked = dict(finite=0, flagged=0, directions=0)
    for case, answer in compiled.items():
        for field in ("count", "invalid_count", "flags"):
            assert plain[case][field] == answer[field], (case, field)
        for field in ("distance", "direction", "blind_distance"):
            np.testing.assert_allclose(plain[case][field], answer[field], rtol=0, atol=1e-12, err_msg=f"{case} {field}")
        distance = np.array(answer["distance"])
        checked["finite"] += int(np.sum(np.isfinite(distance) & (distance > 0)))
        checked["flagged"] += sum(f != 0 for f in answer["flags"])
        checked["directions"] += int(np.count_nonzero(np.linalg.norm(answer["direction"], axis=1)))
    assert all(v > 20 for v in checked.values()), checked  # the answers are not all inf or zero
