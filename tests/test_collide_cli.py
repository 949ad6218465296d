"""``depthguard collide`` and ``depthguard plan`` (issue 10) as a user runs them: a rig file, reference and current
images as PNG files, joint values on the command line; the answers as JSON, checked against where the obstacle is;
bad input refused in one line naming the camera and option."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

import depthguard as dg
from cli_support import assert_refused, run_cli
from depthguard.transforms import look_at

EYES = [(2.2, -1.6, 1.6), (2.2, 1.6, 1.6), (-1.8, 1.8, 1.8), (-1.8, -1.8, 1.4)]
WORKSPACE = [[-1.0, -1.0, -0.1], [1.2, 1.0, 1.5]]
#: The reference's robot poses: no two alike near the shoulder, so that the moving links cover any pixel in fewer than
#: half of them and the median shows the room (the paper chooses them so).
POSES = [(-2.0, 0.9, 0.0, -0.6, 0.0, 0.8, 0.0), (-0.8, -0.7, 0.0, -1.8, 0.0, 0.8, 0.0), (0.4, 0.3, 0.0, -1.0, 0.0, 0.8, 0.0),
         (1.6, 1.1, 0.0, -1.9, 0.0, 0.8, 0.0), (2.6, -0.9, 0.0, -0.5, 0.0, 0.8, 0.0)]
NOW = (-1.8, 0.7, 0.0, -1.2, 0.0, 0.8, 0.0)  # clear of the box (the paper's rule judges it free)
THROUGH = (0.0, 0.7, 0.0, -1.2, 0.0, 0.8, 0.0)  # its end-effector inside the box
AWAY = (-2.2, 0.3, 0.0, -1.0, 0.0, 0.5, 0.0)


def _values(q) -> str:
    return ",".join(f"{x:g}" for x in q)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A folder as a recording gives it: rig.yaml (four 160 x 128 cameras around a KUKA iiwa, the workspace), 8-bit
    grey PNGs of the reference (the robot in five poses) and of the current scene (the robot at NOW, a bright box
    where THROUGH's end-effector is), and the same as 16-bit depth PNGs (millimetres; the robot's collision meshes, as
    a depth camera measures it)."""
    from depthguard.depth import write_depth_png
    from depthguard.robots import RobotModel
    from depthguard.scenes import Box, render_depth
    from depthguard.self_filter import RobotSilhouette

    root = tmp_path_factory.mktemp("recorded")
    cameras = {f"c{k}": dg.PinholeCamera(f"c{k}", 160, 128, 130.0, 130.0, 79.5, 63.5,
                                         look_at(eye, (0.2, 0.0, 0.5)))
               for k, eye in enumerate(EYES)}
    dg.save_rig(dg.Rig(cameras, workspace=WORKSPACE), root / "rig.yaml")
    robot = RobotModel.default()
    meshes = RobotSilhouette(robot, geometry="meshes")  # the robot as a camera sees it
    target = robot.control_point_positions(np.array(THROUGH))[robot.end_effector_index]
    box = Box.from_bounds(target - 0.07, target + 0.07)
    floor = Box.from_bounds([-3.0, -3.0, -0.3], [3.0, 3.0, -0.2])
    rng = np.random.default_rng(4)
    for name, camera in cameras.items():
        background = np.kron(rng.integers(40, 160, (16, 20)), np.ones((8, 8)))
        floor_depth = render_depth(camera, [floor])
        for k, q in enumerate(POSES + [NOW]):
            grey = background.copy()
            grey[meshes.render(camera, np.array(q)) > 0] = 235
            mesh_depth = meshes.render(camera, np.array(q))
            depth = np.where(mesh_depth > 0, mesh_depth, floor_depth)
            stem = f"ref{k}" if k < len(POSES) else "now"
            if stem == "now":
                box_depth = render_depth(camera, [box])
                grey[box_depth > 0] = 250
                nearer = (box_depth > 0) & ((depth == 0) | (box_depth < depth))
                depth = np.where(nearer, box_depth, depth)
            (root / "grey" / name).mkdir(parents=True, exist_ok=True)
            (root / "depth" / name).mkdir(parents=True, exist_ok=True)
            Image.fromarray(grey.astype(np.uint8), mode="L").save(root / "grey" / name / f"{stem}.png")
            write_depth_png(root / "depth" / name / f"{stem}.png", np.rint(depth * 1000).astype(np.uint16))
    return root


def _argv(root, command="collide", kind="grey", *extra):
    argv = [command, "--rig", root / "rig.yaml", "--robot", "iiwa", "--current", _values(NOW), "--tiles", "32x40"]
    for name in ("c0", "c1", "c2", "c3"):
        argv += ["--reference", f"{name}={root / kind / name}/ref*.png", "--image", f"{name}={root / kind / name}/now.png"]
    argv += ["--reference-joints", ";".join(_values(q) for q in POSES)]
    return argv + (["--depth"] if kind == "depth" else []) + list(extra)


