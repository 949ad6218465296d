"""Issue 12: every input is validated where it enters, and bad input gets a named DepthguardError, never a crash or a
silently optimistic answer.

Expected values come from the rules (docs/design.md §2, §8 "Time" and §11, ``depthguard.config``'s ranges), not
from what the program happens to print.
"""

from __future__ import annotations

import math
import os

import numpy as np
import pytest
import yaml

import depthguard as dg
from depthguard import config

# --------------------------------------------------------------------------------------------------------------------
# rig files: unknown keys, types, ranges

CAMERA_KEYS = ("name", "width", "height", "fx", "fy", "cx", "cy", "T_world_camera", "depth_range", "depth_scale",
               "noise", "camera_info", "rectified", "distortion")
RIG_KEYS = ("depth_scale", "principal", "noise", "workspace", "cameras")


def camera_entry(name="cam", **changes) -> dict:
    entry = dict(name=name, width=64, height=48, fx=50.0, fy=52.0, cx=31.5, cy=23.5,
                 T_world_camera=np.eye(4).tolist(), depth_range=[0.3, 5.0])
    entry.update(changes)
    return entry


def load_text(tmp_path, text: str) -> dg.Rig:
    path = tmp_path / "rig.yaml"
    path.write_text(text)
    return dg.load_rig(path)


def load_data(tmp_path, data: dict) -> dg.Rig:
    return load_text(tmp_path, yaml.safe_dump(data, sort_keys=False))


def assert_lists_known_keys(message: str, keys) -> None:
    assert "known keys: " + ", ".join(keys) in message


@pytest.mark.parametrize("typo, meant", [("fxx", "fx"), ("depth_rnage", "depth_range"),
                                         ("T_world_cam", "T_world_camera"), ("Width", "width")])
def test_misspelled_camera_key_is_refused_naming_it_and_listing_the_known_keys(tmp_path, typo, meant):
    entry = camera_entry("left")
    entry[typo] = entry.pop(meant)
    with pytest.raises(dg.RigError) as exc_info:
        load_data(tmp_path, {"cameras": [entry]})
    exc = exc_info.value
    assert exc.camera == "left" and exc.field == typo
    message = str(exc)
    assert f"unknown key {typo!r}" in message and f"did you mean {meant!r}" in message
    assert_lists_known_keys(message, CAMERA_KEYS)
    assert "rig.yaml" in message and "\n" not in message


def test_an_extra_camera_key_is_refused_even_when_everything_else_is_there(tmp_path):
    with pytest.raises(dg.RigError) as exc_info:
        load_data(tmp_path, {"cameras": [camera_entry("left", colour="red")]})
    assert exc_info.value.field == "colour"
    assert_lists_known_keys(str(exc_info.value), CAMERA_KEYS)


def test_misspelled_rig_key_is_refused(tmp_path):
    with pytest.raises(dg.RigError) as exc_info:
        load_data(tmp_path, {"principle": "cam", "cameras": [camera_entry()]})
    assert exc_info.value.field == "principle" and exc_info.value.camera is None
    assert "did you mean 'principal'" in str(exc_info.value)
    assert_lists_known_keys(str(exc_info.value), RIG_KEYS)


def test_unknown_noise_key_is_refused_listing_a_b_c_k(tmp_path):
    with pytest.raises(dg.RigError) as exc_info:
        load_data(tmp_path, {"noise": {"a": 0.001, "sigma": 0.01}, "cameras": [camera_entry()]})
    assert exc_info.value.field == "noise"
    assert "'sigma'" in str(exc_info.value)
    assert_lists_known_keys(str(exc_info.value), ("a", "b", "c", "k"))


@pytest.mark.parametrize("key", ["D", "d"])
def test_distortion_under_D_or_d_is_refused_not_dropped(tmp_path, key):
    with pytest.raises(dg.RigError) as exc_info:
        load_data(tmp_path, {"cameras": [camera_entry("left", **{key: [0.1, 0.0, 0.0, 0.0, 0.0]})]})
    assert exc_info.value.camera == "left" and exc_info.value.field == key
    assert "'distortion'" in str(exc_info.value)  # the hint: where distortion belongs
    # even zero coefficients under the wrong key are refused: the key is unknown
    with pytest.raises(dg.RigError):
        load_data(tmp_path, {"cameras": [camera_entry("left", **{key: [0.0] * 5})]})


def test_rig_with_yaml_anchor_and_alias_is_refused(tmp_path):
    text = """
cameras:
  - &cam
    name: a
    width: 64
    height: 48
    fx: 50.0
    fy: 50.0
    cx: 31.5
    cy: 23.5
    T_world_camera: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
  - *cam
"""
    with pytest.raises(dg.RigError) as exc_info:
        load_text(tmp_path, text)
    assert "rig.yaml" in str(exc_info.value)
    assert "anchor" in str(exc_info.value) or "alias" in str(exc_info.value)


def test_rig_with_a_duplicate_key_is_refused(tmp_path):
    text = yaml.safe_dump({"cameras": [camera_entry("a")]}, sort_keys=False).replace("  fx: 50.0\n",
                                                                                     "  fx: 50.0\n  fx: 500.0\n")
    assert text.count("fx:") == 2
    with pytest.raises(dg.RigError) as exc_info:
        load_text(tmp_path, text)
    assert "duplicate" in str(exc_info.value)


BIG = "1" * 400


