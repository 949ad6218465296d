"""Recordings (design §12a): ``simulate`` writes frames.csv (and with ``--bag`` a ROS 2 bag), the recording
reader (folders and bags), and ``depthguard replay``.

Judges:

- the simulation itself (its joints, its frame times) and the PNG files read by the depth reader, for what the
  folder reader returns;
- the bag read back with rosbags directly (topics, types, counts, camera_info), and the folder it was written from:
  frames bit-exact, the same times and joints;
- for replay, a hand-written loop over the same frames through ``DistanceMonitor.query``: RESULTS.csv must hold
  exactly its numbers (no tolerance: the same computation on the same inputs);
- bad inputs: each error names the file, the camera and the field.
"""

from __future__ import annotations

import csv
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

import depthguard as dg
from cli_support import assert_refused, run_cli
from depthguard.cli import main
from depthguard.depth import write_depth_png
from depthguard.errors import DepthImageError, InputError, RigError
from depthguard.io.recordings import open_recording, write_bag
from depthguard.robots import RobotModel
from depthguard_lab.simulation import default_workcell, write_episode

HEADER = ["time", "frame", "control_point", "x", "y", "z", "distance", "blind_distance", "flags"]
FRAMES = 3  # frames of the simulated episode (0.1 s at 30 Hz)




def read_csv(path) -> list[list[str]]:
    with open(path, newline="") as f:
        return list(csv.reader(f))


@pytest.fixture(scope="module")
def workcell():
    return default_workcell().scaled(0.25)  # 160x120 cameras: the same scene, fast


@pytest.fixture(scope="module")
def episode(workcell, tmp_path_factory):
    """The first FRAMES frames of scenario B (two cameras), and the bag written from it into episode/bag."""
    out = write_episode(workcell, tmp_path_factory.mktemp("rec") / "episode", seed=0, progress=False,
                        frames=range(FRAMES))
    write_bag(open_recording(out), out / "bag")
    return out


# ------------------------------------------------------------------------------------------ simulate writes it


def test_simulate_writes_frames_csv(episode, workcell):
    rows = read_csv(episode / "frames.csv")
    assert rows[0] == ["camera", "frame", "time"]
    expected = [[name, str(i), f"{i / workcell.rate:.6f}"] for i in range(FRAMES) for name in workcell.rig.cameras]
    assert rows[1:] == expected
    for name, frame, _ in rows[1:]:
        assert (episode / "depth" / name / f"{int(frame):06d}.png").is_file()


def test_folder_recording_gives_the_episode(episode, workcell):
    recording = open_recording(episode)
    assert recording.kind == "folder" and len(recording) == FRAMES
    assert recording.rig.fingerprint() == workcell.rig.fingerprint()
    assert recording.joint_names == workcell.robot.joint_names
    sets = list(recording)
    assert [s.frame for s in sets] == list(range(FRAMES))
    for i, frame_set in enumerate(sets):
        t = float(f"{i / workcell.rate:.6f}")
        assert frame_set.time == t
        assert list(frame_set.images) == list(workcell.rig.cameras)
        for name, image in frame_set.images.items():
            camera = workcell.rig.cameras[name]
            png = dg.load_depth(episode / "depth" / name / f"{i:06d}.png", camera)
            assert image.camera == name and image.timestamp == t and image.data.dtype == np.uint16
            np.testing.assert_array_equal(image.data, png.data)
            assert image.data.any()
            # the recorded joints at a recorded time are the simulation's, exactly
            np.testing.assert_array_equal(frame_set.joints[name], workcell.joints_at(i / workcell.rate))


# ------------------------------------------------------------------------------------------------------ bags


