"""The ``depthguard distance`` command: its JSON against the Python API, and one clear line for every bad input."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import depthguard as dg
from cli_support import assert_refused, run_cli
from depthguard import config
from depthguard.io.points import load_points
from depthguard.cli import main
from depthguard.depth import write_depth_png
from depthguard.scenes import Box, Sphere, render_depth, scene_distance
from depthguard.transforms import look_at

EXE = Path(sys.executable).parent / "depthguard"

# Control points, world frame, metres. The camera hangs 2 m above the floor, looking down.
POINTS = [
    [0.0, 0.0, 1.0],      # mid-air: only the frusta of the hole pass within 0.4 m
    [0.45, 0.1, 0.45],    # beside the sphere
    [-0.3, 0.2, 0.2],     # above the box, near the hole
    [0.1, -0.2, 0.15],    # just above the floor
    [0.55, 0.38, 0.3],    # near the edge of the view
    [3.0, 0.0, 0.5],      # outside the view
    [0.0, 0.0, 2.5],      # behind the camera
    [0.0, 0.0, 1.85],     # nearer than the camera's minimum range
]


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """A one-camera rig, a rendered scene saved as 16-bit PNG (millimetres, with a hole) and .npy, and points."""
    folder = tmp_path_factory.mktemp("cli")
    camera = dg.PinholeCamera("front", 64, 48, 50.0, 50.0, 31.5, 23.5, look_at([0, 0, 2], [0, 0, 0], up=(0, 1, 0)),
                              depth_range=(0.3, 4.0))
    side = camera.replace(name="side", T_world_camera=look_at([2, 0, 1], [0, 0, 0.3]))
    scene = [Box.from_bounds([-3, -3, -0.1], [3, 3, 0.0]), Sphere((0.45, 0.1, 0.15), 0.2),
             Box.from_bounds([-0.5, 0.0, 0.0], [-0.2, 0.3, 0.1])]
    depth = render_depth(camera, scene)
    assert (depth > 0).all()
    units = np.round(depth * 1000).astype(np.uint16)
    u, v, _ = camera.project(camera.world_to_camera([[-0.3, 0.2, 0.2]]))
    units[int(round(v[0])) - 1:int(round(v[0])) + 2, int(round(u[0])) + 2:int(round(u[0])) + 4] = 0  # a 3x2 hole
    rig = dg.Rig({"front": camera})
    dg.save_rig(rig, folder / "rig.yaml")
    dg.save_rig(dg.Rig({"front": camera, "side": side}), folder / "rig2.yaml")
    write_depth_png(folder / "front.png", units)
    np.save(folder / "front.npy", depth)
    write_depth_png(folder / "side.png", np.round(render_depth(side, scene) * 1000).astype(np.uint16))
    (folder / "points.csv").write_text("x,y,z\n" + "".join(f"{x},{y},{z}\n" for x, y, z in POINTS))
    (folder / "points.json").write_text(json.dumps(POINTS))
    return dict(folder=folder, rig=folder / "rig.yaml", rig2=folder / "rig2.yaml", png=folder / "front.png",
                npy=folder / "front.npy", side=folder / "side.png", csv=folder / "points.csv",
                json=folder / "points.json", camera=camera, scene=scene)




def distance_json(work, capsys, *extra, depth=None, points=None):
    status, out, err = run_cli(["distance", "--rig", work["rig"], "--depth", f"front={depth or work['png']}",
                            "--points", points or work["csv"], "--json", *extra], capsys)
    assert status == 0, err
    assert err == ""
    assert out.count("\n") == 1  # ONE JSON array on one line
    return json.loads(out)


def api_records(work, depth, points_path, **options):
    rig = dg.load_rig(work["rig"])
    frame = dg.load_depth(depth, rig.camera("front"))
    points = load_points(points_path)
    return dg.DistanceMonitor(rig, **options).query({"front": frame}, points).records(points)


def assert_same_records(got, expected):
    assert len(got) == len(expected)
    for g, e in zip(got, expected):
        assert set(g) == {"point", "distance", "direction", "count", "flags"}
        assert g["point"] == e["point"]
        if e["distance"] is None:
            assert g["distance"] is None
        else:
            assert g["distance"] == pytest.approx(e["distance"], abs=1e-12)
        np.testing.assert_allclose(g["direction"], e["direction"], atol=1e-12)
        assert g["count"] == e["count"]
        assert g["flags"] == e["flags"]


# --------------------------------------------------------------------------------------------------------------------
# the JSON contract


@pytest.mark.parametrize("aggregate", ["min", "mean", "hybrid"])
@pytest.mark.parametrize("invalid", ["occupied", "neighbors", "free"])
@pytest.mark.parametrize("unseen", ["occupied", "free"])
def test_json_matches_the_python_api(work, capsys, aggregate, invalid, unseen):
    got = distance_json(work, capsys, "--aggregate", aggregate, "--invalid", invalid, "--unseen", unseen,
                        "--rho", "0.35")
    expected = api_records(work, work["png"], work["csv"], rho=0.35, aggregate=aggregate, invalid=invalid,
                           unseen=unseen)
    assert_same_records(got, expected)


def test_options_reach_the_computation(work, capsys):
    """Each option changes some answer, so matching the API above is not matching a default by chance."""
    base = distance_json(work, capsys)

    def distances(records):
        return [r["distance"] for r in records]

    assert distances(distance_json(work, capsys, "--aggregate", "mean")) != distances(base)
    assert distances(distance_json(work, capsys, "--invalid", "free")) != distances(base)
    assert distances(distance_json(work, capsys, "--unseen", "free")) != distances(base)
    assert distances(distance_json(work, capsys, "--rho", "0.1")) != distances(base)
    assert len(distance_json(work, capsys, "--method", "paper")) == len(base)


def test_json_record_contents(work, capsys):
    records = distance_json(work, capsys)
    assert [r["point"] for r in records] == POINTS
    by_point = {tuple(r["point"]): r for r in records}
    # mid-air: the frusta of the hole's pixels pass within rho of it, so the fail-safe policy reports them ...
    mid_air = by_point[(0.0, 0.0, 1.0)]
    assert 0.0 < mid_air["distance"] < 0.4 and "invalid_pixels_used" in mid_air["flags"]
    # ... and without them nothing lies within rho
    mid_air = distance_json(work, capsys, "--invalid", "free")[0]
    assert mid_air["distance"] is None and mid_air["count"] == 0 and mid_air["direction"] == [0.0, 0.0, 0.0]
    assert mid_air["flags"] == []
    for p in ([3.0, 0.0, 0.5], [0.0, 0.0, 2.5], [0.0, 0.0, 1.85]):
        r = by_point[tuple(p)]
        assert r["distance"] == 0.0
        assert "region_outside_view" in r["flags"]
    hole = by_point[(-0.3, 0.2, 0.2)]
    assert "invalid_pixels_used" in hole["flags"]
    for r in records:
        assert isinstance(r["count"], int) and isinstance(r["flags"], list)
        assert all(isinstance(f, str) for f in r["flags"])
        assert len(r["direction"]) == 3
        if r["distance"] is not None and r["distance"] > 0:
            assert np.linalg.norm(r["direction"]) == pytest.approx(1.0)
            assert r["count"] >= 1


def test_distances_never_exceed_the_true_distance(work, capsys):
    records = distance_json(work, capsys, "--invalid", "free", "--unseen", "free", "--aggregate", "min")
    truth = scene_distance(work["scene"], np.array(POINTS))
    for r, t in zip(records, truth):
        if r["distance"] is not None:
            assert r["distance"] <= t + 2e-3  # pixel discretisation of the 16-bit millimetre image
    # and a point beside the sphere sees it at about its true distance (the gray area is behind, not beside)
    beside = records[1]
    assert beside["distance"] == pytest.approx(truth[1], abs=0.05)


def test_points_in_input_order(work, capsys, tmp_path):
    order = [5, 1, 7, 0, 3, 2, 6, 4]
    path = tmp_path / "shuffled.csv"
    path.write_text("x,y,z\n" + "".join("{},{},{}\n".format(*POINTS[i]) for i in order))
    base = distance_json(work, capsys)
    shuffled = distance_json(work, capsys, points=path)
    assert shuffled == [base[i] for i in order]


def test_csv_json_png_and_npy_agree(work, capsys, tmp_path):
    from_csv = distance_json(work, capsys, points=work["csv"])
    from_json = distance_json(work, capsys, points=work["json"])
    assert from_csv == from_json
    # the CSV header may name more columns, in any order
    path = tmp_path / "cols.csv"
    path.write_text("label,z,y,x\n" + "".join(f"p{i},{z},{y},{x}\n" for i, (x, y, z) in enumerate(POINTS)))
    assert distance_json(work, capsys, points=path) == from_csv
    # float metres .npy versus the millimetre PNG (with its hole): equal where the hole does not matter
    from_npy = distance_json(work, capsys, "--invalid", "free", depth=work["npy"])
    from_png = distance_json(work, capsys, "--invalid", "free")
    for a, b in zip(from_npy, from_png):
        if a["distance"] is None:
            assert b["distance"] is None
        else:
            assert b["distance"] == pytest.approx(a["distance"], abs=0.01)


@pytest.mark.parametrize("content, name", [("x,y,z\n", "empty.csv"), ("x,y,z\n\n  \n", "blank.csv"),
                                           ("[]", "empty.json")])
def test_empty_points_give_an_empty_array(work, capsys, tmp_path, content, name):
    path = tmp_path / name
    path.write_text(content)
    assert distance_json(work, capsys, points=path) == []


def test_table_output(work, capsys):
    status, out, err = run_cli(["distance", "--rig", work["rig"], "--depth", f"front={work['png']}",
                            "--points", work["csv"], "--invalid", "free"], capsys)
    assert status == 0 and err == ""
    lines = out.splitlines()
    assert len(lines) == 1 + len(POINTS)
    assert "distance" in lines[0] and "flags" in lines[0]
    assert "none" in lines[1]  # the mid-air point
    assert "region_outside_view" in lines[6]


# --------------------------------------------------------------------------------------------------------------------
# bad input: non-zero exit, one line on stderr, no traceback


def _write(folder, name, content):
    path = folder / name
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    return path


def _bad_cases(work, tmp):
    """name -> (argv, a piece of text the error line must contain)."""
    rig, png, csv = work["rig"], work["png"], work["csv"]

    def args(rig=rig, depth=(f"front={png}",), points=csv, extra=()):
        argv = ["distance", "--rig", rig]
        for d in depth:
            argv += ["--depth", d]
        return argv + ["--points", points, *extra]

    small = tmp / "small.png"
    write_depth_png(small, np.full((24, 32), 1000, np.uint16))
    eight_bit = tmp / "eight.png"
    Image.new("L", (64, 48)).save(eight_bit)
    good_png = png.read_bytes()
    rig_text = work["rig"].read_text()
    rotation = rig_text.replace("[1.0, 0.0, 0.0, 0.0]", "[1.0, 0.1, 0.0, 0.0]", 1)
    assert rotation != rig_text
    np.save(tmp / "ints.npy", np.ones((48, 64), np.int32))
    return {
        "missing rig": (args(rig=tmp / "absent.yaml"), "absent.yaml"),
        "missing depth": (args(depth=(f"front={tmp / 'absent.png'}",)), "absent.png"),
        "missing points": (args(points=tmp / "absent.csv"), "absent.csv"),
        "points is a folder": (args(points=tmp), str(tmp)),
        "letters in csv": (args(points=_write(tmp, "letters.csv", "x,y,z\n1,2,3\n1,two,3\n")), "line 3"),
        "short csv row": (args(points=_write(tmp, "short.csv", "x,y,z\n1,2\n")), "line 2"),
        "csv without header": (args(points=_write(tmp, "noheader.csv", "1,2,3\n")), "header"),
        "empty csv file": (args(points=_write(tmp, "empty.csv", "")), "empty.csv"),
        "nan in csv": (args(points=_write(tmp, "nan.csv", "x,y,z\n0,0,1\nnan,0,1\n")), "line 3"),
        "inf in csv": (args(points=_write(tmp, "inf.csv", "x,y,z\ninf,0,1\n")), "line 2"),
        "malformed json": (args(points=_write(tmp, "cut.json", "[[1, 2, 3],")), "cut.json"),
        "nan in json": (args(points=_write(tmp, "nan.json", "[[0, 0, 1], [NaN, 0, 1]]")), "#1"),
        "json not a list": (args(points=_write(tmp, "dict.json", '{"x": 1, "y": 2, "z": 3}')), "dict.json"),
        "json pair": (args(points=_write(tmp, "pair.json", "[[1, 2]]")), "#0"),
        "json strings": (args(points=_write(tmp, "strings.json", '[["1", "2", "3"]]')), "#0"),
        "binary points": (args(points=_write(tmp, "binary.csv", b"\xff\xfe\x00\x81")), "binary.csv"),
        "unknown camera": (args(depth=(f"back={png}",)), "'back'"),
        "wrong image size": (args(depth=(f"front={small}",)), "width/height"),
        "8-bit image": (args(depth=(f"front={eight_bit}",)), "eight.png"),
        "truncated png": (args(depth=(f"front={_write(tmp, 'cut.png', good_png[:200])}",)), "cut.png"),
        "int npy": (args(depth=(f"front={tmp / 'ints.npy'}",)), "ints.npy"),
        "wrong suffix": (args(depth=(f"front={_write(tmp, 'd.jpg', good_png)}",)), "d.jpg"),
        "malformed rig": (args(rig=_write(tmp, "bad.yaml", "cameras: [\n  - {name: front\n")), "bad.yaml"),
        "rig not orthonormal": (args(rig=_write(tmp, "rot.yaml", rotation)), "T_world_camera"),
        "binary rig": (args(rig=_write(tmp, "bin.yaml", b"\x89PNG\r\n\x1a\n\xff\x00")), "bin.yaml"),
        "rig with python tag": (args(rig=_write(tmp, "evil.yaml", 'cameras: !!python/object/apply:os.system '
                                                                    f'["echo hacked > {tmp / "HACKED"}"]\n')),
                                "evil.yaml"),
        "depth without =": (args(depth=(f"front:{png}",)), "NAME=PATH"),
        "depth without name": (args(depth=(f"={png}",)), "NAME=PATH"),
        "depth without path": (args(depth=("front=",)), "NAME=PATH"),
        "camera twice": (args(depth=(f"front={png}", f"front={png}")), "twice"),
        "map of another rig": (args(rig=work["rig2"], depth=(f"front={png}", f"side={work['side']}"),
                                    extra=("--map", str(_other_rig_map(tmp, work)))), "another rig"),
        "unknown option": (args(extra=("--frobnicate",)), "--frobnicate"),
        "bad aggregate": (args(extra=("--aggregate", "max")), "--aggregate"),
        "bad invalid": (args(extra=("--invalid", "ignore")), "--invalid"),
        "negative rho": (args(extra=("--rho", "-0.4")), "rho"),
        "nan rho": (args(extra=("--rho", "nan")), "rho"),
        "text rho": (args(extra=("--rho", "far")), "--rho"),
        "missing --points": (["distance", "--rig", rig, "--depth", f"front={png}"], "--points"),
        "missing --depth": (["distance", "--rig", rig, "--points", csv], "--depth"),
        "no command": ([], "command"),
        "unknown command": (["distances"], "distances"),
    }


BAD_CASE_NAMES = [
    "missing rig", "missing depth", "missing points", "points is a folder", "letters in csv", "short csv row",
    "csv without header", "empty csv file", "nan in csv", "inf in csv", "malformed json", "nan in json",
    "json not a list", "json pair", "json strings", "binary points", "unknown camera", "wrong image size",
    "8-bit image", "truncated png", "int npy", "wrong suffix", "malformed rig", "rig not orthonormal", "binary rig",
    "rig with python tag", "depth without =", "depth without name", "depth without path", "camera twice",
    "map of another rig", "unknown option", "bad aggregate", "bad invalid", "negative rho", "nan rho", "text rho",
    "missing --points", "missing --depth", "no command", "unknown command",
]


@pytest.mark.parametrize("case", BAD_CASE_NAMES)
def test_bad_input_gives_one_line_and_nonzero_exit(work, capsys, tmp_path, case):
    argv, needle = _bad_cases(work, tmp_path)[case]
    status, out, err = run_cli(argv, capsys)
    assert status != 0
    assert out == ""
    assert "Traceback" not in err
    assert err.endswith("\n") and err.count("\n") == 1, err
    assert err.startswith("depthguard: error: ")
    assert needle in err
    assert not (tmp_path / "HACKED").exists()


def test_all_bad_cases_are_tested(work, tmp_path):
    assert sorted(_bad_cases(work, tmp_path)) == sorted(BAD_CASE_NAMES)


# --------------------------------------------------------------------------------------------------------------------
# the installed command, in a real process


def test_installed_command_runs_in_a_subprocess(work, capsys):
    assert EXE.exists()
    argv = ["distance", "--rig", str(work["rig"]), "--depth", f"front={work['png']}", "--points", str(work["json"]),
            "--aggregate", "min", "--json"]
    done = subprocess.run([str(EXE), *argv], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout) == distance_json(work, capsys, "--aggregate", "min", points=work["json"])

    bad = subprocess.run([str(EXE), "distance", "--rig", str(work["rig"]), "--depth", f"back={work['png']}",
                          "--points", str(work["csv"])], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2
    assert bad.stdout == ""
    assert bad.stderr.count("\n") == 1 and "'back'" in bad.stderr and "Traceback" not in bad.stderr


def test_help_exits_zero(capsys):
    status, out, _ = run_cli(["distance", "--help"], capsys)
    assert status == 0
    assert "--rig" in out and "--points" in out


def _other_rig_map(tmp, work):
    """A depth grid map built for a rig whose side camera sits 5 cm off."""
    from depthguard.depthgrid import build_map, save_map

    rig = dg.load_rig(work["rig2"])
    moved = dg.Rig({"front": rig.cameras["front"],
                    "side": rig.cameras["side"].replace(T_world_camera=look_at([2, 0.05, 1], [0, 0, 0.3]))})
    path = tmp / "other.npz"
    save_map(build_map(moved, "front"), path)
    return path


def test_several_cameras_fuse_through_the_depth_grid(work, tmp_path, capsys):
    """Two --depth give the fused result, the same as the Python API; build-map writes a map that --map uses."""
    base = ["distance", "--rig", str(work["rig2"]), "--depth", f"front={work['png']}", "--depth",
            f"side={work['side']}", "--points", str(work["csv"]), "--json"]
    assert main(base) == 0
    built = json.loads(capsys.readouterr().out)
    assert main(["build-map", "--rig", str(work["rig2"]), "--principal", "front", "--out",
                 str(tmp_path / "map.npz")]) == 0
    assert "front" in capsys.readouterr().out
    assert main(base + ["--map", str(tmp_path / "map.npz")]) == 0
    assert json.loads(capsys.readouterr().out) == built
    rig = dg.load_rig(work["rig2"])
    frames = {"front": dg.load_depth(work["png"], rig.cameras["front"]),
              "side": dg.load_depth(work["side"], rig.cameras["side"])}
    points = np.loadtxt(work["csv"], delimiter=",", skiprows=1, ndmin=2)
    expected = dg.DistanceMonitor(rig).query(frames, points).records(points)
    assert built == expected
    single = dg.DistanceMonitor(rig).query({"front": frames["front"]}, points)
    fused = np.array([np.inf if r["distance"] is None else r["distance"] for r in built])
    assert np.all(fused >= single.distance - 1e-12)


# --------------------------------------------------------------------------------------------------------------------
# numeric options: ranges checked where they are parsed (issue 12); exit 2, one line naming the option


def _option_cases(work, tmp):
    distance = ["distance", "--rig", work["rig"], "--depth", f"front={work['png']}", "--points", work["csv"]]
    build = ["build-map", "--rig", work["rig2"], "--out", tmp / "map.npz"]
    simulate = ["simulate", "--out", tmp / "sim"]
    return {
        "rho inf": (distance + ["--rho", "inf"], "--rho"),
        "rho 1e999": (distance + ["--rho", "1e999"], "--rho"),
        "rho -inf": (distance + ["--rho=-inf"], "--rho"),
        "rho zero": (distance + ["--rho", "0"], "--rho"),
        "rho too large": (distance + ["--rho", str(config.RHO_MAX * 2)], "--rho"),
        "d-min nan": (build + ["--d-min", "nan"], "--d-min"),
        "d-min zero": (build + ["--d-min", "0"], "--d-min"),
        "d-max inf": (build + ["--d-max", "inf"], "--d-max"),
        "d-max below d-min": (build + ["--d-min", "1.0", "--d-max", "0.5"], "--d-max"),
        "delta-d nan": (build + ["--delta-d", "nan"], "--delta-d"),
        "delta-d tiny": (build + ["--delta-d", "1e-9"], "--delta-d"),
        "simulate duration inf": (simulate + ["--duration", "inf"], "--duration"),
        "simulate duration nan": (simulate + ["--duration", "nan"], "--duration"),
        "simulate duration below a frame": (simulate + ["--duration", "1e-9"], "--duration"),
        "simulate seed negative": (simulate + ["--seed=-1"], "--seed"),
        "simulate seed 2**64": (simulate + ["--seed", str(2**64)], "--seed"),
        "simulate seed 1.5": (simulate + ["--seed", "1.5"], "--seed"),
        "simulate seed 5000 digits": (simulate + ["--seed", "9" * 5000], "--seed"),
        "demo duration 1e-9": (["demo", "--out", tmp / "demo", "--duration", "1e-9"], "--duration"),
        "demo duration inf": (["demo", "--out", tmp / "demo", "--duration", "inf"], "--duration"),
        "demo unknown mode": (["demo", "--out", tmp / "demo", "--mode", "fast"], "--mode"),
        "workcell duration 1e-9": (["workcell", "--out", tmp / "demo", "--duration", "1e-9"], "--duration"),
        "repeats zero": (["scenario-a", "--out", tmp / "a", "--repeats", "0"], "--repeats"),
        "repeats huge": (["scenario-a", "--out", tmp / "a", "--repeats", "1000000000"], "--repeats"),
    }


OPTION_CASES = ["rho inf", "rho 1e999", "rho -inf", "rho zero", "rho too large", "d-min nan", "d-min zero",
                "d-max inf", "d-max below d-min", "delta-d nan", "delta-d tiny", "simulate duration inf",
                "simulate duration nan", "simulate duration below a frame", "simulate seed negative",
                "simulate seed 2**64", "simulate seed 1.5", "simulate seed 5000 digits", "demo duration 1e-9",
                "demo duration inf", "demo unknown mode", "workcell duration 1e-9", "repeats zero", "repeats huge"]


@pytest.mark.parametrize("case", OPTION_CASES)
def test_numeric_option_out_of_range_exits_2_naming_it(work, capsys, tmp_path, case):
    argv, option = _option_cases(work, tmp_path)[case]
    assert_refused(argv, capsys, option)
    assert not (tmp_path / "sim").exists() and not (tmp_path / "demo").exists() and not (tmp_path / "map.npz").exists()


def test_all_option_cases_are_tested(work, tmp_path):
    assert sorted(_option_cases(work, tmp_path)) == sorted(OPTION_CASES)


@pytest.mark.parametrize("text", ["nan,0", "0,inf", "a=1e999,b=0", "a=-inf"])
def test_joints_must_be_finite(text):
    from depthguard.cli import parse_joints

    with pytest.raises(dg.InputError) as exc_info:
        parse_joints(text)
    assert "--joints" in str(exc_info.value) and "finite" in str(exc_info.value)


TINY_URDF = """<?xml version="1.0"?>
<robot name="tiny">
  <link name="base"><collision><geometry><box size="0.1 0.1 0.1"/></geometry></collision></link>
  <joint name="turn" type="revolute">
    <parent link="base"/><child link="arm"/><origin xyz="0 0 0.1" rpy="0 0 0"/><axis xyz="0 0 1"/>
    <limit effort="1" lower="-1" upper="1" velocity="1"/>
  </joint>
  <link name="arm">
    <inertial><mass value="1"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>
    <collision><origin xyz="0 0 0.2"/><geometry><mesh filename="arm.stl" scale="1 1 1"/></geometry></collision>
    <collision><geometry><sphere radius="0.05"/></geometry></collision>
  </link>
