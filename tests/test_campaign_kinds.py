"""Campaign (issue 37): the four kinds of bad input a second campaign found that no fix had generalised to, each
tested as a kind, with hypothesis, through the one place that now decides it (docs/bad-input.md):

1. **Numbers beyond a float** (``validation.NOT_A_NUMBER``, ``check_real``): any integer whose magnitude no float
   holds, given to any numeric parameter of the API's entries below (introspected where the entry has defaults), a
   rig's, a points file's, a scene file's number: a :class:`DepthguardError` naming the field, never OverflowError.
2. **Writes that fail** (``io.files.write_error``, ``atomic_write``, ``named_stdout``): any OS error at any stage of
   writing a file (opening, writing, flushing to disk, renaming) is a :class:`WriteError` whose one-line message names
   the file asked for and says it could not be written; the older file stays, and nothing is left beside it.
   Standard output on ``/dev/full`` or a closed pipe ends with exit status 2 and one line naming standard output.
3. **Tables with a wrong shape** (``io.files.csv_table``): any CSV row with more or fewer fields than its header is
   refused naming the file and the line; a file name holding line breaks or other control characters still gives a
   one-line message (``errors.one_line``).
4. **Array sizes** (``validation.check_count``): any number of control points beyond ``config.MAX_QUERY_POINTS``,
   given to any API entry that takes points, is refused naming the limit before anything is allocated (the arrays
   here are zero-stride views: a 10-million-point array costs no memory).

Rule for every example: the DepthguardError (or exit 2 and one line) the kind promises; any other exception, or an
accepted input, is a violation (counted by ``campaign_support.record``).
"""

from __future__ import annotations

import errno
import inspect
import os
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import depthguard as dg
from campaign_support import DEPTHGUARD_EXE, campaign, record, surveyed, violation
from depthguard import config
from depthguard.errors import DepthguardError, WriteError
from depthguard.io import files as io_files
from depthguard.transforms import look_at
from test_atomic_writes import CutFile

# ------------------------------------------------------------------------------------------------------ the world


def _camera(name="c", eye=(0.0, 0.0, 2.0)):
    return dg.PinholeCamera(name, 64, 48, 50.0, 50.0, 31.5, 23.5, look_at(list(eye), [0, 0, 0], up=(0, 1, 0)),
                            depth_range=(0.3, 4.0))


CAMERA = _camera("p")
RIG = dg.Rig({"p": CAMERA, "s": _camera("s", (1.5, 0.0, 2.0))}, principal="p",
             workspace=[[-1.0, -1.0, 0.0], [1.0, 1.0, 1.5]])
IMAGES = {name: dg.depth_image(np.full((48, 64), 2.0, np.float32), camera, timestamp=1.0)
          for name, camera in RIG.cameras.items()}


def _numeric_defaults(callable_) -> list[str]:
    """The parameters of ``callable_`` whose default is a number (not a bool)."""
    return [name for name, p in inspect.signature(callable_).parameters.items()
            if isinstance(p.default, (int, float)) and not isinstance(p.default, bool)]


def _camera_with(field):
    def make(value):
        kwargs = dict(name="c", width=64, height=48, fx=50.0, fy=50.0, cx=31.5, cy=23.5,
                      T_world_camera=CAMERA.T_world_camera)
        kwargs[field] = value
        return dg.PinholeCamera(**kwargs)
    return make


