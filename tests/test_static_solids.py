"""Known static solids (DistanceMonitor(static=...); depthguard.static_solids.StaticSolids): their surfaces stop counting
as obstacles, the space they hide does not, and nothing a camera did not see becomes free.

The judges are exact geometry (depthguard.scenes' ray casting and distances, and coal along the workcell), not the
monitor's code."""

from importlib import resources

import numpy as np
import pytest

import depthguard as dg
from depthguard.errors import InputError
from depthguard.scenes import Box, Sphere, render_depth, scene_distance
from depthguard.transforms import look_at

FLOOR = Box.from_bounds([-3.0, -6.0, -0.55], [3.0, 6.0, -0.5])
WALL = Box.from_bounds([-3.1, -6.0, -0.55], [-3.0, 6.0, 4.0])  # every pixel of the camera sees something
PEDESTAL = Box.from_bounds([-0.15, -0.15, -0.5], [0.15, 0.15, 0.0])
#: Behind the pedestal as the camera sees it, and below its top: no ray of the camera reaches it.
HIDDEN = Sphere((-0.3, 0.0, -0.35), 0.04)
VISIBLE = Sphere((0.6, 0.5, 0.3), 0.1)


def _camera():
    return dg.PinholeCamera("cam", 320, 240, 262.5, 262.5, 159.5, 119.5,
                            look_at([1.8, 0.0, 0.6], [0.0, 0.0, -0.2]), depth_range=(0.3, 6.0),
                            noise=dg.NoiseModel.none())


def _distances(static, points, obstacles=(HIDDEN, VISIBLE), rho=1.5):
    camera = _camera()
    rig = dg.Rig({"cam": camera})
    depth = render_depth(camera, [FLOOR, WALL, PEDESTAL, *obstacles])
    monitor = dg.DistanceMonitor(rig, rho=rho, aggregate="min", static=static)
    return monitor.query({"cam": dg.depth_image(depth, camera)}, points).distance, camera, depth


def test_a_known_solid_stops_being_an_obstacle_and_what_it_hides_does_not():
    assert np.array_equal(render_depth(_camera(), [FLOOR, WALL, PEDESTAL, HIDDEN]),
                          render_depth(_camera(), [FLOOR, WALL, PEDESTAL]))
    assert np.all(render_depth(_camera(), [FLOOR, WALL]) > 0)
    above = np.array([0.0, 0.0, 0.12])  # 0.12 m above the pedestal's top
    behind = np.array([-0.3, 0.0, -0.2])  # 0.11 m above the hidden sphere, behind the pedestal
    near_visible = np.array([0.6, 0.5, 0.5])
    points = np.array([above, behind, near_visible])
    plain = _distances(None, points)[0]
    known = _distances([FLOOR, PEDESTAL], points)[0]
    truth = scene_distance([HIDDEN, VISIBLE], points)
    # never farther than what truly is there (the hidden sphere counts: the space behind the pedestal is hidden)
    assert np.all(known <= truth + 1e-6), (known, truth)
    # the pedestal's top no longer counts: the point above it is as far as the space hidden behind the pedestal,
    # which starts at its far top edge (0.19 m away)
    assert plain[0] == pytest.approx(0.12, abs=0.01)
    assert known[0] == pytest.approx(np.hypot(0.15, 0.12), abs=0.015), known
    assert known[1] == 0.0  # inside the hidden space
    # what was nearest anyway is unchanged
    assert known[2] == pytest.approx(plain[2], abs=1e-9)


@pytest.mark.parametrize("obstacle, point", [
    (Box.from_bounds([-0.05, -0.05, 0.0], [0.05, 0.05, 0.05]), [0.0, 0.0, 0.15]),  # a 5 cm block on the pedestal
    (Sphere((0.35, 0.0, -0.25), 0.1), [0.35, 0.0, -0.05]),  # a ball between the camera and the pedestal
])
def test_something_in_front_of_a_known_solid_is_still_seen(obstacle, point):
    """Whatever stands in front of a known solid, by more than the tolerance + the margin, is an obstacle."""
    point = np.array([point])
    known = _distances([FLOOR, WALL, PEDESTAL], point, obstacles=(obstacle,))[0]
    assert known[0] <= scene_distance([obstacle], point)[0] + 1e-6


