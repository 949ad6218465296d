"""The depth grid's collision verdict (design §10, issue 27's second opinion): a configuration collides unless every
sphere over its moving links lies farther than its radius (plus the pixels' slack) from the possibly occupied space
of the frames, the space hidden behind the robot included. Judged on constructed scenes whose truth is the exact
distance from the padded capsules to a box: every configuration that meets a box, seen or hidden behind the robot,
collides; the test fails if the hidden space is dropped (``blind_distance``) or the slack is."""

from __future__ import annotations

import numpy as np
import pytest

import depthguard as dg
from depthguard.collision import DepthGridCollisionTest
from depthguard.rendering import Renderer
from depthguard.robots import RobotModel
from depthguard.scenes import Box, render_depth
from depthguard.self_filter import RobotSilhouette
from depthguard.transforms import look_at

Q = np.array([0.0, 0.5, 0.0, -1.0, 0.0, 0.5, 0.0])
FLOOR = Box.from_bounds([-3, -3, -0.1], [3, 3, 0])
WALL = Box.from_bounds([-2.5, -3, 0], [-2.4, 3, 3])


def _camera():
    return dg.PinholeCamera("right", 320, 240, 262.5, 262.5, 159.5, 119.5, look_at([2.0, 0.5, 1.4], [0, 0, 0.6]),
                            depth_range=(0.3, 6.0), noise=dg.NoiseModel.none())


def _box_gap(robot, q, box: Box) -> float:
    """Metres: the least distance from the padded capsules of ``q``'s moving links to the box (<= 0: they meet),
    sampled finely along each capsule's axis (exact enough: 2 mm steps, the box's distance is exact)."""
    moving = robot.moving_links()
    lo = np.asarray(box.center) - np.asarray(box.half_extents)
    hi = np.asarray(box.center) + np.asarray(box.half_extents)
    gap = np.inf
    for capsule, moves in zip(robot.capsules_world(q), moving):
        if not moves:
            continue
        a, b = np.asarray(capsule.p0), np.asarray(capsule.p1)
        s = np.linspace(0.0, 1.0, max(2, int(np.linalg.norm(b - a) / 0.002) + 1))[:, None]
        axis = a + s * (b - a)
        outside = np.linalg.norm(np.maximum(np.maximum(lo - axis, axis - hi), 0.0), axis=1)
        gap = min(gap, float(outside.min()) - capsule.radius)
    return gap


def _near_box(robot, box: Box, rng, count: int) -> np.ndarray:
    """``count`` configurations whose padded capsules meet the box, drawn from random ones."""
    found = []
    while len(found) < count:
        q = rng.uniform(robot.lower, robot.upper)
        if _box_gap(robot, q, box) < 0.0:
            found.append(q)
    return np.array(found)


@pytest.fixture(scope="module")
def scene():
    robot = RobotModel.default()
    camera = _camera()
    with Renderer() as renderer:
        robot_depth = RobotSilhouette(robot, renderer, geometry="meshes").render(camera, Q)

    def frame(*boxes):
        room = render_depth(camera, [FLOOR, WALL, *boxes])
        return np.where(robot_depth > 0, np.minimum(robot_depth, np.where(room > 0, room, np.inf)),
                        room).astype(np.float32)

    return robot, camera, frame


def test_a_box_in_view_is_hit_by_every_configuration_that_meets_it_and_missed_by_those_far_from_it():
    # No robot in the frames nor in the monitor: the verdict alone, spheres and slack, against a box in open view.
    robot = RobotModel.default()
    camera = _camera()
    box = Box.from_bounds([0.35, -0.45, 0.55], [0.55, -0.25, 0.75])
    depth = render_depth(camera, [FLOOR, WALL, box]).astype(np.float32)
    monitor = dg.DistanceMonitor(dg.Rig({"right": camera}), rho=0.3)
    prepared = monitor.prepare_set({"right": depth})
    test = DepthGridCollisionTest(robot)
    rng = np.random.default_rng(4)
    meeting = _near_box(robot, box, rng, 12)
    verdicts = test.verdicts(prepared, meeting)
    assert verdicts.collision.all() and (verdicts.clearance <= 0).all()
    # Configurations whose moving links stay in space the camera sees free, 0.15 m or more from the box, the floor
    # and the space the box hides: free, and nothing conceded.
    random = rng.uniform(robot.lower, robot.upper, (200, robot.n_joints))
    verdicts = test.verdicts(prepared, random)
    gaps = np.array([_box_gap(robot, q, box) for q in random])
    assert (verdicts.collision[gaps < 0.0]).all()
    assert (~verdicts.collision).sum() >= 10  # some are proven free (not every verdict a collision)
    assert all(f == dg.Flag(0) for f, c in zip(verdicts.conceded, verdicts.collision) if not c)
    # Each clearance is the least over the spheres of the distance less the radius and the pixels' slack (2.5
    # footprints at the sphere's depth + 1 mm): without the slack a box up to 2.5 footprints inside a sphere, where
    # the pixel grid may place its surface, would pass.
    points = np.concatenate([test.surface.control_point_positions(q) for q in random])
    depth = camera.world_to_camera(points)[:, 2]
    slack = 2.5 * depth / camera.fx + 1e-3
    expected = (prepared.query(points).distance - np.tile(test.radii, len(random)) - slack).reshape(len(random), -1)
    np.testing.assert_allclose(verdicts.clearance, expected.min(axis=1), rtol=0, atol=1e-12)