def _entries() -> dict:
    """label -> (function of the number, the field its error must name)."""
    from depthguard.avoidance import AvoidanceParams, SSMParams
    from depthguard.depthgrid import build_map
    from depthguard.freespace import FreeSpaceMemory, VoxelBox

    out = {}
    for name in _numeric_defaults(dg.DistanceMonitor) + _numeric_defaults(dg.MonitorSettings):
        out[f"DistanceMonitor({name}=)"] = (lambda v, n=name: dg.DistanceMonitor(RIG, **{n: v}), name)
    for cls in (AvoidanceParams, SSMParams):
        for name in _numeric_defaults(cls):
            out[f"{cls.__name__}({name}=)"] = (lambda v, c=cls, n=name: c(**{n: v}), name)
    for field in ("fx", "fy", "cx", "cy", "width", "height"):
        out[f"PinholeCamera({field}=)"] = (_camera_with(field), field)
    out["PinholeCamera(depth_range=)"] = (lambda v: CAMERA.replace(depth_range=(0.3, v)), "depth_range")
    out["PinholeCamera(T_world_camera=)"] = (
        lambda v: CAMERA.replace(T_world_camera=[[1, 0, 0, v], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]),
        "T_world_camera")
    out["Rig(workspace=)"] = (lambda v: dg.Rig(dict(RIG.cameras), workspace=[[0, 0, 0], [1, 1, v]]), "workspace")
    out["depth_image(timestamp=)"] = (lambda v: dg.depth_image(IMAGES["p"].data, CAMERA, timestamp=v), "timestamp")
    out["query(a DepthImage's depth_scale)"] = (
        lambda v: dg.DistanceMonitor(RIG).query({**IMAGES, "p": dg.DepthImage("p", IMAGES["p"].data, v, 1.0)},
                                                [[0, 0, 0.5]], now=1.0), "depth_scale")
    out["query(now=)"] = (lambda v: dg.DistanceMonitor(RIG).query(IMAGES, [[0, 0, 0.5]], now=v), "now")
    out["query(points)"] = (lambda v: dg.DistanceMonitor(RIG).query(IMAGES, [[0, 0, v]], now=1.0), "points")
    out["single_camera_distances(rho=)"] = (
        lambda v: dg.single_camera_distances(dg.prepare_depth(IMAGES["p"], CAMERA), [[0, 0, 0.5]], rho=v), "rho")
    for name in ("d_min", "d_max", "delta_d", "n_cells"):
        out[f"build_map({name}=)"] = (lambda v, n=name: build_map(RIG, "p", **{n: v}), name)
    out["VoxelBox(voxel)"] = (lambda v: VoxelBox([0, 0, 0], [1, 1, 1], v), "voxel")
    out["FreeSpaceMemory(v_max)"] = (lambda v: FreeSpaceMemory(VoxelBox([0, 0, 0], [1, 1, 1], 0.1), v), "v_max")
    return out


ENTRIES = _entries()


def beyond_a_float():
    """Any integer no float holds: from 2**1024 to about 4,300 digits (where Python stops printing them), either
    sign."""
    big = st.integers(min_value=2**1024, max_value=10**4200)
    return st.one_of(big, big.map(lambda n: -n))


# -------------------------------------------------------------------------------------- 1. numbers beyond a float

@campaign(120)
@given(entry=st.sampled_from(sorted(ENTRIES)), value=beyond_a_float())
@surveyed
def test_any_integer_beyond_a_float_is_named_wherever_a_number_enters_the_api(entry, value):
    call, field = ENTRIES[entry]
    try:
        call(value)
    except DepthguardError as exc:
        message = str(exc)
        if field not in message or "\n" in message:
            violation("beyond a float", f"{entry}: the message does not name {field!r} on one line", message)
        record("beyond a float", "named")
        return
    except Exception as exc:  # noqa: BLE001 - the kind's violation
        violation("beyond a float", f"{entry}: {type(exc).__name__}", str(exc)[:300])
    violation("beyond a float", f"{entry}: accepted")


@campaign(30)
@given(digits=st.integers(310, 4200), where=st.sampled_from(["rig fx", "rig depth_range", "points csv", "points json",
                                                              "scene rate"]))