def test_a_solid_that_is_not_where_it_is_said_to_be_changes_nothing():
    """A static box given where nothing is (or where the camera sees deeper) replaces no measurement."""
    elsewhere = Box.from_bounds([0.3, -1.0, -0.5], [0.5, -0.8, 0.6])  # not in the scene
    points = np.array([[0.4, -0.9, 0.7], [0.0, 0.0, 0.12]])
    plain = _distances(None, points)[0]
    assert np.array_equal(_distances([elsewhere], points)[0], plain)


def test_only_whole_footprints_on_one_solid_are_replaced():
    """The pixels round a solid's outline (their 3 x 3 neighbours not all on it) keep their measurement."""
    from depthguard.static_solids import StaticSolids

    camera = _camera()
    solids = StaticSolids([PEDESTAL], 0.02)
    entry, usable = solids.view(camera)
    on = entry > 0
    assert on.sum() > 100
    inner = on.copy()
    for dv in (-1, 0, 1):
        for du in (-1, 0, 1):
            inner[1:-1, 1:-1] &= np.roll(np.roll(on, dv, 0), du, 1)[1:-1, 1:-1]
    inner[[0, -1], :] = False
    inner[:, [0, -1]] = False
    assert np.array_equal(usable > 0, inner)
    # where replaced, the depth is the smallest exit of the nine rays, behind the entry
    assert np.all(usable[inner] > entry[inner])
    depth = dg.depth_image(render_depth(camera, [FLOOR, PEDESTAL]), camera)
    out = solids.substitute(depth, camera).data
    assert np.array_equal(out[inner], usable[inner])
    assert np.array_equal(out[~inner], depth.metres()[~inner].astype(np.float32)) or \
        np.allclose(out[~inner], depth.metres()[~inner], equal_nan=True)


def test_the_space_a_robot_hides_above_a_known_solid_still_counts():
    """The robot's arm held out over the floor, seen from above by the depth grid's principal camera and from the
    side by a second one that sees the ball under the arm: the floor (known) is 0.86 m behind the arm, so the space
    between them, which the arm hides from the principal, stays to be checked, and the ball there counts. Only where
    the robot rests on a solid (its base on the pedestal) does the robot's far end move through the solid."""
    from depthguard.robots import RobotModel
    from depthguard.scenes import Capsule

    robot = RobotModel.default()
    q = np.array([0.0, np.pi / 2, 0.0, 0.0, 0.0, 0.0, 0.0])  # the arm horizontal at z = 0.36 m along +x
    links = [Capsule(tuple(c.p0), tuple(c.p1), c.radius) for c in robot.capsules_world(q)]
    ball = Sphere((0.6, 0.0, -0.2), 0.04)  # under the forearm
    cameras = {name: dg.PinholeCamera(name, 320, 240, 262.5, 262.5, 159.5, 119.5, look_at(eye, target, up=up),
                                      depth_range=(0.3, 6.0), noise=dg.NoiseModel.none())
               for name, eye, target, up in (("top", [0.5, 0.0, 2.5], [0.5, 0.0, 0.0], [1.0, 0.0, 0.0]),
                                             ("side", [0.5, 2.5, 1.5], [0.5, 0.0, -0.2], [0.0, 0.0, 1.0]))}
    scene = [FLOOR, WALL, PEDESTAL, *links]
    top = cameras["top"]
    assert np.array_equal(render_depth(top, [*scene, ball]), render_depth(top, scene))  # the arm hides the ball
    rig = dg.Rig(cameras, principal="top", workspace=np.array([[-1.0, -1.0, -0.7], [1.5, 1.0, 1.5]]))
    frames = {name: dg.depth_image(render_depth(camera, [*scene, ball]), camera) for name, camera in cameras.items()}
    points = np.array([[0.6, 0.15, -0.2], [0.6, 0.0, -0.05], [0.75, 0.0, -0.2]])  # 0.11 m from the ball
    truth = scene_distance([ball], points)
    for static in (None, [FLOOR, WALL, PEDESTAL]):
        monitor = dg.DistanceMonitor(rig, rho=0.3, aggregate="min", robot=robot, self_filter="capsules",
                                     static=static)
        result = monitor.query(frames, points, joints=q)
        # the distance itself, not only blind_distance
        assert np.all(result.distance <= truth + 1e-6), (static is not None, result.distance, truth)


