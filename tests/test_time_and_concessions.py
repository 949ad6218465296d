"""Time and concessions in every answer (design sections 9, 11, 11a): a set is as old as its oldest frame, max_age is on
by default, every answer that rests on a concession names it and says how near the conceded space comes, and a blind
answer stops the robot. Judged with exact geometry (depthguard.scenes' ray casting and distances) and brute force,
not with the monitor's own code."""

import math

import numpy as np
import pytest

import depthguard as dg
from depthguard import config
from depthguard.errors import InputError
from depthguard.results import DetectableResult, Flag
from depthguard.scenes import Box, Sphere, render_depth
from depthguard.transforms import look_at

FLOOR = Box.from_bounds([-3.0, -3.0, -0.1], [3.0, 3.0, 0.0])
BALL = Sphere((0.0, 0.0, 0.4), 0.1)


def _camera(name="a", eye=(2.0, 0.0, 1.2)):
    return dg.PinholeCamera(name, 160, 120, 131.25, 131.25, 79.5, 59.5, look_at(eye, [0.0, 0.0, 0.2]),
                            depth_range=(0.3, 6.0), noise=dg.NoiseModel.none())


def _pair():
    a, b = _camera("a"), _camera("b", (-0.5, 2.0, 1.4))
    rig = dg.Rig({"a": a, "b": b}, principal="a")
    depth = {name: render_depth(camera, [FLOOR, BALL]) for name, camera in rig.cameras.items()}
    return rig, depth


POINTS = np.array([[0.0, 0.0, 0.8], [0.5, 0.3, 0.5]])


# --------------------------------------------------------------------------------------------------------- time


def test_a_set_is_as_old_as_its_oldest_frame():
    """Frames at 0 and 0.09 s, asked at 0.10 s: the answer is 0.10 s old (camera a's free space is what it saw
    then), not 0.01 s; SSM's reaction time starts there and counts the set's preparation."""
    rig, depth = _pair()
    monitor = dg.DistanceMonitor(rig, memory=False)
    frames = {"a": dg.depth_image(depth["a"], rig.cameras["a"], timestamp=0.0),
              "b": dg.depth_image(depth["b"], rig.cameras["b"], timestamp=0.09)}
    prepared = monitor.prepare_set(frames, now=0.1)
    result = prepared.query(POINTS)
    assert result.ages == pytest.approx({"a": 0.1, "b": 0.01})
    assert result.age == pytest.approx(0.1)
    assert prepared.time == 0.0 and prepared.newest == 0.09
    assert prepared.prepare_seconds > 0.0
    assert prepared.reaction_time(0.12, 0.002) == pytest.approx(0.12 + prepared.prepare_seconds + 0.002)
    assert prepared.query(POINTS, now=0.095).ages == pytest.approx({"a": 0.095, "b": 0.005})


def test_max_age_is_on_by_default_for_frames_that_carry_timestamps():
    """A camera that froze stops clearing space within config.DEFAULT_MAX_AGE (0.1 s) of the others' frames or of
    ``now``, and is named; frames without timestamps cannot age and are used; an explicit max_age keeps refusing
    them."""
    rig, depth = _pair()
    cam_a, cam_b = rig.cameras["a"], rig.cameras["b"]
    monitor = dg.DistanceMonitor(rig, memory=False)
    assert monitor.max_age == config.DEFAULT_MAX_AGE
    frozen = {"a": dg.depth_image(depth["a"], cam_a, timestamp=0.0),
              "b": dg.depth_image(depth["b"], cam_b, timestamp=0.25)}
    result = monitor.query(frozen, POINTS)  # no now: the newest frame stands for it
    assert all(Flag.STALE_CAMERA in f for f in result.flags) and result.cameras == ("b",)
    result = monitor.query(frozen, POINTS, now=0.26)
    assert result.cameras == ("b",)
    fresh = {"a": dg.depth_image(depth["a"], cam_a, timestamp=0.2), "b": frozen["b"]}
    assert set(monitor.query(fresh, POINTS).cameras) == {"a", "b"}
    # both frozen, now moves on: no usable camera, distance 0 everywhere
    result = monitor.query(fresh, POINTS, now=0.5)
    assert result.is_blind and np.all(result.distance == 0.0)
    untimed = {name: dg.depth_image(depth[name], camera) for name, camera in rig.cameras.items()}
    assert set(monitor.query(untimed, POINTS).cameras) == {"a", "b"}
    strict = dg.DistanceMonitor(rig, memory=False, max_age=0.1)
    with pytest.raises(InputError):
        strict.query(untimed, POINTS)  # an explicit max_age needs now
    assert strict.query(untimed, POINTS, now=0.0).is_blind
    assert dg.DistanceMonitor(rig, memory=False, max_age=None).query(frozen, POINTS, now=100.0).cameras == ("a", "b")


