"""``depthguard live`` (design §12b) with the ROS side played by the test's own zenoh publisher (tests/ros_publisher.py)
on 127.0.0.1: the node's answers equal a DistanceMonitor's on the same frames, joints and stamps, bit for bit, in
both layouts; images big-endian or with padded rows read the same; a CameraInfo that disagrees leaves its camera out
and names the field; a wrong type hash is heard and warned about; --dry-run says what is missing or wrong."""

from __future__ import annotations

import csv
import logging
import time

import numpy as np
import pytest

import depthguard as dg
from cli_support import run_cli
from depthguard.io.recordings import open_recording
from depthguard.live import LiveNode, LiveOptions, Topics
from depthguard.robots import RobotModel
from depthguard_lab.simulation import default_workcell, write_episode
from ros_publisher import RosPublisher

OPTIONS = dict(rho=0.4, aggregate="hybrid", invalid="occupied")
FRAMES = 3


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    workcell = default_workcell().scaled(0.25)  # two 160x120 cameras
    folder = write_episode(workcell, tmp_path_factory.mktemp("live") / "episode", seed=0, progress=False,
                           frames=range(FRAMES))
    return open_recording(folder)


@pytest.fixture(scope="module")
def robot():
    return RobotModel.default()


def topics(rig):
    return Topics({n: (Topics.default_image(n), Topics.info_of(Topics.default_image(n))) for n in rig.cameras})