def test_a_box_the_robot_hides_is_hit_by_every_configuration_that_meets_it(scene):
    robot, camera, frame = scene
    # A box right behind the arm from the camera: the frame is the same with it and without it.
    ray = np.asarray(robot.capsules_world(Q)[4].p0) - camera.T_world_camera[:3, 3]
    centre = np.asarray(robot.capsules_world(Q)[4].p0) + ray / np.linalg.norm(ray) * 0.16
    box = Box.from_bounds(centre - 0.03, centre + 0.03)
    assert np.array_equal(frame(box), frame())  # hidden
    monitor = dg.DistanceMonitor(dg.Rig({"right": camera}), robot=robot, rho=0.3)
    prepared = monitor.prepare_set({"right": dg.depth_image(frame(box), camera)}, joints=Q)
    test = DepthGridCollisionTest(robot)
    meeting = _near_box(robot, box, np.random.default_rng(5), 12)
    verdicts = test.verdicts(prepared, meeting)
    assert verdicts.collision.all()
    assert all(dg.Flag.ROBOT_BLIND_SPOT in f for f in verdicts.flags)
    # Without the space hidden behind the robot the same configurations would be judged free: the test would fail.
    points = np.concatenate([test.surface.control_point_positions(q) for q in meeting])
    seen = prepared.query(points).distance.reshape(len(meeting), -1) - test.radii
    assert (seen.min(axis=1) > 0.0).any()


def test_no_usable_frame_means_every_configuration_collides_and_bad_input_is_named(scene):
    robot, camera, frame = scene
    monitor = dg.DistanceMonitor(dg.Rig({"right": camera}), robot=robot, rho=0.3)
    test = DepthGridCollisionTest(robot)
    blind = monitor.prepare_set({})
    verdicts = test.verdicts(blind, np.array([Q, Q * 0.5]))
    assert verdicts.collision.all() and all(dg.Flag.MISSING_CAMERA in f for f in verdicts.flags)
    assert len(test.verdicts(blind, np.zeros((0, robot.n_joints)))) == 0
    prepared = monitor.prepare_set({"right": dg.depth_image(frame(), camera)}, joints=Q)
    with pytest.raises(dg.InputError) as error:
        test.verdicts(prepared, Q)
    assert error.value.field == "configurations"
    for bad in ([["a"] * robot.n_joints], [[0.0] * robot.n_joints, [0.0]], None):  # words, ragged rows, nothing
        with pytest.raises(dg.InputError) as error:
            test.verdicts(prepared, bad)
        assert error.value.field == "configurations"
    for bad in (np.nan, np.inf, 9.0, 1e300):  # not finite, beyond the joint limits
        with pytest.raises(dg.InputError):
            test.verdicts(prepared, np.full((1, robot.n_joints), bad))
    with pytest.raises(dg.InputError) as error:
        test.verdicts(prepared, np.full((1, robot.n_joints), 9.0))  # beyond the joint limits
    with pytest.raises(dg.InputError) as error:
        test.verdicts("frames", np.array([Q]))
    assert error.value.field == "prepared"
    small = dg.DistanceMonitor(dg.Rig({"right": camera}), robot=robot, rho=0.05)
    with pytest.raises(dg.InputError) as error:
        test.verdicts(small.prepare_set({"right": dg.depth_image(frame(), camera)}, joints=Q), np.array([Q]))
    assert error.value.field == "rho"
    with pytest.raises(dg.InputError) as error:
        DepthGridCollisionTest("iiwa")
    assert error.value.field == "robot"
