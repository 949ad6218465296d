"""DistanceMonitor and the CLI with a robot to filter out (issue 3, item 4)."""

import json

import numpy as np
import pytest

import depthguard as dg
from depthguard import cli
from depthguard.depth import write_depth_png
from depthguard.rendering import Renderer
from depthguard.robots import RobotModel
from depthguard.scenes import Box, render_depth
from depthguard.self_filter import RobotSilhouette, padded_hull
from depthguard.transforms import look_at

Q = np.array([0.0, 0.5, 0.0, -1.0, 0.0, 0.5, 0.0])


@pytest.fixture(scope="module")
def scene():
    robot = RobotModel.default()
    camera = dg.PinholeCamera("right", 320, 240, 262.5, 262.5, 159.5, 119.5, look_at([2.0, 0.5, 1.4], [0, 0, 0.6]),
                              depth_range=(0.3, 6.0), noise=dg.NoiseModel.none())
    room = render_depth(camera, [Box.from_bounds([-3, -3, -0.1], [3, 3, 0]), Box.from_bounds([-2.5, -3, 0],
                                                                                               [-2.4, 3, 3])])
    with Renderer() as renderer:
        robot_depth = RobotSilhouette(robot, renderer, geometry="meshes").render(camera, Q)
    depth = np.where(robot_depth > 0, np.minimum(robot_depth, np.where(room > 0, room, np.inf)), room)
    return robot, camera, depth.astype(np.float32)


def test_joints_are_required_and_checked(scene):
    robot, camera, depth = scene
    monitor = dg.DistanceMonitor(dg.Rig({"right": camera}), robot=robot)
    points = robot.control_point_positions(Q)
    with pytest.raises(dg.InputError, match="joint positions"):
        monitor.query({"right": depth}, points)
    with pytest.raises(dg.InputError, match="lbr_iiwa_joint_7"):
        monitor.query({"right": depth}, points, joints={n: 0.0 for n in robot.joint_names[:6]})
    by_name = monitor.query({"right": depth}, points, joints=dict(zip(robot.joint_names, Q)))
    by_order = monitor.query({"right": depth}, points, joints=list(Q))
    per_camera = monitor.query({"right": depth}, points, camera_joints={"right": list(Q)})
    assert np.array_equal(by_name.distance, by_order.distance)
    assert np.array_equal(by_name.distance, per_camera.distance)
    assert np.all(by_name.distance > 0.3)  # the floor, farther than the arm's own pixels
    # Joints per camera only through camera_joints: a mapping of camera names given as joints is not guessed.
    with pytest.raises(dg.InputError, match="right"):
        monitor.query({"right": depth}, points, joints={"right": list(Q)})
    with pytest.raises(dg.InputError, match="not both"):
        monitor.query({"right": depth}, points, joints=Q, camera_joints={"right": Q})
    with pytest.raises(dg.DepthguardError, match="nowhere"):
        monitor.query({"right": depth}, points, camera_joints={"nowhere": Q})


def test_filtering_at_the_wrong_joints_leaves_the_robot_in_view(scene):
    robot, camera, depth = scene
    monitor = dg.DistanceMonitor(dg.Rig({"right": camera}), robot=robot, aggregate="min")
    points = robot.control_point_positions(Q)
    right = monitor.query({"right": depth}, points, joints=Q)
    wrong = monitor.query({"right": depth}, points, joints=Q + np.array([0.6, 0, 0, 0, 0, 0, 0]))
    assert np.all(right.distance > 0.3)
    assert np.sum(wrong.distance < 0.05) >= 3  # the robot's unfiltered pixels are obstacles now


def test_padded_hull_contains_the_mesh_grown_by_padding():
    import trimesh
    from scipy.spatial import ConvexHull

    robot = RobotModel.default()
    rng = np.random.default_rng(0)
    for link in robot.link_names:
        mesh = robot.collision_meshes[link]
        vertices, faces = padded_hull(mesh.vertices, 0.02)
        hull = trimesh.Trimesh(vertices, faces)
        assert hull.is_watertight and hull.volume > 0
        # Points 2 cm (less a hair) from every mesh vertex, in random directions, lie inside the convex mesh: on the
        # inner side of every face plane.
        directions = rng.normal(size=(len(mesh.vertices), 3))
        probes = mesh.vertices + 0.0199 * directions / np.linalg.norm(directions, axis=1)[:, None]
        planes = ConvexHull(vertices).equations  # n . x + d <= 0 inside
        assert np.all(probes @ planes[:, :3].T + planes[:, 3] <= 1e-9)


def test_cli_robot_options(scene, tmp_path, capsys):
    robot, camera, depth = scene
    dg.save_rig(dg.Rig({"right": camera}), tmp_path / "rig.yaml")
    write_depth_png(tmp_path / "d.png", np.round(depth * 1000).astype(np.uint16))
    points = robot.control_point_positions(Q)
    (tmp_path / "p.json").write_text(json.dumps(points.tolist()))
    base = ["distance", "--rig", str(tmp_path / "rig.yaml"), "--depth", f"right={tmp_path / 'd.png'}", "--points",
            str(tmp_path / "p.json"), "--json"]
    assert cli.main(base + ["--robot", "iiwa", "--joints", ",".join(map(str, Q))]) == 0
    by_order = json.loads(capsys.readouterr().out)
    names = ",".join(f"{n}={v}" for n, v in zip(robot.joint_names, Q))
    assert cli.main(base + ["--robot", "iiwa", "--joints", names]) == 0
    by_name = json.loads(capsys.readouterr().out)
    assert by_order == by_name
    assert all(r["distance"] is None or r["distance"] > 0.3 for r in by_order)
    assert "robot_blind_spot" in by_order[4]["flags"]
    for bad, message in ((["--robot", "iiwa"], "--joints"), (["--joints", "0,1"], "--robot"),
                         (["--robot", "iiwa", "--joints", "0,0.5"], "joint"),
                         (["--robot", "iiwa", "--joints", "a=1,0.5"], "mixes"),
                         (["--robot", "iiwa", "--joints", "x,y"], "not numbers"),
                         (["--robot", str(tmp_path / "missing.urdf"), "--joints", "0"], "missing.urdf")):
        assert cli.main(base + bad) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0], (bad, err)


def test_a_robot_that_stood_still_is_not_rendered_again(scene, monkeypatch):
    """New frames at exactly the joints of the camera's last frame reuse its robot renders (the same answers as a
    monitor that renders them afresh); a joint moved by a microradian renders again, and so does a frame at the old
    joints after one at other joints."""
    from depthguard import self_filter

    robot, camera, depth = scene
    calls = []
    real = self_filter.robot_mask
    monkeypatch.setattr(self_filter, "robot_mask", lambda *args, **kwargs: calls.append(1) or real(*args, **kwargs))
    rig = dg.Rig({"right": camera})
    monitor = dg.DistanceMonitor(rig, robot=robot)
    points = robot.control_point_positions(Q)
    moved = Q.copy()
    moved[2] += 1e-6
    answers = []
    for k, q in enumerate([Q, Q, Q, moved, Q]):
        frame = dg.depth_image(depth.copy(), camera, timestamp=0.1 * k)  # a new frame each time
        answers.append(monitor.query({"right": frame}, points, joints=q, now=0.1 * k))
    assert len(calls) == 3  # Q, moved, Q again
    fresh = dg.DistanceMonitor(rig, robot=robot).query({"right": depth}, points, joints=Q)
    for answer in answers[:3] + answers[4:]:
        assert np.array_equal(answer.distance, fresh.distance) and answer.flags == fresh.flags