@pytest.mark.parametrize("kind", ["grey", "depth"])
def test_collide_answers_each_future_configuration_and_the_motion_in_order(recorded, capsys, kind):
    status, out, err = run_cli(_argv(recorded, "collide", kind, "--theta", "1", "--unseen", "free",
                                     "--future", _values(THROUGH), "--future", _values(NOW),
                                     "--motion", f"{_values(NOW)};{_values(AWAY)}",
                                     "--json"), capsys)
    assert status == 0, err
    answers = json.loads(out)
    assert [a["kind"] for a in answers] == ["future", "future", "motion"]
    through, now, motion = answers
    assert through["collision"] and through["class"] in "CD"
    assert not now["collision"] and now["class"] in "AB"
    assert not motion["collision"] and motion["samples"] > 2  # swinging away from the box
    assert set(through["cameras"]) == {"c0", "c1", "c2", "c3"}
    assert all(set(c) == {"obstacle", "possible", "light_gain", "unreferenced_pixels"}
               for c in through["cameras"].values())
    assert all(c["unreferenced_pixels"] > 0 for c in through["cameras"].values())  # the base, in every image
    if kind == "grey":
        assert all(abs(c["light_gain"] - 1.0) < 0.02 for c in through["cameras"].values())


def test_collide_by_default_counts_what_the_robot_may_hide_as_occupied(recorded, capsys):
    """The fail-safe default (theta = cameras - 1, class B collides) and the table printed without --json."""
    status, out, err = run_cli(_argv(recorded, "collide", "grey", "--future", _values(THROUGH), "--future",
                                     _values(AWAY)), capsys)
    assert status == 0, err
    lines = out.splitlines()
    assert lines[0].startswith("test") and len(lines) == 3
    assert lines[1].split()[1] == "True"


def test_a_motion_through_the_box_collides(recorded, capsys):
    status, out, err = run_cli(_argv(recorded, "collide", "grey", "--theta", "1", "--unseen", "free", "--motion",
                                     f"{_values(NOW)};{_values((1.8,) + THROUGH[1:])}", "--json"), capsys)
    assert status == 0, err
    (motion,) = json.loads(out)
    assert motion["collision"]


def test_plan_goes_around_the_box(recorded, capsys):
    """A plan from NOW to the other side of the box over a small grid: every configuration on it is judged free,
    and the whole path's swept volume too; a straight swing through the box would collide. The paper's rule and
    Table I (--no-robot-pixels): with robot_pixels the box, which shares tiles with the robot's image at NOW in
    three of these 160 x 128 cameras, is an obstacle there, and NOW itself collides."""
    goal = (1.8,) + NOW[1:]
    status, out, err = run_cli(_argv(recorded, "plan", "grey", "--theta", "1", "--unseen", "free", "--no-robot-pixels",
                                     "--goal", _values(goal), "--counts", "64,6,1,6,1,1,1", "--lower",
                                     "-2.2,0.2,0,-1.9,0,0.8,0", "--upper", "2.2,1.2,0,-0.7,0,0.8,0", "--json"), capsys)
    assert status == 0, err
    answer = json.loads(out)
    path = np.array(answer["path"])
    assert np.allclose(path[0], NOW) and np.allclose(path[-1], goal)
    assert answer["motion"] == {"collision": False, "class": answer["motion"]["class"]}
    status, out, err = run_cli(_argv(recorded, "collide", "grey", "--theta", "1", "--unseen", "free",
                                     "--no-robot-pixels", "--motion", ";".join(_values(q) for q in path), "--json"),
                               capsys)
    assert not json.loads(out)[0]["collision"]
    status, out, _ = run_cli(_argv(recorded, "collide", "grey", "--theta", "1", "--unseen", "free",
                                   "--no-robot-pixels", "--motion", f"{_values(NOW)};{_values(goal)}", "--json"),
                             capsys)
    assert json.loads(out)[0]["collision"]


def test_plan_refuses_a_grid_that_leaves_out_the_current_or_the_goal_configuration(recorded, capsys):
    argv = _argv(recorded, "plan", "grey", "--goal", _values((1.8,) + NOW[1:]), "--counts", "4,2,1,2,1,1,1")
    assert_refused(argv + ["--lower", "0,0.2,0,-1.9,0,0.8,0", "--upper", "2.2,1.2,0,-0.7,0,0.8,0"], capsys,
                   "--current", "outside")
    assert_refused(argv + ["--lower", "-2.2,0.2,0,-1.9,0,0.8,0", "--upper", "1,1.2,0,-0.7,0,0.8,0"], capsys,
                   "--goal", "outside")


def test_plan_refuses_a_grid_larger_than_it_judges(recorded, capsys):
    """16.7 million configurations would take gigabytes: refused at once, naming --counts."""
    assert_refused(_argv(recorded, "plan", "grey", "--goal", _values(NOW), "--counts", "64,64,4,16,4,4,4"), capsys,
                   "--counts", "at most")


def test_plan_without_a_way_says_so(recorded, capsys):
    """The default rule near the box leaves no free configuration on this grid: no path, exit status 1."""
    status, out, err = run_cli(_argv(recorded, "plan", "grey", "--goal", _values((1.8,) + NOW[1:]), "--counts",
                                     "8,2,1,2,1,1,1", "--json"), capsys)
    answer = json.loads(out)
    assert status == 1 and answer["path"] is None, (out, err)