def test_bag_holds_the_topics_of_the_layout(episode, workcell):
    """Read with rosbags directly, not with depthguard's reader."""
    from rosbags.highlevel import AnyReader

    rig = workcell.rig
    with AnyReader([episode / "bag"]) as reader:
        counts = {c.topic: (c.msgtype, c.msgcount) for c in reader.connections}
        expected = {"/joint_states": ("sensor_msgs/msg/JointState", FRAMES)}
        for name in rig.cameras:
            expected[f"/{name}/depth/image_raw"] = ("sensor_msgs/msg/Image", FRAMES)
            expected[f"/{name}/depth/camera_info"] = ("sensor_msgs/msg/CameraInfo", FRAMES)
        assert counts == expected
        infos = [c for c in reader.connections if c.topic == "/principal/depth/camera_info"]
        for connection, timestamp, raw in reader.messages(connections=infos):
            info = reader.deserialize(raw, connection.msgtype)
            camera = rig.cameras["principal"]
            assert info.header.frame_id == "principal_optical_frame"
            assert (info.width, info.height) == (camera.width, camera.height) == (160, 120)
            np.testing.assert_array_equal(info.k, [camera.fx, 0, camera.cx, 0, camera.fy, camera.cy, 0, 0, 1])
            assert not np.any(info.d)
            stamp = info.header.stamp.sec * 10**9 + info.header.stamp.nanosec
            assert stamp == timestamp
        images = [c for c in reader.connections if c.topic == "/second/depth/image_raw"]
        stamps = []
        for connection, timestamp, raw in reader.messages(connections=images):
            image = reader.deserialize(raw, connection.msgtype)
            assert image.encoding == "16UC1" and image.is_bigendian == 0 and image.step == 2 * 160
            stamps.append(image.header.stamp.sec * 10**9 + image.header.stamp.nanosec)
            png = dg.load_depth(episode / "depth" / "second" / f"{len(stamps) - 1:06d}.png", rig.cameras["second"])
            np.testing.assert_array_equal(np.frombuffer(image.data, "<u2").reshape(120, 160), png.data)
    assert stamps == [0, 33_333_000, 66_667_000]  # frames.csv's times, to the nanosecond


def assert_same_recording(a, b):
    assert a.rig.fingerprint() == b.rig.fingerprint()
    assert a.joint_names == b.joint_names
    np.testing.assert_array_equal(a.joint_times, b.joint_times)
    np.testing.assert_array_equal(a.joint_positions, b.joint_positions)
    np.testing.assert_array_equal(a.set_times, b.set_times)
    count = 0
    for x, y in zip(a, b, strict=True):
        assert (x.frame, x.time) == (y.frame, y.time)
        assert list(x.images) == list(y.images)
        for name in x.images:
            assert x.images[name].data.dtype == y.images[name].data.dtype
            np.testing.assert_array_equal(x.images[name].data, y.images[name].data)
            assert x.images[name].timestamp == y.images[name].timestamp
            assert x.images[name].depth_scale == y.images[name].depth_scale
            np.testing.assert_array_equal(x.joints[name], y.joints[name])
        count += 1
    assert count == len(a) > 0


def test_bag_reads_back_equal_to_the_folder(episode, tmp_path):
    folder = open_recording(episode)
    assert_same_recording(folder, open_recording(episode / "bag"))
    assert_same_recording(folder, open_recording(episode / "bag" / "bag.mcap"))  # bare MCAP, rig.yaml beside it
    sqlite = write_bag(folder, tmp_path / "sqlite", storage="sqlite3")
    assert any(p.suffix == ".db3" for p in sqlite.iterdir())
    assert_same_recording(folder, open_recording(sqlite))
    # a bare .mcap elsewhere needs its rig: rig.yaml beside it, or rig=
    lonely = tmp_path / "lonely.mcap"
    shutil.copy(episode / "bag" / "bag.mcap", lonely)
    with pytest.raises(RigError, match="rig.yaml"):
        open_recording(lonely)
    assert_same_recording(folder, open_recording(lonely, rig=episode / "rig.yaml"))
    assert_same_recording(folder, open_recording(lonely, rig=folder.rig))


def test_simulate_bag_from_the_command_line(tmp_path, capsys):
    status, out, err = run_cli(["simulate", "--out", tmp_path / "sim", "--duration", str(2 / 30), "--bag"], capsys)
    assert status == 0, err
    assert "sim/bag" in out
    folder = open_recording(tmp_path / "sim")
    assert len(folder) == 2 and folder.rig.cameras["principal"].shape == (480, 640)
    assert_same_recording(folder, open_recording(tmp_path / "sim" / "bag"))
    # the bag folder exists now: a second run is refused before it simulates
    status, out, err = run_cli(["simulate", "--out", tmp_path / "sim", "--duration", str(1 / 30), "--bag"], capsys)
    assert status == 2 and err.count("\n") == 1 and "exists already" in err and out == ""


# ---------------------------------------------------------------------------------------------------- replay