def test_a_prepared_set_goes_stale_at_query_time():
    rig, depth = _pair()
    monitor = dg.DistanceMonitor(rig, memory=False)
    frames = {name: dg.depth_image(depth[name], camera, timestamp=1.0) for name, camera in rig.cameras.items()}
    prepared = monitor.prepare_set(frames, now=1.0)
    assert not prepared.query(POINTS, now=1.05).is_blind
    late = prepared.query(POINTS, now=1.2)
    assert late.is_blind and all(Flag.STALE_CAMERA in f for f in late.flags)


def test_a_prepared_frames_joints_are_checked_like_any_others():
    """A DepthImage prepared before is reused, but joints given with it are still checked: NaN, a wrong count or an
    unknown joint name are refused naming joints."""
    from depthguard.robots import RobotModel

    robot = RobotModel.default()
    camera = _camera()
    rig = dg.Rig({"a": camera})
    monitor = dg.DistanceMonitor(rig, robot=robot)
    frame = dg.depth_image(render_depth(camera, [FLOOR]), camera)
    q = np.zeros(robot.n_joints)
    monitor.query({"a": frame}, POINTS, joints=q)
    for bad in (np.full(robot.n_joints, np.nan), np.zeros(3), {"no_such_joint": 0.0}):
        with pytest.raises(InputError) as caught:
            monitor.query({"a": frame}, POINTS, joints=bad)
        assert caught.value.field == "joints"
    monitor.query({"a": frame}, POINTS, joints=q)  # still answers with good ones


# ------------------------------------------------------------------------------------------------- concessions


def _holed(camera, depth, centre, half):
    """``depth`` with a square hole of (2 half + 1)^2 pixels round pixel ``centre`` (u, v): no measurement."""
    holed = depth.copy()
    u, v = centre
    holed[v - half:v + half + 1, u - half:u + half + 1] = 0.0
    return holed


def _filled_frustum_distance(camera, occupancy, points):
    """Brute force: the distance from each point to the union of the filled pixels' frusta, from the camera's
    minimum range to their fill (:func:`depthguard.frustum_distance` per pixel)."""
    vs, us = np.nonzero(occupancy.filled > 0)
    tangents = np.stack([(us - 0.5 - camera.cx) / camera.fx, (us + 0.5 - camera.cx) / camera.fx,
                         (vs - 0.5 - camera.cy) / camera.fy, (vs + 0.5 - camera.cy) / camera.fy], axis=1)
    z_range = np.stack([np.full(len(us), camera.depth_range[0]), occupancy.filled[vs, us]], axis=1)
    return np.array([dg.frustum_distance(p, tangents, z_range)[0].min() for p in camera.world_to_camera(points)])


