"""Every file depthguard writes is whole or absent (``depthguard.io.files.atomic_write``): a writer stopped part way (a
kill, a full disk, an exception) leaves the older file or none, never a shorter file that loads as valid, and no
leftover under a name that a reader looks for.

A stop is simulated by letting the file take only part of its bytes and then raising (or killing the process),
at several cut points, including one byte short of the whole file."""

from __future__ import annotations

import glob
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import depthguard as dg
from depthguard.io import files as io_files
from depthguard.cameras import NoiseModel
from depthguard.depth import write_depth_pgm, write_depth_png
from depthguard.depthgrid import build_map, load_map, save_map
from depthguard.errors import InputError, RigError
from depthguard.io.recordings import open_recording, write_bag
from depthguard_lab.simulation import _episode, load_workcell, save_workcell, workcell_from_dict, write_episode
from depthguard.transforms import look_at


class Stopped(Exception):
    """The writer stopping part way through a file."""


class CutFile:
    """A file that takes ``budget`` bytes, writes them, and raises ``error`` (default :class:`Stopped`) at the write
    that goes past."""

    def __init__(self, file, budget: int, error: BaseException | type[BaseException] = Stopped):
        self._file = file
        self._left = budget
        self._error = error

    def write(self, data):
        if len(data) > self._left:
            self._file.write(data[:self._left])
            self._file.flush()
            raise self._error
        self._left -= len(data)
        return self._file.write(data)

    def __getattr__(self, name):
        return getattr(self._file, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return self._file.__exit__(*exc)


def stop_writes_after(monkeypatch, budget: int) -> None:
    """From now on, every file depthguard opens for writing stops after ``budget`` bytes (characters for text)."""
    def cut_open(path, mode="r", *args, **kwargs):
        file = open(path, mode, *args, **kwargs)
        return CutFile(file, budget) if "x" in mode or "w" in mode else file

    monkeypatch.setattr(io_files, "open", cut_open, raising=False)


def rig_of(n: int, a: float = 0.001) -> dg.Rig:
    """``n`` 8x6 cameras round the origin, with noise coefficient ``a``."""
    cameras = {}
    for i in range(n):
        angle = 2 * np.pi * i / n
        eye = [2.0 * np.cos(angle), 2.0 * np.sin(angle), 1.5]
        cameras[f"cam{i}"] = dg.PinholeCamera(f"cam{i}", 8, 6, 7.0, 7.0, 3.5, 2.5, look_at(eye, [0, 0, 0.6]),
                                              depth_range=(0.3, 6.0), noise=NoiseModel(a=a))
    return dg.Rig(cameras, principal="cam0")


def cut_points(size: int) -> list[int]:
    return sorted({0, 1, size // 3, size // 2, size - 1})


def files_in(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


# --------------------------------------------------------------------------------------------------------------------
# the helper


def test_atomic_write_keeps_the_older_file_or_none(tmp_path):
    path = tmp_path / "a.txt"
    with pytest.raises(Stopped):
        with io_files.atomic_write(path) as f:
            f.write("half of it")
            raise Stopped
    assert files_in(tmp_path) == []
    io_files.write_whole(path, "older")
    with pytest.raises(Stopped):
        with io_files.atomic_write(path, "wb") as f:
            f.write(b"newer, ")
            raise Stopped
    assert path.read_text() == "older" and files_in(tmp_path) == ["a.txt"]
    io_files.write_whole(path, b"newer")
    assert path.read_bytes() == b"newer" and files_in(tmp_path) == ["a.txt"]


def test_atomic_write_errors_name_the_file_asked_for(tmp_path):
    import errno

    from depthguard.errors import WriteError

    with pytest.raises(WriteError) as info:
        io_files.write_whole(tmp_path / "no" / "such.yaml", "x")
    assert info.value.filename == str(tmp_path / "no" / "such.yaml") and info.value.errno == errno.ENOENT
    assert str(info.value) == f"{tmp_path / 'no' / 'such.yaml'}: could not be written: No such file or directory"
    (tmp_path / "folder").mkdir()
    with pytest.raises(OSError) as info:  # a WriteError is an OSError too
        io_files.write_whole(tmp_path / "folder", "x")
    assert info.value.filename == str(tmp_path / "folder") and files_in(tmp_path) == ["folder"]
    assert info.value.errno == errno.EISDIR and "could not be written" in str(info.value)
    with pytest.raises(ValueError):
        with io_files.atomic_write(tmp_path / "a", "a"):
            pass


def test_the_temporary_file_is_hidden_and_matches_no_name_a_reader_looks_for(tmp_path):
    path = tmp_path / "000001.png"
    with io_files.atomic_write(path, "wb") as f, io_files.atomic_write(path, "wb") as g:
        f.write(b"f")
        g.write(b"g")
        names = sorted(p.name for p in tmp_path.iterdir())
        assert len(names) == 2, names  # two writers of one file (two threads) do not share a temporary file
        for name in names:
            assert name.startswith(".000001.png.") and name.endswith(".partial"), name
        assert list(tmp_path.glob("*.png")) == [] and glob.glob(str(tmp_path / "*")) == []  # a shell glob: no hidden
    assert files_in(tmp_path) == ["000001.png"] and path.read_bytes() == b"f"  # the last one renamed wins


# --------------------------------------------------------------------------------------------------------------------
# the rig


def test_a_stopped_save_rig_never_leaves_a_rig_with_fewer_cameras(tmp_path, monkeypatch):
    """The review's case: a rig file cut short used to load as a valid rig with a camera fewer, or a noise
    coefficient cut short. Cut at any point, the file is the older rig, or absent."""
    older, newer = rig_of(3, a=0.001), rig_of(4, a=0.0012345678)
    path = tmp_path / "rig.yaml"
    dg.save_rig(newer, tmp_path / "whole.yaml")
    size = len((tmp_path / "whole.yaml").read_text())
    (tmp_path / "whole.yaml").unlink()
    for budget in cut_points(size):
        with monkeypatch.context() as patch:
            stop_writes_after(patch, budget)
            with pytest.raises(Stopped):
                dg.save_rig(newer, path)
        assert files_in(tmp_path) == []
        with pytest.raises(RigError):
            dg.load_rig(path)
        dg.save_rig(older, path)
        with monkeypatch.context() as patch:
            stop_writes_after(patch, budget)
            with pytest.raises(Stopped):
                dg.save_rig(newer, path)
        assert files_in(tmp_path) == ["rig.yaml"]
        assert dg.load_rig(path).fingerprint() == older.fingerprint()
        path.unlink()
    dg.save_rig(newer, path)
    assert dg.load_rig(path).fingerprint() == newer.fingerprint()


# Writes the rig of argv[2] to argv[1] in a process whose files may hold at most argv[3] bytes: a write past that
# kills it (SIGXFSZ), or with argv[4] == "error" fails (OSError EFBIG, as a full disk would).
LIMITED_WRITER = r"""
import resource, signal, sys
import depthguard as dg

path, rig, limit, how = sys.argv[1], dg.load_rig(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
if how == "killed":
    signal.signal(signal.SIGXFSZ, signal.SIG_DFL)  # Python ignores it, to raise EFBIG instead
resource.setrlimit(resource.RLIMIT_FSIZE, (limit, resource.RLIM_INFINITY))
dg.save_rig(rig, path)
"""


@pytest.mark.parametrize("how", ["killed", "error"])
def test_a_process_stopped_while_it_writes_the_rig_leaves_the_older_rig(how, tmp_path):
    """A real stop, with no stand-in for depthguard's code: the process may write only half the new rig."""
    folder = tmp_path / "rigs"
    folder.mkdir()
    older, newer = rig_of(3), rig_of(4, a=0.0012345678)
    path = folder / "rig.yaml"
    dg.save_rig(older, path)
    dg.save_rig(newer, tmp_path / "newer.yaml")
    limit = (tmp_path / "newer.yaml").stat().st_size // 2
    done = subprocess.run([sys.executable, "-c", LIMITED_WRITER, str(path), str(tmp_path / "newer.yaml"), str(limit),
                           how], capture_output=True, text=True, timeout=120, cwd=tmp_path,
                          env=dict(os.environ, PYTHONDONTWRITEBYTECODE="1"))
    if how == "killed":
        assert done.returncode == -signal.SIGXFSZ, done.stderr
    else:
        assert done.returncode == 1 and "File too large" in done.stderr, done.stderr
    assert dg.load_rig(path).fingerprint() == older.fingerprint()
    leftovers = [name for name in files_in(folder) if name != "rig.yaml"]
    if how == "killed":  # a killed process cannot clean up: its temporary file keeps a name no reader looks for
        assert len(leftovers) == 1 and leftovers[0].startswith(".rig.yaml.") and leftovers[0].endswith(".partial")
        assert (folder / leftovers[0]).stat().st_size == limit
    else:
        assert leftovers == []


# --------------------------------------------------------------------------------------------------------------------
# the other files, each cut at several points


def _map_writer():
    rig = rig_of(2)
    grid = build_map(rig, "cam0", d_min=0.5, delta_d=0.05, n_cells=20)
    return lambda path: save_map(grid, path), lambda path: load_map(path, rig).corners


def _workcell_writer():
    wc = workcell_from_dict({
        "duration": 0.1, "rate": 30,
        "cameras": [{"name": "cam", "width": 16, "height": 12, "fx": 13.0, "fy": 13.0, "cx": 7.5, "cy": 5.5,
                     "look_at": {"eye": [0.0, 3.0, 1.0], "target": [0.0, 6.0, 1.0]}, "depth_range": [0.5, 4.5]}],
        "robot": {"model": "iiwa", "trajectory": {"type": "joints", "waypoints": [{"time": 0.0, "joints": [0.0] * 7}]}},
        "static_objects": [{"name": "wall", "box": {"center": [0.0, 5.0, 1.0], "size": [8.0, 0.1, 8.0]}}],
    })
    return lambda path: save_workcell(wc, path), lambda path: load_workcell(path).scene


DEPTH = np.arange(48, dtype=np.uint16).reshape(6, 8) * 100 + 500
CAMERA = rig_of(1).cameras["cam0"]
WRITERS = {
    "depth png": lambda: (lambda path: write_depth_png(path, DEPTH), lambda path: dg.load_depth(path, CAMERA).data),
    "depth pgm": lambda: (lambda path: write_depth_pgm(path, DEPTH), lambda path: dg.load_depth(path, CAMERA).data),
    "depth grid map": _map_writer,
    "scene": _workcell_writer,
}
SUFFIXES = {"depth png": ".png", "depth pgm": ".pgm", "depth grid map": ".npz", "scene": ".yaml"}


@pytest.mark.parametrize("kind", list(WRITERS))
def test_a_stopped_writer_leaves_the_older_file_or_none(kind, tmp_path, monkeypatch):
    write, load = WRITERS[kind]()
    path = tmp_path / f"file{SUFFIXES[kind]}"
    write(path)
    expected = load(path)
    older = path.read_bytes()
    for budget in cut_points(len(older)):
        with monkeypatch.context() as patch:
            stop_writes_after(patch, budget)
            with pytest.raises(Stopped):
                write(path)
        assert path.read_bytes() == older and files_in(tmp_path) == [path.name]
    path.unlink()
    with monkeypatch.context() as patch:
        stop_writes_after(patch, len(older) // 2)
        with pytest.raises(Stopped):
            write(path)
    assert files_in(tmp_path) == []
    write(path)
    assert np.array_equal(load(path), expected) if isinstance(expected, np.ndarray) else load(path) == expected


# --------------------------------------------------------------------------------------------------------------------
# folders: a simulated episode, a bag


def tiny_workcell():
    return workcell_from_dict({
        "duration": 0.1, "rate": 30,
        "cameras": [{"name": "cam", "width": 32, "height": 24, "fx": 26.25, "fy": 26.25, "cx": 15.5, "cy": 11.5,
                     "look_at": {"eye": [0.0, 3.0, 1.0], "target": [0.0, 6.0, 1.0]}, "depth_range": [0.5, 4.5]}],
        "robot": {"model": "iiwa", "trajectory": {"type": "joints", "waypoints": [{"time": 0.0, "joints": [0.0] * 7}]}},
        "static_objects": [{"name": "wall", "box": {"center": [0.0, 5.0, 1.0], "size": [8.0, 0.1, 8.0]}}],
    })


def test_an_episode_stopped_part_way_has_no_frames_csv_and_is_refused(tmp_path, monkeypatch):
    """frames.csv is written last: an episode stopped part way (here at its third frame) is refused as a recording,
    even in a folder that held a complete episode before; no temporary file is left."""
    wc = tiny_workcell()
    out = tmp_path / "episode"
    real_simulate = _episode.simulate

    def stopping(*args, **kwargs):
        for k, frame in enumerate(real_simulate(*args, **kwargs)):
            if k == 2:
                raise Stopped
            yield frame

    def stopped_episode():
        with monkeypatch.context() as patch:
            patch.setattr(_episode, "simulate", stopping)
            with pytest.raises(Stopped):
                write_episode(wc, out, seed=1, progress=False)
        names = files_in(out)
        assert "frames.csv" not in names and not [name for name in names if name.endswith(".partial")], names
        with pytest.raises(InputError, match="no frames.csv"):
            open_recording(out)
        return names

    names = stopped_episode()
    assert {"rig.yaml", "scene.yaml", "timeline.csv", "depth/cam/000001.png"} <= set(names)
    assert "joint_states.csv" not in names and "ground_truth.csv" not in names
    write_episode(wc, out, seed=1, progress=False)
    assert len(open_recording(out)) == wc.n_frames
    stopped_episode()
    write_episode(wc, out, seed=1, progress=False)
    assert len(open_recording(out)) == wc.n_frames


def test_a_bag_stopped_part_way_leaves_no_folder(tmp_path, monkeypatch):
    wc = tiny_workcell()
    episode = write_episode(wc, tmp_path / "episode", seed=1, progress=False)
    recording = open_recording(episode)
    import depthguard.io.recordings as recordings

    real_messages = recordings.depth_messages
    calls = []

    def stopping(*args):
        calls.append(1)
        if len(calls) == 2:
            raise Stopped
        return real_messages(*args)

    monkeypatch.setattr(recordings, "depth_messages", stopping)
    with pytest.raises(InputError, match="cannot write the bag"):
        write_bag(recording, tmp_path / "out" / "bag")
    assert files_in(tmp_path / "out") == []
    monkeypatch.setattr(recordings, "depth_messages", real_messages)
    bag = write_bag(recording, tmp_path / "out" / "bag")
    assert [name for name in files_in(tmp_path / "out") if "/" not in name] == ["bag"]
    assert {"bag/metadata.yaml", "bag/rig.yaml"} <= set(files_in(tmp_path / "out"))
    assert len(open_recording(bag)) == len(recording)