@pytest.mark.parametrize(
    "key, value, field",
    [
        ("fx", BIG, "fx"), ("fx", ".nan", "fx"), ("fx", ".inf", "fx"), ("fy", "-.inf", "fy"), ("cx", ".nan", "cx"),
        ("cy", BIG, "cy"), ("width", BIG, "width"), ("height", "-" + BIG, "height"),
        ("width", str(config.MAX_IMAGE_SIDE + 1), "width"), ("fx", "true", "fx"), ("fx", "'525'", "fx"),
        ("width", "640.0", "width"), ("depth_scale", ".nan", "depth_scale"), ("depth_scale", BIG, "depth_scale"),
        ("depth_scale", ".inf", "depth_scale"), ("depth_range", f"[0.3, {BIG}.0]", None),
        ("depth_range", "[.nan, 4.0]", "depth_range"), ("depth_range", "[0.3, .nan]", "depth_range"),
        ("depth_range", "[.inf, .inf]", "depth_range"), ("noise", "{k: .inf}", "noise"), ("noise", f"{{a: {BIG}}}",
                                                                                       "noise"),
        ("T_world_camera", f"[[1, 0, 0, {BIG}], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]", "T_world_camera"),
        ("T_world_camera", "[[1, 0, 0, .inf], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]", "T_world_camera"),
        ("T_world_camera", "[[1, 0, 0, 10001], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]", "T_world_camera"),
        ("rectified", "1", "rectified"), ("camera_info", "7", "camera_info"),
        ("distortion", "[.nan, 0, 0, 0, 0]", "distortion"),
    ],
)
def test_numeric_fields_refuse_huge_integers_nan_inf_and_wrong_types(tmp_path, key, value, field):
    lines = [f"  - name: cam"] + [f"    {k}: {v}" for k, v in dict(width=64, height=48, fx=50.0, fy=50.0, cx=31.5,
                                                                     cy=23.5).items() if k != key]
    lines.append("    T_world_camera: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]"
                 if key != "T_world_camera" else f"    T_world_camera: {value}")
    if key != "T_world_camera":
        lines.append(f"    {key}: {value}")
    text = "cameras:\n" + "\n".join(lines) + "\n"
    if field is None:  # a 400-digit maximum depth is a float (1.1e399 -> inf): infinite max range is allowed
        assert load_text(tmp_path, text).camera("cam").depth_range == (0.3, math.inf)
        return
    with pytest.raises(dg.RigError) as exc_info:
        load_text(tmp_path, text)
    assert exc_info.value.camera == "cam" and exc_info.value.field == field
    assert len(str(exc_info.value)) < 400  # a huge value is cut short in the message


def test_rig_level_depth_scale_range(tmp_path):
    for value in (BIG, ".nan", ".inf", "0", "-0.001", "2.0", "'mm'", "true"):
        with pytest.raises(dg.RigError) as exc_info:
            load_text(tmp_path, f"depth_scale: {value}\n" + yaml.safe_dump({"cameras": [camera_entry()]}))
        assert exc_info.value.field == "depth_scale"


def test_max_depth_range_may_be_infinite_and_save_rig_round_trips(tmp_path):
    rig = load_data(tmp_path, {"cameras": [camera_entry("a", depth_range=[0.2, math.inf], noise="none")],
                               "principal": "a", "noise": {"a": 0.001, "b": 0.0, "c": 0.001, "k": 2.0}})
    assert rig.camera("a").depth_range == (0.2, math.inf)
    assert rig.camera("a").noise == dg.NoiseModel.none()
    dg.save_rig(rig, tmp_path / "saved.yaml")
    again = dg.load_rig(tmp_path / "saved.yaml")
    assert again.fingerprint() == rig.fingerprint() and again.camera("a").noise == rig.camera("a").noise


def test_rig_from_dict_accepts_numpy_values_as_a_program_passes_them():
    entry = camera_entry("a", width=np.int64(64), fx=np.float32(50.0), T_world_camera=np.eye(4),
                         depth_range=(0.3, np.float64(5.0)))
    camera = dg.rig_from_dict({"depth_scale": np.float64(0.001), "cameras": (entry,)}).camera("a")
    assert (camera.width, camera.fx, camera.depth_range) == (64, 50.0, (0.3, 5.0))


@pytest.mark.parametrize("path", ["/dev/zero", "/dev/null"])
def test_rig_from_a_device_is_refused_unread(path):
    if not os.path.exists(path):
        pytest.skip(f"no {path}")
    with pytest.raises(dg.RigError) as exc_info:
        dg.load_rig(path)
    assert path in str(exc_info.value)


def test_rig_file_larger_than_the_cap_is_refused(tmp_path):
    path = tmp_path / "rig.yaml"
    path.write_text("# " + "x" * config.MAX_TEXT_FILE_BYTES + "\n")
    with pytest.raises(dg.RigError) as exc_info:
        dg.load_rig(path)
    assert "rig.yaml" in str(exc_info.value)


# --------------------------------------------------------------------------------------------------------------------
# PinholeCamera, NoiseModel and Rig built in Python: wrong types are RigErrors too


def make_camera(**changes) -> dg.PinholeCamera:
    fields = dict(name="cam", width=64, height=48, fx=50.0, fy=52.0, cx=31.5, cy=23.5, T_world_camera=np.eye(4),
                  depth_range=(0.3, 5.0))
    fields.update(changes)
    return dg.PinholeCamera(**fields)