def test_a_filled_hole_is_flagged_and_its_space_is_stated():
    """invalid="neighbors" fills a hole from the surface round it: the space it counts free lies in the hole's
    frusta up to the fill. Points nearer to that space than their answer are flagged hole_filled, and
    concession_distance is exactly the distance to it; the default policy fills nothing and flags nothing."""
    camera = _camera()
    rig = dg.Rig({"a": camera})
    depth = render_depth(camera, [FLOOR, BALL])
    u, v, _ = camera.project(camera.world_to_camera([[0.0, 0.0, 0.5]]))
    u, v = int(round(u[0])), int(round(v[0]))
    holed = _holed(camera, depth, (u, v), 2)
    frame = dg.depth_image(holed, camera)
    points = np.array([[0.3, 0.0, 0.6], [0.0, -0.4, 0.9], [-1.5, 1.5, 0.5]])
    filled = dg.DistanceMonitor(rig, invalid="neighbors").query({"a": frame}, points)
    occupancy = dg.prepare_depth(frame, camera, "neighbors")
    assert occupancy.filled is not None and np.count_nonzero(occupancy.filled) == 25
    exact = _filled_frustum_distance(camera, occupancy, points)
    expected = np.where(exact < config.DEFAULT_RHO, exact, np.inf)
    np.testing.assert_allclose(filled.concession_distance, expected, atol=1e-9)
    for flags, near, d in zip(filled.flags, filled.concession_distance, filled.distance):
        assert (Flag.HOLE_FILLED in flags) == (near < min(d, config.DEFAULT_RHO))
    assert any(Flag.HOLE_FILLED in f for f in filled.flags)
    plain = dg.DistanceMonitor(rig).query({"a": frame}, points)
    assert not any(Flag.HOLE_FILLED in f for f in plain.flags) and np.all(np.isinf(plain.concession_distance))
    assert np.all(plain.distance <= filled.distance + 1e-12)  # the fill only ever gives space up


def test_a_known_solid_flags_the_answers_its_band_could_hide_something_from():
    """A known solid's replaced measurements count free a band of tolerance + 2 noise margins over its surface. A
    point whose answer reaches past that band is flagged known_solid, with concession_distance the distance to the
    solid less the band (a lower bound of the distance to anything the band can hide); one farther from it than its
    answer is not."""
    camera = dg.PinholeCamera("a", 160, 120, 131.25, 131.25, 79.5, 59.5, look_at([2.0, 0.0, 1.2], [0.0, 0.0, 0.2]),
                              depth_range=(0.3, 6.0))  # the default (Kinect) noise
    rig = dg.Rig({"a": camera})
    frame = dg.depth_image(render_depth(camera, [FLOOR, BALL]), camera)
    monitor = dg.DistanceMonitor(rig, static=[FLOOR], rho=1.0)
    points = np.array([[0.0, 0.6, 0.05], [0.0, 0.0, 0.58], [0.6, -0.3, 0.3]])
    result = monitor.query({"a": frame}, points)
    band = monitor._static.largest_band(camera)
    margin = camera.noise.margin(np.array([np.linalg.norm(camera.T_world_camera[:3, 3])]))[0]
    assert band > config.SELF_FILTER_TOLERANCE + 2.0 * margin - 0.05  # tolerance + twice a margin at the floor
    above = np.maximum(points[:, 2], 0.0)  # the floor's top is z = 0, the points lie over it
    np.testing.assert_allclose(result.concession_distance, np.where(above - band < 1.0, np.maximum(above - band, 0.0),
                                                                     np.inf), atol=1e-9)
    for flags, near, d in zip(result.flags, result.concession_distance, result.distance):
        assert (Flag.KNOWN_SOLID in flags) == (near < min(d, 1.0))
    assert Flag.KNOWN_SOLID in result.flags[0]  # 5 cm over the floor: its band reaches nearer than the answer
    assert Flag.KNOWN_SOLID not in result.flags[1]  # just over the ball: the ball is nearer than the band