def expected_rows(episode, workcell, points_file=None) -> list[list[str]]:
    """RESULTS.csv rows from a hand-written loop: the episode's PNGs by file name, the simulation's joints, one
    DistanceMonitor queried frame by frame (``min``, replay's default aggregate)."""
    rig = dg.load_rig(episode / "rig.yaml")
    robot = RobotModel.default()
    monitor = dg.DistanceMonitor(rig, rho=0.4, aggregate="min", invalid="occupied", robot=robot)
    fixed = None if points_file is None else np.loadtxt(points_file, delimiter=",", skiprows=1, ndmin=2)
    rows = []
    for i in range(FRAMES):
        t = float(f"{i / workcell.rate:.6f}")
        q = workcell.joints_at(i / workcell.rate)
        frames = {name: dg.load_depth(episode / "depth" / name / f"{i:06d}.png", camera, timestamp=t)
                  for name, camera in rig.cameras.items()}
        points = robot.control_point_positions(q) if fixed is None else fixed
        names = robot.control_point_names if fixed is None else [f"p{k}" for k in range(len(fixed))]
        result = monitor.query(frames, points, camera_joints={name: q for name in rig.cameras}, now=t)
        for k, name in enumerate(names):
            rows.append([repr(t), str(i), name, *(repr(float(c)) for c in points[k]), repr(float(result.distance[k])),
                         repr(float(result.blind_distance[k])), ";".join(result.flags[k].names)])
    return rows


@pytest.fixture(scope="module")
def replayed(episode, tmp_path_factory):
    """RESULTS.csv of the folder, replayed once for the tests below."""
    out = tmp_path_factory.mktemp("replay") / "results.csv"
    assert main(["replay", str(episode), "--out", str(out)]) == 0
    return out


def test_replay_equals_querying_frame_by_frame(episode, workcell, replayed):
    rows = read_csv(replayed)
    assert rows[0] == HEADER
    expected = expected_rows(episode, workcell)
    assert rows[1:] == expected
    assert len(expected) == FRAMES * 9
    distances = np.array([float(r[6]) for r in expected])
    assert np.isfinite(distances).any() and (distances < 0.4).any()  # the comparison is not of empty answers


def test_replay_with_fixed_points(episode, workcell, tmp_path, capsys):
    points = tmp_path / "points.csv"
    points.write_text("x,y,z\n0.6,0.0,0.5\n0.3,-0.4,0.9\n5.0,5.0,5.0\n")
    out = tmp_path / "fixed.csv"
    status, _, err = run_cli(["replay", episode, "--out", out, "--points", points], capsys)
    assert status == 0, err
    rows = read_csv(out)
    assert rows[1:] == expected_rows(episode, workcell, points)
    assert [r[2] for r in rows[1:4]] == ["p0", "p1", "p2"] and rows[3][3:6] == ["5.0", "5.0", "5.0"]


def test_replay_of_the_bag_equals_the_folder(episode, replayed, tmp_path, capsys):
    for source in (episode / "bag", episode / "bag" / "bag.mcap"):
        out = tmp_path / "bag.csv"
        status, _, err = run_cli(["replay", source, "--out", out], capsys)
        assert status == 0, err
        assert out.read_text() == replayed.read_text()
    # frames.csv rows in any order: sorted by time
    shuffled = tmp_path / "shuffled"
    shutil.copytree(episode, shuffled, ignore=shutil.ignore_patterns("bag", "intensity"))
    lines = (shuffled / "frames.csv").read_text().splitlines()
    body = lines[1:]
    np.random.default_rng(3).shuffle(body)
    assert body != lines[1:]
    (shuffled / "frames.csv").write_text("\n".join([lines[0], *body]) + "\n")
    status, _, err = run_cli(["replay", shuffled, "--out", tmp_path / "shuffled.csv"], capsys)
    assert status == 0, err
    assert (tmp_path / "shuffled.csv").read_text() == replayed.read_text()


