"""The robot's inner volume (design §8a's Robot_k): capsules that lie inside the links' collision meshes, never in
their padding, and the free-space memory taking them as free.

Judged against an analytic tube (its open ends closed as the module closes them) and, for the iiwa's meshes, by code
the project did not write: coal (no inner capsule crosses its link's mesh) and pybullet's ray test (the mesh lies
round each capsule's centre across the link's axis)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import depthguard as dg
from depthguard.freespace import robot_inside_voxels
from depthguard.rendering import Renderer
from depthguard.robots import RobotModel
from depthguard.robots._capsules import LinkCapsule
from depthguard.robots._inner import closed_triangles, inner_capsules
from depthguard.scenes import Box, render_depth
from depthguard.self_filter import RobotSilhouette
from depthguard.transforms import look_at

Q = np.array([0.0, 0.5, 0.0, -1.0, 0.0, 0.5, 0.0])


def test_an_open_tube_holds_its_inner_capsules():
    """A tube of radius 5 cm and height 30 cm with no end caps: the fans close its ends, and every inner capsule
    lies within the tube (radially within the 64-gon's inscribed radius, axially within its ends), while their union
    fills most of it."""
    radius, height = 0.05, 0.3
    solid = trimesh.creation.cylinder(radius, height, sections=64)
    side = np.abs(solid.face_normals[:, 2]) < 0.5  # the wall only: both ends open
    tube = trimesh.Trimesh(solid.vertices, solid.faces[side], process=True)
    assert not tube.is_watertight and closed_triangles(tube) is not None
    enclosing = LinkCapsule(link="tube", p0=np.array([0.0, 0.0, -0.2]), p1=np.array([0.0, 0.0, 0.2]),
                            radius=0.06, padding=0.0)
    pieces = inner_capsules(tube, enclosing, 0.01)
    assert pieces
    inscribed = radius * np.cos(np.pi / 64)
    for piece in pieces:
        for end in (piece.p0, piece.p1):
            assert np.hypot(end[0], end[1]) + piece.radius <= inscribed + 1e-9
            assert abs(end[2]) + piece.radius <= height / 2 + 1e-9
    assert max(piece.radius for piece in pieces) > 0.95 * inscribed
    # A point on the axis halfway up lies 4.9 cm deep in some piece: the union is not a thin core.
    centre = np.zeros(3)
    assert max(piece.radius - np.linalg.norm(centre - piece.p0) for piece in pieces) > 0.045


def test_the_iiwa_inner_capsules_lie_inside_its_meshes():
    """coal: no inner capsule meets its link's collision mesh; pybullet: rays across the link's axis from each
    capsule's centre all hit that mesh (it lies round the capsule, which therefore lies inside it)."""
    coal = pytest.importorskip("coal")
    pybullet = pytest.importorskip("pybullet")
    robot = RobotModel.default()
    client = pybullet.connect(pybullet.DIRECT)
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
            axis = capsule.p1 - capsule.p0
            axis = axis / np.linalg.norm(axis) if np.linalg.norm(axis) > 0 else np.array([0.0, 0.0, 1.0])
            across = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
            across /= np.linalg.norm(across)
            directions = [across, -across, np.cross(axis, across), -np.cross(axis, across)]
            for piece in inner_capsules(mesh, capsule, 0.01):
                length = float(np.linalg.norm(piece.p1 - piece.p0))
                middle = 0.5 * (piece.p0 + piece.p1)
                transform = coal.Transform3s()
                transform.setTranslation(middle)
                if length > 0:
                    z = (piece.p1 - piece.p0) / length
                    x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
                    x /= np.linalg.norm(x)
                    transform.setRotation(np.column_stack([x, np.cross(z, x), z]))
                request, result = coal.CollisionRequest(), coal.CollisionResult()
                coal.collide(coal.Capsule(piece.radius, length), transform, model, coal.Transform3s(), request,
                             result)
                assert not result.isCollision(), (capsule.link, piece)
                hits = pybullet.rayTestBatch([middle.tolist()] * 4, [(middle + 0.5 * d).tolist() for d in directions],
                                             physicsClientId=client)
                assert all(hit[0] == body for hit in hits), (capsule.link, piece)
                count += 1
            pybullet.removeBody(body, physicsClientId=client)
        assert count > 50  # every link but the flange (whose capsule's centre lies on its closing fan) has some
    finally:
        pybullet.disconnect(client)


def test_the_memory_takes_the_robot_inside_as_free(monkeypatch):
    """Two cameras, the robot standing still from the first frame on: every update of the memory is told which
    voxels lie wholly inside the links at the frames' joints (Robot_k: no person can be there, so they are never
    where a person may be), and only those."""
    from depthguard.freespace import FreeSpaceMemory

    robot = RobotModel.default()
    cameras = {name: dg.PinholeCamera(name, 320, 240, 262.5, 262.5, 159.5, 119.5, look_at(eye, [0, 0, 0.6]),
                                      depth_range=(0.3, 6.0), noise=dg.NoiseModel.none())
               for name, eye in (("p", [2.0, 0.5, 1.4]), ("s", [0.3, -2.0, 1.2]))}
    rig = dg.Rig(cameras, principal="p", workspace=((-1.0, -1.0, 0.0), (1.0, 1.0, 1.4)))
    room = [Box.from_bounds([-3, -3, -0.1], [3, 3, 0])]
    with Renderer() as renderer:
        silhouette = RobotSilhouette(robot, renderer, geometry="meshes")
        depth = {}
        for name, camera in cameras.items():
            floor = render_depth(camera, room)
            arm = silhouette.render(camera, Q)
            depth[name] = np.where(arm > 0, np.minimum(arm, np.where(floor > 0, floor, np.inf)), floor)
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
