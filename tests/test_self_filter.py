"""Self-filtering (design §7) in the frame preparation and the single-camera kernels, on ray-cast scenes whose
"robot" is a chain of capsules (the robot model and its rendering are tested elsewhere)."""

import numpy as np
import pytest

import depthguard as dg
import naive
from depthguard.scenes import Box, Capsule, Sphere, render_depth, scene_distance
from depthguard.transforms import look_at

ROOM = [Box.from_bounds([-3, -3, -0.1], [3, 3, 0.0]), Box.from_bounds([-2.5, -3, 0], [-2.4, 3, 3])]
ARM = [Capsule((0.0, 0.0, 0.0), (0.0, 0.0, 0.6), 0.07), Capsule((0.0, 0.0, 0.6), (0.4, 0.1, 0.9), 0.06),
       Capsule((0.4, 0.1, 0.9), (0.5, 0.3, 0.6), 0.05)]
CONTROL_POINTS = np.array([[0.0, 0.0, 0.3], [0.0, 0.0, 0.6], [0.2, 0.05, 0.75], [0.4, 0.1, 0.9], [0.5, 0.3, 0.6]])


def camera(width=320, height=240, noise=None):
    f = 525.0 * width / 640
    return dg.PinholeCamera("cam", width, height, f, f, (width - 1) / 2, (height - 1) / 2,
                            look_at([2.2, 0.5, 1.5], [0.1, 0.1, 0.5]), depth_range=(0.3, 6.0),
                            noise=noise or dg.NoiseModel.none())


def prepare(cam, obstacles, invalid="occupied", holes=None, padding=0.01):
    depth = render_depth(cam, ROOM + ARM + obstacles)
    if holes is not None:
        depth[holes] = 0.0
    padded = [Capsule(c.p0, c.p1, c.radius + padding) for c in ARM]
    robot_near = render_depth(cam, padded)
    return dg.prepare_depth(dg.depth_image(depth, cam), cam, invalid, robot_near=robot_near)


def test_robot_is_not_its_own_obstacle():
    cam = camera()
    occupancy = prepare(cam, [])
    unfiltered = dg.prepare_depth(dg.depth_image(render_depth(cam, ROOM + ARM), cam), cam)
    truth = scene_distance(ROOM, CONTROL_POINTS)
    filtered = dg.single_camera_distances(occupancy, CONTROL_POINTS, 0.4, "min")
    raw = dg.single_camera_distances(unfiltered, CONTROL_POINTS, 0.4, "min")
    assert np.all(raw.distance == 0.0)  # without the filter, the robot sits inside its own occupied set
    # With it, only the room counts (the floor, for the lowest point), never more than the truth.
    near = truth < 0.4
    assert near[0] and not near[1:].any()
    assert filtered.distance[0] <= truth[0] + 2 * 2.5 / cam.fx and filtered.distance[0] > 0.25
    assert np.all(filtered.distance[1:] == np.inf)
    assert occupancy.robot_pixels > 1000
    assert all(dg.Flag.ROBOT_BLIND_SPOT in f for f in filtered.flags)  # a camera cannot see behind the arm


def test_obstacle_in_front_of_the_robot_stays():
    cam = camera()
    hand = Sphere((0.75, 0.3, 0.85), 0.05)  # between the camera and the arm's elbow
    occupancy = prepare(cam, [hand])
    truth = scene_distance([hand] + ROOM, CONTROL_POINTS)
    result = dg.single_camera_distances(occupancy, CONTROL_POINTS, 0.4, "min")
    near = truth < 0.4
    assert near.sum() >= 2
    assert np.all(result.distance[near] <= truth[near] + 1e-9 + 2 * 2.5 / cam.fx)
    # The hand (and the space it hides, which covers part of the arm) counts: without it these points see nothing.
    without = dg.single_camera_distances(prepare(cam, []), CONTROL_POINTS, 0.4, "min")
    assert np.all(result.distance[near] < np.minimum(without.distance[near], 0.4))


def test_hidden_hand_behind_the_robot_is_flagged_not_seen():
    cam = camera()
    # A hand exactly behind the upper arm as the camera sees it.
    elbow = np.array([0.2, 0.05, 0.75])
    eye = cam.T_world_camera[:3, 3]
    behind = elbow + 0.15 * (elbow - eye) / np.linalg.norm(elbow - eye)
    hand = Sphere(tuple(behind), 0.03)
    depth_with = render_depth(cam, ROOM + ARM + [hand])
    assert np.array_equal(depth_with, render_depth(cam, ROOM + ARM))  # the hand is hidden
    occupancy = prepare(cam, [hand])
    result = dg.single_camera_distances(occupancy, elbow[None], 0.4, "min")
    assert dg.Flag.ROBOT_BLIND_SPOT in result.flags[0]