def test_bad_input_is_refused_naming_the_camera_and_option(recorded, capsys, tmp_path):
    base = _argv(recorded, "collide", "grey", "--future", _values(THROUGH))
    without_c3 = base[: base.index("--reference", base.index("c2=" + str(recorded / "grey" / "c2") + "/now.png"))]
    assert_refused(without_c3 + ["--future", "0,0,0,0,0,0,0"], capsys, "c3", "--reference")
    assert_refused(base + ["--reference", f"c9={recorded}/grey/c0/ref*.png"], capsys, "c9")
    nothing = [a if not str(a).startswith("c1=") or "ref" not in str(a) else f"c1={tmp_path}/none*.png" for a in base]
    assert_refused(nothing, capsys, "c1", "no file matches")
    assert_refused(base + ["--future", "0,0,0"], capsys, "--future")
    assert_refused(base + ["--future", "0,0,0,0,0,0,9"], capsys, "--future", "limits")
    assert_refused(base + ["--theta", "4"], capsys, "theta")
    assert_refused(base + ["--tiles", "abc"], capsys, "--tiles")
    for bad in ("a,b,c", "1,2", "1,2,3,4,5", "nan,0,0", "0,0,1e9"):
        assert_refused(base + ["--base", bad], capsys, "--base")
    for bad in ("a,b,c,d,e,f", "0,0,0,1,1", "0,0,0,1,1,inf"):
        assert_refused(base + ["--workspace", bad], capsys, "--workspace")
    assert_refused(base + ["--tiles", "0x5"], capsys, "rows")
    assert_refused(base + ["--reference-joints", _values(NOW)], capsys, "--reference-joints", "5 images")
    assert_refused(base[: -2], capsys, "--future")  # nothing to test
    colour = tmp_path / "colour.png"
    Image.fromarray(np.zeros((128, 160, 3), dtype=np.uint8)).save(colour)
    swapped = [a if not str(a).startswith("c2=") or "now" not in str(a) else f"c2={colour}" for a in base]
    assert_refused(swapped, capsys, "c2", "grayscale")
    small = tmp_path / "small.png"
    Image.fromarray(np.zeros((64, 80), dtype=np.uint8), mode="L").save(small)
    swapped = [a if not str(a).startswith("c0=") or "now" not in str(a) else f"c0={small}" for a in base]
    assert_refused(swapped, capsys, "c0")


def test_any_urdf_file_gives_the_built_in_robots_answers(recorded, capsys):
    """--robot takes a URDF file as well as a built-in name: the iiwa's file from pybullet_data answers as 'iiwa'."""
    from depthguard.robots import default_robot_path

    extra = ("--theta", "1", "--unseen", "free", "--future", _values(THROUGH), "--future", _values(AWAY), "--json")
    by_name = run_cli(_argv(recorded, "collide", "grey", *extra), capsys)
    argv = [str(default_robot_path()) if a == "iiwa" else a for a in _argv(recorded, "collide", "grey", *extra)]
    by_file = run_cli(argv, capsys)
    assert by_name[0] == by_file[0] == 0 and json.loads(by_name[1]) == json.loads(by_file[1])
    assert_refused([a if a != "iiwa" else str(recorded / "missing.urdf") for a in _argv(recorded, "collide", "grey",
                                                                                          *extra)], capsys, "missing")


def test_a_gripped_piece_is_part_of_the_robot(recorded, capsys):
    """--gripped: a box held in the end-effector link's frame extends the robot: a configuration whose bare arm
    passes beside the box collides once it holds a 40 cm piece; plan uses it too; a bad piece is refused."""
    beside = (THROUGH[0] + 0.6,) + THROUGH[1:]
    rule = ("--theta", "1", "--unseen", "free", "--no-robot-pixels", "--json")  # the paper's Table I
    _, bare, _ = run_cli(_argv(recorded, "collide", "grey", "--future", _values(beside), *rule), capsys)
    status, held, err = run_cli(_argv(recorded, "collide", "grey", "--future", _values(beside), "--gripped",
                                      "0,0,0,0.2,0.2,0.2", *rule), capsys)
    assert status == 0, err
    assert not json.loads(bare)[0]["collision"] and json.loads(held)[0]["collision"]
    status, out, err = run_cli(_argv(recorded, "plan", "grey", "--goal", _values((1.8,) + NOW[1:]), "--counts",
                                     "16,2,1,2,1,1,1", "--gripped", "0,0,0,0.25,0.25,0.25", *rule), capsys)
    assert status in (0, 1) and set(json.loads(out)) >= {"path", "free_cells", "motion"}, err
    for bad in ("0,0,0,0.1,0.1", "0,0,0,0,0.1,0.1", "0,0,0,-0.1,0.1,0.1", "a,b,c,d,e,f"):
        assert_refused(_argv(recorded, "collide", "grey", "--future", _values(beside), "--gripped", bad), capsys,
                       "--gripped")