@surveyed
def test_any_integer_beyond_a_float_in_a_file_is_named(tmp_path_factory, digits, where):
    from depthguard_lab.simulation import load_workcell

    folder = tmp_path_factory.mktemp("huge")
    number = "9" * digits
    if where.startswith("rig"):
        dg.save_rig(dg.Rig({"p": CAMERA}), folder / "rig.yaml")
        text = (folder / "rig.yaml").read_text()
        text = text.replace("fx: 50.0", f"fx: {number}") if where == "rig fx" else \
            text.replace("depth_range: [0.3, 4.0]", f"depth_range: [0.3, {number}]", 1)
        assert text != (folder / "rig.yaml").read_text()
        (folder / "rig.yaml").write_text(text)
        load, path, field = dg.load_rig, folder / "rig.yaml", where.split()[1]
    elif where == "points csv":
        (folder / "p.csv").write_text(f"x,y,z\n0,0,{number}\n")
        load, path, field = __import__("depthguard.io.points", fromlist=["load_points"]).load_points, \
            folder / "p.csv", "line 2"
    elif where == "points json":
        (folder / "p.json").write_text(f"[[0, 0, {number}]]")
        load, path, field = __import__("depthguard.io.points", fromlist=["load_points"]).load_points, \
            folder / "p.json", "entry #0"
    else:
        import re
        from pathlib import Path

        import depthguard_lab.simulation as simulation

        scene = (Path(simulation.__file__).parent / "scenario_c.yaml").read_text()
        (folder / "scene.yaml").write_text(re.sub(r"(?m)^rate: .*$", f"rate: {number}", scene))
        load, path, field = load_workcell, folder / "scene.yaml", "rate"
    try:
        load(path)
    except DepthguardError as exc:
        if str(path) not in str(exc) or field not in str(exc) or "\n" in str(exc):
            violation("beyond a float", f"{where}: not named on one line", str(exc)[:300])
        record("beyond a float", "named (file)")
        return
    except Exception as exc:  # noqa: BLE001
        violation("beyond a float", f"{where}: {type(exc).__name__}", str(exc)[:300])
    violation("beyond a float", f"{where}: accepted")


# ------------------------------------------------------------------------------------------- 2. writes that fail

WRITE_ERRNOS = [errno.ENOSPC, errno.EROFS, errno.EPIPE, errno.EIO, errno.EDQUOT, errno.EFBIG, errno.EACCES,
                errno.EPERM, errno.ENOENT]
STAGES = ["open", "write", "fsync", "replace"]


def _writers(folder):
    """name -> (the file it writes, a function that writes it)."""
    from depthguard.depth import write_depth_png

    return {
        "write_whole": (folder / "a.txt", lambda p: io_files.write_whole(p, "new " * 1000)),
        "save_rig": (folder / "rig.yaml", lambda p: dg.save_rig(RIG, p)),
        "write_depth_png": (folder / "d.png", lambda p: write_depth_png(p, np.full((48, 64), 2000, np.uint16))),
    }


@campaign(60)
@given(code=st.sampled_from(WRITE_ERRNOS), stage=st.sampled_from(STAGES), writer=st.sampled_from(["write_whole",
                                                                                                  "save_rig",
                                                                                                  "write_depth_png"]))
@surveyed
def test_any_os_error_at_any_stage_of_a_write_names_the_file(tmp_path_factory, code, stage, writer):
    folder = tmp_path_factory.mktemp("write")
    path, write = _writers(folder)[writer]
    path.write_bytes(b"the older file")
    failure = OSError(code, os.strerror(code))
    real_open = open

    def fake_open(name, *args, **kwargs):
        if stage == "open" and str(name).endswith(".partial"):
            raise OSError(code, os.strerror(code), str(name))
        file = real_open(name, *args, **kwargs)
        return CutFile(file, 0, failure) if stage == "write" and str(name).endswith(".partial") else file

    def fake_fsync(fd):
        raise failure

    def fake_replace(a, b):
        raise OSError(code, os.strerror(code), str(a), None, str(b))

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(io_files, "open", fake_open, raising=False)
        if stage == "fsync":
            patch.setattr(os, "fsync", fake_fsync)
        if stage == "replace":
            patch.setattr(os, "replace", fake_replace)
        try:
            write(path)
        except WriteError as exc:
            message = str(exc)
            if not message.startswith(f"{path}: could not be written: {os.strerror(code)}") or "\n" in message:
                violation("writes", f"{writer} at {stage}: message", message)
            outcome = "named"
        except Exception as exc:  # noqa: BLE001
            violation("writes", f"{writer} at {stage}, {errno.errorcode[code]}: {type(exc).__name__}", str(exc))
        else:
            violation("writes", f"{writer} at {stage}: no error")
    left = sorted(p.name for p in folder.iterdir())
    if path.read_bytes() != b"the older file" or left != [path.name]:
        violation("writes", f"{writer} at {stage}: the older file changed or something was left", str(left))
    record("writes", outcome)