@pytest.mark.parametrize(
    "field, value",
    [
        ("width", "64"), ("width", None), ("width", 10**400), ("width", config.MAX_IMAGE_SIDE + 1),
        ("height", np.float64(48)), ("fx", None), ("fx", 1j), ("fx", "50"), ("fx", 10**400), ("fx", 1e-9),
        ("fy", config.INTRINSICS_LIMIT * 10), ("cx", config.INTRINSICS_LIMIT * 10), ("cy", [23.5]),
        ("T_world_camera", object()), ("T_world_camera", None), ("T_world_camera", "eye"),
        ("depth_range", 5), ("depth_range", None), ("depth_range", (True, 2.0)), ("depth_range", ("0", "1")),
        ("depth_range", (0.3, 1j)), ("depth_scale", "mm"), ("depth_scale", None), ("depth_scale", 2.0),
        ("depth_scale", math.inf), ("noise", "none"), ("noise", None),
    ],
)
def test_camera_constructor_refuses_wrong_types_and_ranges_with_rig_error(field, value):
    with pytest.raises(dg.RigError) as exc_info:
        make_camera(**{field: value})
    assert exc_info.value.camera == "cam" and exc_info.value.field == field


@pytest.mark.parametrize("name", [None, 5, "", "a\nb", "x" * (config.MAX_NAME_LENGTH + 1)])
def test_camera_name_must_be_a_short_printable_string(name):
    with pytest.raises(dg.RigError) as exc_info:
        make_camera(name=name)
    assert exc_info.value.field == "name"
    assert "\n" not in str(exc_info.value)


def test_camera_position_beyond_the_coordinate_limit_is_refused():
    T = np.eye(4)
    T[1, 3] = -config.COORDINATE_LIMIT * 1.01
    with pytest.raises(dg.RigError) as exc_info:
        make_camera(T_world_camera=T)
    assert exc_info.value.field == "T_world_camera"
    T[1, 3] = -config.COORDINATE_LIMIT  # the limit itself is in range
    assert make_camera(T_world_camera=T).T_world_camera[1, 3] == -config.COORDINATE_LIMIT


@pytest.mark.parametrize(
    "kwargs",
    [dict(a=math.nan), dict(b=math.inf), dict(c="0.1"), dict(k=-1.0), dict(k=config.NOISE_K_MAX * 2),
     dict(a=config.NOISE_COEFFICIENT_LIMIT * 2), dict(k=True), dict(a=None), dict(b=10**400)],
)
def test_noise_model_raises_a_rig_error(kwargs):
    with pytest.raises(dg.RigError) as exc_info:
        dg.NoiseModel(**kwargs)
    assert isinstance(exc_info.value, dg.DepthguardError)
    assert exc_info.value.field == "noise" and next(iter(kwargs)) in str(exc_info.value)


def test_rig_constructor_refuses_wrong_types():
    camera = make_camera()
    for kwargs, field in [(dict(cameras=[camera]), "cameras"), (dict(cameras={"cam": "camera"}), "cameras"),
                          (dict(cameras={"cam": camera}, depth_scale=math.nan), "depth_scale"),
                          (dict(cameras={"cam": camera}, depth_scale="0.001"), "depth_scale"),
                          (dict(cameras={"cam": camera}, principal=["cam"]), "principal")]:
        with pytest.raises(dg.RigError) as exc_info:
            dg.Rig(**kwargs)
        assert exc_info.value.field == field
    rig = dg.Rig({"cam": camera})
    with pytest.raises(dg.RigError):
        rig.camera(["cam"])  # unhashable: still a named error, not a TypeError


# --------------------------------------------------------------------------------------------------------------------
# camera_info files: the ROS keys, and nothing else

K = [518.0, 0.0, 325.5, 0.0, 519.0, 253.5, 0.0, 0.0, 1.0]
P = [500.0, 0.0, 320.0, 0.0, 0.0, 501.0, 240.0, 0.0, 0.0, 0.0, 1.0, 0.0]


def calibration_file(**changes) -> dict:
    data = {"image_width": 640, "image_height": 480, "camera_name": "depth",
            "camera_matrix": {"rows": 3, "cols": 3, "data": list(K)}, "distortion_model": "plumb_bob",
            "distortion_coefficients": {"rows": 1, "cols": 5, "data": [0.0] * 5},
            "rectification_matrix": {"rows": 3, "cols": 3, "data": [1, 0, 0, 0, 1, 0, 0, 0, 1]},
            "projection_matrix": {"rows": 3, "cols": 4, "data": list(P)}}
    data.update(changes)
    return data