def test_the_robot_zone_flags_every_fused_answer_on_the_robot():
    """The robot zone counts space within robot_zone of the padded capsules as the robot: a control point inside the
    capsules has it at 0 and its fused answer is flagged robot_zone; without a zone nothing is."""
    from depthguard.robots import RobotModel

    robot = RobotModel.default()
    rig, depth = _pair()
    q = np.zeros(robot.n_joints)
    frames = {name: dg.depth_image(depth[name], camera) for name, camera in rig.cameras.items()}
    points = np.vstack([robot.control_point_positions(q), [[1.5, 1.5, 0.3]]])
    zoned = dg.DistanceMonitor(rig, robot=robot, robot_zone=0.06, memory=False).query(frames, points, joints=q)
    assert np.all(zoned.concession_distance[:-1] == 0.0)
    inside = zoned.distance[:-1] > 0.0  # a point inside an obstacle (distance 0) rests on nothing
    assert inside.any() and all(Flag.ROBOT_ZONE in f for f, x in zip(zoned.flags[:-1], inside) if x)
    capsules = robot.capsules_world(q)
    far = min(float(c.distance(points[-1:])[0]) for c in capsules) - 0.06
    assert zoned.concession_distance[-1] == pytest.approx(far if far < config.DEFAULT_RHO else np.inf)
    plain = dg.DistanceMonitor(rig, robot=robot, memory=False).query(frames, points, joints=q)
    assert not any(Flag.ROBOT_ZONE in f for f in plain.flags)


def test_flag_names_are_stable():
    """The flags' names are part of the command line's JSON output."""
    assert (Flag.ROBOT_ZONE | Flag.KNOWN_SOLID | Flag.HOLE_FILLED | Flag.DETECTION_OPENING).names == [
        "robot_zone", "known_solid", "hole_filled", "detection_opening"]


# --------------------------------------------------------------------------------------------------------- SSM


def test_ssm_refuses_detectable_distances_of_another_capability():
    """design §9: SSM's d and the monitor's are one value: C is taken for the distances' effective capability
    (d + the band the monitor's concessions hide), and SSM refuses distances of another."""
    from depthguard.avoidance import SpeedSeparationMonitor, SSMParams

    result = DetectableResult(np.array([1.0]), (Flag.DETECTION_OPENING,), capability=0.04, hidden_band=0.02)
    assert result.effective_capability == pytest.approx(0.06)
    jacobians, dq = np.eye(3)[None], np.array([0.1, 0.0, 0.0])
    for d in (0.04, 0.05, 0.07):
        with pytest.raises(InputError) as caught:
            SpeedSeparationMonitor(SSMParams(detection_capability=d), rho=2.0).speed_factor(
                result, None, jacobians, dq, 0.1)
        assert caught.value.field == "detection_capability"
    verdict = SpeedSeparationMonitor(SSMParams(detection_capability=0.06), rho=2.0).speed_factor(
        result, None, jacobians, dq, 0.1)
    assert 0.0 <= verdict.factor <= 1.0


def test_the_stopping_time_comes_from_the_braking_of_the_command():
    from depthguard.avoidance import SpeedSeparationMonitor, SSMParams, brake_along_path

    ssm = SpeedSeparationMonitor(SSMParams(), rho=2.0, braking=np.array([10.0, 5.0]))
    assert ssm.stopping_time(np.array([1.0, -1.0])) == pytest.approx(0.2)
    assert SpeedSeparationMonitor(SSMParams(), rho=2.0).stopping_time(np.ones(2)) == SSMParams().stopping_time
    dq, steps = np.array([1.0, -1.0]), 0
    while np.any(dq):
        new = brake_along_path(dq, ssm.braking, 0.002)
        assert np.all(np.abs(new - dq) <= ssm.braking * 0.002 + 1e-12)
        assert new[0] * -1.0 == pytest.approx(new[1])  # in proportion: the path is kept
        dq, steps = new, steps + 1
    assert steps * 0.002 <= 0.2 + 0.002
    with pytest.raises(InputError):
        SpeedSeparationMonitor(SSMParams(), rho=2.0, braking=np.array([0.0, 1.0]))


