"""Recordings: depth frames of a rig and the robot's joint states over time, read back for replay (design §12a).

Two layouts hold the same data:

- **A recording folder** (``depthguard simulate`` writes one; a user can write one from any sensor)::

      RECORDING/
        rig.yaml                      the rig (design §2)
        frames.csv                    camera,frame,time: one row per depth image, capture time in seconds
        depth/<camera>/<frame>.png    16-bit PNG in depth_scale units, frame as six digits (000042.png)
        joint_states.csv              time,<joint name>,...: radians (metres for prismatic joints), at any rate

  Rows of ``frames.csv`` may come in any order (they are sorted by time, stably). Other columns are ignored.

- **A ROS 2 bag** (rosbag2 folder with ``metadata.yaml``, MCAP or SQLite storage, or a bare ``.mcap`` file), read
  with ``rosbags`` (no ROS installation):

  - ``/<camera>/depth/image_raw``: ``sensor_msgs/msg/Image``, encoding ``16UC1`` (units of the camera's depth_scale)
    or ``32FC1`` (metres);
  - ``/<camera>/depth/camera_info``: ``sensor_msgs/msg/CameraInfo``, which must agree with the rig (``width``,
    ``height``, ``fx``, ``fy``, ``cx``, ``cy`` from ``k``, as for any ``image_raw``; distortion ``d`` all zero, of a
    model whose zero is the pinhole (``plumb_bob``, ``rational_polynomial`` or none); ``r`` the identity; no binning
    or region of interest; ``p`` describes the rectified image and is not used: as
    :func:`~depthguard.cameras.load_camera_info` with ``rectified=False``);
  - ``/joint_states``: ``sensor_msgs/msg/JointState``, every message naming the same joints (in any order).

  Capture time = the message's header stamp. Frame number of an image = its index among that camera's images.
  Camera poses, depth ranges and noise are not in standard messages: the rig comes from ``rig.yaml`` in the bag
  folder (beside a bare ``.mcap`` file), or from the ``rig=`` argument of :func:`open_recording`.
  :func:`write_bag` writes this layout.

A :class:`Recording` gives the rig, the joints (interpolated linearly to any capture time inside the recorded span;
a time outside it is an error naming the time, never an extrapolation), and its **frame sets** in capture-time
order: the frames of every camera that share one frame number, answered once the last of them has arrived.

Input from outside is checked where it is read. Files go through :mod:`depthguard.io.files` (regular files only,
bounded); depth PNGs through the depth image reader. A missing file, a row naming a camera the rig lacks, a frame
file missing, a capture time that is not finite or that goes back for one camera, a joint state time that does not
increase, a bag without the topics it needs, a camera_info that contradicts the rig: each raises an
:class:`~depthguard.errors.InputError` (:class:`~depthguard.errors.DepthImageError` for a depth image file) whose
message names the file, the camera and the field.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from depthguard import config
from depthguard.io.files import atomic_folder, check_regular_file, csv_table, load_yaml, read_text
from depthguard.cameras import Rig, load_rig, save_rig
from depthguard.depth import DepthImage, depth_image, load_depth
from depthguard.errors import DepthguardError, DepthImageError, InputError
from depthguard.io.ros_messages import (CAMERA_INFO, IMAGE, JOINT_STATE, JOINT_STATES_TOPIC, check_camera_info,
                                        depth_messages, header_seconds, image_array, joint_state, joint_state_message,
                                        ros_nanoseconds, ros_typestore)
from depthguard.validation import check_path, short_repr

__all__ = ["FrameRecord", "FrameSet", "Recording", "open_recording", "write_bag"]

# Bounds of the files a recording holds (a depth PNG is bounded by config.MAX_DEPTH_FILE_BYTES, a rig by
# config.MAX_TEXT_FILE_BYTES). The CSV files are parsed whole; a bag is streamed message by message by rosbags, so its
# bound only refuses what cannot be a recording.
#: frames.csv and joint_states.csv: 256 MiB each (an hour of four cameras at 30 Hz is about 10 MB of frames.csv).
MAX_CSV_BYTES = 256 << 20
#: One storage file of a bag (.mcap, .db3): 1 TiB.
MAX_BAG_FILE_BYTES = 1 << 40
#: Frame numbers in [0, MAX_FRAME_NUMBER].
MAX_FRAME_NUMBER = 10**9 - 1

#: A plain decimal number, as the CSV readers accept it (no nan, inf, 1_000 or non-ASCII digits).
_NUMBER = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_WHOLE = re.compile(r"[0-9]{1,10}")
#: The bag's topics: /<camera>/depth/image_raw and /<camera>/depth/camera_info.
_CAMERA_TOPIC = re.compile(r"/(?P<camera>.+)/depth/(?P<kind>image_raw|camera_info)")


@dataclass(frozen=True)
class FrameRecord:
    """One depth image of a recording.

    Attributes:
        camera: the camera that took it (a camera of the recording's rig).
        frame: its frame number (folder: from ``frames.csv``; bag: its index among the camera's images), >= 0.
        time: capture time, seconds, finite (the recording's clock).
    """

    camera: str
    frame: int
    time: float


@dataclass(frozen=True, eq=False)
class FrameSet:
    """The frames of every camera that share one frame number.

    Attributes:
        frame: the frame number.
        time: seconds, the latest capture time of the set (when its last frame arrived).
        images: camera name -> :class:`~depthguard.DepthImage` stamped with its own capture time, in the rig's
            camera order; a camera without a frame of this number is absent.
        joints: camera name -> (n,) float64 joint positions at that camera's capture time, in
            :attr:`Recording.joint_names` order (radians, metres for prismatic joints).
    """

    frame: int
    time: float
    images: dict[str, DepthImage]
    joints: dict[str, np.ndarray]


class Recording:
    """A recording opened by :func:`open_recording`: rig, joints over time, and frame sets in capture-time order.

    Images are read when the frame sets are iterated (never all at once); everything else is read and checked when
    the recording is opened.

    Attributes:
        path: the recording folder, bag folder or ``.mcap`` file.
        kind: ``"folder"`` or ``"bag"``.
        rig: the cameras (:class:`~depthguard.Rig`).
        joint_names: the joints of ``joint_states`` (folder: the CSV's columns; bag: the first message's names).
        joint_times: (k,) float64 seconds, strictly increasing, read-only.
        joint_positions: (k, n) float64, row i the joints at ``joint_times[i]``, columns in ``joint_names`` order,
            read-only.
        frames: every :class:`FrameRecord`, sorted by capture time (stably: rows of one time keep their order).
    """

    def __init__(self, path: Path, kind: str, rig: Rig, joint_names, joint_times, joint_positions, frames,
                 joints_source: str, reader, replay: bool = False, left_out: dict | None = None):
        self.path = path
        self.kind = kind
        self.rig = rig
        self.joint_names = tuple(joint_names)
        self.joint_times = np.array(joint_times, dtype=np.float64)
        self.joint_times.setflags(write=False)
        self.joint_positions = np.array(joint_positions, dtype=np.float64).reshape(len(self.joint_times), -1)
        self.joint_positions.setflags(write=False)
        self.frames = tuple(frames)
        self._joints_source = joints_source
        # The layout's image reader: reader(sets) yields (frame, time, records, {camera: DepthImage}) per set.
        self._reader = reader
        #: camera -> why it is left out (replay=True: its camera_info disagrees with the rig), naming the field
        self.left_out = dict(left_out or {})
        if not replay:
            for record in self.frames:  # every capture time inside the joints' span, checked before any replay
                self._check_time(record.time, camera=record.camera, frame=record.frame)
        self._sets = _schedule(self.frames, list(rig.cameras))

    def __repr__(self) -> str:
        return (f"Recording({str(self.path)!r}, kind={self.kind!r}, cameras={list(self.rig.cameras)}, "
                f"frames={len(self.frames)}, sets={len(self._sets)})")

    def __len__(self) -> int:
        """The number of frame sets."""
        return len(self._sets)

    @property
    def set_times(self) -> np.ndarray:
        """(sets,) float64 seconds: each frame set's latest capture time, in iteration order."""
        return np.array([time for _, time, _ in self._sets], dtype=np.float64)

    def joints_at(self, time: float) -> np.ndarray:
        """(n,) float64 joint positions at ``time`` (seconds), in :attr:`joint_names` order: linear interpolation
        between the two recorded joint states around it (the recorded values themselves at their times).

        Raises :class:`InputError` naming the time and the recorded span when ``time`` is outside it (nothing is
        extrapolated) or not finite.
        """
        time = self._check_time(time)
        times = self.joint_times
        i = int(np.searchsorted(times, time, side="right")) - 1
        if times[i] == time:
            return self.joint_positions[i].copy()
        w = (time - times[i]) / (times[i + 1] - times[i])
        return (1.0 - w) * self.joint_positions[i] + w * self.joint_positions[i + 1]

    def _check_time(self, time, camera: str | None = None, frame: int | None = None) -> float:
        if isinstance(time, bool) or not isinstance(time, (int, float, np.integer, np.floating)) or \
                not math.isfinite(float(time)):
            raise InputError(f"a time must be a finite number of seconds, got {short_repr(time)}", field="time")
        time = float(time)
        first, last = float(self.joint_times[0]), float(self.joint_times[-1])
        if not first <= time <= last:
            what = f"frame {frame} captured at {time!r} s" if frame is not None else f"time {time!r} s"
            raise InputError(f"{what} is outside the recorded joint states ({first!r} to {last!r} s); joints are "
                             "interpolated, never extrapolated", source=self._joints_source, camera=camera,
                             field="time")
        return time

    def __iter__(self) -> Iterator[FrameSet]:
        return self.frame_sets()

    def frame_sets(self) -> Iterator[FrameSet]:
        """The frame sets in capture-time order (each once its last frame has arrived): a generator of
        :class:`FrameSet`. Images are read as the sets are reached."""
        for frame, time, records, images in self._reader(self._sets):
            joints = {record.camera: self.joints_at(record.time) for record in records}
            yield FrameSet(frame=frame, time=time, images=images, joints=joints)


    def messages(self) -> Iterator[tuple]:
        """Every joint state and depth image in time order, as the live node receives them (design §12b):
        ``("joints", time, (n,) float64 in joint_names order)`` and ``("frame", time, DepthImage)``; a joint state
        comes before a frame of the same time. Images are read as they are reached."""
        buffered: dict[tuple[str, int], DepthImage] = {}
        sets = self._reader(self._sets)
        j = 0
        times = self.joint_times
        for record in self.frames:
            while j < len(times) and times[j] <= record.time:
                yield "joints", float(times[j]), self.joint_positions[j]
                j += 1
            key = (record.camera, record.frame)
            while key not in buffered:
                _, _, records, images = next(sets)
                buffered.update({(r.camera, r.frame): images[r.camera] for r in records})
            yield "frame", record.time, buffered.pop(key)
        while j < len(times):
            yield "joints", float(times[j]), self.joint_positions[j]
            j += 1


def open_recording(path, rig=None, *, replay: bool = False) -> Recording:
    """Open a recording: a recording folder (with ``frames.csv``), a rosbag2 folder (with ``metadata.yaml``) or a
    bare ``.mcap`` file (see the module docstring for the layouts).

    Args:
        path: the folder or file.
        rig: the rig, as a :class:`~depthguard.Rig` or a rig file; default: ``rig.yaml`` in the recording folder,
            in the bag folder, or beside the ``.mcap`` file.
        replay: open it for :meth:`Recording.messages` (``depthguard replay``, design §12b), as the live node
            takes its input: a camera whose camera_info disagrees with the rig is left out (``left_out`` names the
            field) rather than refused, and capture times outside the joint states are not refused (the frame-set
            loop counts a frame without joints near its stamp as blind).

    Raises :class:`InputError` (or :class:`~depthguard.RigError` for the rig file) naming the file, the camera and
    the field at fault.
    """
    path = check_path(path, "recording")
    if path.is_dir():
        if (path / "metadata.yaml").exists():
            return _open_bag(path, rig, folder=True, replay=replay)
        if (path / "frames.csv").exists():
            return _open_folder(path, rig, replay=replay)
        raise InputError("is neither a recording folder (no frames.csv) nor a rosbag2 folder (no metadata.yaml)",
                         source=str(path))
    if path.suffix.lower() == ".mcap":
        check_regular_file(path, what="MCAP bag", max_bytes=MAX_BAG_FILE_BYTES)
        return _open_bag(path, rig, folder=False, replay=replay)
    if not path.exists():
        raise InputError("no such recording (a recording folder, a rosbag2 folder or an .mcap file)",
                         source=str(path))
    raise InputError("not a recording: give a recording folder, a rosbag2 folder or an .mcap file",
                     source=str(path))


def _rig_of(rig, default: Path) -> Rig:
    if rig is None:
        return load_rig(default)
    if isinstance(rig, Rig):
        return rig
    return load_rig(check_path(rig, "rig file"))


# ------------------------------------------------------------------------------------------------ schedule


def _schedule(frames: tuple, camera_order: list) -> list:
    """The frame sets in answering order: [(frame number, latest time, records in rig camera order)], each set
    placed where its last record comes in ``frames`` (sorted by time)."""
    last_index: dict[int, int] = {}
    members: dict[int, list] = {}
    for i, record in enumerate(frames):
        last_index[record.frame] = i
        members.setdefault(record.frame, []).append(record)
    rank = {name: i for i, name in enumerate(camera_order)}
    out = []
    for frame in sorted(last_index, key=last_index.__getitem__):
        records = sorted(members[frame], key=lambda r: rank[r.camera])
        out.append((frame, frames[last_index[frame]].time, tuple(records)))
    return out


def _check_order(frames: list, source: str, what: str) -> None:
    """Per camera, capture times strictly increasing with the frame number."""
    by_camera: dict[str, list] = {}
    for record in frames:
        by_camera.setdefault(record.camera, []).append(record)
    for camera, records in by_camera.items():
        records.sort(key=lambda r: r.frame)
        for a, b in zip(records, records[1:]):
            if not b.time > a.time:
                raise InputError(f"capture times must increase with the frame number ({what}): frame {b.frame} at "
                                 f"{b.time!r} s is not after frame {a.frame} at {a.time!r} s", source=source,
                                 camera=camera, field="time")


def _check_cameras_present(rig: Rig, frames: list, source: str, where: str) -> None:
    seen = {record.camera for record in frames}
    for name in rig.cameras:
        if name not in seen:
            raise InputError(f"the rig's camera has no frames in {where}", source=source, camera=name,
                             field="camera")


# ------------------------------------------------------------------------------------------ recording folders


def _open_folder(path: Path, rig, replay: bool = False) -> Recording:
    rig = _rig_of(rig, path / "rig.yaml")
    frames_path = path / "frames.csv"
    frames = _read_frames_csv(frames_path, rig)
    if not frames:
        raise InputError("lists no frames (one row per depth image: camera,frame,time)", source=str(frames_path))
    _check_cameras_present(rig, frames, str(frames_path), "frames.csv")
    _check_order(frames, str(frames_path), "frames.csv")
    files = {}
    for record in frames:  # every frame file present, before any replay starts
        file = path / "depth" / record.camera / f"{record.frame:06d}.png"
        files[(record.camera, record.frame)] = check_regular_file(
            file, what="depth image (listed in frames.csv)", max_bytes=config.MAX_DEPTH_FILE_BYTES,
            error=DepthImageError, camera=record.camera)
    joints_path = path / "joint_states.csv"
    names, times, positions = read_joint_states_csv(joints_path)
    frames.sort(key=lambda r: r.time)  # stable: rows of one time keep their order

    def read(sets):
        cameras = rig.cameras
        for frame, time, records in sets:
            data = {r.camera: load_depth(files[(r.camera, r.frame)], cameras[r.camera], timestamp=r.time)
                    for r in records}
            yield frame, time, records, data

    return Recording(path, "folder", rig, names, times, positions, frames, str(joints_path), read, replay=replay)


def _read_frames_csv(path: Path, rig: Rig) -> list[FrameRecord]:
    text = read_text(path, what="frames file", max_bytes=MAX_CSV_BYTES)
    header, rows = csv_table(text, source=path)
    for name in ("camera", "frame", "time"):
        if header.count(name) != 1:
            raise InputError(f"line 1: the header must name each of the columns camera, frame, time once, got "
                             f"{short_repr(header, 80)}", source=str(path), field=name)
    col = {name: header.index(name) for name in ("camera", "frame", "time")}
    frames, seen = [], {}
    for line, row in rows:
        cells = {name: row[c].strip() for name, c in col.items()}
        camera = cells["camera"]
        if camera not in rig.cameras:
            raise InputError(f"line {line}: no such camera in the rig (cameras: {', '.join(rig.cameras)})",
                             source=str(path), camera=camera if len(camera) <= 40 else camera[:37] + "...",
                             field="camera")
        if not _WHOLE.fullmatch(cells["frame"]) or int(cells["frame"]) > MAX_FRAME_NUMBER:
            raise InputError(f"line {line}: a frame number must be a whole number in [0, {MAX_FRAME_NUMBER}], got "
                             f"{short_repr(cells['frame'])}", source=str(path), camera=camera, field="frame")
        frame = int(cells["frame"])
        time = _finite(cells["time"], f"line {line}: a capture time", path, camera=camera, field="time")
        if (camera, frame) in seen:
            raise InputError(f"line {line}: frame {frame} is listed twice (also on line {seen[(camera, frame)]})",
                             source=str(path), camera=camera, field="frame")
        seen[(camera, frame)] = line
        frames.append(FrameRecord(camera, frame, time))
    return frames


def read_joint_states_csv(path: Path):
    """(names, (k,) times, (k, n) positions) from joint_states.csv."""
    text = read_text(path, what="joint states file", max_bytes=MAX_CSV_BYTES)
    header, rows = csv_table(text, source=path)
    if not header or header[0] != "time":
        raise InputError(f"line 1: the header must be time,<joint name>,..., got {short_repr(header, 80)}",
                         source=str(path), field="time")
    names = header[1:]
    if not names or any(not name for name in names):
        raise InputError(f"line 1: the header must name every joint column after time, got "
                         f"{short_repr(header, 80)}", source=str(path), field="joints")
    repeated = sorted({name for name in names if names.count(name) > 1})
    if repeated:
        raise InputError(f"line 1: joint column named twice: {', '.join(repeated)}", source=str(path),
                         field=repeated[0])
    if not rows:
        raise InputError("holds no joint states (one row per time: time,<joint values>)", source=str(path))
    times = np.empty(len(rows))
    positions = np.empty((len(rows), len(names)))
    for i, (line, row) in enumerate(rows):
        times[i] = _finite(row[0], f"line {line}: a time", path, field="time")
        for j, name in enumerate(names):
            positions[i, j] = _finite(row[j + 1], f"line {line}: a joint value", path, field=name)
        if i and not times[i] > times[i - 1]:
            raise InputError(f"line {line}: times must increase from row to row ({float(times[i])!r} s follows "
                             f"{float(times[i - 1])!r} s)", source=str(path), field="time")
    return names, times, positions


def _finite(text: str, what: str, path: Path, **context) -> float:
    text = text.strip()
    value = float(text) if _NUMBER.fullmatch(text) else math.nan
    if not math.isfinite(value):
        raise InputError(f"{what} must be a finite decimal number, got {short_repr(text)}", source=str(path),
                         **context)
    return value


# ------------------------------------------------------------------------------------------------------ bags


class _Bag:
    """A rosbag2 folder or a bare MCAP file, opened for one pass: ``connections``, ``messages(connections)`` ->
    (connection, log time ns, raw bytes), ``deserialize(raw, msgtype)``. Every failure of the bag library is an
    :class:`InputError` naming the bag."""

    def __init__(self, path: Path, folder: bool):
        self.path = path
        self.folder = folder
        self._reader = None

    def __enter__(self) -> "_Bag":
        with self.errors():
            if self.folder:
                from rosbags.highlevel import AnyReader

                self._reader = AnyReader([self.path], default_typestore=ros_typestore())
                self._reader.open()
                self.connections = list(self._reader.connections)
                self.deserialize = self._reader.deserialize
            else:
                from rosbags.rosbag2.storage_mcap import McapReader

                store = ros_typestore()
                self._reader = McapReader(self.path)
                self._reader.open()
                self.connections = list(self._reader.connections)
                self.deserialize = store.deserialize_cdr
        return self

    def __exit__(self, *exc) -> None:
        if self._reader is not None:
            try:
                self._reader.close()
            except Exception:  # noqa: BLE001 - closing a broken bag must not hide the first error
                pass
            self._reader = None

    def messages(self, connections):
        with self.errors():
            yield from self._reader.messages(connections=connections) if self.folder else \
                self._reader.messages(connections)

    def errors(self):
        return _BagErrors(self.path)


class _BagErrors:
    """Context manager: an exception of the bag library (a corrupt or truncated bag, an unknown message type)
    becomes an InputError naming the bag; depthguard's own errors pass through."""

    def __init__(self, path: Path):
        self.path = path

    def __enter__(self):
        return self

    def __exit__(self, kind, exc, tb):
        if exc is None or isinstance(exc, (DepthguardError, GeneratorExit)) or not isinstance(exc, Exception):
            return False
        reason = " ".join(str(exc).split())[:200] or type(exc).__name__
        raise InputError(f"not a readable ROS 2 bag ({type(exc).__name__}: {reason})", source=str(self.path)) \
            from None


def _check_bag_files(path: Path) -> None:
    """metadata.yaml and every storage file it lists: regular files within bounds (rosbags opens them itself)."""
    meta_path = path / "metadata.yaml"
    text = read_text(meta_path, what="rosbag2 metadata", max_bytes=config.MAX_TEXT_FILE_BYTES)
    meta = load_yaml(text, source=meta_path)
    info = meta.get("rosbag2_bagfile_information") if isinstance(meta, dict) else None
    files = info.get("relative_file_paths") if isinstance(info, dict) else None
    if not isinstance(files, list) or not files or not all(isinstance(f, str) and f for f in files):
        raise InputError("not rosbag2 metadata: rosbag2_bagfile_information.relative_file_paths must list the "
                         "bag's storage files", source=str(meta_path), field="relative_file_paths")
    for name in files:
        check_regular_file(path / Path(name).name, what="bag storage file", max_bytes=MAX_BAG_FILE_BYTES)


def _open_bag(path: Path, rig, folder: bool, replay: bool = False) -> Recording:
    if folder:
        _check_bag_files(path)
    rig = _rig_of(rig, (path if folder else path.parent) / "rig.yaml")
    source = str(path)
    topics: dict[str, dict[str, object]] = {}  # camera -> {"image_raw": connection, "camera_info": connection}
    joints_connection = None
    with _Bag(path, folder) as bag:
        for connection in bag.connections:
            match = _CAMERA_TOPIC.fullmatch(connection.topic)
            if connection.topic == JOINT_STATES_TOPIC:
                _check_type(connection, JOINT_STATE, source)
                joints_connection = connection
            elif match:
                kind = match["kind"]
                _check_type(connection, IMAGE if kind == "image_raw" else CAMERA_INFO, source)
                camera = match["camera"]
                if camera not in rig.cameras:
                    raise InputError(f"topic {connection.topic} is of a camera the rig lacks (cameras: "
                                     f"{', '.join(rig.cameras)})", source=source, camera=camera, field="topic")
                topics.setdefault(camera, {})[kind] = connection
        for name in rig.cameras:
            for kind in ("image_raw", "camera_info"):
                if kind not in topics.get(name, {}):
                    msgtype = IMAGE if kind == "image_raw" else CAMERA_INFO
                    raise InputError(f"the bag has no topic /{name}/depth/{kind} ({msgtype})", source=source,
                                     camera=name, field="topic")
        if joints_connection is None:
            raise InputError(f"the bag has no topic {JOINT_STATES_TOPIC} ({JOINT_STATE})", source=source,
                             field="topic")
        image_cameras = {topics[name]["image_raw"].id: name for name in rig.cameras}
        info_cameras = {topics[name]["camera_info"].id: name for name in rig.cameras}
        wanted = [joints_connection] + [topics[n][k] for n in rig.cameras for k in ("image_raw", "camera_info")]
        frames: list[FrameRecord] = []
        left_out: dict[str, str] = {}  # replay: camera -> why its camera_info leaves it out
        counts = {name: 0 for name in rig.cameras}
        joint_names, joint_times, joint_rows = None, [], []
        for connection, _, raw in bag.messages(wanted):
            with bag.errors():
                message = bag.deserialize(raw, connection.msgtype)
            if connection.id in image_cameras:
                camera = image_cameras[connection.id]
                image_array(message, rig.cameras[camera], source, counts[camera], check_only=True)
                frames.append(FrameRecord(camera, counts[camera], header_seconds(message, source, camera, counts[camera])))
                counts[camera] += 1
            elif connection.id in info_cameras:
                camera = info_cameras[connection.id]
                try:
                    check_camera_info(message, rig.cameras[camera], source)
                except InputError as exc:
                    if not replay:
                        raise
                    left_out.setdefault(camera, str(exc))
            else:
                index = len(joint_times)
                names, values = joint_state(message, source, index)
                if joint_names is None:
                    joint_names = names
                elif set(names) != set(joint_names) or len(names) != len(joint_names):
                    raise InputError(f"joint state #{index} names the joints {', '.join(names)}, the first one "
                                     f"{', '.join(joint_names)}", source=source, field="name")
                else:
                    order = [names.index(n) for n in joint_names]
                    values = values[order]
                time = header_seconds(message, source, None, index, what="joint state")
                if joint_times and not time > joint_times[-1]:
                    raise InputError(f"joint state #{index} at {time!r} s does not come after the previous one at "
                                     f"{joint_times[-1]!r} s (header stamps must increase)", source=source,
                                     field="header.stamp")
                joint_times.append(time)
                joint_rows.append(values)
    for name in rig.cameras:
        if counts[name] == 0:
            raise InputError(f"topic /{name}/depth/image_raw holds no images", source=source, camera=name,
                             field="topic")
    if not joint_times:
        raise InputError(f"topic {JOINT_STATES_TOPIC} holds no joint states", source=source, field="topic")
    _check_order(frames, source, "header stamps in bag order")
    frames.sort(key=lambda r: r.time)

    def read(sets):
        # Stream the images in bag order; keep each until its set is answered (sets come in capture-time order,
        # which a bag written by time keeps: few images wait).
        pending: dict[tuple[str, int], DepthImage] = {}
        queue = iter(sets)
        current = next(queue, None)
        counts = {name: 0 for name in rig.cameras}
        with _Bag(path, folder) as bag:
            # This reader's own connections (a connection belongs to the reader that opened it).
            cameras = {f"/{name}/depth/image_raw": name for name in rig.cameras}
            connections = [c for c in bag.connections if c.topic in cameras and c.msgtype == IMAGE]
            for connection, _, raw in bag.messages(connections):
                camera = cameras[connection.topic]
                index = counts[camera]
                counts[camera] += 1
                with bag.errors():
                    message = bag.deserialize(raw, connection.msgtype)
                data = image_array(message, rig.cameras[camera], source, index)
                time = header_seconds(message, source, camera, index)
                pending[(camera, index)] = depth_image(data, rig.cameras[camera], timestamp=time)
                while current is not None and all((r.camera, r.frame) in pending for r in current[2]):
                    frame, set_time, records = current
                    yield frame, set_time, records, {r.camera: pending.pop((r.camera, r.frame)) for r in records}
                    current = next(queue, None)
        if current is not None:
            raise InputError(f"the bag changed while it was read: frame {current[0]} is incomplete", source=source)

    return Recording(path, "bag", rig, joint_names, joint_times, np.array(joint_rows), frames,
                     f"{source} {JOINT_STATES_TOPIC}", read, replay=replay, left_out=left_out)


def _check_type(connection, msgtype: str, source: str) -> None:
    if connection.msgtype != msgtype:
        raise InputError(f"topic {connection.topic} holds {connection.msgtype}, expected {msgtype}", source=source,
                         field="topic")


# ------------------------------------------------------------------------------------------------ writing bags


def write_bag(recording: Recording, path, storage: str = "mcap") -> Path:
    """Write ``recording`` as a ROS 2 bag (the layout of the module docstring) in the new folder ``path``, with
    the rig as ``rig.yaml`` beside the bag's files; returns ``path`` as a Path.

    Every depth image goes to ``/<camera>/depth/image_raw`` (``16UC1``, or ``32FC1`` for float images) with a
    ``/<camera>/depth/camera_info`` (frame_id ``<camera>_optical_frame``) of the same stamp, and every recorded
    joint state to ``/joint_states``. Stamps and log times are the capture times rounded to nanoseconds (the
    shortest decimal of each time, rounded: a time written with 6 decimals reads back as the same float).

    ``storage``: ``"mcap"`` or ``"sqlite3"``. Raises :class:`InputError` if ``path`` exists or a time is negative or
    beyond a ROS time (2**31 s). The folder appears whole or not at all (:func:`depthguard.io.files.atomic_folder`).
    """
    from rosbags.rosbag2 import Writer
    from rosbags.rosbag2.enums import StoragePlugin

    if not isinstance(recording, Recording):
        raise InputError(f"write_bag needs a Recording (open_recording), got {type(recording).__name__}",
                         field="recording")
    plugins = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
    if not isinstance(storage, str) or storage not in plugins:
        raise InputError(f"storage must be one of {tuple(plugins)}, got {short_repr(storage)}", field="storage")
    path = check_path(path, "bag folder")
    if path.exists() or path.is_symlink():
        raise InputError("exists already; a bag is written into a new folder", source=str(path))
    store = ros_typestore()
    rig = recording.rig
    joint_ns = [ros_nanoseconds(t, "joint state time") for t in recording.joint_times]
    names = list(recording.joint_names)
    try:
        # Written beside path and renamed: the bag appears whole, rig.yaml included, or not at all.
        with atomic_folder(path) as folder, Writer(folder, version=Writer.VERSION_LATEST,
                                                   storage_plugin=plugins[storage]) as writer:
            save_rig(rig, folder / "rig.yaml")
            joints_out = writer.add_connection(JOINT_STATES_TOPIC, JOINT_STATE, typestore=store)
            images_out = {n: writer.add_connection(f"/{n}/depth/image_raw", IMAGE, typestore=store)
                          for n in rig.cameras}
            infos_out = {n: writer.add_connection(f"/{n}/depth/camera_info", CAMERA_INFO, typestore=store)
                         for n in rig.cameras}
            written = 0

            def joints_until(ns_limit):
                nonlocal written
                while written < len(joint_ns) and joint_ns[written] <= ns_limit:
                    ns = joint_ns[written]
                    message = joint_state_message(store, ns, names, recording.joint_positions[written])
                    writer.write(joints_out, ns, store.serialize_cdr(message, JOINT_STATE))
                    written += 1

            for frame_set in recording.frame_sets():
                joints_until(ros_nanoseconds(frame_set.time, "capture time"))
                for name, image in frame_set.images.items():
                    ns = ros_nanoseconds(image.timestamp, "capture time")
                    info, message = depth_messages(store, ns, rig.cameras[name], image.data)
                    writer.write(infos_out[name], ns, store.serialize_cdr(info, CAMERA_INFO))
                    writer.write(images_out[name], ns, store.serialize_cdr(message, IMAGE))
            joints_until(math.inf)
    except DepthguardError:
        raise
    except Exception as exc:  # noqa: BLE001 - the bag library's errors, named with the bag
        reason = " ".join(str(exc).split())[:200] or type(exc).__name__
        raise InputError(f"cannot write the bag ({type(exc).__name__}: {reason})", source=str(path)) from None
    return path