def test_missing_measurements_on_the_robot_are_occupied_only_in_front_of_it():
    cam = camera()
    robot_mask = render_depth(cam, ARM) > 0
    occupancy = prepare(cam, [], holes=robot_mask)
    result = dg.single_camera_distances(occupancy, CONTROL_POINTS, 0.4, "min")
    # The holes' frusta end in front of the robot, so a point inside the arm is not at distance 0 ...
    assert np.all(result.distance[1:] > 0.0)
    # ... but the space in front of the robot, where a hand could hide in the holes, counts as occupied.
    toward_camera = cam.T_world_camera[:3, 3] - CONTROL_POINTS[0]
    in_front = CONTROL_POINTS[0] + 0.15 * toward_camera / np.linalg.norm(toward_camera)
    front = dg.single_camera_distances(occupancy, in_front[None], 0.4, "min")
    assert front.distance[0] == 0.0 and dg.Flag.INVALID_PIXELS_USED in front.flags[0]


@pytest.mark.parametrize("invalid", ["occupied", "neighbors", "free"])
def test_kernels_equal_twin_with_self_filtering(invalid):
    rng = np.random.default_rng(7)
    cam = camera(160, 120)
    holes = rng.random(cam.shape) < 0.05
    occupancy = prepare(cam, [Sphere((0.7, 0.3, 0.8), 0.06)], invalid, holes=holes)
    assert np.isfinite(occupancy.z_end).any() == (invalid == "occupied")
    points = np.concatenate([CONTROL_POINTS, rng.uniform([-0.5, -0.5, 0.1], [1.0, 1.0, 1.2], (8, 3))])
    for aggregate in ("min", "mean", "hybrid"):
        result = dg.single_camera_distances(occupancy, points, 0.4, aggregate)
        twin = naive.query_reference(occupancy, points, 0.4, aggregate, "occupied")
        distance, direction, count, invalid_count, flags, blind, tied = twin
        naive.assert_same_answers(result, distance, direction, count, invalid_count, flags, blind, tied)


def test_robot_images_are_checked():
    cam = camera(160, 120)
    image = dg.depth_image(render_depth(cam, ROOM), cam)
    with pytest.raises(dg.InputError, match="robot_near"):
        dg.prepare_depth(image, cam, robot_near=np.zeros((10, 10), np.float32))
    with pytest.raises(dg.InputError, match="robot_near"):
        dg.prepare_depth(image, cam, robot_near=np.full(cam.shape, np.nan, np.float32))


@pytest.mark.parametrize("seed", range(4))
def test_hole_filling_kernel_equals_its_twin(seed):
    """invalid="neighbors": the numba flood fill against the scipy whole-image twin, with and without the robot, on
    scattered holes, thin lines along depth edges and larger blobs."""
    rng = np.random.default_rng(seed)
    cam = camera(160, 120, noise=dg.NoiseModel())
    depth = render_depth(cam, ROOM + ARM)
    edges = np.abs(np.diff(depth, axis=1, prepend=depth[:, :1])) > 0.05
    holes = (rng.random(cam.shape) < 0.03) | (edges & (rng.random(cam.shape) < 0.7))
    holes[50:56, 20:31] = True  # a thick hole of 66 pixels
    holes[80:84, 100:103] = True  # a small thick one
    raw = np.where(holes, 0, np.round(depth * 1000)).astype(np.uint16)
    image = dg.depth_image(raw, cam)
    padded = [Capsule(c.p0, c.p1, c.radius + 0.01) for c in ARM]
    for robot_near in (None, render_depth(cam, padded)):
        for hole_pixels in (0, 16, 64):
            occupancy = dg.prepare_depth(image, cam, "neighbors", hole_pixels=hole_pixels, robot_near=robot_near)
            # The twin starts from the same state before hole filling: the "occupied" preparation.
            base = dg.prepare_depth(image, cam, "occupied", robot_near=robot_near)
            z_start, z_end, blind = (np.array(a) for a in (base.z_start, base.z_end, base.blind))
            naive.fill_small_holes_reference(raw, 0.001, base.invalid, hole_pixels, cam.noise.margin, z_start, z_end,
                                             blind)
            if robot_near is not None:
                naive.fill_self_filter_reference(robot_near, dg.config.SELF_FILTER_TOLERANCE, cam.noise.margin,
                                                 cam.depth_range[0], base.invalid, z_start, z_end, blind)
            assert np.array_equal(occupancy.z_start, z_start.astype(np.float32))
            assert np.array_equal(occupancy.z_end, z_end.astype(np.float32))
            assert np.array_equal(occupancy.blind, blind.astype(np.float32))