def wait_for(condition, timeout=30.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if condition():
            return True
        time.sleep(0.01)
    return False


def assert_withheld_once_the_node_is_gone(publisher, recording) -> None:
    """After the node closed, its subscription tokens go away: the peer counts no subscriber of the first camera's
    image topic and withholds that camera's next frame, as a driver that publishes only to counted subscribers."""
    camera = next(iter(recording.rig.cameras))
    assert wait_for(lambda: publisher.subscribers(f"/{camera}/depth/image_raw") == 0, timeout=10.0)
    assert publisher.withheld == 0  # every frame published before went out
    frame_set = next(recording.frame_sets())
    assert publisher.publish_frame(camera, time.time_ns(), frame_set.images[camera].data) is False
    assert publisher.withheld == 1


def publish_first_set(publisher, recording, node) -> int:
    """Publish the recording's first set, restamped now: its joint state, and once ``node`` has it, the frames (each
    published: the peer counts the node's subscription). Returns the stamp, nanoseconds."""
    frame_set = next(recording.frame_sets())
    ns = time.time_ns()
    publisher.publish_joints(ns, recording.joints_at(frame_set.time))
    assert wait_for(lambda: node.joint_states > 0)
    for camera, image in frame_set.images.items():
        assert publisher.publish_frame(camera, ns, image.data)
    return ns


def publishing(publisher, recording, seconds):
    """A started thread that publishes the recording's first set (joints, then frames), restamped now, every 50 ms
    for ``seconds``."""
    import threading

    stop = time.monotonic() + seconds

    def keep_publishing():
        frame_set = next(recording.frame_sets())
        while time.monotonic() < stop:
            ns = time.time_ns()
            publisher.publish_joints(ns, recording.joints_at(frame_set.time))
            for camera, image in frame_set.images.items():
                publisher.publish_frame(camera, ns, image.data)
            time.sleep(0.05)

    thread = threading.Thread(target=keep_publishing)
    thread.start()
    return thread


def play(recording, robot, tmp_path, layout="rmw_zenoh", odd_images=False, info=None, type_hash=None, record=None,
         options=OPTIONS, ssm=None):
    """Publish the recording's sets one by one, each restamped now, waiting for the node's answer to it. Returns
    (the node's CSV rows, [(stamp, {camera: data}, joints)] as published, the publisher's answers, the node)."""
    rig = recording.rig
    publisher = RosPublisher(rig, recording.joint_names, layout=layout, type_hash=type_hash)
    node = LiveNode(rig, robot, topics(rig), LiveOptions(layout=layout, connect=[publisher.endpoint], transport=1.0), options,
                    out=tmp_path / "live.csv", record=record, ssm=ssm)
    # The host's clock held back 1 s (LiveOptions.transport): a frame delayed by this busy machine still joins its
    # set, so that the sets are those of the stamps alone.
    published = []
    try:
        node.start()
        assert publisher.wait_for_node()  # the client's subscriptions reach the peer
        for i, frame_set in enumerate(recording.frame_sets()):
            ns = time.time_ns()
            q = recording.joints_at(frame_set.time)
            publisher.publish_joints(ns, q)
            # zenoh orders samples per key, not across keys: the joint state is in before the frames go.
            assert wait_for(lambda: node.joint_states > i)
            data = {}
            for camera, image in frame_set.images.items():
                odd = odd_images and i == 1
                publisher.publish_frame(camera, ns, image.data, big_endian=odd, padding=6 if odd else 0,
                                        info=info(camera) if info else None)
                data[camera] = image.data
            published.append((ns, data, q))
            assert wait_for(lambda: any(t >= ns / 1e9 and why != "idle" for t, why, _ in list(node.recent))), (i, ns, list(node.errors), list(node.recent)[:5], node.counts)
        if ssm is not None:  # every factor published so far heard (node.heard_scaling: (key, attachment, factor))
            answered = node.answers
            assert wait_for(lambda: len([f for f in publisher.scaling]) >= answered)
            node.heard_scaling = list(publisher.scaling)
            # and the factor's status on /diagnostics (once a second)
            assert wait_for(lambda: any(s.name == "depthguard: speed scaling" for d in publisher.diagnostics
                                        for s in d.status), timeout=3)
            node.heard_diagnostics = list(publisher.diagnostics)
    finally:
        node.close()
        publisher.close()
    with open(tmp_path / "live.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    return rows, published, publisher.answers, node


def expected(recording, robot, published, cameras=None):
    """{stamp: (distances as repr strings, flags)} from a DistanceMonitor given the same frames, joints, stamps."""
    rig = recording.rig
    monitor = dg.DistanceMonitor(rig, robot=robot, **OPTIONS)
    out = {}
    for ns, data, q in published:
        t = ns / 1e9
        frames = {n: dg.depth_image(d, rig.cameras[n], timestamp=t) for n, d in data.items()
                  if cameras is None or n in cameras}
        result = monitor.query(frames, robot.control_point_positions(q), camera_joints={n: q for n in frames}, now=t)
        out[repr(t)] = ([repr(float(d)) for d in result.distance], [";".join(f.names) for f in result.flags])
    return out


@pytest.mark.parametrize("layout", ["rmw_zenoh", "bridge"])
def test_live_answers_equal_the_monitor_on_the_same_frames(recording, robot, tmp_path, layout):
    rows, published, answers, node = play(recording, robot, tmp_path, layout=layout, odd_images=True)
    truth = expected(recording, robot, published)
    answered = {}
    for row in rows:
        if row["time"] in truth and row["cameras"] == "principal;second":
            answered.setdefault(row["time"], []).append(row)
    assert set(answered) == set(truth)  # every published set answered with both cameras seen
    for t, (distances, flags) in truth.items():
        assert [r["distance"] for r in answered[t]] == distances
        assert [r["flags"] for r in answered[t]] == flags
        assert [r["control_point"] for r in answered[t]] == list(robot.control_point_names)
    finite = [float(d) for d, _ in [(x, 0) for v in truth.values() for x in v[0]]]
    assert any(d < 0.4 for d in finite)  # answers of something, not of empty space
    # What ros2 topic echo would read: one Float64MultiArray per answer at the layout's key.
    keys = {key for key, _, _ in answers}
    if layout == "rmw_zenoh":
        assert keys == {"0/depthguard/distances/std_msgs::msg::dds_::Float64MultiArray_/RIHS01_1025ddc6b9552d191f89"
                        "ef1a8d2f60f3d373e28b283d8891ddcc974e8c55397f"}
        assert all(has for _, has, _ in answers)
    else:
        assert keys == {"depthguard/distances"} and not any(has for _, has, _ in answers)
    assert all(len(data) == 9 for _, _, data in answers)
    assert node.counts["principal"].received == FRAMES and node.counts["principal"].errors == 0


def test_replay_of_what_live_recorded_gives_live_s_answers(recording, robot, tmp_path, capsys):
    rows, published, _, node = play(recording, robot, tmp_path, record=tmp_path / "recorded")
    status, _, err = run_cli(["replay", tmp_path / "recorded", "--out", tmp_path / "replayed.csv", "--rho", "0.4",
                              "--aggregate", "hybrid", "--invalid", "occupied"], capsys)
    assert status == 0, err
    with open(tmp_path / "replayed.csv", newline="") as f:
        replayed = list(csv.DictReader(f))
    stamps = {repr(ns / 1e9) for ns, _, _ in published}
    columns = ("time", "control_point", "x", "y", "z", "distance", "blind_distance", "flags")

    def complete(table):
        return [tuple(r[c] for c in columns) for r in table if r["time"] in stamps]

    assert len(complete(rows)) == FRAMES * 9, (sorted(stamps), list(node.recent)[:8], list(node.errors), node.dropped)
    assert complete(replayed) == complete(rows)


def test_a_camera_info_that_disagrees_leaves_the_camera_out_and_named(recording, robot, tmp_path):
    rig = recording.rig
    store_info = {}

    def info(camera):
        from depthguard.io.ros_messages import depth_messages
        from depthguard.live.wire import type_store

        message, _ = depth_messages(type_store(), 0, rig.cameras[camera], np.zeros((1, 1), np.uint16))
        if camera == "second":
            k = message.k.copy()
            k[0] += 5.0
            message = type(message)(**{**{f: getattr(message, f) for f in message.__dataclass_fields__}, "k": k})
        store_info[camera] = message
        return message

    rows, published, _, node = play(recording, robot, tmp_path, info=info)
    assert "fx" in node.counts["second"].info_error
    assert node.counts["principal"].info_error == ""
    # Each set waited for the second camera (config.FRAME_SET_WAIT) and went on without it.
    now = published[-1][0] / 1e9 + dg.config.FRAME_SET_WAIT
    last = [r for r in rows if r["time"] == repr(now)]
    assert len(last) == 9 and all(r["cameras"] == "principal" for r in last)
    assert all("missing_camera:second" in r["flags"] for r in last), [r["flags"] for r in last]
    monitor = dg.DistanceMonitor(rig, robot=robot, **OPTIONS)
    for ns, data, q in published:
        frames = {"principal": dg.depth_image(data["principal"], rig.cameras["principal"], timestamp=ns / 1e9)}
        result = monitor.query(frames, robot.control_point_positions(q), camera_joints={"principal": q},
                               now=ns / 1e9 + dg.config.FRAME_SET_WAIT)
    assert [r["distance"] for r in last] == [repr(float(d)) for d in result.distance]


def test_a_wrong_type_hash_is_heard_and_named(recording, robot, tmp_path, caplog):
    with caplog.at_level(logging.WARNING, logger="depthguard"):
        rows, published, _, node = play(recording, robot, tmp_path, type_hash="RIHS01_" + "0" * 64)
    warnings = [r.getMessage() for r in caplog.records if "type hash" in r.getMessage()]
    assert any("/principal/depth/image_raw" in w and "RIHS01_" + "0" * 64 in w for w in warnings)
    assert node.counts["principal"].received == FRAMES


def test_dry_run_says_what_is_missing(recording, tmp_path, capsys):
    rig_file = tmp_path / "rig.yaml"
    dg.save_rig(recording.rig, rig_file)
    publisher = RosPublisher(recording.rig, recording.joint_names)
    try:
        status, out, err = run_cli(["live", "--rig", rig_file, "--connect", publisher.endpoint, "--dry-run",
                                    "--dry-run-wait", "0.5"], capsys)
        assert status == 2 and "no image on /principal/depth/image_raw" in err
        thread = publishing(publisher, recording, 3.0)
        status, out, err = run_cli(["live", "--rig", rig_file, "--connect", publisher.endpoint, "--dry-run",
                                    "--dry-run-wait", "2.5"], capsys)
        thread.join()
        assert status == 0 and "agree" in out, err
    finally:
        publisher.close()


def test_a_camera_that_stops_loses_messages_restarts_or_steps_back_is_named(recording, robot, tmp_path):
    rig = recording.rig
    publisher = RosPublisher(rig, recording.joint_names)
    node = LiveNode(rig, robot, topics(rig), LiveOptions(connect=[publisher.endpoint], transport=1.0), OPTIONS,
                    out=tmp_path / "live.csv")
    frame_set = next(recording.frame_sets())
    q = recording.joints_at(frame_set.time)
    data = {name: image.data for name, image in frame_set.images.items()}

    def send(cameras, ns=None):
        ns = time.time_ns() if ns is None else ns
        publisher.publish_joints(ns, q)
        assert wait_for(lambda: node.joints_received(ns))
        for camera in cameras:
            publisher.publish_frame(camera, ns, data[camera])
        return ns

    try:
        node.start()
        assert publisher.wait_for_node()
        first = send(["principal", "second"])
        assert wait_for(lambda: any(t == first / 1e9 for t, _, _ in list(node.recent))), (
            first, list(node.recent)[:4], node.counts, list(node.errors), node.dropped)
        # The second camera stops: the principal's sets wait for it, then go on; once its frame is older than
        # max_age the answers name it stale and count it out.
        for _ in range(5):
            ns = send(["principal"])
            assert wait_for(lambda: any(t >= ns / 1e9 and why == "waited" for t, why, _ in list(node.recent)))
        # The last of those answers (not node.last: an idle answer may follow it max_age later, seeing nothing).
        waited = [seen for t, why, seen in list(node.recent) if t >= ns / 1e9 and why == "waited"]
        assert waited[-1] == ("principal",), list(node.recent)[-4:]
        # Its publisher loses 4 messages (rmw_zenoh's sequence numbers jump), then starts again (they go back).
        publisher.sequences["/second/depth/image_raw"] += 4
        ns = back = send(["principal", "second"])
        assert wait_for(lambda: node.counts["second"].missed >= 4)
        publisher.sequences["/second/depth/image_raw"] = 0
        send(["principal", "second"])
        assert wait_for(lambda: node.counts["second"].restarts == 1)
        # A stamp that goes back (a clock stepped back): the camera starts again, named once.
        send(["second"], ns=ns - 10**9)
        assert wait_for(lambda: any("reset_camera:second" in r for r in open(tmp_path / "live.csv").read().split())), (
            list(node.recent)[-6:], list(node.errors), node.dropped, node.counts["second"])
        # A frame stamped 10 s ahead of the host's clock (a clock stepped forward) is held out of the loop, counted,
        # and the answers go on (the loop's clock, which never goes back, is not carried ahead).
        answered = node.answers
        publisher.publish_frame("second", time.time_ns() + 10 * 10**9, data["second"])
        assert wait_for(lambda: node.counts["second"].future == 1)
        assert wait_for(lambda: node.answers > answered + 2)
    finally:
        node.close()
        publisher.close()
    with open(tmp_path / "live.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    stale = [r for r in rows if "stale_camera:second" in r["flags"]]
    assert stale and all("second" not in r["cameras"].split(";") for r in stale)
    assert any(r["cameras"] == "principal" for r in stale)  # the principal goes on alone
    # It went stale while it was quiet (the time it took depends on this machine's load: frames age on the host's
    # clock, so it is not checked here; tests/test_live_sets.py and the monitor's own tests check max_age).
    assert any(float(r["time"]) < back / 1e9 for r in stale)
    assert node.counts["second"].missed >= 4 and node.counts["second"].restarts == 1


def test_diagnostics_each_second_and_a_clock_that_disagrees(recording, robot, tmp_path):
    """/diagnostics comes once a second with each camera's counts; a camera stamping 5 s behind the host is
    reported there (ERROR, naming the clocks) and its frames never count as seen."""
    rig = recording.rig
    publisher = RosPublisher(rig, recording.joint_names)
    node = LiveNode(rig, robot, topics(rig), LiveOptions(connect=[publisher.endpoint]), OPTIONS,
                    out=tmp_path / "live.csv")
    frame_set = next(recording.frame_sets())
    q = recording.joints_at(frame_set.time)
    try:
        node.start()
        assert publisher.wait_for_node()
        for _ in range(3):
            ns = time.time_ns() - 5 * 10**9
            publisher.publish_joints(ns, q)
            assert wait_for(lambda: node.joints_received(ns))
            for camera, image in frame_set.images.items():
                publisher.publish_frame(camera, ns, image.data)
            time.sleep(0.1)
        assert wait_for(lambda: len(publisher.diagnostics) >= 2 and any(
            s.name == "depthguard: camera principal" and s.level == 2 and "clocks disagree" in s.message
            for s in publisher.diagnostics[-1].status), timeout=10)
    finally:
        node.close()
        publisher.close()
    last = publisher.diagnostics[-1]
    values = {s.name: {v.key: v.value for v in s.values} for s in last.status}
    assert int(values["depthguard: camera second"]["received"]) == 3
    assert float(values["depthguard: camera second"]["clock_offset_ms"]) > 4000
    assert "sets_dropped" in values["depthguard: node"]
    with open(tmp_path / "live.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    # Every answer blind: no camera seen, each named (stale, or missing when a set went out before its frame came).
    assert rows and all(r["cameras"] == "" for r in rows)
    assert all(any(f in r["flags"].split(";") for f in ("stale_camera:principal", "missing_camera:principal"))
               for r in rows)
    assert any("stale_camera:principal" in r["flags"] for r in rows)
    assert all(float(r["distance"]) == 0.0 for r in rows)  # blind: 0, flagged, never optimistic


@pytest.mark.parametrize("argv, words", [
    (["--duration", "nan"], ["--duration"]), (["--duration", "-1"], ["--duration"]),
    (["--dry-run-wait", "inf", "--dry-run"], ["--dry-run-wait"]),
    (["--connect", "not an endpoint", "--dry-run"], ["connect", "not an endpoint"]), (["--domain", "999", "--dry-run"], ["domain"]),
    (["--camera", "nosuch=/a/b"], ["nosuch"]), (["--camera", "/a/b"], ["--camera"])])
def test_bad_live_options_are_named(recording, tmp_path, capsys, argv, words):
    from cli_support import assert_refused

    rig_file = tmp_path / "rig.yaml"
    dg.save_rig(recording.rig, rig_file)
    assert_refused(["live", "--rig", rig_file, *argv], capsys, *words)


@pytest.mark.parametrize("argv, words", [
    (["--ssm", "--invalid", "neighbors"], ["detection_capability", "70 mm"]),
    (["--ssm", "--ssm-joint-speed", "1,2"], ["--ssm-joint-speed"]),
    (["--ssm", "--ssm-braking", "0"], ["--ssm-braking"]),
    (["--ssm", "--ssm-joint-speed", "1e300"], ["joint_speed", "at most 100"]),
    (["--ssm", "--ssm-braking", "1e9"], ["braking", "at most 1000"]),
    (["--ssm", "--ssm-joint-speed", "inf"], ["--ssm-joint-speed"]),
    (["--ssm", "--detection-capability", "0.08"], ["--detection-capability"]),
    (["--ssm", "--ssm-hold", "nan"], ["--ssm-hold"]),
    (["--ssm", "--speed-scaling-topic", "{node}/x"], ["topic", "{node}/x"]),
    (["--speed-scaling-topic", "/a/b"], ["needs --ssm"]),
    (["--detection-capability", "0.04"], ["needs --ssm"])])
def test_bad_speed_scaling_options_are_named(recording, tmp_path, capsys, argv, words):
    from cli_support import assert_refused

    rig_file = tmp_path / "rig.yaml"
    dg.save_rig(recording.rig, rig_file)
    assert_refused(["live", "--rig", rig_file, *argv], capsys, *words)


def test_speed_scaling_is_published_after_each_answer_as_ros2_control_takes_it(recording, robot, tmp_path):
    """--ssm: one control_msgs/msg/SpeedScalingFactor per answer at rmw_zenoh's key for its hash, each the factor
    of SSM's bound (speed_factor_within) on the detectable distances of the robot's surface on those same frames,
    with the reaction time the node counted (which holds the hold, the transport and the clock's skew)."""
    from depthguard.avoidance import SpeedScaling

    options = dict(OPTIONS, detection_capability=0.04)
    ssm = dict(joint_speed=0.3, hold=0.1)
    rows, published, answers, node = play(recording, robot, tmp_path, options=options, ssm=ssm)
    scaling = SpeedScaling(dg.DistanceMonitor(recording.rig, robot=robot, **options), **ssm)
    monitor = dg.DistanceMonitor(recording.rig, robot=robot, **options)
    stamps = {repr(ns / 1e9): (ns, data, q) for ns, data, q in published}
    checked = 0
    for row in rows:
        if row["control_point"] != robot.control_point_names[0] or row["time"] not in stamps:
            continue
        ns, data, q = stamps[row["time"]]
        t = ns / 1e9
        frames = {n: dg.depth_image(d, recording.rig.cameras[n], timestamp=t) for n, d in data.items()}
        prepared = monitor.prepare_set(frames, camera_joints={n: q for n in frames}, now=t)
        reaction = float(row["reaction_ms"]) / 1e3
        assert reaction >= scaling.extra_time + scaling.control_period
        points, jacobians = scaling.surface.control_point_kinematics(q)
        distance = prepared.detectable_distances(points, limit=5.0, check=False).distance  # exact this far
        surface = np.maximum(distance - scaling.radii, 0.0)
        want = scaling.ssm.speed_factor_within(surface, jacobians, scaling.joint_speed, reaction,
                                               radii=scaling.radii).factor
        assert float(row["speed_factor"]) == pytest.approx(want, abs=1e-4)
        checked += 1
    assert checked == FRAMES
    # What a controller subscribed to the topic reads: the factors of the CSV, in order, at the hashed key.
    factors = [float(r["speed_factor"]) for r in rows if r["control_point"] == robot.control_point_names[0]]
    heard = node.heard_scaling
    assert {key for key, _, _ in heard} == {
        "0/depthguard/speed_scaling/control_msgs::msg::dds_::SpeedScalingFactor_/" + dg.live.wire.type_hash(
            "control_msgs/msg/SpeedScalingFactor")}
    assert all(has for _, has, _ in heard)
    heard = [f for _, _, f in heard]
    # One per answer, in order; between them only zeros: before the joints came (no answer), and the deadline's
    # whenever no answer came within hold (this busy machine, the test's pauses between sets).
    matched = _subsequence(heard, factors)
    assert matched is not None and all(heard[i] == 0.0 for i in range(len(heard)) if i not in matched)
    assert all(0.0 <= f <= 1.0 for f in factors)
    # /diagnostics carries the last factor's status, "starting" included (speed_scaling_status)
    statuses = [s for d in node.heard_diagnostics for s in d.status if s.name == "depthguard: speed scaling"]
    for status in statuses:
        values = {v.key: v.value for v in status.values}
        assert values["starting"] in ("true", "false")
        assert status.message.startswith("starting: ") == (values["starting"] == "true"), status.message


def test_the_speed_factor_s_status_says_starting_while_it_may_rest_on_space_not_seen_yet():
    """/diagnostics' speed-scaling status (issue 35, start-up stated): ERROR with the reason "starting" while the
    factor may rest on space not seen since start-up, ERROR without it for a 0 from the distances alone, WARN below 1,
    OK at 1; the deadline's zeros say why."""
    from depthguard.avoidance import ScalingAnswer
    from depthguard.live._node import speed_scaling_status

    level, message, values = speed_scaling_status(ScalingAnswer(0.0, 0.2, limiting="link_3/1", distance=0.0,
                                                                starting=True))
    assert level == 2 and message.startswith("starting: limited by link_3/1") and ("starting", "true") in values
    level, message, values = speed_scaling_status(ScalingAnswer(0.0, 0.2, limiting="link_3/1", distance=0.0))
    assert level == 2 and message == "limited by link_3/1" and ("starting", "false") in values
    assert speed_scaling_status(ScalingAnswer(0.4, 0.2, limiting="link_3/1", distance=0.3))[0] == 1
    assert speed_scaling_status(ScalingAnswer(1.0, 0.2))[:2] == (0, "full speed")
    assert speed_scaling_status(ScalingAnswer(0.0, float("inf"), "no answer within hold"))[:2] == (2, "no answer within hold")


def _subsequence(values, wanted):
    """The indices at which ``wanted`` occurs in ``values`` in order, skipping only zeros; None if it does not."""
    out, i = set(), 0
    for want in wanted:
        while i < len(values) and values[i] != want:
            if values[i] != 0.0:
                return None
            i += 1
        if i == len(values):
            return None
        out.add(i)
        i += 1
    return out


def test_the_node_is_counted_as_a_subscriber_of_every_topic_it_reads(recording, robot, tmp_path):
    """issue 36: image_transport and realsense-ros publish only while they count a subscriber (rmw_zenoh's liveliness
    tokens of kind MS). The test's publisher does the same: the node declares a token for each topic it reads,
    best effort and volatile (compatible with any camera's QoS), and takes them away when it closes."""
    from depthguard.live import wire

    rig = recording.rig
    publisher = RosPublisher(rig, recording.joint_names)
    node = LiveNode(rig, robot, topics(rig), LiveOptions(connect=[publisher.endpoint]), OPTIONS)
    try:
        node.start()
        assert publisher.wait_for_node()
        tokens = [wire.parse_liveliness_key(key) for key in list(publisher.tokens)]
        assert None not in tokens
        ours = [t for t in tokens if t.node == "depthguard"]
        read = {t.topic: t for t in ours if t.kind == "MS"}
        expected_types = {"/joint_states": "sensor_msgs/msg/JointState"}
        for name in rig.cameras:
            expected_types[f"/{name}/depth/image_raw"] = "sensor_msgs/msg/Image"
            expected_types[f"/{name}/depth/camera_info"] = "sensor_msgs/msg/CameraInfo"
        assert set(read) == set(expected_types)
        for topic, msgtype in expected_types.items():
            assert read[topic].qos == wire.SENSOR_QOS and read[topic].qos.startswith("2:")  # best effort
            assert (read[topic].type, read[topic].hash) == (wire.type_name(msgtype), wire.type_hash(msgtype))
        assert {t.topic for t in ours if t.kind == "MP"} == {"/depthguard/distances", "/depthguard/status",
                                                             "/diagnostics"}
        assert [t.kind for t in ours].count("NN") == 1
        assert len({(t.zid, t.kind, t.topic) for t in ours}) == len(ours)
    finally:
        node.close()
    try:
        assert_withheld_once_the_node_is_gone(publisher, recording)
    finally:
        publisher.close()


def test_in_the_bridge_layout_the_node_announces_its_routes_to_zenoh_bridge_ros2dds(recording, robot, tmp_path):
    """issue 36: zenoh-bridge-ros2dds creates the DDS reader of a topic (which the DDS camera driver counts as a
    subscriber) only when another zenoh session announces a route to it, and the DDS writer that makes depthguard's
    outputs visible to ``ros2 topic list`` only for an announced publisher (zenoh-plugin-ros2dds 1.10.0,
    ``routes_mgr.rs``: ``on_ros_announcement_event``). The test's publisher plays the bridge and a DDS driver: it
    reads the tokens as the bridge parses them (``ros_publisher.bridge_route``, from its ``liveliness_mgt.rs``) and
    withholds a camera's frames while no MS route of its image topic is announced. Before, the node announced
    nothing in this layout: no frame came."""
    from ros_publisher import bridge_route

    rig = recording.rig
    publisher = RosPublisher(rig, recording.joint_names, layout="bridge")
    node = LiveNode(rig, robot, topics(rig), LiveOptions(layout="bridge", connect=[publisher.endpoint]), OPTIONS)
    try:
        node.start()
        assert publisher.wait_for_node()
        zid = str(node.session.info.zid())
        routes = [bridge_route(key) for key in list(publisher.tokens) if key.startswith(f"@ros2_lv/{zid}/")]
        assert routes and None not in routes
        read = {topic: (msgtype, qos) for _, kind, topic, msgtype, qos in routes if kind == "MS"}
        expected = {"/joint_states": "sensor_msgs/msg/JointState"}
        for name in rig.cameras:
            expected[f"/{name}/depth/image_raw"] = "sensor_msgs/msg/Image"
            expected[f"/{name}/depth/camera_info"] = "sensor_msgs/msg/CameraInfo"
        assert {topic: msgtype for topic, (msgtype, _) in read.items()} == expected
        assert all(qos == (True, "0", "0", "0,10") for _, qos in read.values())  # keyless, best effort, volatile
        written = {topic: qos for _, kind, topic, _, qos in routes if kind == "MP"}
        assert set(written) == {"/depthguard/distances", "/depthguard/status", "/diagnostics"}
        assert all(qos == (True, "1", "0", "0,10") for qos in written.values())  # reliable: any reader matches
        publish_first_set(publisher, recording, node)
        assert publisher.wait_answer(1)
    finally:
        node.close()
    try:
        assert_withheld_once_the_node_is_gone(publisher, recording)
    finally:
        publisher.close()


def test_the_domain_comes_from_ros_domain_id(recording, tmp_path, capsys, monkeypatch):
    from cli_support import assert_refused
    from depthguard.cli.live import ros_domain

    monkeypatch.setenv("ROS_DOMAIN_ID", "7")
    assert ros_domain(None) == 7 and ros_domain(3) == 3  # --domain wins
    monkeypatch.setenv("ROS_DOMAIN_ID", " ")
    assert ros_domain(None) == 0  # unset or empty: ROS 2's default
    monkeypatch.delenv("ROS_DOMAIN_ID")
    assert ros_domain(None) == 0
    rig_file = tmp_path / "rig.yaml"
    dg.save_rig(recording.rig, rig_file)
    for bad in ("abc", "233", "-1", "1e3", "nan", "inf", "²", "7\n8", "9" * 5000, "0x1"):
        monkeypatch.setenv("ROS_DOMAIN_ID", bad)
        assert_refused(["live", "--rig", rig_file, "--dry-run"], capsys, "ROS_DOMAIN_ID")


def test_the_speed_factor_has_a_deadline_and_goes_to_0_on_exit(recording, robot, tmp_path):
    """issue 36: joint_trajectory_controller keeps the last factor it heard, with no timeout. So depthguard keeps the
    deadline: each factor holds for hold seconds, then 0 goes out (a stream of zeros while no answer comes), and 0 is
    the last word when the node closes. --speed-scaling-topic puts it where the controller listens."""
    rig = recording.rig
    topic = "/joint_trajectory_controller/speed_scaling_input"
    publisher = RosPublisher(rig, recording.joint_names, scaling_topic=topic)
    hold = 0.1
    options = LiveOptions(connect=[publisher.endpoint], transport=1.0, scaling_topic=topic)
    node = LiveNode(rig, robot, topics(rig), options,
                    dict(OPTIONS, detection_capability=0.04), ssm=dict(joint_speed=0.3, hold=hold))
    try:
        node.start()
        assert publisher.wait_for_node()
        assert wait_for(lambda: len(publisher.scaling) >= 3)  # no joints, no frames: zeros, every hold seconds
        assert {f for _, _, f in publisher.scaling} == {0.0}
        ns = publish_first_set(publisher, recording, node)
        assert wait_for(lambda: node.answers >= 1)
        zeros = node.deadline_zeros
        assert wait_for(lambda: node.deadline_zeros > zeros + 2, timeout=10.0)  # nothing new: the deadline's zeros
        assert node.last_scaling.factor == 0.0 and node.last_scaling.why == "no answer within hold"
        assert all(key.startswith(f"0{topic}/") for key, _, _ in publisher.scaling)
    finally:
        node.close()
    assert wait_for(lambda: node.scaling_published == len(publisher.scaling), timeout=10.0)
    assert publisher.scaling[-1][2] == 0.0 and node.last_scaling.why == "closing"
    publisher.close()


def test_a_camera_info_latched_before_the_node_started_arrives(recording, robot, tmp_path):
    """issue 36: a driver publishes its CameraInfo once, transient local, before depthguard starts, and never again.
    The node asks the publisher's cache for it (zenoh's advanced subscriber with history, as rmw_zenoh's
    transient-local subscribers do), so the frames that follow do not wait for it forever."""
    rig = recording.rig
    publisher = RosPublisher(rig, recording.joint_names, latched_info=True)
    for camera in rig.cameras:
        publisher.latch_info(camera, time.time_ns())
    node = LiveNode(rig, robot, topics(rig), LiveOptions(connect=[publisher.endpoint], transport=1.0), OPTIONS)
    try:
        node.start()
        assert publisher.wait_for_node()
        assert wait_for(lambda: all(node.counts[n].info_seen for n in rig.cameras), timeout=20.0), node.counts
        ns = publish_first_set(publisher, recording, node)  # the image alone: no CameraInfo beside it
        assert wait_for(lambda: any(t >= ns / 1e9 and set(seen) == set(rig.cameras)
                                    for t, _, seen in list(node.recent)))
    finally:
        node.close()
        publisher.close()


def test_a_worker_that_dies_leaves_0_as_the_last_factor(recording, robot, tmp_path, monkeypatch):
    """issue 36: the factor's deadline does not depend on the worker. A fault that kills the worker's loop (not an
    answer's fault, which is caught and answered with 0) leaves the deadline's zeros."""
    from depthguard.live import _node

    def broken(self, image):
        raise RuntimeError("the worker's loop broke")

    monkeypatch.setattr(_node.FrameSetLoop, "add_frame", broken)
    rig = recording.rig
    publisher = RosPublisher(rig, recording.joint_names)
    node = LiveNode(rig, robot, topics(rig), LiveOptions(connect=[publisher.endpoint], transport=1.0),
                    dict(OPTIONS, detection_capability=0.04), ssm=dict(joint_speed=0.3, hold=0.1))
    try:
        node.start()
        assert publisher.wait_for_node()
        frame_set = next(recording.frame_sets())
        ns = time.time_ns()
        publisher.publish_joints(ns, recording.joints_at(frame_set.time))
        for camera, image in frame_set.images.items():
            publisher.publish_frame(camera, ns, image.data)
        assert wait_for(lambda: not node._worker.is_alive(), timeout=20.0)  # the loop died, and says so
        assert any("the worker stopped: RuntimeError" in e for e in node.errors)
        zeros = node.deadline_zeros
        assert wait_for(lambda: node.deadline_zeros > zeros + 2, timeout=10.0)
        assert wait_for(lambda: len(publisher.scaling) > 3) and publisher.scaling[-1][2] == 0.0
    finally:
        node.close()
        publisher.close()


def test_sigterm_leaves_0_as_the_last_factor(recording, tmp_path):
    """issue 36: ``depthguard live --ssm`` stopped with SIGTERM (ros2 launch, systemd, docker stop) publishes 0 as its
    last factor, on the controller's topic."""
    import signal
    import subprocess
    import sys

    rig_file = tmp_path / "rig.yaml"
    dg.save_rig(recording.rig, rig_file)
    topic = "/joint_trajectory_controller/speed_scaling_input"
    publisher = RosPublisher(recording.rig, recording.joint_names, scaling_topic=topic)
    process = subprocess.Popen(
        [sys.executable, "-m", "depthguard.cli", "live", "--rig", str(rig_file), "--connect", publisher.endpoint,
         "--ssm", "--ssm-joint-speed", "0.3", "--speed-scaling-topic", topic, "--duration", "120"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert wait_for(lambda: len(publisher.scaling) >= 3 or process.poll() is not None, timeout=90.0)
        assert process.poll() is None, process.communicate()
        process.send_signal(signal.SIGTERM)
        out, err = process.communicate(timeout=60)
        assert process.returncode == 0, err
        assert wait_for(lambda: publisher.scaling and publisher.scaling[-1][2] == 0.0)
        heard = len(publisher.scaling)
        time.sleep(0.5)
        assert len(publisher.scaling) == heard  # nothing after the last word
    finally:
        if process.poll() is None:
            process.kill()
        publisher.close()


@pytest.mark.parametrize("distro", ["humble", "jazzy"])
def test_the_node_speaks_the_hash_style_of_its_peers(recording, robot, tmp_path, distro):
    """issue 36: rmw_zenoh on Humble keys topics and writes tokens with TypeHashNotSupported, Jazzy and later with
    the RIHS01 hash; a subscriber listens at the exact key of its own style. The node takes the style from the
    peers' liveliness tokens, and a peer of that style hears its distances. (The layout, as in nano-ros's Humble
    key ``0/chatter/std_msgs::msg::dds_::Int32_/TypeHashNotSupported`` and token ``@ros2_lv/0/<zid>/0/5/MP/%/%/
    <node>/<topic>/std_msgs::msg::dds_::Int32_/TypeHashNotSupported/1:2:1,10:,:,:,,``.)"""
    from depthguard.live import wire

    assert wire.data_key("/chatter", "std_msgs/msg/Int32", distro="humble") == \
        "0/chatter/std_msgs::msg::dds_::Int32_/TypeHashNotSupported"
    assert wire.liveliness_key("z", 5, "MP", "talker", "/chatter", "std_msgs/msg/Int32", qos="1:2:1,10:,:,:,,",
                               distro="humble") == \
        "@ros2_lv/0/z/0/5/MP/%/%/talker/%chatter/std_msgs::msg::dds_::Int32_/TypeHashNotSupported/1:2:1,10:,:,:,,"
    rig = recording.rig
    publisher = RosPublisher(rig, recording.joint_names, distro=distro)
    node = LiveNode(rig, robot, topics(rig), LiveOptions(connect=[publisher.endpoint], transport=1.0), OPTIONS)
    try:
        node.start()
        assert node.distro == distro
        assert publisher.wait_for_node()
        ours = [wire.parse_liveliness_key(k) for k in list(publisher.tokens)]
        ours = [t for t in ours if t is not None and t.node == "depthguard" and t.kind != "NN"]
        assert ours and {t.hash == wire.HUMBLE_HASH for t in ours} == {distro == "humble"}
        ns = publish_first_set(publisher, recording, node)
        assert publisher.wait_answer(1)
        assert publisher.answers[0][0].endswith("/" + wire.hash_of("std_msgs/msg/Float64MultiArray", distro))
    finally:
        node.close()
        publisher.close()


def test_dry_run_names_a_peer_of_an_older_rmw_zenoh(recording, tmp_path, capsys):
    """issue 36: rmw_zenoh before Jazzy 0.2.4 wrote its attachment as named fields, and its subscribers throw on the
    33-byte form depthguard writes. Such a peer is named, with exit status 2 at --dry-run, never silence."""
    rig_file = tmp_path / "rig.yaml"
    dg.save_rig(recording.rig, rig_file)
    publisher = RosPublisher(recording.rig, recording.joint_names, old_attachment=True)
    thread = publishing(publisher, recording, 4.0)
    try:
        status, out, err = run_cli(["live", "--rig", rig_file, "--connect", publisher.endpoint, "--dry-run",
                                    "--dry-run-wait", "3"], capsys)
        assert status == 2 and "attachment in another form" in err and "not supported" in err, err
    finally:
        thread.join()
        publisher.close()