def test_the_robot_resting_on_a_solid_ends_where_the_solid_does():
    """Seen from above, the robot's base stands on the pedestal: behind the base is the pedestal's inside, so the
    robot's far end moves to where the pedestal ends; behind the arm held out over the floor, nothing moves."""
    from depthguard.robots import RobotModel
    from depthguard.self_filter import RobotSilhouette
    from depthguard.static_solids import StaticSolids

    robot = RobotModel.default()
    q = np.array([0.0, np.pi / 2, 0.0, 0.0, 0.0, 0.0, 0.0])
    camera = dg.PinholeCamera("top", 320, 240, 262.5, 262.5, 159.5, 119.5,
                              look_at([0.5, 0.0, 2.5], [0.5, 0.0, 0.0], up=[1.0, 0.0, 0.0]), depth_range=(0.3, 6.0),
                              noise=dg.NoiseModel.none())
    silhouette = RobotSilhouette(robot, geometry="capsules")
    near, far = silhouette.render(camera, q), silhouette.render_far(camera, q)
    solids = StaticSolids([FLOOR, PEDESTAL], 0.02)
    moved_far, moved = solids.extend_robot(camera, near, far)
    entry, usable = solids.view(camera)

    def pixel(x):
        c = camera.world_to_camera(np.array([x]))[0]
        return int(round(camera.fy * c[1] / c[2] + camera.cy)), int(round(camera.fx * c[0] / c[2] + camera.cx))

    base, arm = pixel([0.05, 0.05, 0.2]), pixel([0.7, 0.0, 0.36])
    assert near[base] > 0 and near[arm] > 0
    assert moved[base] and moved_far[base] == usable[base] and usable[base] > far[base]
    assert not moved[arm] and moved_far[arm] == far[arm]
    assert np.all(moved_far >= far) and np.array_equal(moved_far[~moved], far[~moved])


def test_the_workcell_with_its_background_known_is_never_farther_than_the_truth():
    """Scenario B's reach, two cameras, the robot filtered and its pedestal, the floor and the walls known: at frames
    with the person near, no control point reads farther from the person than coal's exact distance plus the
    monitor's tolerance (2.5 principal footprints + 1 mm, as tests/test_closed_loop.py, + the robot zone), and the
    known solids move some distances out. Only a little here (measured: the upper arm's first point 1 cm farther at
    0.5 s and 2.2 s): what is nearest the arm without a person is the space its own links hide round its base, and
    the top of what the principal camera sees (docs/design.md, "Avoidance")."""
    from depthguard_lab.simulation import load_workcell
    from depthguard_lab.simulation._episode import SceneRenderer, sense
    from depthguard_lab.simulation._truth import TruthComputer

    workcell = load_workcell(resources.files("depthguard_lab.simulation") / "scenario_b_reach.yaml")
    robot = workcell.robot
    static = workcell.background_parts()
    assert all(isinstance(box, Box) for box in static) and len(static) == 5
    kwargs = dict(rho=1.0, robot=robot, aggregate="min", invalid="neighbors", robot_zone=0.06)
    plain = dg.DistanceMonitor(workcell.rig, **kwargs)
    known = dg.DistanceMonitor(workcell.rig, static=static, **kwargs)
    truth = TruthComputer(robot)
    parts = {name: workcell.part_names(name) for name in workcell.obstacle_names}
    principal = workcell.rig.cameras[workcell.rig.principal]
    scene = SceneRenderer(workcell, None)
    moved = 0
    try:
        for t in (0.5, 2.2, 2.6, 3.0, 5.2):
            q = workcell.joints_at(t)
            frame = sense(workcell, scene, truth, parts, q.copy(), t, int(round(t * workcell.rate)), 0)
            points = robot.control_point_positions(q)
            a = plain.query(frame.depth, points, joints=q, now=t).distance
            b = known.query(frame.depth, points, joints=q, now=t).distance
            tolerance = 2.5 * (principal.world_to_camera(points)[:, 2] + 1.0) / principal.fx + 1e-3 + 0.06
            assert np.all(b <= frame.truth.distance + tolerance), (t, b, frame.truth.distance)
            assert np.all(b >= a - 1e-9)
            moved += int(np.sum(b > a + 0.005))
    finally:
        scene.release()
    assert moved > 0