@pytest.mark.parametrize("sink", ["/dev/full", "closed pipe"])
def test_standard_output_that_cannot_be_written_is_named(tmp_path, sink):
    camera = CAMERA
    dg.save_rig(dg.Rig({"p": camera}), tmp_path / "rig.yaml")
    np.save(tmp_path / "d.npy", np.full((48, 64), 2.0, np.float32))
    (tmp_path / "p.csv").write_text("x,y,z\n" + "0,0,0.5\n" * 2000)
    argv = [str(DEPTHGUARD_EXE), "distance", "--rig", str(tmp_path / "rig.yaml"), "--depth", f"p={tmp_path / 'd.npy'}",
            "--points", str(tmp_path / "p.csv")]
    if sink == "/dev/full":
        with open("/dev/full", "w") as full:
            done = subprocess.run(argv, stdout=full, stderr=subprocess.PIPE, text=True, timeout=120)
    else:
        process = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        process.stdout.close()  # the reader went away: a broken pipe
        err = process.stderr.read()
        done = subprocess.CompletedProcess(argv, process.wait(timeout=120), None, err)
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr and "Exception ignored" not in done.stderr
    assert done.stderr.startswith("depthguard: error: standard output: could not be written: "), done.stderr


# --------------------------------------------------------------------------------------- 3. tables with a wrong shape

@campaign(80)
@given(extra=st.lists(st.sampled_from(["id", "note", "w"]), max_size=3, unique=True), data=st.data())
@surveyed
def test_any_row_with_another_field_count_than_its_header_is_refused(tmp_path_factory, extra, data):
    from depthguard.io.points import load_points
    from depthguard.io.recordings import read_joint_states_csv

    header = ["x", "y", "z"] + extra
    kind = data.draw(st.sampled_from(["points", "joint states"]))
    if kind == "joint states":
        header = ["time", "a", "b"] + extra
    width = len(header)
    counts = data.draw(st.lists(st.integers(1, width + 4), min_size=1, max_size=6))
    rows = [",".join(["0.5"] * n) if kind == "points" else
            ",".join([f"{i + 1}.0"] + ["0.5"] * (n - 1)) for i, n in enumerate(counts)]
    path = tmp_path_factory.mktemp("table") / ("p.csv" if kind == "points" else "joint_states.csv")
    path.write_text(",".join(header) + "\n" + "\n".join(rows) + "\n")
    load = load_points if kind == "points" else read_joint_states_csv
    ragged = [i for i, n in enumerate(counts) if n != width]
    try:
        load(path)
    except DepthguardError as exc:
        message = str(exc)
        if not ragged:
            violation("tables", f"{kind}: a well-shaped table refused", message)
        if f"line {ragged[0] + 2}:" not in message or str(path) not in message or "\n" in message:
            violation("tables", f"{kind}: not the first ragged line, or not named on one line", message)
        record("tables", "named")
        return
    except Exception as exc:  # noqa: BLE001
        violation("tables", f"{kind}: {type(exc).__name__}", str(exc))
    if ragged:
        violation("tables", f"{kind}: a row of {counts[ragged[0]]} fields under {width} accepted", str(counts))
    record("tables", "accepted (well shaped)")


@campaign(40)
@given(name=st.text(st.characters(min_codepoint=1, max_codepoint=0x2FF, blacklist_characters="/"), min_size=1,
                    max_size=12).filter(lambda s: s not in (".", "..")))