def test_a_blind_answer_stops_the_avoidance_and_the_papers_rule_creeps():
    """On a blind answer (no camera could see) the avoidance brakes to rest along its path; the papers' rule
    (on_blind="papers"), kept as an option, scales the joint bounds by 1 - f(0) and lets the arm creep."""
    from depthguard.avoidance import AvoidanceController, AvoidanceParams, JointLimits
    from depthguard.robots import RobotModel

    robot = RobotModel.default()
    limits = JointLimits.from_robot(robot)
    q = np.array([0.3, 0.6, 0.0, -1.2, 0.0, 0.8, 0.0])
    blind = dg.DistanceResult.blind(len(robot.control_points), Flag.MISSING_CAMERA)
    assert blind.is_blind
    task = np.array([0.0, 0.0, 0.4])
    dq = np.zeros(robot.n_joints)
    stop = AvoidanceController(robot, AvoidanceParams(), limits)
    creep = AvoidanceController(robot, AvoidanceParams(on_blind="papers"), limits)
    moving = creep.command(blind, q, task, dq, 0.002).dq
    for _ in range(200):
        moving = creep.command(blind, q, task, moving, 0.002).dq
    assert np.linalg.norm(moving) > 0.0  # the papers' rule still moves the arm
    braking = np.full(robot.n_joints, 0.5)
    for _ in range(200):
        braking = stop.command(blind, q, task, braking, 0.002).dq
    assert np.all(braking == 0.0)
    with pytest.raises(InputError):
        AvoidanceParams(on_blind="creep")


# --------------------------------------------------------------------------------------------- robot coverage


def test_the_surface_points_cover_every_moving_links_capsule_within_the_tolerance():
    """RobotModel.with_surface_points: every point of every moving link's padded capsule lies inside some sphere
    (distance from its centre minus its radius <= 0), and no sphere reaches more than the tolerance beyond the
    capsule; the papers' nine control points leave 4-5 cm of the iiwa's capsules outside theirs."""
    from depthguard.robots import RobotModel

    robot = RobotModel.default()
    tolerance = 0.01
    covered = robot.with_surface_points(tolerance)
    assert covered.end_effector == robot.end_effector
    rng = np.random.default_rng(2)
    for _ in range(5):
        q = rng.uniform(np.maximum(robot.lower, -2.0), np.minimum(robot.upper, 2.0))
        centres, radii = covered.control_point_positions(q), covered.control_point_radii
        nine, nine_radii = robot.control_point_positions(q), robot.control_point_radii
        worst_nine = 0.0
        for capsule, moves in zip(robot.capsules_world(q), robot.moving_links()):
            if not moves:
                continue
            p0, p1 = np.asarray(capsule.p0), np.asarray(capsule.p1)
            d = rng.normal(size=(400, 3))
            d /= np.linalg.norm(d, axis=1)[:, None]
            surface = p0 + rng.uniform(0, 1, (400, 1)) * (p1 - p0) + capsule.radius * d
            outside = np.min(np.linalg.norm(surface[:, None] - centres[None], axis=2) - radii[None], axis=1)
            assert np.all(outside <= 1e-9), outside.max()
            worst_nine = max(worst_nine, float(np.max(np.min(
                np.linalg.norm(surface[:, None] - nine[None], axis=2) - nine_radii[None], axis=1))))
        # each sphere's reach beyond its own capsule
        for point, centre, radius in zip(covered.control_points, centres, radii):
            capsule = robot.capsules_world(q)[robot.link_names.index(point.link)]
            assert radius - capsule.radius <= tolerance + 1e-12
        assert worst_nine > 0.03  # what the nine leave out