def test_replay_gives_each_camera_its_own_joints(episode, tmp_path, capsys):
    """Cameras that capture at different times: each frame is self-filtered with the joints at its own capture
    time, the points come from the joints at the set's latest time."""
    folder = tmp_path / "staggered"
    shutil.copytree(episode, folder, ignore=shutil.ignore_patterns("bag", "intensity"))
    times = {("principal", i): float(f"{i / 30:.6f}") for i in range(FRAMES)}
    times.update({("second", 0): 0.01, ("second", 1): 0.043333, ("second", 2): float(f"{2 / 30:.6f}")})
    rows = "".join(f"{camera},{i},{t!r}\n" for (camera, i), t in times.items())
    (folder / "frames.csv").write_text("camera,frame,time\n" + rows)
    # Joint states at 500 Hz, as a robot publishes them: each frame's joints are interpolated between the two
    # states around its stamp (the frame-set loop, design §12b, asks for states within JOINT_GAP).
    workcell = default_workcell()
    names = RobotModel.default().joint_names
    lines = [f"{k * 0.002!r}," + ",".join(repr(float(v)) for v in workcell.joints_at(k * 0.002)) for k in range(40)]
    (folder / "joint_states.csv").write_text("time," + ",".join(names) + "\n" + "\n".join(lines) + "\n")
    status, _, err = run_cli(["replay", folder, "--out", tmp_path / "r.csv"], capsys)
    assert status == 0, err
    rows = read_csv(tmp_path / "r.csv")[1:]
    recording = open_recording(folder)  # its joints_at is checked against exact values above and below
    rig, robot = recording.rig, RobotModel.default()

    def loop(own_times: bool) -> list[list[str]]:
        monitor = dg.DistanceMonitor(rig, robot=robot, aggregate="min")  # replay's default
        out = []
        for i in range(FRAMES):
            frames = {name: dg.load_depth(folder / "depth" / name / f"{i:06d}.png", camera,
                                          timestamp=times[(name, i)]) for name, camera in rig.cameras.items()}
            now = max(times[(name, i)] for name in rig.cameras)
            joints = {name: recording.joints_at(times[(name, i)] if own_times else now) for name in rig.cameras}
            points = robot.control_point_positions(recording.joints_at(now))
            result = monitor.query(frames, points, camera_joints=joints, now=now)
            out += [[repr(now), str(i), name, *(repr(float(c)) for c in points[k]), repr(float(result.distance[k])),
                     repr(float(result.blind_distance[k])), ";".join(result.flags[k].names)]
                    for k, name in enumerate(robot.control_point_names)]
        return out

    assert [r[0] for r in rows[::9]] == ["0.01", "0.043333", repr(float(f"{2 / 30:.6f}"))]
    assert rows == loop(own_times=True)
    assert rows != loop(own_times=False)  # the joints per camera matter here: the test can tell


def test_replay_json_summary(episode, replayed, tmp_path, capsys):
    status, out, err = run_cli(["replay", episode, "--out", tmp_path / "r.csv", "--json"], capsys)
    assert status == 0, err
    assert "replaying" in err  # what it is doing, on stderr
    summary = json.loads(out)
    rows = read_csv(replayed)[1:]
    distances = np.array([float(r[6]) for r in rows])
    assert summary["frames"] == FRAMES and summary["points"] == 9 and summary["answers"] == len(rows)
    assert summary["flagged"] == sum(1 for r in rows if r[8])
    assert summary["distance_min"] == distances.min()
    median = float(np.median(distances))
    assert summary["distance_median"] == (None if math.isinf(median) else median)


def test_replay_errors_are_one_line(episode, tmp_path, capsys):
    cases = [
        (["replay", episode, "--out", tmp_path / "r.csv", "--robot", "panda"], ["joints", "panda_joint1"]),
        (["replay", tmp_path / "nowhere", "--out", tmp_path / "r.csv"], ["nowhere", "no such recording"]),
        (["replay", episode, "--out", tmp_path], ["--out", "not a regular file"]),
        (["replay", episode, "--out", tmp_path / "r.csv", "--rho", "inf"], ["--rho"]),
        (["replay", episode, "--out", tmp_path / "r.csv", "--points", tmp_path / "none.csv"], ["none.csv"]),
        (["replay", episode / "bag" / "bag.mcap", "--out", tmp_path / "r.csv", "--rig", tmp_path / "x.yaml"],
         ["x.yaml"]),
    ]
    for argv, words in cases:
        assert_refused(argv, capsys, *words)
        assert not (tmp_path / "r.csv").exists() and not list(tmp_path.glob(".r.csv.*"))  # nor a temporary file


# ---------------------------------------------------------------------------- a small hand-made recording

JOINTS = ("a", "b")


def small_rig() -> dg.Rig:
    left = dg.PinholeCamera("left", 8, 6, 10.0, 10.0, 3.5, 2.5, np.eye(4))
    T_world_right = np.eye(4)
    T_world_right[0, 3] = 1.0
    right = left.replace(name="right", T_world_camera=T_world_right)
    return dg.Rig({"left": left, "right": right})


