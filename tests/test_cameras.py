"""Cameras, rigs and camera_info files: validation, geometry, YAML round trips, and refusal of bad files.

Every error about one camera must name the camera and the field (design §2, STYLE "Errors").
"""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
import yaml

import naive

import depthguard as dg
from depthguard.transforms import look_at

# --------------------------------------------------------------------------------------------------------------------
# helpers


def random_pose(rng) -> np.ndarray:
    return naive.random_pose(rng, 3.0)


def make_camera(name="cam", **changes) -> dg.PinholeCamera:
    fields = dict(name=name, width=64, height=48, fx=50.0, fy=52.0, cx=31.5, cy=23.5, T_world_camera=np.eye(4),
                  depth_range=(0.3, 5.0))
    fields.update(changes)
    return dg.PinholeCamera(**fields)


def camera_entry(name="cam", **changes) -> dict:
    entry = dict(name=name, width=64, height=48, fx=50.0, fy=52.0, cx=31.5, cy=23.5,
                 T_world_camera=np.eye(4).tolist(), depth_range=[0.3, 5.0])
    entry.update(changes)
    return entry


def write_rig(path, data) -> None:
    path.write_text(yaml.safe_dump(data, sort_keys=False))


def assert_names(exc_info, camera, field):
    """The error names the camera and the field, both as attributes and in the message a log would show."""
    exc = exc_info.value
    assert exc.camera == camera
    assert exc.field == field
    assert repr(camera) in str(exc)
    assert field in str(exc)


# --------------------------------------------------------------------------------------------------------------------
# PinholeCamera validation


@pytest.mark.parametrize(
    "field, value",
    [
        ("fx", 0.0), ("fx", -525.0), ("fy", 0.0), ("fy", -1e-9),
        ("fx", math.nan), ("fy", math.inf), ("cx", math.nan), ("cy", "239.5"),
        ("width", 0), ("width", -640), ("height", 0), ("width", 64.0), ("height", True),
        ("depth_range", (-0.1, 4.0)), ("depth_range", (2.0, 1.0)), ("depth_range", (1.0, 1.0)),
        ("depth_range", (math.nan, 4.0)), ("depth_range", (0.4, math.nan)), ("depth_range", "near"),
        ("depth_range", (0.4,)),
        ("depth_scale", 0.0), ("depth_scale", -0.001), ("depth_scale", math.nan),
    ],
)
def test_camera_rejects_bad_field_and_names_it(field, value):
    with pytest.raises(dg.RigError) as exc_info:
        make_camera(**{field: value})
    assert_names(exc_info, "cam", field)


def _T_with(rotation, translation=(0.1, 0.2, 0.3)):
    T = np.eye(4)
    T[:3, :3] = rotation
    T[:3, 3] = translation
    return T


@pytest.mark.parametrize(
    "label, T",
    [
        ("scaled rotation", _T_with(1.01 * np.eye(3))),
        ("shear", _T_with([[1, 0.05, 0], [0, 1, 0], [0, 0, 1]])),
        ("reflection det -1", _T_with(np.diag([1.0, 1.0, -1.0]))),
        ("rotation times -1 (det -1)", _T_with(-np.eye(3))),
        ("NaN entry", _T_with(np.eye(3), (0.0, math.nan, 0.0))),
        ("inf entry", _T_with(np.eye(3), (math.inf, 0.0, 0.0))),
        ("bad last row", np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0.5, 1]], float)),
        ("3x3", np.eye(3)),
        ("flat 16", np.eye(4).ravel()),
    ],
)
def test_camera_rejects_bad_pose(label, T):
    with pytest.raises(dg.RigError) as exc_info:
        make_camera(T_world_camera=T)
    assert_names(exc_info, "cam", "T_world_camera")


def test_camera_accepts_rotation_within_tolerance_and_pose_is_frozen_copy():
    rng = np.random.default_rng(1)
    T = random_pose(rng)
    cam = make_camera(T_world_camera=T)
    np.testing.assert_array_equal(cam.T_world_camera, T)
    T[0, 3] += 1.0  # the caller changes its matrix afterwards
    assert cam.T_world_camera[0, 3] == pytest.approx(T[0, 3] - 1.0)
    with pytest.raises(ValueError):
        cam.T_world_camera[0, 3] = 5.0  # read-only


def test_camera_defaults_and_shape():
    cam = dg.PinholeCamera("c", 640, 480, 525.0, 525.0, 319.5, 239.5, np.eye(4))
    assert cam.shape == (480, 640)
    assert cam.depth_range == (0.0, math.inf)
    assert cam.depth_scale == pytest.approx(0.001)
    np.testing.assert_array_equal(cam.K, [[525, 0, 319.5], [0, 525, 239.5], [0, 0, 1]])


# --------------------------------------------------------------------------------------------------------------------
# projection and frames


def test_project_follows_the_pinhole_formula_by_hand():
    cam = make_camera()
    # x right, y down, z forward: a point 1 m ahead, 0.2 m right and 0.1 m up.
    u, v, z = cam.project([[0.2, -0.1, 1.0]])
    assert u[0] == pytest.approx(50.0 * 0.2 + 31.5)
    assert v[0] == pytest.approx(52.0 * -0.1 + 23.5)
    assert z[0] == 1.0