def test_a_declared_tool_counts_as_the_robot():
    """RobotModel.with_tool: a gripped box fixed to the flange becomes part of the last link's geometry. Its capsule
    holds it, the surface points cover it, and self-filtering takes it out of a frame that sees it (a point next to
    it reads as far as without the box), while the same box not declared is an obstacle there."""
    from depthguard.robots import RobotModel
    from depthguard.scenes import render_depth

    robot = RobotModel.default()
    piece = Box((0.0, 0.0, 0.12), (0.05, 0.05, 0.06))  # link 7's frame: 12 cm beyond the flange
    tooled = robot.with_tool("lbr_iiwa_link_7", piece)
    q = np.array([0.0, 0.5, 0.0, -1.0, 0.0, 1.0, 0.0])
    T = tooled.link_poses(q)["lbr_iiwa_link_7"]
    corners = np.array([[x, y, z] for x in (-0.05, 0.05) for y in (-0.05, 0.05) for z in (0.06, 0.18)])
    world = corners @ T[:3, :3].T + T[:3, 3]
    capsule = tooled.capsules_world(q)[tooled.link_names.index("lbr_iiwa_link_7")]
    assert np.all(capsule.distance(world) <= 1e-9)  # inside the refitted capsule
    covered = tooled.with_surface_points(0.01)
    outside = np.min(np.linalg.norm(world[:, None] - covered.control_point_positions(q)[None], axis=2)
                     - covered.control_point_radii[None], axis=1)
    assert np.all(outside <= 1e-9)
    # Rendered with the box in a camera: declared, it is the robot; not declared, it is an obstacle.
    camera = _camera(eye=(2.0, 0.5, 1.5))
    rig = dg.Rig({"a": camera})
    box_world = Box(tuple(T[:3, :3] @ np.array([0.0, 0.0, 0.12]) + T[:3, 3]), (0.05, 0.05, 0.06), T[:3, :3])
    frame = dg.depth_image(render_depth(camera, [FLOOR, box_world]), camera)
    near = (T[:3, :3] @ np.array([0.0, 0.15, 0.12]) + T[:3, 3])[None]  # 10 cm beside the box
    seen = dg.DistanceMonitor(rig, robot=robot, rho=0.4).query({"a": frame}, near, joints=q)
    filtered = dg.DistanceMonitor(rig, robot=tooled, rho=0.4).query({"a": frame}, near, joints=q)
    assert seen.distance[0] < 0.11 and filtered.distance[0] > seen.distance[0] + 0.02
    with pytest.raises(Exception):
        robot.with_tool("no_such_link", piece)
    with pytest.raises(InputError):
        robot.with_tool("lbr_iiwa_link_7", "box")


def test_the_monitors_settings_are_one_validated_dataclass():
    """DistanceMonitor's values live in one MonitorSettings: made (and checked) once, given whole or field by field,
    fields given beside settings override them, and a bad value is refused naming it, either way."""
    rig, depth = _pair()
    frames = {name: dg.depth_image(depth[name], camera) for name, camera in rig.cameras.items()}
    settings = dg.MonitorSettings(rho=0.6, aggregate="min", memory=False)
    by_fields = dg.DistanceMonitor(rig, rho=0.6, aggregate="min", memory=False)
    whole = dg.DistanceMonitor(rig, settings)
    assert whole.settings == by_fields.settings == settings
    np.testing.assert_array_equal(whole.query(frames, POINTS).distance, by_fields.query(frames, POINTS).distance)
    assert dg.DistanceMonitor(rig, settings, rho=0.3).settings.rho == 0.3
    for bad in (dict(rho=-1.0), dict(aggregate="max"), dict(max_age=0.0), dict(hole_pixels=1.5),
                dict(robot_zone=1.0), dict(detection_capability=0.08), dict(memory="yes")):
        (field,) = bad
        with pytest.raises(InputError) as caught:
            dg.MonitorSettings(**bad)
        assert caught.value.field == field
        with pytest.raises(InputError) as caught:
            dg.DistanceMonitor(rig, **bad)
        assert caught.value.field == field
    with pytest.raises(InputError) as caught:
        dg.DistanceMonitor(rig, settings={"rho": 0.4})
    assert caught.value.field == "settings"
