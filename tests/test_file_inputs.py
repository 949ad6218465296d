"""Points and scene files from outside (issue 12): every bad file is a named error of depthguard's own, promptly,
without running code, and every accepted file gives exactly the numbers it holds."""

from __future__ import annotations

import json
import os
import stat

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

import hostile
from depthguard import config
from depthguard.io.points import load_points
from depthguard.errors import InputError, SceneError
from depthguard_lab.simulation import load_workcell

LIMIT = config.COORDINATE_LIMIT


def _refused(path, error=InputError, *words):
    with hostile.deadline(10), hostile.no_process_started(), pytest.raises(error) as exc_info:
        (load_workcell if error is SceneError else load_points)(path)
    message = str(exc_info.value)
    assert type(exc_info.value) is error, type(exc_info.value)
    assert str(path) in message and "\n" not in message, message
    for word in words:
        assert word in message, message
    return message


# --------------------------------------------------------------------------------------------------------------------
# points: CSV


def test_csv_points_by_column_name(tmp_path):
    path = tmp_path / "p.csv"
    path.write_bytes("\ufeffZ, x ,label,y\r\n3,1,a,2\r\n\r\n-0.5,.25,b,1e-3\r\n".encode())
    np.testing.assert_array_equal(load_points(path), [[1.0, 2.0, 3.0], [0.25, 0.001, -0.5]])


def test_csv_with_only_the_header_has_no_points_and_an_empty_file_is_refused(tmp_path):
    path = tmp_path / "header.csv"
    path.write_text("x,y,z\n")
    points = load_points(path)
    assert points.shape == (0, 3) and points.dtype == np.float64
    path = tmp_path / "empty.csv"
    path.write_text("")
    _refused(path, InputError, "header")


def test_csv_field_longer_than_the_csv_module_allows(tmp_path):
    path = tmp_path / "long.csv"
    path.write_text("x,y,z\n0,0,1\n" + "1" * 200_000 + ",0,1\n")
    message = _refused(path, InputError, "line 3")
    assert len(message) < 500  # the field is not copied into the message


@pytest.mark.parametrize(
    "rows, line",
    [("nan,0,1", 2), ("0,inf,1", 2), ("0,0,-Infinity", 2), ("1_0,0,1", 2), ("\u0661,0,1", 2), ("0x10,0,1", 2),
     ("1,2", 2), ("1,,3", 2), ("one,2,3", 2), ("0,0,1\n1,2,3e", 3), ('"1,2,3', 2), ("1\x00,2,3", 2),
     (f"{LIMIT * (1 + 1e-15)},0,0", 2), (f"0,{-LIMIT * 2},0", 2), ("0,0,1e400", 2), ("0,0,1\n\n0,0,2\n1,1,x", 5)],
)
def test_csv_bad_rows_name_the_line(tmp_path, rows, line):
    path = tmp_path / "bad.csv"
    path.write_text("x,y,z\n" + rows + "\n")
    _refused(path, InputError, f"line {line}")


@pytest.mark.parametrize("header", ["a,b,c", "x,y", "x,x,y,z", "x,y,z,Z", "1,2,3"])
def test_csv_header_must_name_x_y_z_once(tmp_path, header):
    path = tmp_path / "header.csv"
    path.write_text(header + "\n1,2,3\n")
    _refused(path, InputError, "line 1")


def test_csv_coordinate_limit_is_inclusive(tmp_path):
    path = tmp_path / "edge.csv"
    path.write_text(f"x,y,z\n{LIMIT!r},{-LIMIT!r},0\n")
    np.testing.assert_array_equal(load_points(path), [[LIMIT, -LIMIT, 0.0]])


# --------------------------------------------------------------------------------------------------------------------
# points: JSON


@pytest.mark.parametrize(
    "text, words",
    [("[[" + "1" * 400 + ", 0, 0]]", ("#0",)),
     ("[[0, 0, -" + "9" * 400 + "]]", ("#0",)),
     ("[[1e400, 0, 0]]", ("#0",)),
     ("[[0, 0, 1], [NaN, 0, 1]]", ("#1",)),
     ("[[Infinity, 0, 1]]", ("#0",)),
     ("[[0, -Infinity, 1]]", ("#0",)),
     (f"[[0, 0, {LIMIT * 2}]]", ("#0", "limit")),
     ("[[true, 0, 1]]", ("#0",)),
     ("[[null, 0, 1]]", ("#0",)),
     ('[["1", "2", "3"]]', ("#0",)),
     ("[[1, 2]]", ("#0",)),
     ("[[1, 2, 3, 4]]", ("#0",)),
     ("[[[1], 2, 3]]", ("#0",)),
     ("[1, 2, 3]", ("#0",)),
     ('{"x": 1, "y": 2, "z": 3}', ("list",)),
     ("[[1, 2, 3],", ("malformed",)),
     ("", ("malformed",)),
     ("[" * 100_000 + "]" * 100_000, ("deep",)),
     ('[{"a":' * 50_000 + "1" + "}]" * 50_000, ("deep",)),
     ("[[1, 2, 3]] trailing", ("malformed",))],
)
def test_json_bad_points_are_input_errors(tmp_path, text, words):
    path = tmp_path / "bad.json"
    path.write_text(text)
    _refused(path, InputError, *words)