</robot>
"""

#: (text of TINY_URDF, its replacement, what the error names). Before URDF numbers were checked, the first was an
#: internal error (exit 3), the next two were accepted, the others printed pinocchio's parser's errors on stderr.
BAD_URDF_NUMBERS = [
    ('radius="0.05"', 'radius="inf"', "link 'arm' <collision> <geometry> <sphere radius>"),
    ('scale="1 1 1"', 'scale="0 0 0"', "link 'arm' <collision>: <mesh scale>"),
    ('<origin xyz="0 0 0.2"/>', '<origin xyz="1e300 0 0.2"/>', "link 'arm' <collision> <origin xyz>"),
    ('<origin xyz="0 0 0.1"', '<origin xyz="0 nan 0.1"', "joint 'turn' <origin xyz>"),
    ('upper="1"', 'upper="1e400"', "joint 'turn' <limit upper>"),
    ('<mass value="1"/>', '<mass value="inf"/>', "link 'arm' <inertial> <mass value>"),
]


@pytest.mark.parametrize("old, new, words", BAD_URDF_NUMBERS, ids=[new for _, new, _ in BAD_URDF_NUMBERS])
def test_a_urdf_number_out_of_range_exits_2_with_one_line(work, capfd, tmp_path, old, new, words):
    """capfd, not capsys: pinocchio's parser writes its complaints to file descriptor 2 itself."""
    import trimesh

    from depthguard.robots import RobotModel

    trimesh.creation.box(extents=(0.05, 0.05, 0.3)).export(tmp_path / "arm.stl")
    (tmp_path / "good.urdf").write_text(TINY_URDF)
    assert RobotModel.from_urdf(tmp_path / "good.urdf").joint_names == ("turn",)  # the URDF but for the edit is good
    assert old in TINY_URDF
    urdf = tmp_path / "bad.urdf"
    urdf.write_text(TINY_URDF.replace(old, new, 1))
    capfd.readouterr()
    assert_refused(["distance", "--rig", work["rig"], "--depth", f"front={work['png']}", "--points", work["csv"],
                    "--robot", urdf, "--joints", "0"], capfd, "bad.urdf", words)