def test_project_back_project_round_trip():
    rng = np.random.default_rng(7)
    cam = make_camera()
    points = np.column_stack([rng.uniform(-2, 2, 500), rng.uniform(-2, 2, 500), rng.uniform(0.05, 10, 500)])
    u, v, z = cam.project(points)
    back = cam.back_project(u, v, z)
    np.testing.assert_allclose(back, points, rtol=0, atol=1e-12)
    # and the other way round: pixels at depths -> points -> the same pixels
    uu, vv = rng.uniform(-0.5, 63.5, 200), rng.uniform(-0.5, 47.5, 200)
    dd = rng.uniform(0.3, 5.0, 200)
    u2, v2, z2 = cam.project(cam.back_project(uu, vv, dd))
    np.testing.assert_allclose(np.column_stack([u2, v2, z2]), np.column_stack([uu, vv, dd]), atol=1e-10)


def test_project_behind_camera_gives_nan():
    cam = make_camera()
    u, v, z = cam.project([[0.1, 0.1, -1.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    assert np.isnan(u[:2]).all() and np.isnan(v[:2]).all()
    assert np.isfinite(u[2]) and np.isfinite(v[2])


def test_depth_to_points_back_projects_every_pixel():
    cam = make_camera(width=5, height=4, fx=2.0, fy=3.0, cx=2.0, cy=1.5)
    depth = np.full((4, 5), 2.0)
    pts = cam.depth_to_points(depth)
    assert pts.shape == (4, 5, 3)
    # pixel (u=4, v=0): x = (4 - 2)/2 * 2 = 2, y = (0 - 1.5)/3 * 2 = -1
    np.testing.assert_allclose(pts[0, 4], [2.0, -1.0, 2.0])


def test_world_camera_transforms_with_random_rigid_poses():
    rng = np.random.default_rng(2024)
    for _ in range(20):
        T = random_pose(rng)
        cam = make_camera(T_world_camera=T)
        p_cam = rng.normal(size=(50, 3))
        p_world = cam.camera_to_world(p_cam)
        # against the plain homogeneous product
        homog = np.column_stack([p_cam, np.ones(50)]) @ T.T
        np.testing.assert_allclose(p_world, homog[:, :3], atol=1e-12)
        np.testing.assert_allclose(cam.world_to_camera(p_world), p_cam, atol=1e-10)
        np.testing.assert_allclose(cam.T_camera_world @ cam.T_world_camera, np.eye(4), atol=1e-12)
        # rigid: pairwise distances are preserved
        np.testing.assert_allclose(np.linalg.norm(p_world[1:] - p_world[:-1], axis=1),
                                   np.linalg.norm(p_cam[1:] - p_cam[:-1], axis=1), rtol=1e-12)


def test_look_at_camera_sees_its_target_on_the_optical_axis():
    eye, target = np.array([1.0, -2.0, 1.5]), np.array([0.2, 0.3, 0.1])
    cam = make_camera(T_world_camera=look_at(eye, target))
    p = cam.world_to_camera([target])[0]
    np.testing.assert_allclose(p[:2], 0.0, atol=1e-12)
    assert p[2] == pytest.approx(np.linalg.norm(target - eye))
    # the world's up (+z) appears upwards in the image, i.e. towards -y in the optical frame
    above = cam.world_to_camera([target + [0, 0, 0.1]])[0]
    assert above[1] < 0


# --------------------------------------------------------------------------------------------------------------------
# Rig


def test_rig_camera_lookup_names_unknown_camera():
    rig = dg.Rig({"left": make_camera("left"), "right": make_camera("right")})
    assert rig.camera("right").name == "right"
    with pytest.raises(dg.RigError) as exc_info:
        rig.camera("middle")
    assert_names(exc_info, "middle", "name")
    assert "left" in str(exc_info.value) and "right" in str(exc_info.value)


def test_rig_rejects_unknown_principal_misfiled_camera_and_empty():
    with pytest.raises(dg.RigError) as exc_info:
        dg.Rig({"a": make_camera("a")}, principal="b")
    assert exc_info.value.field == "principal"
    assert "'b'" in str(exc_info.value)
    with pytest.raises(dg.RigError) as exc_info:
        dg.Rig({"a": make_camera("b")})
    assert exc_info.value.field == "name"
    with pytest.raises(dg.RigError):
        dg.Rig({})


def _two_camera_rig(rng) -> dg.Rig:
    left = make_camera("left", T_world_camera=random_pose(rng), depth_range=(0.25, 4.5), depth_scale=0.0002,
                       noise=dg.NoiseModel(0.001, 0.002, 0.003, 2.0))
    right = make_camera("right", width=80, height=60, fx=61.25, fy=60.5, cx=40.1, cy=29.7,
                        T_world_camera=random_pose(rng), depth_range=(0.0, math.inf), noise=dg.NoiseModel.none())
    return dg.Rig({"left": left, "right": right}, depth_scale=0.001, principal="right")


def test_save_load_rig_round_trip_is_exact(tmp_path):
    rig = _two_camera_rig(np.random.default_rng(3))
    path = tmp_path / "rig.yaml"
    dg.save_rig(rig, path)
    loaded = dg.load_rig(path)
    assert list(loaded.cameras) == ["left", "right"]
    assert loaded.principal == "right"
    for name, cam in rig.cameras.items():
        got = loaded.cameras[name]
        for key in ("width", "height", "fx", "fy", "cx", "cy", "depth_range", "depth_scale", "noise"):
            assert getattr(got, key) == getattr(cam, key), key
        np.testing.assert_array_equal(got.T_world_camera, cam.T_world_camera)  # bit for bit
    assert loaded.fingerprint() == rig.fingerprint()
    # the file is plain YAML a safe loader reads
    assert isinstance(yaml.safe_load(path.read_text()), dict)


def test_fingerprint_is_deterministic():
    a = _two_camera_rig(np.random.default_rng(5))
    b = _two_camera_rig(np.random.default_rng(5))
    assert a is not b
    assert a.fingerprint() == b.fingerprint()
    assert len(a.fingerprint()) == 64


def _perturbed_T(cam):
    T = np.array(cam.T_world_camera)
    T[2, 3] += 1e-9
    return T


def _rotated_T(cam):
    c, s = math.cos(1e-6), math.sin(1e-6)
    return np.array(cam.T_world_camera) @ np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])


@pytest.mark.parametrize(
    "change",
    [
        lambda c: dict(width=c.width + 1),
        lambda c: dict(height=c.height - 1),
        lambda c: dict(fx=c.fx + 1e-9),
        lambda c: dict(fy=c.fy * 1.001),
        lambda c: dict(cx=c.cx + 0.5),
        lambda c: dict(cy=c.cy - 1e-6),
        lambda c: dict(T_world_camera=_perturbed_T(c)),
        lambda c: dict(T_world_camera=_rotated_T(c)),
        lambda c: dict(depth_range=(c.depth_range[0] + 0.01, c.depth_range[1])),
        lambda c: dict(depth_range=(c.depth_range[0], 3.0)),
    ],
    ids=["width", "height", "fx", "fy", "cx", "cy", "translation", "rotation", "depth_min", "depth_max"],
)
def test_fingerprint_changes_with_every_geometric_field(change):
    rig = _two_camera_rig(np.random.default_rng(9))
    for name in rig.cameras:
        cameras = dict(rig.cameras)
        cameras[name] = cameras[name].replace(**change(cameras[name]))
        other = dg.Rig(cameras, depth_scale=rig.depth_scale, principal=rig.principal)
        assert other.fingerprint() != rig.fingerprint(), name


def test_fingerprint_changes_with_names_order_and_principal():
    rig = _two_camera_rig(np.random.default_rng(9))
    left, right = rig.cameras["left"], rig.cameras["right"]
    base = rig.fingerprint()
    assert dg.Rig({"left": left, "right": right}, principal="left").fingerprint() != base
    assert dg.Rig({"left": left, "right": right}).fingerprint() != base
    renamed = left.replace(name="left2")
    assert dg.Rig({"left2": renamed, "right": right}, principal="right").fingerprint() != base
    assert dg.Rig({"left": left}).fingerprint() != dg.Rig({"left": left, "right": right}).fingerprint()


# --------------------------------------------------------------------------------------------------------------------
# load_rig: good files and every kind of bad one


def test_load_rig_reads_the_spec_example(tmp_path):
    text = """
depth_scale: 0.001
principal: right
cameras:
  - name: right
    width: 640
    height: 480
    fx: 525.0
    fy: 525.0
    cx: 319.5
    cy: 239.5
    T_world_camera:
      - [1, 0, 0, 0]
      - [0, 1, 0, 0]
      - [0, 0, 1, 0]
      - [0, 0, 0, 1]
    depth_range: [0.4, 4.5]
"""
    path = tmp_path / "rig.yaml"
    path.write_text(text)
    rig = dg.load_rig(path)
    cam = rig.camera("right")
    assert rig.principal == "right"
    assert (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy) == (640, 480, 525.0, 525.0, 319.5, 239.5)
    assert cam.depth_range == (0.4, 4.5)
    assert cam.depth_scale == 0.001


@pytest.mark.parametrize("field", ["width", "height", "fx", "fy", "cx", "cy", "T_world_camera"])
def test_load_rig_missing_field_names_camera_and_field(tmp_path, field):
    entry = camera_entry("wrist")
    del entry[field]
    path = tmp_path / "rig.yaml"
    write_rig(path, {"cameras": [camera_entry("ok"), entry]})
    with pytest.raises(dg.RigError) as exc_info:
        dg.load_rig(path)
    assert_names(exc_info, "wrist", field)
    assert "rig.yaml" in str(exc_info.value)


def _R(deg):
    a = math.radians(deg)
    return [[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]]


def _T_rows(R, t=(0.0, 0.0, 1.0)):
    return [list(map(float, R[0])) + [t[0]], list(map(float, R[1])) + [t[1]], list(map(float, R[2])) + [t[2]],
            [0.0, 0.0, 0.0, 1.0]]


@pytest.mark.parametrize(
    "changes, field",
    [
        (dict(T_world_camera=_T_rows([[1, 0, 0], [0, 1, 0.01], [0, 0, 1]])), "T_world_camera"),   # not orthonormal
        (dict(T_world_camera=_T_rows([[2, 0, 0], [0, 2, 0], [0, 0, 2]])), "T_world_camera"),      # scaled
        (dict(T_world_camera=_T_rows([[1, 0, 0], [0, 1, 0], [0, 0, -1]])), "T_world_camera"),     # det -1
        (dict(T_world_camera=_T_rows([[0, 1, 0], [1, 0, 0], [0, 0, 1]])), "T_world_camera"),      # det -1, swap
        (dict(T_world_camera=_T_rows(_R(30), (0.0, math.nan, 1.0))), "T_world_camera"),          # NaN
        (dict(T_world_camera=[[1, 0, 0], [0, 1, 0], [0, 0, 1]]), "T_world_camera"),              # 3x3
        (dict(T_world_camera="identity"), "T_world_camera"),
        (dict(fx=0.0), "fx"),
        (dict(fy=-525.0), "fy"),
        (dict(fx=math.nan), "fx"),
        (dict(cx="centre"), "cx"),
        (dict(width=0), "width"),
        (dict(height=480.5), "height"),
        (dict(depth_range=[4.5, 0.4]), "depth_range"),
        (dict(depth_range=[-1.0, 4.0]), "depth_range"),
        (dict(depth_range=[0.4]), "depth_range"),
        (dict(depth_range=[0.4, 4.5, 6.0]), "depth_range"),
        (dict(depth_range="0.4..4.5"), "depth_range"),
        (dict(depth_range=[math.nan, 4.0]), "depth_range"),
        (dict(depth_range=[0.4, None]), "depth_range"),
        (dict(depth_scale=0), "depth_scale"),
        (dict(depth_scale="mm"), "depth_scale"),
        (dict(noise={"a": 0.001, "k": -3.0}), "noise"),
        (dict(noise={"sigma": 0.01}), "noise"),
        (dict(distortion=[0.1, 0.0, 0.0, 0.0, 0.0]), "distortion"),
    ],
)
def test_load_rig_bad_field_names_camera_and_field(tmp_path, changes, field):
    path = tmp_path / "rig.yaml"
    write_rig(path, {"cameras": [camera_entry("left"), camera_entry("right", **changes)]})
    with pytest.raises(dg.RigError) as exc_info:
        dg.load_rig(path)
    assert_names(exc_info, "right", field)
    assert "rig.yaml" in str(exc_info.value)


def test_load_rig_accepts_zero_distortion_and_inf_max_range(tmp_path):
    path = tmp_path / "rig.yaml"
    write_rig(path, {"cameras": [camera_entry("a", distortion=[0, 0, 0, 0, 0], depth_range=[0.2, math.inf])]})
    assert dg.load_rig(path).camera("a").depth_range == (0.2, math.inf)


def test_load_rig_duplicate_names(tmp_path):
    path = tmp_path / "rig.yaml"
    write_rig(path, {"cameras": [camera_entry("a"), camera_entry("b"), camera_entry("a", fx=60.0)]})
    with pytest.raises(dg.RigError) as exc_info:
        dg.load_rig(path)
    assert_names(exc_info, "a", "name")
    assert "twice" in str(exc_info.value)


def test_load_rig_unknown_principal(tmp_path):
    path = tmp_path / "rig.yaml"
    write_rig(path, {"principal": "center", "cameras": [camera_entry("left"), camera_entry("right")]})
    with pytest.raises(dg.RigError) as exc_info:
        dg.load_rig(path)
    assert exc_info.value.field == "principal"
    message = str(exc_info.value)
    assert "'center'" in message and "left" in message and "right" in message


@pytest.mark.parametrize(
    "data, field",
    [
        ({"cameras": []}, "cameras"),
        ({"cameras": {"a": camera_entry("a")}}, "cameras"),
        ({"cameras": ["a"]}, "cameras"),
        ({"cameras": [dict(camera_entry(), name="")]}, "name"),
        ({"cameras": [dict(camera_entry(), name=7)]}, "name"),
        ({"depth_scale": -1.0, "cameras": [camera_entry()]}, "depth_scale"),
        ({"principal": 3, "cameras": [camera_entry()]}, "principal"),
        ({"noise": [1, 2], "cameras": [camera_entry()]}, "noise"),
    ],
)
def test_load_rig_bad_structure_names_field(tmp_path, data, field):
    path = tmp_path / "rig.yaml"
    write_rig(path, data)
    with pytest.raises(dg.RigError) as exc_info:
        dg.load_rig(path)
    assert exc_info.value.field == field
    assert field in str(exc_info.value)


@pytest.mark.parametrize(
    "text",
    [
        "cameras: [\n  - {name: a\n",          # unclosed flow collection
        "cameras:\n  - name: a\n    fx: [1, 2\n",
        "cameras:\n\t- name: a\n",                # tab indentation
        "? [1]\n: 2\n",                           # unhashable key
        "",                                       # empty file
        "- just\n- a list\n",                     # not a mapping
        "42\n",
    ],
)
def test_load_rig_malformed_yaml_names_file(tmp_path, text):
    path = tmp_path / "broken.yaml"
    path.write_text(text)
    with pytest.raises(dg.RigError) as exc_info:
        dg.load_rig(path)
    assert "broken.yaml" in str(exc_info.value)
    assert "\n" not in str(exc_info.value)  # one line, for a log or a CLI


def test_load_rig_binary_or_missing_file(tmp_path):
    path = tmp_path / "rig.yaml"
    path.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe\x00\x00garbage")
    with pytest.raises(dg.RigError) as exc_info:
        dg.load_rig(path)
    assert "rig.yaml" in str(exc_info.value)
    with pytest.raises(dg.RigError) as exc_info:
        dg.load_rig(tmp_path / "absent.yaml")
    assert "absent.yaml" in str(exc_info.value)
    with pytest.raises(dg.RigError):
        dg.load_rig(tmp_path)  # a directory


@pytest.mark.parametrize(
    "template",
    [
        'cameras: !!python/object/apply:os.system ["echo hacked > {marker}"]\n',
        '!!python/object/apply:os.system ["echo hacked > {marker}"]\n',
        'cameras:\n  - name: !!python/object/apply:os.system ["echo hacked > {marker}"]\n',
        'cameras: !!python/object/new:subprocess.Popen [["sh", "-c", "echo hacked > {marker}"]]\n',
        'x: !!python/name:os.system\n',
    ],
)
def test_load_rig_refuses_python_tags_and_runs_nothing(tmp_path, template):
    marker = tmp_path / "HACKED"
    path = tmp_path / "evil.yaml"
    path.write_text(template.format(marker=marker))
    with pytest.raises(dg.RigError) as exc_info:
        dg.load_rig(path)
    assert "evil.yaml" in str(exc_info.value)
    assert not marker.exists()


# --------------------------------------------------------------------------------------------------------------------
# camera_info files (ROS)

K = [518.0, 0.0, 325.5, 0.0, 519.0, 253.5, 0.0, 0.0, 1.0]
P = [500.0, 0.0, 320.0, 0.0, 0.0, 501.0, 240.0, 0.0, 0.0, 0.0, 1.0, 0.0]


def calibration_file(distortion=(0.0, 0.0, 0.0, 0.0, 0.0), **changes) -> dict:
    """The layout the ROS camera_calibration package writes (ost.yaml)."""
    data = {
        "image_width": 640,
        "image_height": 480,
        "camera_name": "depth",
        "camera_matrix": {"rows": 3, "cols": 3, "data": list(K)},
        "distortion_model": "plumb_bob",
        "distortion_coefficients": {"rows": 1, "cols": 5, "data": list(distortion)},
        "rectification_matrix": {"rows": 3, "cols": 3, "data": [1, 0, 0, 0, 1, 0, 0, 0, 1]},
        "projection_matrix": {"rows": 3, "cols": 4, "data": list(P)},
    }
    data.update(changes)
    return data


def camera_info_message(distortion=(0.0, 0.0, 0.0, 0.0, 0.0), upper=False, **changes) -> dict:
    """A sensor_msgs/CameraInfo message dumped as YAML (ROS 2 lower-case fields, or ROS 1 upper-case K, D, P)."""
    data = {
        "header": {"frame_id": "depth_optical_frame"},
        "height": 480,
        "width": 640,
        "distortion_model": "plumb_bob",
        ("D" if upper else "d"): list(distortion),
        ("K" if upper else "k"): list(K),
        ("R" if upper else "r"): [1, 0, 0, 0, 1, 0, 0, 0, 1],
        ("P" if upper else "p"): list(P),
        "binning_x": 0,
        "binning_y": 0,
    }
    data.update(changes)
    return data


LAYOUTS = {
    "camera_calibration": calibration_file,
    "CameraInfo": camera_info_message,
    "CameraInfo ROS 1": lambda **kw: camera_info_message(upper=True, **kw),
}


@pytest.mark.parametrize("layout", LAYOUTS)
def test_camera_info_zero_distortion_uses_K(tmp_path, layout):
    path = tmp_path / "info.yaml"
    path.write_text(yaml.safe_dump(LAYOUTS[layout]()))
    info = dg.load_camera_info(path, camera="depth")
    assert info == dict(width=640, height=480, fx=518.0, fy=519.0, cx=325.5, cy=253.5)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_camera_info_distortion_refused_unless_rectified(tmp_path, layout):
    path = tmp_path / "info.yaml"
    path.write_text(yaml.safe_dump(LAYOUTS[layout](distortion=(0.12, -0.25, 0.001, 0.0, 0.08))))
    with pytest.raises(dg.RigError) as exc_info:
        dg.load_camera_info(path, camera="depth")
    assert_names(exc_info, "depth", "distortion_coefficients")
    info = dg.load_camera_info(path, camera="depth", rectified=True)
    assert info == dict(width=640, height=480, fx=500.0, fy=501.0, cx=320.0, cy=240.0)  # from P, not K


@pytest.mark.parametrize("layout", ["camera_calibration", "CameraInfo"])
def test_camera_info_rectified_without_P_is_refused(tmp_path, layout):
    data = LAYOUTS[layout](distortion=(0.1, 0, 0, 0, 0))
    data.pop("projection_matrix", None)
    data.pop("p", None)
    path = tmp_path / "info.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(dg.RigError) as exc_info:
        dg.load_camera_info(path, camera="depth", rectified=True)
    assert_names(exc_info, "depth", "projection_matrix")


@pytest.mark.parametrize(
    "changes, field",
    [
        (dict(camera_matrix={"rows": 3, "cols": 3, "data": K[:8]}), "camera_matrix"),
        (dict(camera_matrix=518.0), "camera_matrix"),
        (dict(camera_matrix={"rows": 3, "cols": 3, "data": ["a"] * 9}), "camera_matrix"),
        (dict(camera_matrix={"rows": 3, "cols": 3, "data": [518.0, 0, math.nan, 0, 519.0, 253.5, 0, 0, 1]}),
         "camera_matrix"),
        (dict(distortion_coefficients={"rows": 1, "cols": 5, "data": [math.nan, 0, 0, 0, 0]}),
         "distortion_coefficients"),
        (dict(distortion_coefficients={"rows": 1, "cols": 2, "data": ["x", "y"]}), "distortion_coefficients"),
    ],
)
def test_camera_info_bad_matrix_names_camera_and_field(tmp_path, changes, field):
    path = tmp_path / "info.yaml"
    path.write_text(yaml.safe_dump(calibration_file(**changes)))
    with pytest.raises(dg.RigError) as exc_info:
        dg.load_camera_info(path, camera="depth")
    assert_names(exc_info, "depth", field)


def test_camera_info_P_with_nan_is_refused(tmp_path):
    bad_P = list(P)
    bad_P[5] = math.nan
    path = tmp_path / "info.yaml"
    path.write_text(yaml.safe_dump(camera_info_message(p=bad_P)))
    with pytest.raises(dg.RigError) as exc_info:
        dg.load_camera_info(path, camera="depth", rectified=True)
    assert_names(exc_info, "depth", "projection_matrix")


def _with(layout, field, value, **changes):
    """The layout's file with one matrix (named by its camera_calibration name) replaced by ``value`` (9 or 12
    numbers), under that layout's key."""
    data = LAYOUTS[layout](**changes)
    key = {"camera_calibration": field,
           "CameraInfo": {"rectification_matrix": "r", "projection_matrix": "p", "camera_matrix": "k"}[field],
           "CameraInfo ROS 1": {"rectification_matrix": "R", "projection_matrix": "P", "camera_matrix": "K"}[field]}
    data[key[layout]] = {"rows": 3, "cols": len(value) // 3, "data": list(value)} if layout == "camera_calibration" \
        else list(value)
    return data


# A rectification matrix that turns the rectified frame 2 degrees about y (a stereo pair's left camera): the rectified
# image's rays are the raw camera's turned by R, so with R ignored every ray would be off by 2 degrees, 7 cm at 2 m.
_ANGLE = math.radians(2.0)
R_TURNED = [math.cos(_ANGLE), 0.0, math.sin(_ANGLE), 0.0, 1.0, 0.0, -math.sin(_ANGLE), 0.0, math.cos(_ANGLE)]


@pytest.mark.parametrize("rectified", [False, True])
@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("R", [R_TURNED, [0.0] * 9, [-1.0, 0, 0, 0, -1.0, 0, 0, 0, 1.0], [1, 0, 0, 0, 1, 0, 0, 0, 1.001]],
                         ids=["2 degrees", "zeros (uncalibrated)", "half turn", "scaled"])
def test_camera_info_rectification_other_than_identity_is_refused(tmp_path, layout, rectified, R):
    path = tmp_path / "info.yaml"
    path.write_text(yaml.safe_dump(_with(layout, "rectification_matrix", R)))
    with pytest.raises(dg.RigError) as exc_info:
        dg.load_camera_info(path, camera="depth", rectified=rectified)
    assert_names(exc_info, "depth", "rectification_matrix")
    assert "identity" in str(exc_info.value)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_camera_info_rectification_identity_within_tolerance_or_absent_is_accepted(tmp_path, layout):
    path = tmp_path / "info.yaml"
    nearly = [1.0 + 0.5e-6, 0.5e-6, 0, 0, 1.0, 0, 0, 0, 1.0]
    path.write_text(yaml.safe_dump(_with(layout, "rectification_matrix", nearly)))
    assert dg.load_camera_info(path, camera="depth")["fx"] == 518.0
    data = LAYOUTS[layout]()
    for key in ("rectification_matrix", "r", "R"):
        data.pop(key, None)
    path.write_text(yaml.safe_dump(data))
    assert dg.load_camera_info(path, camera="depth", rectified=True)["fx"] == 500.0
    path.write_text(yaml.safe_dump(_with(layout, "rectification_matrix", [1.0, 0, 0, 0, 1.0, 0, 0, 0])))
    with pytest.raises(dg.RigError) as exc_info:  # 8 numbers: not a 3x3 matrix
        dg.load_camera_info(path, camera="depth")
    assert_names(exc_info, "depth", "rectification_matrix")


def test_rig_with_a_turned_rectification_is_refused_naming_the_camera(tmp_path):
    for distortion, rectified in (((0.0,) * 5, False), ((0.1, 0, 0, 0, 0), True)):
        info = _with("CameraInfo", "rectification_matrix", R_TURNED, distortion=distortion)
        with pytest.raises(dg.RigError) as exc_info:
            dg.load_rig(_rig_with_camera_info(tmp_path, info, rectified=rectified))
        assert_names(exc_info, "depth", "rectification_matrix")
        assert "rig.yaml" in str(exc_info.value)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_camera_info_K_for_raw_images_P_for_rectified_ones(tmp_path, layout):
    """K and P differ (P was chosen for the rectified image): each image gets its own matrix, never the other's."""
    path = tmp_path / "info.yaml"
    path.write_text(yaml.safe_dump(LAYOUTS[layout]()))
    assert dg.load_camera_info(path, camera="depth") == dict(width=640, height=480, fx=518.0, fy=519.0, cx=325.5,
                                                             cy=253.5)
    assert dg.load_camera_info(path, camera="depth", rectified=True) == dict(width=640, height=480, fx=500.0,
                                                                             fy=501.0, cx=320.0, cy=240.0)


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("index, value", [(3, -38.0), (7, 5.0), (1, 0.5), (8, 0.1), (10, 2.0), (11, 1.0)],
                         ids=["Tx (stereo baseline)", "Ty", "skew", "last row x", "last row z", "last row w"])
def test_camera_info_projection_that_is_not_a_pinhole_is_refused_when_used(tmp_path, layout, index, value):
    bad = list(P)
    bad[index] = value
    path = tmp_path / "info.yaml"
    path.write_text(yaml.safe_dump(_with(layout, "projection_matrix", bad)))
    with pytest.raises(dg.RigError) as exc_info:
        dg.load_camera_info(path, camera="depth", rectified=True)
    assert_names(exc_info, "depth", "projection_matrix")
    assert dg.load_camera_info(path, camera="depth")["fx"] == 518.0  # an image that is not rectified: K, P unused


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("model, count", [("plumb_bob", 5), ("rational_polynomial", 8), ("equidistant", 4),
                                          ("fisheye", 4), ("", 5), ("my_model", 3)])
def test_camera_info_non_zero_distortion_is_refused_for_every_model(tmp_path, layout, model, count):
    for index in range(count):
        distortion = [0.0] * count
        distortion[index] = 1e-9
        path = tmp_path / "info.yaml"
        path.write_text(yaml.safe_dump(LAYOUTS[layout](distortion=distortion, distortion_model=model)))
        with pytest.raises(dg.RigError) as exc_info:
            dg.load_camera_info(path, camera="depth")
        assert_names(exc_info, "depth", "distortion_coefficients")
        # A rectified image: the distortion was undone, whatever its model; the intrinsics are P's.
        assert dg.load_camera_info(path, camera="depth", rectified=True)["fx"] == 500.0


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("model, accepted", [("plumb_bob", True), ("rational_polynomial", True), ("", True),
                                             ("equidistant", False), ("fisheye", False), ("none", False),
                                             ("Plumb_Bob", False), ("my_model", False)])
def test_camera_info_zero_distortion_is_a_pinhole_only_for_plumb_bob_and_rational_polynomial(tmp_path, layout, model,
                                                                                            accepted):
    """Zero coefficients of equidistant (fisheye) still map the angle, not its tangent, to the pixel: r = f theta. A
    pinhole reading of such an image would put a ray at 60 degrees off axis at 1.73 f instead of 1.05 f."""
    path = tmp_path / "info.yaml"
    path.write_text(yaml.safe_dump(LAYOUTS[layout](distortion=[0.0] * 4, distortion_model=model)))
    if accepted:
        assert dg.load_camera_info(path, camera="depth")["fx"] == 518.0
    else:
        with pytest.raises(dg.RigError) as exc_info:
            dg.load_camera_info(path, camera="depth")
        assert_names(exc_info, "depth", "distortion_model")
        assert repr(model) in str(exc_info.value)
    assert dg.load_camera_info(path, camera="depth", rectified=True)["fx"] == 500.0
    data = LAYOUTS[layout](distortion=[0.0] * 4)
    data.pop("distortion_model")  # no model given: zero coefficients are no distortion
    path.write_text(yaml.safe_dump(data))
    assert dg.load_camera_info(path, camera="depth")["fx"] == 518.0


@pytest.mark.parametrize("layout", ["CameraInfo", "CameraInfo ROS 1"])
@pytest.mark.parametrize("rectified", [False, True])
def test_camera_info_binning_is_refused_naming_its_axis(tmp_path, layout, rectified):
    path = tmp_path / "info.yaml"
    for key in ("binning_x", "binning_y"):
        for value in (0, 1):
            path.write_text(yaml.safe_dump(LAYOUTS[layout](**{key: value})))
            assert dg.load_camera_info(path, camera="depth", rectified=rectified)["width"] == 640
        path.write_text(yaml.safe_dump(LAYOUTS[layout](**{key: 2})))
        with pytest.raises(dg.RigError) as exc_info:
            dg.load_camera_info(path, camera="depth", rectified=rectified)
        assert_names(exc_info, "depth", key)


def _roi(x_offset=0, y_offset=0, width=0, height=0, do_rectify=False) -> dict:
    return dict(x_offset=x_offset, y_offset=y_offset, width=width, height=height, do_rectify=do_rectify)


@pytest.mark.parametrize("roi", [_roi(), _roi(width=640, height=480), _roi(do_rectify=True)],
                         ids=["zero", "whole image", "do_rectify"])
def test_camera_info_roi_of_the_whole_image_is_accepted(tmp_path, roi):
    path = tmp_path / "info.yaml"
    path.write_text(yaml.safe_dump(camera_info_message(roi=roi)))
    assert dg.load_camera_info(path, camera="depth")["fx"] == 518.0


@pytest.mark.parametrize(
    "roi, rectified",
    [(_roi(x_offset=1), False), (_roi(y_offset=3, width=640, height=480), False), (_roi(width=320, height=240), False),
     (_roi(width=640), False), (_roi(width=641, height=480), False), (_roi(x_offset=10, width=320, height=240), True),
     (_roi(do_rectify=True), True), (_roi(width=640, height=480, do_rectify=True), True)],
    ids=["offset, zero size", "offset, whole size", "smaller", "width only", "wider than the image", "rectified smaller",
         "rectified do_rectify", "rectified do_rectify whole"],
)
def test_camera_info_roi_smaller_than_the_image_or_rectified_is_refused(tmp_path, roi, rectified):
    path = tmp_path / "info.yaml"
    path.write_text(yaml.safe_dump(camera_info_message(distortion=(0.1, 0, 0, 0, 0) if rectified else (0,) * 5,
                                                       roi=roi)))
    with pytest.raises(dg.RigError) as exc_info:
        dg.load_camera_info(path, camera="depth", rectified=rectified)
    assert_names(exc_info, "depth", "roi")


@pytest.mark.parametrize(
    "content",
    [
        yaml.safe_dump({k: v for k, v in calibration_file().items() if k != "image_width"}),
        "image_width: [640\n",
        "just a string\n",
        b"\xff\xfe\x00\x01\x80 binary",
    ],
    ids=["no width", "malformed", "not a mapping", "binary"],
)
def test_camera_info_unreadable_names_camera(tmp_path, content):
    path = tmp_path / "info.yaml"
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(dg.RigError) as exc_info:
        dg.load_camera_info(path, camera="depth")
    assert exc_info.value.camera == "depth"
    assert "'depth'" in str(exc_info.value)


def test_camera_info_refuses_python_tags(tmp_path):
    marker = tmp_path / "HACKED"
    path = tmp_path / "info.yaml"
    path.write_text(f'image_width: !!python/object/apply:os.system ["echo hacked > {marker}"]\n')
    with pytest.raises(dg.RigError):
        dg.load_camera_info(path, camera="depth")
    assert not marker.exists()


def _rig_with_camera_info(tmp_path, info: dict, **entry_changes):
    """A rig in a sub-folder whose camera takes its intrinsics from a camera_info file beside it."""
    folder = tmp_path / "config"
    folder.mkdir(exist_ok=True)
    (folder / "info.yaml").write_text(yaml.safe_dump(info))
    entry = {"name": "depth", "camera_info": "info.yaml", "T_world_camera": np.eye(4).tolist()}
    entry.update(entry_changes)
    path = folder / "rig.yaml"
    write_rig(path, {"cameras": [entry]})
    return path


def test_rig_camera_info_path_is_relative_to_the_rig_file(tmp_path, monkeypatch):
    path = _rig_with_camera_info(tmp_path, calibration_file())
    monkeypatch.chdir(tmp_path)  # not the rig's folder: a path taken relative to the cwd would not be found
    cam = dg.load_rig("config/rig.yaml").camera("depth")
    assert (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy) == (640, 480, 518.0, 519.0, 325.5, 253.5)
    assert dg.load_rig(path).fingerprint() == dg.load_rig("config/rig.yaml").fingerprint()


def test_rig_camera_info_rectified_uses_P_and_entry_overrides(tmp_path):
    info = camera_info_message(distortion=(0.1, -0.2, 0, 0, 0))
    with pytest.raises(dg.RigError) as exc_info:
        dg.load_rig(_rig_with_camera_info(tmp_path, info))
    assert_names(exc_info, "depth", "distortion_coefficients")
    cam = dg.load_rig(_rig_with_camera_info(tmp_path, info, rectified=True)).camera("depth")
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (500.0, 501.0, 320.0, 240.0)
    # keys written in the rig entry win over the file
    cam = dg.load_rig(_rig_with_camera_info(tmp_path, camera_info_message(), fx=600.0)).camera("depth")
    assert (cam.fx, cam.fy) == (600.0, 519.0)


@pytest.mark.parametrize("value", ["false", "yes", 1, [True]])
def test_rig_rectified_must_be_a_boolean(tmp_path, value):
    info = camera_info_message(distortion=(0.1, 0, 0, 0, 0))
    with pytest.raises(dg.RigError) as exc_info:
        dg.load_rig(_rig_with_camera_info(tmp_path, info, rectified=value))
    assert_names(exc_info, "depth", "rectified")


def test_rig_camera_info_missing_file_names_camera(tmp_path):
    path = _rig_with_camera_info(tmp_path, calibration_file(), camera_info="nowhere.yaml")
    with pytest.raises(dg.RigError) as exc_info:
        dg.load_rig(path)
    assert_names(exc_info, "depth", "camera_info")
    assert "nowhere.yaml" in str(exc_info.value)


def test_rig_camera_info_bad_focal_length_names_camera(tmp_path):
    info = calibration_file(camera_matrix={"rows": 3, "cols": 3, "data": [0.0, 0, 325.5, 0, 519.0, 253.5, 0, 0, 1]})
    with pytest.raises(dg.RigError) as exc_info:
        dg.load_rig(_rig_with_camera_info(tmp_path, info))
    assert_names(exc_info, "depth", "fx")


def test_rig_from_dict_does_not_modify_its_input():
    data = {"principal": "a", "cameras": [camera_entry("a"), camera_entry("b")]}
    before = copy.deepcopy(data)
    dg.rig_from_dict(data)
    assert data == before
