"""Issue 12: every input is validated where it enters, and bad input gets a named DepthguardError, never a crash or a
silently optimistic answer.

Expected values come from the rules (README, SPEC sections 2, 8 "Time" and 11, ``depthguard.config``'s ranges), not
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
RIG_KEYS = ("depth_scale", "principal", "noise", "cameras")


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


@pytest.mark.parametrize("typo, meant", [("fxx", "fx"), ("depth_rnage", "depth_range"), ("T_world_cam", "T_world_camera"),
                                         ("Width", "width")])
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