def make_recording(folder: Path, frames=None, joints=None) -> Path:
    """A recording folder with two 8x6 cameras. ``frames``: (camera, frame, time) rows, default three frames of
    each camera, 'right' 10 ms after 'left'; ``joints``: (time, a, b) rows, default 0 -> (0, 0) to 0.2 -> (1, -2).
    Every image is filled with 1000 + 10 * frame (+ 1 for 'right')."""
    folder.mkdir(parents=True, exist_ok=True)
    rig = small_rig()
    dg.save_rig(rig, folder / "rig.yaml")
    if frames is None:
        frames = [(name, i, round(i * 0.05 + (0.01 if name == "right" else 0.0), 6))
                  for i in range(3) for name in rig.cameras]
    if joints is None:
        joints = [(0.0, 0.0, 0.0), (0.2, 1.0, -2.0)]
    rows = ["camera,frame,time"] + [f"{c},{f},{t}" for c, f, t in frames]
    (folder / "frames.csv").write_text("\n".join(rows) + "\n")
    (folder / "joint_states.csv").write_text("time,a,b\n" + "".join(f"{t},{a},{b}\n" for t, a, b in joints))
    for camera, frame, _ in frames:
        if camera in rig.cameras:
            (folder / "depth" / camera).mkdir(parents=True, exist_ok=True)
            value = 1000 + 10 * int(frame) + (camera == "right")
            write_depth_png(folder / "depth" / camera / f"{int(frame):06d}.png", np.full((6, 8), value, np.uint16))
    return folder