@pytest.mark.parametrize("static", ["floor", [FLOOR, "pedestal"], [Sphere((0, 0, 0), 0.1)], FLOOR,
                                    [Box((0.0, 0.0, np.nan), (1.0, 1.0, 1.0))],
                                    [Box((0.0, 0.0, 0.0), (1.0, 0.0, 1.0))],
                                    [Box((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), np.diag([1.0, 1.0, -1.0]))],
                                    [Box((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 2.0 * np.eye(3))],
                                    [Box((0.0, 0.0), (1.0, 1.0, 1.0))],
                                    [Box(("a", 0.0, 0.0), (1.0, 1.0, 1.0))],
                                    [Box((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), None)],
                                    [Box((0.0, 0.0, 0.0), (1e300, 1.0, 1.0))]])
def test_bad_static_solids_are_refused(static):
    rig = dg.Rig({"cam": _camera()})
    with pytest.raises(InputError) as info:
        dg.DistanceMonitor(rig, static=static)
    assert info.value.field == "static"


def test_the_solids_ray_casting_agrees_with_the_renderer():
    """StaticSolids casts each pixel's centre ray against the boxes exactly (no OpenGL). Judged against the
    renderer, which draws the same boxes as meshes (closed, exact for boxes): the same box first entered, and the same
    entry and first-exit depths to float32 rounding, for boxes at random poses, overlapping or not."""
    from depthguard.rendering import MeshInstance, Renderer, primitive_mesh
    from depthguard.static_solids import ray_boxes

    rng = np.random.default_rng(4)
    renderer = Renderer()
    camera = _camera()
    for trial in range(3):
        boxes = [FLOOR, WALL, PEDESTAL]
        for _ in range(3):
            q = rng.normal(size=4)
            q /= np.linalg.norm(q)
            w, x, y, z = q
            R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                          [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                          [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
            boxes.append(Box(tuple(rng.uniform([-0.6, -0.8, -0.4], [0.6, 0.8, 0.8])),
                             tuple(rng.uniform(0.05, 0.3, 3)), R))
        label, entry, exits = ray_boxes(camera, boxes)
        instances = [MeshInstance(renderer.add_mesh(*primitive_mesh(b), closed=True), np.eye(4), label=i)
                     for i, b in enumerate(boxes)]
        drawn = renderer.render(camera, instances)
        drawn_exit = renderer.render_depth_first_exit(camera, instances)
        seen = (drawn.label >= 0) & (label >= 0)
        assert np.mean(drawn.label == label) > 0.995  # rasterisation decides a few edge pixels otherwise
        np.testing.assert_allclose(entry[seen & (drawn.label == label)], drawn.depth[seen & (drawn.label == label)],
                                   rtol=2e-6, atol=1e-6)
        both = (exits > 0) & (drawn_exit > 0)
        assert np.mean((exits > 0) == (drawn_exit > 0)) > 0.995
        close = np.isclose(exits[both], drawn_exit[both], rtol=2e-6, atol=1e-6)
        assert np.mean(close) > 0.995, np.mean(close)