def test_edges_of_the_ranges_are_accepted(work, capsys):
    for rho in (config.RHO_MIN, config.RHO_MAX):
        assert len(distance_json(work, capsys, "--rho", repr(rho))) == len(POINTS)


def test_build_map_out_that_is_not_a_regular_file_is_refused(work, capsys, tmp_path):
    import os

    fifo = tmp_path / "map.npz"
    os.mkfifo(fifo)
    for out in (fifo, tmp_path):
        status, out_text, err = run_cli(["build-map", "--rig", work["rig2"], "--out", out], capsys)
        assert status == 2 and out_text == "" and "--out" in err and err.count("\n") == 1


def test_replay_and_live_default_to_the_aggregate_of_their_outputs():
    """replay and live write and publish distances and flags, no direction: their --aggregate defaults to min (the
    distances are hybrid's, design §6); distance, which prints directions, keeps hybrid. Each can be asked for."""
    from depthguard.cli import build_parser
    from depthguard.cli.options import monitor_options

    parser = build_parser()
    replay = parser.parse_args(["replay", "folder", "--out", "r.csv"])
    live = parser.parse_args(["live", "--rig", "rig.yaml", "--robot", "iiwa"])
    assert monitor_options(replay)["aggregate"] == "min" and monitor_options(live)["aggregate"] == "min"
    asked = parser.parse_args(["replay", "folder", "--out", "r.csv", "--aggregate", "hybrid"])
    assert monitor_options(asked)["aggregate"] == "hybrid"
    distance = parser.parse_args(["distance", "--rig", "rig.yaml", "--depth", "a.png", "--points", "p.csv"])
    assert distance.aggregate == "hybrid"