def test_a_surface_seen_past_the_padded_robot_stays_a_surface():
    """Where the padded geometry is rendered but the camera saw past it (the padding is empty space), the
    measurement is a surface when robot_far tells where the rendered robot ends, and blind space without it. A small
    ball in that space, behind the padding's far side, is then an obstacle rather than a flagged blind spot."""
    from depthguard.rendering import MeshInstance, Renderer, primitive_mesh

    cam = camera()
    padding = 0.06  # generous, so that the camera sees past the padding all round the arm
    padded = [Capsule(c.p0, c.p1, c.radius + padding) for c in ARM]
    near = render_depth(cam, padded)
    with Renderer() as renderer:
        far = renderer.render_depth_max(cam, [MeshInstance(renderer.add_mesh(*primitive_mesh(c, 32), closed=True),
                                                           np.eye(4)) for c in padded])

    def both(obstacles):
        image = dg.depth_image(render_depth(cam, ROOM + ARM + obstacles), cam)
        return (dg.prepare_depth(image, cam, robot_near=near),
                dg.prepare_depth(image, cam, robot_near=near, robot_far=far), image.data)

    blind_only, with_far, depth = both([])
    padding_pixels = (near > 0) & (depth > far + 0.1)  # the camera saw past the padded geometry
    assert padding_pixels.sum() > 100
    assert np.all(np.isinf(blind_only.z_start[padding_pixels]))  # made blind without robot_far
    assert np.array_equal(with_far.z_start[padding_pixels], depth[padding_pixels])  # a surface with it
    assert np.all(np.isinf(with_far.blind[padding_pixels]))
    # Where the camera sees the arm itself, both agree: free up to the robot, blind behind it.
    arm_pixels = (near > 0) & (depth >= near - 0.02) & (depth <= far)
    assert arm_pixels.sum() > 1000
    assert np.all(np.isinf(with_far.z_start[arm_pixels])) and np.all(np.isinf(blind_only.z_start[arm_pixels]))
    assert np.array_equal(with_far.blind[arm_pixels], blind_only.blind[arm_pixels])
    # A ball on such a pixel's ray, 8 cm past the padded geometry, beside the real arm.
    v, u = np.argwhere(padding_pixels)[len(np.argwhere(padding_pixels)) // 2]
    centre = cam.camera_to_world(cam.back_project(u, v, float(far[v, u]) + 0.08)[None])[0]
    ball = Sphere(tuple(centre), 0.02)
    blind_only, with_far, _ = both([ball])
    P = (centre + np.array([0.0, 0.0, 0.12]))[None]
    truth = scene_distance([ball] + ROOM, P)[0]
    found = dg.single_camera_distances(with_far, P, 0.4, "min")
    missed = dg.single_camera_distances(blind_only, P, 0.4, "min")
    assert truth < 0.4 and found.distance[0] <= truth + 2 * 2.5 / cam.fx
    assert missed.distance[0] > truth + 0.02 and dg.Flag.ROBOT_BLIND_SPOT in missed.flags[0]


@pytest.mark.parametrize("beside, robot_hole", [(2.01, True), (1.90, False)])
def test_a_hole_filled_inside_the_robots_outline_is_self_filtered_like_a_measurement(beside, robot_hole):
    """invalid="neighbors" fills a thin hole from the nearest surface around it. Inside the robot's rendered outline,
    with that surface just beside the robot and behind its padded front (the pedestal round the base: 2.01 m, the
    rendered robot at 2.00 m, the robot measured at 2.02 m), the fill lies inside the robot: the hole shows the
    robot (free in front, blind behind), as a measurement of 2.01 m there would. A surface clearly in front of the
    robot (1.90 m) stays an obstacle."""
    cam = dg.PinholeCamera("cam", 20, 20, 20.0, 20.0, 9.5, 9.5, np.eye(4), depth_range=(0.3, 6.0),
                           noise=dg.NoiseModel.none())
    near = np.zeros(cam.shape, np.float32)
    near[:, 8:] = 2.0  # the robot's padded outline covers columns 8..19
    depth = np.where(near > 0, 2.02, beside).astype(np.float32)
    depth[9:11, 8:10] = 0.0  # a thin hole at the outline's edge, inside it
    occupancy = dg.prepare_depth(dg.depth_image(depth, cam), cam, "neighbors", robot_near=near)
    hole = (slice(9, 11), slice(8, 10))
    if robot_hole:
        assert np.all(np.isinf(occupancy.z_start[hole])) and np.all(occupancy.blind[hole] == np.float32(2.0))
    else:
        assert np.all(occupancy.z_start[hole] == np.float32(beside)) and np.all(np.isinf(occupancy.blind[hole]))
    assert np.all(occupancy.invalid[hole] == 1)  # still counted as pixels without a measurement


def test_instances_of_the_same_joints_are_placed_once_and_bad_joints_still_refused():
    """A set's passes ask the silhouette for the robot at the same joints: placed once, the same instances after.
    Joints of another shape with the same numbers are refused as before, not answered from the last placement."""
    from depthguard.errors import InputError
    from depthguard.rendering import Renderer
    from depthguard.robots import RobotModel
    from depthguard.self_filter import RobotSilhouette

    robot = RobotModel.default()
    q = np.zeros(len(robot.joint_names))
    with Renderer() as renderer:
        silhouette = RobotSilhouette(robot, renderer)
        first = silhouette.instances(q)
        again = silhouette.instances(q.copy())
        assert all(a is b for a, b in zip(first, again)) and len(first) == len(again)
        moved = silhouette.instances(q + 0.1)
        assert not np.allclose(moved[-1].T_world_mesh, first[-1].T_world_mesh)
        silhouette.instances(q)  # q's placement is the one kept
        with pytest.raises(InputError):
            silhouette.instances(q.reshape(-1, 1))