def message(**changes) -> dict:
    data = {"header": {"stamp": {"sec": 1, "nanosec": 2}, "frame_id": "depth_optical_frame"}, "height": 480,
            "width": 640, "distortion_model": "plumb_bob", "d": [0.0] * 5, "k": list(K),
            "r": [1, 0, 0, 0, 1, 0, 0, 0, 1], "p": list(P), "binning_x": 0, "binning_y": 0,
            "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False}}
    data.update(changes)
    return data


def info(tmp_path, data, rectified=False):
    path = tmp_path / "info.yaml"
    path.write_text(yaml.safe_dump(data))
    return dg.load_camera_info(path, camera="depth", rectified=rectified)


EXPECTED_K = dict(width=640, height=480, fx=518.0, fy=519.0, cx=325.5, cy=253.5)


def test_camera_info_every_ros_key_is_accepted(tmp_path):
    assert info(tmp_path, calibration_file()) == EXPECTED_K
    assert info(tmp_path, message()) == EXPECTED_K
    ros1 = message()
    for key in "dkrp":
        ros1[key.upper()] = ros1.pop(key)
    ros1["header"] = {"seq": 3, "stamp": {"secs": 1, "nsecs": 2}, "frame_id": "x"}
    assert info(tmp_path, ros1) == EXPECTED_K
    full_roi = message(binning_x=1, roi={"x_offset": 0, "y_offset": 0, "height": 480, "width": 640,
                                         "do_rectify": True})
    assert info(tmp_path, full_roi) == EXPECTED_K


@pytest.mark.parametrize("key", ["focal_length", "K_matrix", "image_w", "distortion"])
def test_camera_info_unknown_key_is_refused(tmp_path, key):
    with pytest.raises(dg.RigError) as exc_info:
        info(tmp_path, calibration_file(**{key: 1}))
    assert exc_info.value.camera == "depth"
    assert repr(key) in str(exc_info.value) and "known keys: image_width" in str(exc_info.value)


@pytest.mark.parametrize(
    "changes, field",
    [
        (dict(width=640), "image_width"),                                 # both layouts' width
        (dict(k=list(K)), "camera_matrix"),                                # K twice
        (dict(binning_x=2), "binning_x"),
        (dict(camera_matrix={"rows": 3, "cols": 3, "data": [518.0, 0.5, 325.5, 0, 519.0, 253.5, 0, 0, 1]}),
         "camera_matrix"),                                                 # skew
        (dict(camera_matrix={"rows": 3, "cols": 3, "data": K, "extra": 1}), "camera_matrix"),
        (dict(camera_matrix={"rows": 2, "cols": 3, "data": K}), "camera_matrix"),
        (dict(image_width=640.0), "image_width"),
        (dict(image_height=10**400), "image_height"),
        (dict(camera_matrix={"rows": 3, "cols": 3, "data": [518.0, 0, 325.5, 0, math.inf, 253.5, 0, 0, 1]}),
         "camera_matrix"),
    ],
)
def test_camera_info_bad_content_names_the_field(tmp_path, changes, field):
    with pytest.raises(dg.RigError) as exc_info:
        info(tmp_path, calibration_file(**changes))
    assert exc_info.value.camera == "depth" and exc_info.value.field == field


def test_camera_info_roi_and_stereo_projection_are_refused(tmp_path):
    with pytest.raises(dg.RigError) as exc_info:
        info(tmp_path, message(roi={"x_offset": 10, "y_offset": 0, "height": 240, "width": 320, "do_rectify": False}))
    assert exc_info.value.field == "roi"
    stereo = list(P)
    stereo[3] = -38.0  # -fx * baseline: the right camera of a stereo pair
    with pytest.raises(dg.RigError) as exc_info:
        info(tmp_path, message(p=stereo, d=[0.1, 0, 0, 0, 0]), rectified=True)
    assert exc_info.value.field == "projection_matrix"
    assert info(tmp_path, message(d=[0.1, 0, 0, 0, 0]), rectified=True)["fx"] == 500.0


def test_camera_info_with_an_alias_is_refused(tmp_path):
    path = tmp_path / "info.yaml"
    path.write_text("image_width: &w 640\nimage_height: *w\ncamera_matrix: {data: [1, 0, 1, 0, 1, 1, 0, 0, 1]}\n")
    with pytest.raises(dg.RigError) as exc_info:
        dg.load_camera_info(path, camera="depth")
    assert exc_info.value.camera == "depth"


# --------------------------------------------------------------------------------------------------------------------
# the monitor and the API: wrong types and ranges

from depthguard import Flag  # noqa: E402
from depthguard.depth import DepthImage  # noqa: E402
from depthguard.scenes import Box, render_depth  # noqa: E402
from depthguard.transforms import look_at  # noqa: E402

SCENE = [Box.from_bounds([-3, -3, -0.1], [3, 3, 0.0]), Box.from_bounds([-0.2, -0.2, 0.0], [0.2, 0.2, 0.3])]
IN_VIEW = [[0.0, 0.0, 1.0], [0.3, 0.1, 0.5]]


@pytest.fixture(scope="module")
def top():
    # 2 m above the floor looking down; the box's top is 1.7 m away, the floor 2 m
    return dg.PinholeCamera("top", 64, 48, 50.0, 50.0, 31.5, 23.5, look_at([0, 0, 2], [0, 0, 0], up=(0, 1, 0)),
                            depth_range=(0.3, 4.0), noise=dg.NoiseModel.none())


@pytest.fixture(scope="module")
def side(top):
    return top.replace(name="side", T_world_camera=look_at([2, 0, 1], [0, 0, 0.3]))


@pytest.fixture(scope="module")
def rig(top):
    return dg.Rig({"top": top})


@pytest.fixture(scope="module")
def rig2(top, side):
    return dg.Rig({"top": top, "side": side}, principal="top")


@pytest.fixture(scope="module")
def clean(top):
    return render_depth(top, SCENE)


@pytest.fixture(scope="module")
def clean_side(side):
    return render_depth(side, SCENE)


@pytest.mark.parametrize(
    "options",
    [dict(rho=config.RHO_MIN / 2), dict(rho=config.RHO_MAX * 1.01), dict(rho=True), dict(rho=1j), dict(rho=[0.4]),
     dict(rho=10**400), dict(aggregate=["min"]), dict(aggregate=np.array(["min", "mean"])), dict(unseen=None),
     dict(method=1), dict(invalid=("occupied",)), dict(max_age="0.1"), dict(max_age=math.inf),
     dict(max_age=config.MAX_AGE_LIMIT * 2), dict(max_age=True), dict(hole_pixels=config.MAX_HOLE_PIXELS + 1),
     dict(hole_pixels=10**400), dict(hole_pixels="64"), dict(robot="iiwa"), dict(robot=object()),
     dict(self_filter="boxes"), dict(self_filter=None), dict(self_filter_tolerance=-0.01),
     dict(self_filter_tolerance=math.nan), dict(self_filter_tolerance=config.SELF_FILTER_TOLERANCE_MAX * 2),
     dict(self_filter_tolerance="0.02"), dict(fusion_margin=math.inf), dict(fusion_margin=-1e-3),
     dict(fusion_margin="0.01"), dict(fusion_pixels=-1), dict(fusion_pixels=1.0),
     dict(fusion_pixels=config.MAX_FUSION_PIXELS + 1), dict(maps="map.npz"), dict(maps={"top": "map.npz"}),
     dict(principals="top"), dict(principals="cam"), dict(principals=[]), dict(principals=[1]),
     dict(principals=["top", "top"]), dict(principals={"top"})],
    ids=lambda o: f"{next(iter(o))}={str(next(iter(o.values())))[:20]}",
)
def test_monitor_refuses_wrong_types_and_ranges_naming_the_option(rig, options):
    name = next(iter(options))
    with pytest.raises(dg.InputError) as exc_info:
        dg.DistanceMonitor(rig, **options)
    assert name in str(exc_info.value)


def test_principals_string_is_not_read_as_letters(top):
    rig = dg.Rig({"c": top.replace(name="c"), "a": top.replace(name="a"), "m": top.replace(name="m"),
                  "cam": top.replace(name="cam")})
    with pytest.raises(dg.InputError) as exc_info:
        dg.DistanceMonitor(rig, principals="cam")
    assert exc_info.value.field == "principals" and "list or tuple" in str(exc_info.value)
    assert dg.DistanceMonitor(rig, principals=["cam"]).principals == ("cam",)


def test_map_filed_under_another_principal_is_refused(rig2):
    from depthguard.depthgrid import build_map

    grid = build_map(rig2, "top")
    with pytest.raises(dg.InputError) as exc_info:
        dg.DistanceMonitor(rig2, maps={"side": grid})
    assert "'top'" in str(exc_info.value)


@pytest.mark.parametrize(
    "points",
    [
        np.array([[0.0, 0.0, 1.0 + 0.1j]]),                     # complex: refused, not a warning
        np.array([[True, False, True]]),
        np.array([[0.0, 0.0, 1.0]], dtype=object),
        np.array([["0", "0", "1"]]),
        np.zeros((2, 0)),                                       # (n, 0)
        np.zeros((0, 0)),
        [[]],
        np.ma.masked_array([[0.0, 0.0, 1.0]], mask=[[False, True, False]]),
        np.ma.masked_array([[0.0, 0.0, 1.0]]),                  # masked arrays are refused even without a mask
        b"0,0,1",
        [[0.0, 0.0, config.COORDINATE_LIMIT * 1.5]],
        [[10**400, 0.0, 1.0]],
    ],
    ids=["complex", "bool", "object", "text", "n by 0", "0 by 0", "list of empty", "masked", "masked unmasked",
         "bytes", "too far", "huge int"],
)
def test_points_refused_before_conversion(rig, clean, points):
    with pytest.raises(dg.InputError) as exc_info:
        dg.DistanceMonitor(rig).query({"top": clean}, points)
    assert exc_info.value.field == "points"


def test_point_beyond_the_coordinate_limit_is_named_by_index(rig, clean):
    points = [[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [-2 * config.COORDINATE_LIMIT, 0.0, 0.0]]
    with pytest.raises(dg.InputError) as exc_info:
        dg.DistanceMonitor(rig).query({"top": clean}, points)
    assert "#2" in str(exc_info.value)
    edge = [[config.COORDINATE_LIMIT, 0.0, 0.0]]  # the limit itself is a point
    assert len(dg.DistanceMonitor(rig).query({"top": clean}, edge)) == 1


def test_integer_points_are_accepted_as_metres(rig, clean):
    ints = dg.DistanceMonitor(rig).query({"top": clean}, np.array([[0, 0, 1]], dtype=np.int32))
    floats = dg.DistanceMonitor(rig).query({"top": clean}, [[0.0, 0.0, 1.0]])
    np.testing.assert_array_equal(ints.distance, floats.distance)


@pytest.mark.parametrize("frames", ["top", ["top"], None, 5])
def test_frames_must_be_a_mapping(rig, frames):
    with pytest.raises(dg.InputError):
        dg.DistanceMonitor(rig).query(frames, IN_VIEW)


def test_frame_keys_must_be_camera_names(rig, clean):
    with pytest.raises(dg.DepthguardError):
        dg.DistanceMonitor(rig).query({0: clean}, IN_VIEW)
    with pytest.raises(dg.DepthguardError):
        dg.DistanceMonitor(rig).query({("top",): clean}, IN_VIEW)


@pytest.mark.parametrize("data", ["depth", None, [[1.0, 2.0], [3.0]], np.ones((48, 64), complex),
                                  np.ones((48, 64), bool), np.ones((48, 64), object), np.ones((48, 64, 1), np.float32)])
def test_depth_of_wrong_type_is_a_depth_image_error(rig, data):
    with pytest.raises(dg.DepthImageError) as exc_info:
        dg.DistanceMonitor(rig).query({"top": data}, IN_VIEW)
    assert exc_info.value.camera == "top"


def test_masked_depth_pixels_mean_no_measurement(rig, top, clean):
    """Masked pixels over the box behave exactly as 0-valued pixels (uint16) or NaN (float), never as the value
    underneath the mask."""
    rows, cols = slice(20, 28), slice(28, 36)  # over the box
    mask = np.zeros(top.shape, bool)
    mask[rows, cols] = True
    units = np.round(clean * 1000).astype(np.uint16)
    zeroed = units.copy()
    zeroed[mask] = 0
    masked_units = np.ma.masked_array(units, mask=mask)
    points = [[0.0, 0.0, 0.5], [0.1, 0.0, 0.35], [0.5, 0.5, 0.5]]
    monitor = dg.DistanceMonitor(rig, aggregate="min")
    expected = monitor.query({"top": zeroed}, points)
    got = monitor.query({"top": masked_units}, points)
    np.testing.assert_array_equal(got.distance, expected.distance)
    assert got.flags == expected.flags and Flag.INVALID_PIXELS_USED in got.flags[0]
    unmasked = monitor.query({"top": units}, points)
    assert got.distance[0] < unmasked.distance[0]  # the mask matters: it is not read as the depth underneath
    nan = clean.astype(np.float32)
    nan[mask] = np.nan
    masked_float = np.ma.masked_array(clean.astype(np.float32), mask=mask)
    np.testing.assert_array_equal(monitor.query({"top": masked_float}, points).distance,
                                  monitor.query({"top": nan}, points).distance)
    frame = dg.depth_image(masked_float, top)
    assert not isinstance(frame.data, np.ma.MaskedArray) and np.isnan(frame.data[mask]).all()


# --------------------------------------------------------------------------------------------------------------------
# a DepthImage built by hand is checked again


def test_hand_built_depth_image_with_wrong_dtype_or_shape_is_refused(rig, top, clean):
    monitor = dg.DistanceMonitor(rig)
    for data, field in [(clean.astype(np.int32), "dtype"), (clean.astype(complex), "dtype"),
                        (clean[:, :10].astype(np.float32), "width/height"), (clean.tolist(), None)]:
        frame = DepthImage(camera="top", data=data, depth_scale=1.0, timestamp=0.0)
        if field is None:  # a list of lists is an image too, once checked
            assert len(monitor.query({"top": frame}, IN_VIEW)) == 2
            continue
        with pytest.raises(dg.DepthImageError) as exc_info:
            monitor.query({"top": frame}, IN_VIEW)
        assert exc_info.value.camera == "top" and exc_info.value.field == field


@pytest.mark.parametrize("scale", [0.0, -0.001, math.nan, math.inf, "0.001", None, 2.0])
def test_hand_built_depth_image_with_bad_depth_scale_is_refused(rig, clean, scale):
    frame = DepthImage(camera="top", data=np.round(clean * 1000).astype(np.uint16), depth_scale=scale)
    with pytest.raises(dg.DepthImageError) as exc_info:
        dg.DistanceMonitor(rig).query({"top": frame}, IN_VIEW)
    assert exc_info.value.field == "depth_scale"


@pytest.mark.parametrize("timestamp", ["0.0", [0.0], 1j, True])
def test_hand_built_depth_image_with_a_timestamp_that_is_no_number_is_refused(rig, clean, timestamp):
    frame = DepthImage(camera="top", data=clean.astype(np.float32), depth_scale=1.0, timestamp=timestamp)
    with pytest.raises(dg.DepthImageError) as exc_info:
        dg.DistanceMonitor(rig).query({"top": frame}, IN_VIEW)
    assert exc_info.value.field == "timestamp"


def test_writable_data_of_a_hand_built_frame_cannot_change_the_prepared_frame(rig2, top, side, clean, clean_side):
    """The monitor copies the data of a DepthImage it did not make: the caller's later writes reach neither the
    single-camera answer nor the fused one (whose secondary free depths are computed lazily)."""
    monitor = dg.DistanceMonitor(rig2, aggregate="min")
    buffers = {"top": clean.astype(np.float32), "side": clean_side.astype(np.float32)}
    frames = {name: DepthImage(camera=name, data=buffer, depth_scale=1.0, timestamp=0.0)
              for name, buffer in buffers.items()}
    monitor.prepare("top", frames["top"])
    monitor.prepare("side", frames["side"])  # prepared; its free depths not computed yet
    for buffer in buffers.values():
        buffer[:] = 9.0  # beyond the range: the whole view would be unseen
    fused = monitor.query(frames, IN_VIEW)
    expected = dg.DistanceMonitor(rig2, aggregate="min").query(
        {"top": dg.depth_image(clean, top), "side": dg.depth_image(clean_side, side)}, IN_VIEW)
    np.testing.assert_array_equal(fused.distance, expected.distance)
    single = monitor.query({"top": frames["top"]}, IN_VIEW)
    np.testing.assert_array_equal(single.distance, dg.DistanceMonitor(rig2, aggregate="min").query(
        {"top": dg.depth_image(clean, top)}, IN_VIEW).distance)


def test_depth_image_still_refuses_a_nan_timestamp_at_the_boundary(top, clean):
    for bad in (math.nan, math.inf, -math.inf, 10**400, "1.0"):
        with pytest.raises(dg.DepthImageError) as exc_info:
            dg.depth_image(clean, top, timestamp=bad)
        assert exc_info.value.field == "timestamp"


def test_prepare_depth_refuses_what_its_kernels_cannot_take(top, clean):
    good = dg.depth_image(clean, top)
    for depth in (clean, DepthImage("top", clean.astype(np.float64), 1.0), DepthImage("top", clean.tolist(), 1.0),
                  DepthImage("top", clean.astype(np.float32), math.nan)):
        with pytest.raises(dg.InputError):
            dg.prepare_depth(depth, top)
    for kwargs in (dict(invalid=["occupied"]), dict(hole_pixels=-1), dict(hole_pixels=2.5)):
        with pytest.raises(dg.InputError):
            dg.prepare_depth(good, top, **kwargs)
    with pytest.raises(dg.InputError):
        dg.single_camera_distances("occupancy", IN_VIEW)


# --------------------------------------------------------------------------------------------------------------------
# time (design §8 "Time")


def hand_frame(data, name, timestamp):
    """A frame built directly, as a driver might, bypassing depth_image's timestamp check."""
    return DepthImage(camera=name, data=np.asarray(data, np.float32), depth_scale=1.0, timestamp=timestamp)


def assert_blind(result, flag):
    np.testing.assert_array_equal(result.distance, 0.0)
    np.testing.assert_array_equal(result.direction, 0.0)
    assert all(flag in f for f in result.flags)


@pytest.mark.parametrize("timestamp", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("max_age", [None, 0.1])
def test_non_finite_timestamp_makes_the_frame_stale_whatever_max_age(rig, clean, timestamp, max_age):
    monitor = dg.DistanceMonitor(rig, max_age=max_age)
    result = monitor.query({"top": hand_frame(clean, "top", timestamp)}, IN_VIEW, now=None if max_age is None else 1.0)
    assert_blind(result, Flag.STALE_CAMERA)
    if max_age is None:  # also with now given
        assert_blind(monitor.query({"top": hand_frame(clean, "top", timestamp)}, IN_VIEW, now=1.0), Flag.STALE_CAMERA)


@pytest.mark.parametrize("timestamp", [math.nan, math.inf])
def test_non_finite_timestamp_is_stale_in_the_fused_path_too(rig2, clean, clean_side, timestamp):
    monitor = dg.DistanceMonitor(rig2, max_age=None)
    fresh = monitor.query({"top": hand_frame(clean, "top", 1.0), "side": hand_frame(clean_side, "side", 1.0)},
                          IN_VIEW, now=1.0)
    assert not any(Flag.STALE_CAMERA in f for f in fresh.flags)
    # the principal stale: the fresh camera answers alone (the monitor's plan), every answer flagged
    alone = monitor.query({"top": hand_frame(clean, "top", timestamp), "side": hand_frame(clean_side, "side", 1.0)},
                          IN_VIEW, now=1.0)
    side_only = dg.DistanceMonitor(dg.Rig({"side": rig2.cameras["side"]})).query(
        {"side": hand_frame(clean_side, "side", 1.0)}, IN_VIEW)
    assert all(Flag.STALE_CAMERA in f for f in alone.flags) and set(alone.principal) == {"side"}
    assert np.array_equal(alone.distance, side_only.distance)
    # both stale: no camera answers, distance 0 flagged
    blind = monitor.query({"top": hand_frame(clean, "top", timestamp), "side": hand_frame(clean_side, "side",
                                                                                          timestamp)},
                          IN_VIEW, now=1.0)
    assert_blind(blind, Flag.STALE_CAMERA)
    # the secondary stale: it clears nothing (the principal's own answer at most) and the result is flagged
    single = dg.DistanceMonitor(rig2).query({"top": hand_frame(clean, "top", 1.0)}, IN_VIEW)
    stale_side = monitor.query({"top": hand_frame(clean, "top", 1.0), "side": hand_frame(clean_side, "side",
                                                                                      timestamp)}, IN_VIEW, now=1.0)
    assert all(Flag.STALE_CAMERA in f for f in stale_side.flags)
    assert np.all(stale_side.distance <= single.distance + 1e-12)
    assert stale_side.cameras == ("top",)


def test_non_finite_timestamp_is_stale_without_the_monitor(rig2, top, clean, clean_side):
    from depthguard.depthgrid import FusedFrames, build_map

    occupancy = dg.prepare_depth(hand_frame(clean, "top", math.nan), top)
    assert_blind(dg.single_camera_distances(occupancy, IN_VIEW), Flag.STALE_CAMERA)
    frames = FusedFrames(build_map(rig2, "top"), rig2, occupancy, {"side": None})
    assert_blind(frames.distances(IN_VIEW), Flag.STALE_CAMERA)


@pytest.mark.parametrize("max_age", [None, 0.1])
def test_frame_from_the_future_beyond_the_skew_tolerance_is_stale(rig, top, clean, max_age):
    monitor = dg.DistanceMonitor(rig, max_age=max_age)
    future = dg.depth_image(clean, top, timestamp=100.0)
    assert_blind(monitor.query({"top": future}, IN_VIEW, now=0.0), Flag.STALE_CAMERA)
    # within the tolerance a frame a little ahead of now is used
    ahead = dg.depth_image(clean, top, timestamp=0.5 * config.CLOCK_SKEW_TOLERANCE)
    used = monitor.query({"top": ahead}, IN_VIEW, now=0.0)
    assert np.all(used.distance > 0.1) and not any(Flag.STALE_CAMERA in f for f in used.flags)
    beyond = dg.depth_image(clean, top, timestamp=2 * config.CLOCK_SKEW_TOLERANCE)
    assert_blind(monitor.query({"top": beyond}, IN_VIEW, now=0.0), Flag.STALE_CAMERA)


def test_future_secondary_frame_clears_nothing(rig2, top, side, clean, clean_side):
    monitor = dg.DistanceMonitor(rig2, max_age=0.1)
    principal = dg.depth_image(clean, top, timestamp=10.0)
    good = monitor.query({"top": principal, "side": dg.depth_image(clean_side, side, timestamp=10.0)}, IN_VIEW,
                         now=10.0)
    future = monitor.query({"top": principal, "side": dg.depth_image(clean_side, side, timestamp=110.0)}, IN_VIEW,
                           now=10.0)
    assert all(Flag.STALE_CAMERA in f for f in future.flags)
    assert not any(Flag.STALE_CAMERA in f for f in good.flags)
    single = dg.DistanceMonitor(dg.Rig({"top": top})).query({"top": clean}, IN_VIEW)
    assert np.all(future.distance <= single.distance + 1e-12)


@pytest.mark.parametrize("now", [math.nan, math.inf, -math.inf, "1.0", True, [1.0], 1j, 10**400])
def test_now_must_be_a_finite_number(rig, top, clean, now):
    for max_age in (None, 0.1):
        with pytest.raises(dg.InputError) as exc_info:
            dg.DistanceMonitor(rig, max_age=max_age).query({"top": dg.depth_image(clean, top, timestamp=0.0)},
                                                           IN_VIEW, now=now)
        assert exc_info.value.field == "now"


def test_age_rule_at_its_edges(rig, top, clean):
    monitor = dg.DistanceMonitor(rig, max_age=0.1)
    frame = dg.depth_image(clean, top, timestamp=5.0)
    assert not any(Flag.STALE_CAMERA in f for f in monitor.query({"top": frame}, IN_VIEW, now=5.1).flags)
    assert_blind(monitor.query({"top": frame}, IN_VIEW, now=5.1 + 1e-6), Flag.STALE_CAMERA)
    assert dg.DistanceMonitor(rig, max_age=config.MAX_AGE_LIMIT).max_age == config.MAX_AGE_LIMIT


# --------------------------------------------------------------------------------------------------------------------
# property tests: whatever a rig entry, a point array or a timestamp holds, the answer is a named error or a result
# that keeps the rules

from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from hypothesis.extra import numpy as hnp  # noqa: E402

YAML_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers() | st.integers(min_value=10**300, max_value=10**400)
    | st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=24)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(where=st.sampled_from(["camera", "rig"]), key=st.sampled_from(CAMERA_KEYS + RIG_KEYS + ("D", "extra", "a")),
       value=YAML_VALUES)
def test_any_value_in_a_rig_gives_a_rig_or_a_rig_error(where, key, value):
    entry = camera_entry("a")
    data = {"cameras": [entry]}
    (entry if where == "camera" else data)[key] = value
    try:
        rig = dg.rig_from_dict(data)
    except dg.RigError as exc:
        assert "\n" not in str(exc) and len(str(exc)) < 1000
        return
    camera = rig.camera(rig.principal or next(iter(rig.cameras)))  # what was accepted keeps the ranges (the one
    # camera is "a" unless the drawn value was a valid name for it, e.g. "0")
    assert 0 < camera.width <= config.MAX_IMAGE_SIDE and config.FOCAL_LENGTH_MIN <= camera.fx <= config.INTRINSICS_LIMIT
    assert np.isfinite(camera.T_world_camera).all() and math.isfinite(camera.depth_range[0])
    assert key in RIG_KEYS + CAMERA_KEYS  # an unknown key never passes


@settings(max_examples=200, deadline=None)
@given(hnp.arrays(dtype=hnp.scalar_dtypes(), shape=hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=4)))
def test_any_array_of_points_is_checked_or_refused(array):
    from depthguard.validation import check_points

    try:
        points = check_points(array)
    except dg.InputError:
        return
    assert array.dtype.kind in "fiu"
    assert points.dtype == np.float64 and points.ndim == 2 and points.shape[1] == 3
    assert np.isfinite(points).all() and (np.abs(points) <= config.COORDINATE_LIMIT).all()


@pytest.fixture(scope="module")
def time_setup(rig, clean):
    fresh = dg.DistanceMonitor(rig).query({"top": clean}, IN_VIEW)
    assert np.all(fresh.distance > 0.1)
    return fresh.distance


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(timestamp=st.floats(allow_nan=True, allow_infinity=True, width=64),
       now=st.none() | st.floats(min_value=-1e9, max_value=1e9),
       max_age=st.none() | st.floats(min_value=1e-6, max_value=config.MAX_AGE_LIMIT))
def test_a_frame_is_used_only_when_its_time_is_right(rig, clean, time_setup, timestamp, now, max_age):
    if max_age is not None and now is None:
        return
    result = dg.DistanceMonitor(rig, max_age=max_age).query({"top": hand_frame(clean, "top", timestamp)}, IN_VIEW,
                                                              now=now)
    right = math.isfinite(timestamp) and (now is None or timestamp <= now + config.CLOCK_SKEW_TOLERANCE) and (
        max_age is None or now - timestamp <= max_age)
    if right:
        np.testing.assert_array_equal(result.distance, time_setup)
        assert not any(Flag.STALE_CAMERA in f for f in result.flags)
    else:
        assert_blind(result, Flag.STALE_CAMERA)


# --------------------------------------------------------------------------------------------------------------------
# file names given to the loaders


@pytest.mark.parametrize("path", [None, 5, b"rig.yaml", "", "rig\0.yaml", ["rig.yaml"]])
def test_loaders_refuse_what_is_no_file_name(top, path):
    with pytest.raises(dg.RigError):
        dg.load_rig(path)
    with pytest.raises(dg.RigError) as exc_info:
        dg.load_camera_info(path, camera="depth")
    assert exc_info.value.camera == "depth" and exc_info.value.field == "camera_info"
    with pytest.raises(dg.DepthImageError) as exc_info:
        dg.load_depth(path, top)
    assert exc_info.value.camera == "top"
    with pytest.raises(dg.RigError):
        dg.rig_from_dict({"cameras": [camera_entry()]}, base_dir=path)


def test_save_rig_refuses_what_is_no_rig_or_no_file_name(tmp_path, rig):
    with pytest.raises(dg.RigError):
        dg.save_rig({"cameras": []}, tmp_path / "rig.yaml")
    with pytest.raises(dg.RigError):
        dg.save_rig(rig, None)
    with pytest.raises(dg.InputError):
        dg.load_depth(tmp_path / "d.png", "top")