def test_json_empty_list_has_no_points(tmp_path):
    path = tmp_path / "none.json"
    path.write_text("[]")
    points = load_points(path)
    assert points.shape == (0, 3) and points.dtype == np.float64


coordinates = st.floats(min_value=-LIMIT, max_value=LIMIT, allow_nan=False, allow_infinity=False)


@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(points=st.lists(st.tuples(coordinates, coordinates, coordinates), max_size=20))
def test_points_round_trip_exactly(tmp_path, points):
    """Whatever is in range is read back bit for bit, from CSV (Python's repr) and JSON alike."""
    expected = np.array(points, dtype=np.float64).reshape(-1, 3)
    csv_path, json_path = tmp_path / "p.csv", tmp_path / "p.json"
    csv_path.write_text("x,y,z\n" + "".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in points))
    json_path.write_text(json.dumps([list(p) for p in points]))
    for path in (csv_path, json_path):
        got = load_points(path)
        assert got.shape == expected.shape and got.dtype == np.float64
        assert np.array_equal(got, expected)


# --------------------------------------------------------------------------------------------------------------------
# points: what the file is, not what it holds


@pytest.mark.parametrize("name", ["fifo.csv", "fifo.json"])
def test_points_fifo_is_refused_promptly(tmp_path, name):
    path = tmp_path / name
    os.mkfifo(path)
    _refused(path, InputError, "regular file")


def test_points_device_folder_binary_and_size_cap(tmp_path, monkeypatch):
    if os.path.exists("/dev/zero") and stat.S_ISCHR(os.stat("/dev/zero").st_mode):
        (tmp_path / "zero.csv").symlink_to("/dev/zero")
        _refused(tmp_path / "zero.csv", InputError, "regular file")
    (tmp_path / "folder.json").mkdir()
    _refused(tmp_path / "folder.json", InputError, "folder")
    (tmp_path / "binary.csv").write_bytes(b"x,y,z\n\xff\xfe\x00\x81\n")
    _refused(tmp_path / "binary.csv", InputError, "UTF-8")
    _refused(tmp_path / "absent.csv", InputError, "cannot read")
    path = tmp_path / "big.csv"
    path.write_text("x,y,z\n" + "0,0,1\n" * 100)
    monkeypatch.setattr(config, "MAX_POINTS_FILE_BYTES", path.stat().st_size - 1)
    _refused(path, InputError, "more than")
    monkeypatch.setattr(config, "MAX_POINTS_FILE_BYTES", path.stat().st_size)
    assert load_points(path).shape == (100, 3)


# --------------------------------------------------------------------------------------------------------------------
# scene files: read bounded, parsed safely (their keys are checked in test_simulation.py)


def test_scene_fifo_is_refused_promptly(tmp_path):
    path = tmp_path / "scene.yaml"
    os.mkfifo(path)
    _refused(path, SceneError, "regular file")


@pytest.mark.parametrize(
    "text, word",
    [("a: &a [1, 2]\nb: *a\n", "anchors"),
     ("a: &a ['lol', 'lol']\nb: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a]\nc: [*b, *b, *b, *b, *b, *b, *b, *b]\n",
      "anchors"),
     ("duration: 1\nduration: 2\n", "duplicate key"),
     ("duration: !!python/object/apply:os.system ['echo hacked']\n", "not allowed"),
     ("duration: !!python/object/new:subprocess.Popen [['sh', '-c', 'echo hacked']]\n", "not allowed"),
     ("duration: !custom 1\n", "not allowed"),
     ("a: " + "[" * 100 + "]" * 100 + "\n", "nested"),
     ("a: [1, 2\n", "malformed")],
)
def test_scene_yaml_is_parsed_safely(tmp_path, text, word):
    path = tmp_path / "scene.yaml"
    path.write_text(text)
    _refused(path, SceneError, word)


def test_scene_size_cap_device_and_binary(tmp_path, monkeypatch):
    path = tmp_path / "scene.yaml"
    path.write_text("# " + "x" * 100 + "\nduration: 1\n")
    monkeypatch.setattr(config, "MAX_TEXT_FILE_BYTES", path.stat().st_size - 1)
    _refused(path, SceneError, "more than")
    monkeypatch.undo()
    if os.path.exists("/dev/zero") and stat.S_ISCHR(os.stat("/dev/zero").st_mode):
        (tmp_path / "zero.yaml").symlink_to("/dev/zero")
        _refused(tmp_path / "zero.yaml", SceneError, "regular file")
    (tmp_path / "binary.yaml").write_bytes(b"duration: \xff\xfe\n")
    _refused(tmp_path / "binary.yaml", SceneError, "UTF-8")

