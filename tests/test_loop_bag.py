"""The closed loop's recording (issue 9, item 6): an MCAP bag that Foxglove's own reader and ROS 2 decoder (the
``mcap`` and ``mcap-ros2-support`` packages, code the project did not write) open, holding exactly what the run
did: every depth image bit for bit, the joints and the monitor's distances at every control step, the exact
distances, the robot's capsules and control points coloured by distance, the cameras' poses; and that replays
through depthguard like any recording."""

import math

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from scipy.spatial.transform import Rotation

from depthguard.errors import InputError
from depthguard_lab.experiments import avoidance_demo
from depthguard_lab.simulation._closed_loop import LoopSettings, run_closed_loop
from depthguard_lab.simulation._loop_bag import MARKER_EVERY, NEAR, write_loop_bag


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    workcell = avoidance_demo.load_scene()
    log = run_closed_loop(workcell, "avoid", start=1.5, duration=0.1, keep_frames=True)
    path = write_loop_bag(tmp_path_factory.mktemp("bag") / "bag", workcell, log, LoopSettings().avoidance.rho)
    (mcap_file,) = path.glob("*.mcap")
    messages = {}
    with open(mcap_file, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, ros in reader.iter_decoded_messages():
            messages.setdefault(channel.topic, []).append((message.log_time, schema.name, ros))
    return workcell, log, path, messages


def test_every_topic_holds_what_the_run_did(run):
    workcell, log, path, messages = run
    steps, m = log.reported.shape
    assert [r[1] for r in messages["/depthguard/distances"]][:1] == ["std_msgs/msg/Float64MultiArray"]
    distances = messages["/depthguard/distances"]
    assert len(distances) == steps == len(messages["/joint_states"]) == len(messages["/depthguard/repulsive"])
    ns = [round(t * 1e9) for t in log.times]
    for k, (stamp, _, ros) in enumerate(distances):
        assert stamp == ns[k]
        assert np.array_equal(np.asarray(ros.data), log.reported[k])  # inf stays inf
    label = distances[0][2].layout.dim[0].label  # the points the loop measured from (covering every moving link)
    assert label == "control_points:" + ",".join(log.robot.control_point_names) and m > 9
    truth_label = messages["/depthguard/true_distances"][0][2].layout.dim[0].label
    assert truth_label == "control_points:" + ",".join(workcell.robot.control_point_names)
    for k, (_, _, ros) in enumerate(messages["/joint_states"]):
        assert list(ros.name) == list(workcell.robot.joint_names) and np.array_equal(ros.position, log.q[k])
    truth = messages["/depthguard/true_distances"]
    assert len(truth) == len(log.truth_steps)
    for row, (stamp, _, ros) in enumerate(truth):
        assert stamp == ns[log.truth_steps[row]] and np.array_equal(np.asarray(ros.data), log.truth[row])
    for k, (_, _, ros) in enumerate(messages["/depthguard/repulsive"]):
        assert ros.header.frame_id == "world"
        assert [ros.vector.x, ros.vector.y, ros.vector.z] == log.repulsive[k].tolist()
    assert np.abs(log.repulsive).max() > 0  # the avoidance acted: the vectors are not all zero


def test_depth_images_are_the_captured_frames_bit_for_bit(run):
    workcell, log, path, messages = run
    assert log.captures and len(log.captures) == log.frames
    for name, camera in workcell.rig.cameras.items():
        images = messages[f"/{name}/depth/image_raw"]
        infos = messages[f"/{name}/depth/camera_info"]
        assert len(images) == len(infos) == log.frames
        for (t, q, depth), (stamp, _, image), (_, _, info) in zip(log.captures, images, infos):
            assert stamp == round(t * 1e9) and image.encoding == "16UC1"
            data = np.frombuffer(bytes(image.data), dtype="<u2").reshape(image.height, image.width)
            assert np.array_equal(data, depth[name].data)
            assert image.header.frame_id == info.header.frame_id == f"{name}_optical_frame"
            assert info.k[0] == camera.fx and info.k[2] == camera.cx and info.k[5] == camera.cy


def test_camera_poses_and_robot_markers(run):
    workcell, log, path, messages = run
    ((_, _, tf),) = messages["/tf_static"]
    for transform in tf.transforms:
        name = transform.child_frame_id.removesuffix("_optical_frame")
        T = workcell.rig.cameras[name].T_world_camera
        r = transform.transform.rotation
        R = Rotation.from_quat([r.x, r.y, r.z, r.w]).as_matrix()
        t = transform.transform.translation
        assert transform.header.frame_id == "world"
        np.testing.assert_allclose(R, T[:3, :3], atol=1e-9)
        np.testing.assert_allclose([t.x, t.y, t.z], T[:3, 3], atol=0)
    assert {t.child_frame_id for t in tf.transforms} == {f"{n}_optical_frame" for n in workcell.rig.cameras}
    robot = log.robot  # the points the loop measured from
    arrays = messages["/depthguard/robot"]
    assert len(arrays) == math.ceil(len(log.times) / MARKER_EVERY)
    rho = LoopSettings().avoidance.rho
    for i, (_, _, ros) in enumerate(arrays):
        k = i * MARKER_EVERY
        points = [mk for mk in ros.markers if mk.ns == "control_points"]
        expected = robot.control_point_positions(log.q[k])
        assert len(points) == len(expected)
        for marker, position, distance in zip(points, expected, log.reported[k]):
            assert [marker.pose.position.x, marker.pose.position.y, marker.pose.position.z] == position.tolist()
            red, green = marker.color.r > 0.8 and marker.color.g < 0.2, marker.color.g > 0.7
            assert red == (distance < NEAR) and green == (distance >= rho)
        links = [mk for mk in ros.markers if mk.ns == "links"]
        capsules = robot.capsules_world(log.q[k])
        spheres = [mk for mk in links if mk.type == 2]
        assert len(spheres) == 2 * len(capsules)
        for sphere, end in zip(spheres, [e for c in capsules for e in (c.p0, c.p1)]):
            assert [sphere.pose.position.x, sphere.pose.position.y, sphere.pose.position.z] == list(end)


def test_the_bag_replays_as_a_recording(run, tmp_path, capsys):
    from depthguard import cli, open_recording

    workcell, log, path, messages = run
    recording = open_recording(path)
    sets = list(recording.frame_sets())
    assert len(sets) == log.frames
    for frame_set, (t, q, depth) in zip(sets, log.captures):
        assert frame_set.time == pytest.approx(t, abs=1e-9)
        for name, image in frame_set.images.items():
            assert np.array_equal(image.data, depth[name].data)
        np.testing.assert_allclose(recording.joints_at(t), q, atol=1e-12)
    assert cli.main(["replay", str(path), "--out", str(tmp_path / "results.csv")]) == 0
    rows = (tmp_path / "results.csv").read_text().splitlines()
    assert len(rows) == 1 + log.frames * len(workcell.robot.control_point_names)


def test_refusals(run, tmp_path):
    workcell, log, path, messages = run
    with pytest.raises(InputError, match="exists already"):
        write_loop_bag(path, workcell, log, 0.4)
    without = run_closed_loop(workcell, "none", start=1.5, duration=0.01)
    with pytest.raises(InputError, match="keep_frames"):
        write_loop_bag(tmp_path / "new", workcell, without, 0.4)
    assert not (tmp_path / "new").exists()