def test_frame_sets_in_capture_time_order_with_joints_at_each_capture_time(tmp_path):
    frames = [("left", 0, 0.0), ("right", 0, 0.04), ("left", 1, 0.033), ("right", 1, 0.073), ("left", 2, 0.066)]
    recording = open_recording(make_recording(tmp_path / "r", frames=frames))
    sets = list(recording)
    # set 0 is complete at 0.04, set 2 (left only) at 0.066, set 1 at 0.073
    assert [(s.frame, s.time) for s in sets] == [(0, 0.04), (2, 0.066), (1, 0.073)]
    np.testing.assert_array_equal(recording.set_times, [0.04, 0.066, 0.073])
    assert list(sets[1].images) == ["left"]
    first = sets[0]
    assert first.images["left"].timestamp == 0.0 and first.images["right"].timestamp == 0.04
    assert first.images["right"].data[0, 0] == 1001 and sets[2].images["left"].data[3, 4] == 1010
    np.testing.assert_array_equal(first.joints["left"], [0.0, 0.0])
    np.testing.assert_allclose(first.joints["right"], [0.2, -0.4], rtol=0, atol=1e-15)  # 0.04 of 0.2 s
    np.testing.assert_allclose(sets[2].joints["right"], [0.365, -0.73], rtol=0, atol=1e-15)
    np.testing.assert_allclose(recording.joints_at(0.1), [0.5, -1.0], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(recording.joints_at(0.2), [1.0, -2.0])


def test_joints_are_never_extrapolated(tmp_path):
    recording = open_recording(make_recording(tmp_path / "r"))
    for t in (-0.001, 0.2000001, math.nan, math.inf):
        with pytest.raises(InputError, match="time") as info:
            recording.joints_at(t)
        if math.isfinite(t):
            assert repr(t) in str(info.value) and "joint_states.csv" in str(info.value)
    late = make_recording(tmp_path / "late", frames=[("left", 0, 0.1), ("right", 0, 0.25)])
    with pytest.raises(InputError) as info:
        open_recording(late)
    message = str(info.value)
    assert "joint_states.csv" in message and "camera 'right'" in message and "field 'time'" in message
    assert "frame 0 captured at 0.25 s is outside the recorded joint states (0.0 to 0.2 s)" in message


def _rewrite(name: str, old: str, new: str):
    def change(folder: Path):
        path = folder / name
        text = path.read_text()
        assert old in text, (old, text)
        path.write_text(text.replace(old, new, 1))
    return change


BAD_FOLDERS = {
    # case: (change to the folder, error class, words the message must hold: file, camera, field)
    "unknown camera": (_rewrite("frames.csv", "right,1,", "middle,1,"), InputError,
                       ["frames.csv", "line 5", "camera 'middle'", "field 'camera'"]),
    "frame file missing": (lambda f: (f / "depth" / "right" / "000002.png").unlink(), DepthImageError,
                           ["000002.png", "camera 'right'", "cannot read"]),
    "time nan": (_rewrite("frames.csv", "left,1,0.05", "left,1,nan"), InputError,
                 ["frames.csv", "line 4", "camera 'left'", "field 'time'"]),
    "time 1e999": (_rewrite("frames.csv", "left,1,0.05", "left,1,1e999"), InputError,
                   ["frames.csv", "camera 'left'", "field 'time'"]),
    "time goes back": (_rewrite("frames.csv", "right,2,0.11", "right,2,0.03"), InputError,
                       ["frames.csv", "camera 'right'", "field 'time'", "frame 2"]),
    "frame listed twice": (_rewrite("frames.csv", "left,2,", "left,1,"), InputError,
                           ["frames.csv", "camera 'left'", "field 'frame'", "twice"]),
    "frame not a number": (_rewrite("frames.csv", "left,2,", "left,two,"), InputError,
                           ["frames.csv", "camera 'left'", "field 'frame'"]),
    "header without time": (_rewrite("frames.csv", "camera,frame,time", "camera,frame,stamp"), InputError,
                            ["frames.csv", "field 'time'"]),
    "camera without frames": (_rewrite("frames.csv", "camera,frame,time\n",
                                       "camera,frame,time\n"), None, None),  # replaced below
    "joint value missing": (_rewrite("joint_states.csv", "0.2,1.0,-2.0", "0.2,1.0"), InputError,
                            ["joint_states.csv", "line 3", "field 'b'"]),
    "joint value nan": (_rewrite("joint_states.csv", "0.2,1.0,-2.0", "0.2,nan,-2.0"), InputError,
                        ["joint_states.csv", "line 3", "field 'a'"]),
    "joint times not increasing": (_rewrite("joint_states.csv", "0.2,1.0", "0.0,1.0"), InputError,
                                   ["joint_states.csv", "line 3", "field 'time'", "(0.0 s follows 0.0 s)"]),
    "joint header": (_rewrite("joint_states.csv", "time,a,b", "t,a,b"), InputError,
                     ["joint_states.csv", "field 'time'"]),
    "joint named twice": (_rewrite("joint_states.csv", "time,a,b", "time,a,a"), InputError,
                          ["joint_states.csv", "field 'a'", "twice"]),
    "joint states missing": (lambda f: (f / "joint_states.csv").unlink(), InputError,
                             ["joint_states.csv", "cannot read"]),
    "rig missing": (lambda f: (f / "rig.yaml").unlink(), RigError, ["rig.yaml", "cannot read"]),
}


def _only_left(folder: Path):
    path = folder / "frames.csv"
    path.write_text("".join(line + "\n" for line in path.read_text().splitlines() if not line.startswith("right")))


BAD_FOLDERS["camera without frames"] = (_only_left, InputError, ["frames.csv", "camera 'right'", "field 'camera'"])


@pytest.mark.parametrize("case", sorted(BAD_FOLDERS))
def test_bad_recording_folders_name_file_camera_and_field(tmp_path, case):
    change, error, words = BAD_FOLDERS[case]
    folder = make_recording(tmp_path / "r")
    open_recording(folder)  # fine before the change
    change(folder)
    with pytest.raises(error) as info:
        open_recording(folder)
    message = str(info.value)
    assert "\n" not in message
    for word in words:
        assert word in message, (word, message)


def test_not_a_recording(tmp_path):
    with pytest.raises(InputError, match="neither a recording folder"):
        open_recording(tmp_path)
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(InputError, match="not a recording"):
        open_recording(tmp_path / "notes.txt")
    with pytest.raises(InputError, match="no such recording"):
        open_recording(tmp_path / "missing")


# ----------------------------------------------------------------------------------------- hand-made bags


def custom_bag(path: Path, rig: dg.Rig, *, encoding="16UC1", fx_offset=0.0, distortion=0.0, skip=(),
               stamps=(0.0, 0.05, 0.1), extra_camera=None, info=None) -> Path:
    """A bag written with rosbags directly (not with write_bag): 'left' and 'right' images stamped ``stamps`` and
    logged at 0, 0.05, 0.1 s, camera infos (with the fields in ``info`` changed), joint states at 0 and 0.2 s; with
    the given faults. rig.yaml beside it."""
    from rosbags.rosbag2 import Writer
    from rosbags.rosbag2.enums import StoragePlugin
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    T = store.types
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]

    def header(t):
        ns = round(t * 1e9)
        return Header(stamp=Time(sec=ns // 10**9, nanosec=ns % 10**9), frame_id="")

    cameras = dict(rig.cameras)
    if extra_camera:
        cameras[extra_camera] = rig.cameras["left"]
    with Writer(path, version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin.MCAP) as writer:
        def connection(topic, msgtype):
            return None if topic in skip else writer.add_connection(topic, msgtype, typestore=store)

        joints = connection("/joint_states", "sensor_msgs/msg/JointState")
        if joints is not None:
            for t, values in ((0.0, [0.0, 0.0]), (0.2, [1.0, -2.0])):
                message = T["sensor_msgs/msg/JointState"](header=header(t), name=list(JOINTS),
                                                          position=np.array(values), velocity=np.zeros(0),
                                                          effort=np.zeros(0))
                writer.write(joints, round(t * 1e9), store.serialize_cdr(message, message.__msgtype__))
        for name, camera in cameras.items():
            images = connection(f"/{name}/depth/image_raw", "sensor_msgs/msg/Image")
            infos = connection(f"/{name}/depth/camera_info", "sensor_msgs/msg/CameraInfo")
            for j, t in enumerate(stamps):
                logged = round(j * 0.05 * 1e9)
                if images is not None:
                    data = np.full((camera.height, camera.width), 1000, np.uint16) if encoding != "32FC1" else \
                        np.full((camera.height, camera.width), 1.25, np.float32)
                    message = T["sensor_msgs/msg/Image"](header=header(t), height=camera.height, width=camera.width,
                                                         encoding=encoding, is_bigendian=0,
                                                         step=data.itemsize * camera.width,
                                                         data=data.view(np.uint8).ravel())
                    writer.write(images, logged, store.serialize_cdr(message, message.__msgtype__))
                if infos is not None:
                    k = [camera.fx + fx_offset, 0, camera.cx, 0, camera.fy, camera.cy, 0, 0, 1]
                    fields = dict(distortion_model="plumb_bob", d=np.array([distortion, 0, 0, 0, 0.0]),
                                  k=np.array(k, float), r=np.eye(3).ravel(), p=np.zeros(12), binning_x=0, binning_y=0,
                                  roi=dict(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))
                    fields.update(info or {})
                    fields["roi"] = T["sensor_msgs/msg/RegionOfInterest"](**fields["roi"])
                    message = T["sensor_msgs/msg/CameraInfo"](header=header(t), height=camera.height,
                                                              width=camera.width, **fields)
                    writer.write(infos, logged, store.serialize_cdr(message, message.__msgtype__))
    dg.save_rig(rig, path / "rig.yaml")
    return path


def test_a_bag_written_by_another_tool_reads(tmp_path):
    recording = open_recording(custom_bag(tmp_path / "ok", small_rig()))
    assert recording.kind == "bag" and len(recording) == 3 and recording.joint_names == JOINTS
    sets = list(recording)
    assert [s.frame for s in sets] == [0, 1, 2] and [s.time for s in sets] == [0.0, 0.05, 0.1]
    np.testing.assert_allclose(sets[1].joints["right"], [0.25, -0.5], rtol=0, atol=1e-15)
    assert sets[2].images["left"].data.dtype == np.uint16 and (sets[2].images["left"].data == 1000).all()


@pytest.mark.parametrize("info", [dict(distortion_model="rational_polynomial", d=np.zeros(8)),
                                  dict(distortion_model="", d=np.zeros(0)), dict(binning_x=1, binning_y=1),
                                  dict(p=np.arange(12.0))],
                         ids=["rational_polynomial", "no model", "binning 1", "p (of image_rect)"])
def test_camera_info_fields_that_leave_image_raw_a_pinhole_are_accepted(tmp_path, info):
    assert len(open_recording(custom_bag(tmp_path / "bag", small_rig(), info=info))) == 3


def test_camera_info_roi_of_the_whole_image_is_accepted(tmp_path):
    rig = small_rig()
    width, height = rig.cameras["left"].width, rig.cameras["left"].height
    assert rig.cameras["right"].width == width and rig.cameras["right"].height == height
    roi = dict(x_offset=0, y_offset=0, height=height, width=width, do_rectify=True)
    assert len(open_recording(custom_bag(tmp_path / "bag", rig, info=dict(roi=roi)))) == 3


def test_float_images_in_metres(tmp_path):
    recording = open_recording(custom_bag(tmp_path / "float", small_rig(), encoding="32FC1"))
    image = next(iter(recording)).images["right"]
    assert image.data.dtype == np.float32 and image.depth_scale == 1.0 and (image.data == 1.25).all()
    copy = write_bag(recording, tmp_path / "copy", storage="sqlite3")  # float images written as 32FC1
    assert_same_recording(recording, open_recording(copy))


BAD_BAGS = {
    "no joint states": (dict(skip=("/joint_states",)), ["/joint_states", "field 'topic'"]),
    "no camera_info": (dict(skip=("/right/depth/camera_info",)), ["camera 'right'", "field 'topic'", "camera_info"]),
    "no images": (dict(skip=("/left/depth/image_raw",)), ["camera 'left'", "field 'topic'", "image_raw"]),
    "camera_info fx": (dict(fx_offset=2.0), ["camera 'left'", "field 'fx'", "says fx 12.0, the rig 10.0"]),
    "distortion": (dict(distortion=0.1), ["camera 'left'", "field 'd'", "rectified"]),
    "equidistant without distortion": (dict(info=dict(distortion_model="equidistant", d=np.zeros(4))),
                                       ["camera 'left'", "field 'distortion_model'", "'equidistant'"]),
    "unknown distortion model": (dict(info=dict(distortion_model="kannala_brandt")),
                                 ["camera 'left'", "field 'distortion_model'", "'kannala_brandt'"]),
    "rectification turned": (dict(info=dict(r=np.array([0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]))),
                             ["camera 'left'", "field 'r'", "identity"]),
    "rectification zeros": (dict(info=dict(r=np.zeros(9))), ["camera 'left'", "field 'r'", "identity"]),
    "binning": (dict(info=dict(binning_y=2)), ["camera 'left'", "field 'binning'"]),
    "roi offset": (dict(info=dict(roi=dict(x_offset=4, y_offset=0, height=0, width=0, do_rectify=False))),
                   ["camera 'left'", "field 'roi'"]),
    "roi smaller": (dict(info=dict(roi=dict(x_offset=0, y_offset=0, height=2, width=2, do_rectify=False))),
                    ["camera 'left'", "field 'roi'"]),
    "encoding": (dict(encoding="mono16"), ["camera 'left'", "field 'encoding'", "mono16"]),
    "camera not in the rig": (dict(extra_camera="top"), ["camera 'top'", "field 'topic'"]),
    "stamps go back": (dict(stamps=(0.0, 0.1, 0.05)), ["camera 'left'", "field 'time'", "frame 1"]),
    "stamp outside the joints": (dict(stamps=(0.0, 0.1, 0.3)), ["camera 'left'", "field 'time'", "0.3"]),
}


@pytest.mark.parametrize("case", sorted(BAD_BAGS))
def test_bad_bags_name_file_camera_and_field(tmp_path, case):
    changes, words = BAD_BAGS[case]
    path = custom_bag(tmp_path / "bag", small_rig(), **changes)
    with pytest.raises(InputError) as info:
        open_recording(path)
    message = str(info.value)
    assert str(path) in message and "\n" not in message
    for word in words:
        assert word in message, (word, message)


def test_corrupt_bags(episode, tmp_path):
    truncated = tmp_path / "truncated.mcap"
    truncated.write_bytes((episode / "bag" / "bag.mcap").read_bytes()[:5000])
    with pytest.raises(InputError, match="not a readable ROS 2 bag") as info:
        open_recording(truncated, rig=episode / "rig.yaml")
    assert "truncated.mcap" in str(info.value)
    broken = tmp_path / "broken"
    shutil.copytree(episode / "bag", broken)
    (broken / "bag.mcap").write_bytes(b"\x89MCAP0\r\n" + bytes(100))
    with pytest.raises(InputError, match="not a readable ROS 2 bag"):
        open_recording(broken)
    (broken / "metadata.yaml").write_text("rosbag2_bagfile_information: {relative_file_paths: [gone.mcap]}\n")
    with pytest.raises(InputError, match="gone.mcap"):
        open_recording(broken)
    with pytest.raises(InputError, match="exists already"):
        write_bag(open_recording(episode), broken)


def test_replay_places_the_robot_at_base(episode, replayed, tmp_path, capsys):
    """--base X,Y,Z[,YAW] (shared with live and collide): the control points move with the robot's base."""
    status, _, err = run_cli(["replay", episode, "--out", tmp_path / "r.csv", "--base", "0.25,0,0"], capsys)
    assert status == 0, err
    moved = read_csv(tmp_path / "r.csv")[1:]
    original = read_csv(replayed)[1:]
    assert [float(r[3]) for r in moved] == pytest.approx([float(r[3]) + 0.25 for r in original], abs=1e-9)
    assert [r[4:6] for r in moved] == [r[4:6] for r in original]
    assert_refused(["replay", episode, "--out", tmp_path / "s.csv", "--base", "1,2"], capsys, "--base")