@surveyed
def test_any_file_name_gives_a_one_line_message(tmp_path_factory, name):
    from depthguard.io.points import load_points

    folder = tmp_path_factory.mktemp("names")
    for load in (load_points, dg.load_rig):
        try:
            load(folder / (name + "\n\r\t.csv"))  # no such file, whatever the name holds
        except DepthguardError as exc:
            if "\n" in str(exc) or "\r" in str(exc):
                violation("tables", "a file name broke the message's line", repr(str(exc)))
        except Exception as exc:  # noqa: BLE001
            violation("tables", f"{type(exc).__name__} for a file name", repr(name))
        else:
            violation("tables", "a missing file was read", repr(name))
    record("tables", "one line")


# ------------------------------------------------------------------------------------------------- 4. array sizes

def _point_entries():
    monitor = dg.DistanceMonitor(RIG)
    prepared = monitor.prepare_set(IMAGES, now=1.0)
    single = dg.prepare_depth(IMAGES["p"], CAMERA)
    return {
        "DistanceMonitor.query": lambda pts: monitor.query(IMAGES, pts, now=1.0),
        "PreparedSet.query": prepared.query,
        "single_camera_distances": lambda pts: dg.single_camera_distances(single, pts),
        "LiveMonitor-free monitor, one camera": lambda pts: dg.DistanceMonitor(dg.Rig({"p": CAMERA})).query(
            {"p": IMAGES["p"]}, pts, now=1.0),
    }


@campaign(30)
@given(n=st.integers(config.MAX_QUERY_POINTS + 1, 100 * config.MAX_QUERY_POINTS), form=st.sampled_from(["array",
                                                                                                          "list"]),
       entry=st.sampled_from(["DistanceMonitor.query", "PreparedSet.query", "single_camera_distances",
                              "LiveMonitor-free monitor, one camera"]))
@surveyed
def test_any_number_of_points_beyond_the_limit_is_refused_naming_it(point_entries, n, form, entry):
    points = np.broadcast_to(np.zeros(3), (n, 3))  # a zero-stride view: no memory
    if form == "list":
        points = _LongList(n)
    try:
        point_entries[entry](points)
    except DepthguardError as exc:
        if "MAX_QUERY_POINTS" not in str(exc) or str(n) not in str(exc):
            violation("array sizes", f"{entry}: the limit is not named", str(exc))
        record("array sizes", "named")
        return
    except Exception as exc:  # noqa: BLE001
        violation("array sizes", f"{entry} with {n} points ({form}): {type(exc).__name__}", str(exc)[:300])
    violation("array sizes", f"{entry}: {n} points accepted")


class _LongList(list):
    """A list that says it holds n points (of [0, 0, 0]) without holding them: what a caller's huge list looks like to
    the size check, at no memory."""

    def __init__(self, n):
        super().__init__()
        self._n = n

    def __len__(self):
        return self._n


@pytest.fixture(scope="module")
def point_entries():
    return _point_entries()


@campaign(20)
@given(rows=st.integers(CAMERA.height + 1, 10**9))
@surveyed
def test_an_image_list_with_more_rows_than_its_camera_is_refused_before_numpy_reads_it(rows):
    try:
        dg.depth_image(_LongList(rows), CAMERA)
    except DepthguardError as exc:
        if "'shape'" not in str(exc) or str(rows) not in str(exc):
            violation("array sizes", "an image's rows not named", str(exc))
        record("array sizes", "named (image)")
        return
    except Exception as exc:  # noqa: BLE001
        violation("array sizes", f"an image list of {rows} rows: {type(exc).__name__}", str(exc)[:300])
    violation("array sizes", f"an image list of {rows} rows accepted")


def test_a_query_at_the_limit_is_not_refused_for_its_size():
    """The limit refuses only beyond it: 1,000 points pass the same check (the answer itself is other tests')."""
    from depthguard.validation import check_points

    assert check_points(np.broadcast_to(np.zeros(3), (1000, 3))).shape == (1000, 3)
    assert config.MAX_QUERY_POINTS >= 100_000  # a robot's surface spheres, many times over
