"""The robot's inner volume (design §8a's Robot_k): balls that lie inside the links' collision meshes, never in
their padding, and the free-space memory taking them as free.

Judged against an analytic tube (its open ends closed as the module closes them), two nested boxes and, for the
iiwa's meshes, by code the project did not write: coal (no inner ball crosses its link's mesh) and pybullet's ray test
(the mesh lies round each ball's centre)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import depthguard as dg
from depthguard.freespace import robot_inside_voxels
from depthguard.rendering import Renderer
from depthguard.robots import RobotModel
from depthguard.robots._inner import closed_triangles, inner_balls, points_inside, triangle_distances
from depthguard.scenes import Box, render_depth
from depthguard.self_filter import RobotSilhouette
from depthguard.transforms import look_at

Q = np.array([0.0, 0.5, 0.0, -1.0, 0.0, 0.5, 0.0])


COVER = 0.5 * np.sqrt(3.0) * 0.01  # the half-diagonal of a 1 cm voxel


def _balls(mesh, link="link"):
    return inner_balls(mesh, link)  # the defaults: a 1 cm grid, 64 balls, 1 cm voxels, samples every 1.5 mm


def test_an_open_tube_holds_its_inner_balls():
    """A tube of radius 5 cm and height 30 cm with no end caps: the fans close its ends, and every inner ball lies
    within the tube (radially within the 64-gon's inscribed radius, axially within its ends), while their union holds
    a 1 cm voxel round most of the points deeper than 1.5 cm."""
    radius, height = 0.05, 0.3
    solid = trimesh.creation.cylinder(radius, height, sections=64)
    side = np.abs(solid.face_normals[:, 2]) < 0.5  # the wall only: both ends open
    tube = trimesh.Trimesh(solid.vertices, solid.faces[side], process=True)
    assert not tube.is_watertight and closed_triangles(tube) is not None
    balls = _balls(tube)
    assert 10 < len(balls) <= 64
    inscribed = radius * np.cos(np.pi / 64)
    for ball in balls:
        assert np.array_equal(ball.p0, ball.p1) and ball.padding == 0.0
        assert np.hypot(ball.p0[0], ball.p0[1]) + ball.radius <= inscribed + 1e-9
        assert abs(ball.p0[2]) + ball.radius <= height / 2 + 1e-9
    assert max(ball.radius for ball in balls) > inscribed - 0.01
    rng = np.random.default_rng(7)
    r = (inscribed - 0.015) * np.sqrt(rng.uniform(0.0, 1.0, 4000))
    angle = rng.uniform(0.0, 2.0 * np.pi, 4000)
    points = np.column_stack([r * np.cos(angle), r * np.sin(angle), rng.uniform(-0.135, 0.135, 4000)])
    centres = np.array([ball.p0 for ball in balls])
    radii = np.array([ball.radius for ball in balls])
    deepest = (radii[None, :] - np.linalg.norm(points[:, None] - centres[None], axis=2)).max(axis=1)
    assert np.mean(deepest >= COVER) > 0.8


def test_a_closed_mesh_with_an_inner_shell_counts_only_what_lies_inside():
    """A box with a smaller box's surface inside it (two shells): the parity test counts the inner box's inside as
    outside (two crossings), so no ball lies there or crosses either surface."""
    outer = trimesh.creation.box((0.2, 0.2, 0.2))
    inner = trimesh.creation.box((0.08, 0.08, 0.08))
    both = trimesh.util.concatenate([outer, inner])
    balls = _balls(both)
    assert balls
    for ball in balls:
        assert np.all(np.abs(ball.p0) + ball.radius <= 0.1 + 1e-9)
        nearest = np.clip(ball.p0, -0.04, 0.04)  # the inner box's point nearest to the centre
        assert np.linalg.norm(ball.p0 - nearest) >= ball.radius - 1e-9, ball


def test_a_thin_flange_gets_its_balls_from_a_finer_grid():
    """A closed slab 30 mm thick: no point of the 1 cm grid lies deep enough for a 1 cm voxel round it to fit in a
    ball, so the grid is halved; the balls then found lie inside the slab (and a 5 mm grid finds its inside at all:
    once, its grouping's queries stopped short of spacing / 2 and found none)."""
    slab = trimesh.creation.box((0.08, 0.08, 0.03))
    balls = _balls(slab)
    assert balls
    for ball in balls:
        assert np.all(np.abs(ball.p0) + ball.radius <= np.array([0.04, 0.04, 0.015]) + 1e-9), ball


def test_a_link_fifty_metres_across_gets_its_balls_with_bounded_work():
    """A URDF may bring a mesh up to config.COORDINATE_LIMIT across (a wrong scale): a closed box 50 m a side would
    need 10^11 grid points and 10^9 surface samples at the default spacings. The grid and the samples are coarsened
    to config.INNER_BALL_LIMITS instead, and the balls found still lie inside the box."""
    box = trimesh.creation.box((50.0, 50.0, 50.0))
    balls = _balls(box)
    assert balls
    for ball in balls:
        assert np.all(np.abs(ball.p0) + ball.radius <= 25.0 + 1e-9), ball


def test_the_iiwa_inner_balls_lie_inside_its_meshes():
    """coal: no inner ball meets its link's collision mesh; pybullet: rays from each ball's centre in six directions
    all hit that mesh (it lies round the ball, which therefore lies inside it). And they fill the links: every link
    but the flange holds a 1 cm voxel round at least 40 % of the points (uniform samples) 1.5 cm or deeper inside it."""
    coal = pytest.importorskip("coal")
    pybullet = pytest.importorskip("pybullet")
    robot = RobotModel.default()
    client = pybullet.connect(pybullet.DIRECT)
    directions = np.vstack([np.eye(3), -np.eye(3)]) @ np.array([[0.96, 0.2, 0.19], [-0.2, 0.98, 0.0],
                                                                 [-0.19, -0.04, 0.98]])
    try:
        count = 0
        for capsule in robot.capsules:
            mesh = robot.collision_meshes[capsule.link]
            model = coal.BVHModelOBBRSS()
            model.beginModel(len(mesh.faces), len(mesh.vertices))
            model.addVertices(np.ascontiguousarray(mesh.vertices, dtype=np.float64))
            model.addTriangles(np.asarray(mesh.faces, dtype=np.int64))
            model.endModel()
            shape = pybullet.createCollisionShape(pybullet.GEOM_MESH, vertices=np.asarray(mesh.vertices).tolist(),
                                                  indices=np.asarray(mesh.faces).ravel().tolist(),
                                                  flags=pybullet.GEOM_FORCE_CONCAVE_TRIMESH, physicsClientId=client)
            body = pybullet.createMultiBody(0, shape, physicsClientId=client)
            balls = _balls(mesh, capsule.link)
            for ball in balls:
                transform = coal.Transform3s()
                transform.setTranslation(ball.p0)
                request, result = coal.CollisionRequest(), coal.CollisionResult()
                coal.collide(coal.Sphere(ball.radius), transform, model, coal.Transform3s(), request, result)
                assert not result.isCollision(), (capsule.link, ball)
                hits = pybullet.rayTestBatch([ball.p0.tolist()] * 6, [(ball.p0 + 0.5 * d).tolist() for d in directions],
                                             physicsClientId=client)
                assert all(hit[0] == body for hit in hits), (capsule.link, ball)
                count += 1
            pybullet.removeBody(body, physicsClientId=client)
            if capsule.link != "lbr_iiwa_link_7":  # the flange: faces inside its body leave it small balls
                triangles = closed_triangles(mesh)
                points = np.random.default_rng(3).uniform(*mesh.bounds, size=(800, 3))
                points = points[points_inside(points, triangles)]
                points = points[triangle_distances(points, triangles) >= 0.015]
                centres = np.array([ball.p0 for ball in balls])
                radii = np.array([ball.radius for ball in balls])
                deepest = (radii[None, :] - np.linalg.norm(points[:, None] - centres[None], axis=2)).max(axis=1)
                assert len(points) > 20 and np.mean(deepest >= COVER) >= 0.4, capsule.link
        assert count > 300
    finally:
        pybullet.disconnect(client)


def _standing_robot(eyes):
    """(robot, rig, depth images by camera) of the iiwa standing at Q over a floor, seen by noise-free 320 x 240
    cameras at ``eyes`` (name -> eye, metres, world), all looking at (0, 0, 0.6)."""
    robot = RobotModel.default()
    cameras = {name: dg.PinholeCamera(name, 320, 240, 262.5, 262.5, 159.5, 119.5, look_at(eye, [0, 0, 0.6]),
                                      depth_range=(0.3, 6.0), noise=dg.NoiseModel.none())
               for name, eye in eyes.items()}
    rig = dg.Rig(cameras, principal=next(iter(eyes)), workspace=((-1.0, -1.0, -0.05), (1.0, 1.0, 1.4)))
    room = [Box.from_bounds([-3, -3, -0.1], [3, 3, 0])]
    with Renderer() as renderer:
        silhouette = RobotSilhouette(robot, renderer, geometry="meshes")
        depth = {}
        for name, camera in cameras.items():
            floor = render_depth(camera, room)
            arm = silhouette.render(camera, Q)
            depth[name] = np.where(arm > 0, np.minimum(arm, np.where(floor > 0, floor, np.inf)), floor)
    return robot, rig, depth


def test_the_detectable_space_takes_the_robot_inside_as_free(monkeypatch):
    """Four cameras round the standing robot, no robot zone: SSM's detectable space counts free every voxel wholly
    inside the links at the frames' joints (Robot_k is the truth, not a concession), so a ball of d no longer fits
    in the middle of a link. Without it (Robot_k taken away) every control point reads 0; with it some read more."""
    from depthguard.freespace import DetectableSpace

    robot, rig, depth = _standing_robot({"p": [2.0, 0.5, 1.4], "s": [0.3, -2.0, 1.2], "t": [-1.5, 1.5, 2.0],
                                         "u": [-0.5, -0.3, 3.0]})
    watched = []
    watch = DetectableSpace.watch

    def spy(self, sources):
        watched.append(sources)
        return watch(self, sources)

    monkeypatch.setattr(DetectableSpace, "watch", spy)
    frames = {n: dg.depth_image(d.astype(np.float32), rig.cameras[n], timestamp=0.0) for n, d in depth.items()}
    points = robot.control_point_positions(Q)
    inner = robot.inner_capsules_world(Q)
    read = {}
    for label in ("with Robot_k", "without"):
        if label == "without":
            monkeypatch.setattr(RobotModel, "inner_capsules_world", lambda self, q, check=True: np.zeros((0, 7)))
        monitor = dg.DistanceMonitor(rig, robot=robot, detection_capability=0.04, memory=False)
        read[label] = monitor.prepare_set(frames, joints=Q, now=0.0).detectable_distances(points).distance
    box = monitor.detectable.box
    inside = robot_inside_voxels(box, [inner])
    assert inside.sum() > 1000
    assert np.all(watched[0].mask(box)[inside])  # every voxel inside the robot is free
    assert not np.all(watched[1].mask(box)[inside])  # without it the cameras do not see into the links
    assert np.all(read["without"] == 0.0) and np.any(read["with Robot_k"] > 0.0), read


def test_the_memory_takes_the_robot_inside_as_free(monkeypatch):
    """Two cameras, the robot standing still from the first frame on: every update of the memory is told which
    voxels lie wholly inside the links at the frames' joints (Robot_k: no person can be there, so they are never
    where a person may be), and only those."""
    from depthguard.freespace import FreeSpaceMemory

    robot, rig, depth = _standing_robot({"p": [2.0, 0.5, 1.4], "s": [0.3, -2.0, 1.2]})
    cameras = rig.cameras
    told = []
    update = FreeSpaceMemory.update

    def spy(self, t, seen, robot=None, check=True):
        told.append(None if robot is None else robot.copy())
        return update(self, t, seen, robot, check)

    monkeypatch.setattr(FreeSpaceMemory, "update", spy)
    monitor = dg.DistanceMonitor(rig, robot=robot, memory_voxel=0.02)
    for k in range(4):
        t = k / 30
        frames = {n: dg.depth_image(d.astype(np.float32), cameras[n], timestamp=t) for n, d in depth.items()}
        monitor.prepare_set(frames, joints=Q, now=t)
    box = monitor.memory.box
    inside = robot_inside_voxels(box, [robot.inner_capsules_world(Q)])
    assert inside.sum() > 100
    assert len(told) == 4 and all(mask is not None and np.array_equal(mask, inside) for mask in told)
