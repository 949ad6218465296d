"""Rigs: several named cameras in one world frame, read from and written to YAML (design §2).

A rig file holds exactly these keys; any other key (a typo such as ``fxx``, ``depth_rnage`` or ``principle``) is an
error that lists them:

- the rig: ``depth_scale``, ``principal``, ``noise``, ``workspace``, ``cameras``;
- each camera: ``name``, ``width``, ``height``, ``fx``, ``fy``, ``cx``, ``cy``, ``T_world_camera``, ``depth_range``,
  ``depth_scale``, ``noise``, ``camera_info``, ``rectified``, ``distortion``;
- a noise model: ``a``, ``b``, ``c``, ``k`` (or the word ``none``).

Values are checked for type and range where they are read (ranges in ``depthguard.config``, see
:class:`PinholeCamera`): a bool, a string or a 400-digit integer is not a focal length, NaN and infinity are refused
everywhere except as the maximum of ``depth_range``. Distortion coefficients go under ``distortion`` and must be
zero (depthguard needs rectified images); ``D:`` or ``d:`` in a camera entry is refused rather than dropped.

A ``camera_info`` file (ROS) holds the keys of the ``camera_calibration`` layout (``image_width``,
``image_height``, ``camera_name``, ``camera_matrix``, ``distortion_model``, ``distortion_coefficients``,
``rectification_matrix``, ``projection_matrix``) or of a ``sensor_msgs/CameraInfo`` message (``header``,
``height``, ``width``, ``distortion_model``, ``d``, ``k``, ``r``, ``p``, ``binning_x``, ``binning_y``, ``roi``,
and ROS 1's ``D``, ``K``, ``R``, ``P``); any other key is an error. Every field is applied or refused, never
ignored where it would change the geometry (:func:`load_camera_info` lists them): the intrinsics come from K (images
not rectified, zero distortion of a model whose zero is the pinhole) or from P (rectified images), and a
rectification matrix R other than the identity, binning, a region of interest smaller than the image, a skewed
camera matrix and a projection matrix with a stereo baseline are refused.

Files are read through :mod:`depthguard.io.files`: regular files only, at most ``config.MAX_TEXT_FILE_BYTES``, YAML
without anchors, aliases or duplicate keys.
"""

from __future__ import annotations

import difflib
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Optional

import numpy as np
import yaml
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError

from depthguard import config
from depthguard.io.files import read_yaml, write_whole
from depthguard.cameras._noise import NoiseModel
from depthguard.cameras._pinhole import PinholeCamera
from depthguard.errors import RigError
from depthguard.validation import NOT_A_NUMBER, check_path, short_repr

_INTRINSIC_KEYS = ("width", "height", "fx", "fy", "cx", "cy")


@dataclass(frozen=True, eq=False)
class Rig:
    """Cameras by name, in the order of the rig file.

    Attributes:
        cameras: name -> :class:`PinholeCamera`.
        depth_scale: metres per unit of ``uint16`` depth images (cameras may override it).
        principal: the principal camera's name for the depth grid, or None.
        workspace: (2, 3) float64 metres, world frame, or None: the box [lo, hi] that holds everything to be watched,
            the robot and every control point's surveillance region (rho around it). Each principal's depth grid
            spans the depths at which it sees this box (design §8, "Grid range"); without it, the camera's
            depth_range.
    """

    cameras: dict[str, PinholeCamera]
    depth_scale: float = config.DEFAULT_DEPTH_SCALE
    principal: str | None = None
    workspace: np.ndarray | None = None

    def __post_init__(self):
        if not isinstance(self.cameras, dict):
            raise RigError(f"must be a dict of camera name -> PinholeCamera, got {type(self.cameras).__name__}",
                           field="cameras")
        if not self.cameras:
            raise RigError("a rig needs at least one camera", field="cameras")
        for name, camera in self.cameras.items():
            if not isinstance(camera, PinholeCamera):
                raise RigError(f"must be a PinholeCamera, got {type(camera).__name__}", camera=short_repr(name),
                               field="cameras")
            if camera.name != name:
                raise RigError(f"is filed under the name {short_repr(name)}", camera=camera.name, field="name")
        scale = self.depth_scale
        if isinstance(scale, bool) or not isinstance(scale, (int, float, np.integer, np.floating)) or \
                not 0.0 < float(scale) <= config.DEPTH_SCALE_MAX:
            raise RigError(f"must be a positive number of metres per unit, at most {config.DEPTH_SCALE_MAX:g}, got "
                           f"{short_repr(scale)}", field="depth_scale")
        object.__setattr__(self, "depth_scale", float(scale))
        if self.principal is not None and not isinstance(self.principal, str):
            raise RigError(f"must be a camera name, got {short_repr(self.principal)}", field="principal")
        if self.principal is not None and self.principal not in self.cameras:
            raise RigError(f"{self.principal!r} names no camera of the rig (cameras: {', '.join(self.cameras)})",
                           field="principal")
        if self.workspace is not None:
            object.__setattr__(self, "workspace", _workspace_box(self.workspace))

    def camera(self, name: str) -> PinholeCamera:
        """The camera called ``name``; a :class:`RigError` listing the rig's cameras if there is none."""
        try:
            return self.cameras[name]
        except (KeyError, TypeError):  # TypeError: an unhashable "name"
            raise RigError(f"no such camera in the rig (cameras: {', '.join(self.cameras)})",
                           camera=name if isinstance(name, str) else short_repr(name), field="name") from None

    def to_dict(self) -> dict:
        """The rig as plain Python types, ready for ``yaml.safe_dump``."""
        d = {"depth_scale": self.depth_scale}
        if self.principal is not None:
            d["principal"] = self.principal
        if self.workspace is not None:
            d["workspace"] = self.workspace.tolist()
        d["cameras"] = [camera.to_dict() for camera in self.cameras.values()]
        return d

    def fingerprint(self) -> str:
        """SHA-256 (hex) of everything geometric in the rig: offline artefacts record it and refuse other rigs."""
        canonical = []
        for camera in self.cameras.values():
            canonical.append(
                [camera.name, camera.width, camera.height, repr(camera.fx), repr(camera.fy), repr(camera.cx),
                 repr(camera.cy), [repr(float(x)) for x in camera.T_world_camera.ravel()],
                 [repr(x) for x in camera.depth_range]]
            )
        text = json.dumps({"cameras": canonical, "principal": self.principal}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()


# ------------------------------------------------------------------------------------------------- the rig schema
#
# Why pydantic: a rig is nested YAML (cameras -> entries -> matrices and noise models). One declarative schema per
# level states every key with its type and range, in one place a reader can check against docs/usage.md. pydantic
# refuses unknown keys (extra="forbid"), so a misspelled key is an error instead of a silent default, and it locates
# every error by its path (cameras[1].T_world_camera[2][3]), which _rig_error turns into a RigError naming the camera
# and the field, with the known keys when a key is unknown. strict=True: no coercion, so "525" or true is not a
# focal length and 480.5 is not a width. The same checks by hand took more code and still ignored unknown keys.

_STRICT = ConfigDict(extra="forbid", strict=True)

_Finite = Annotated[float, Field(allow_inf_nan=False)]
_Side = Annotated[int, Field(gt=0, le=config.MAX_IMAGE_SIDE)]
_Focal = Annotated[float, Field(ge=config.FOCAL_LENGTH_MIN, le=config.INTRINSICS_LIMIT, allow_inf_nan=False)]
_Centre = Annotated[float, Field(ge=-config.INTRINSICS_LIMIT, le=config.INTRINSICS_LIMIT, allow_inf_nan=False)]
_DepthScale = Annotated[float, Field(gt=0, le=config.DEPTH_SCALE_MAX, allow_inf_nan=False)]
_Coefficient = Annotated[float, Field(ge=-config.NOISE_COEFFICIENT_LIMIT, le=config.NOISE_COEFFICIENT_LIMIT,
                                      allow_inf_nan=False)]
_Name = Annotated[str, Field(min_length=1, max_length=config.MAX_NAME_LENGTH)]


def _none_word(value):
    """``noise: none`` means no margin, like ``noise: null``."""
    return None if isinstance(value, str) and value == "none" else value


class _Noise(BaseModel):
    """A noise model's keys; the ones not given take the Kinect v1 defaults (``config.DEFAULT_NOISE_SIGMA``)."""

    model_config = _STRICT
    a: _Coefficient = config.DEFAULT_NOISE_SIGMA[0]
    b: _Coefficient = config.DEFAULT_NOISE_SIGMA[1]
    c: _Coefficient = config.DEFAULT_NOISE_SIGMA[2]
    k: Annotated[float, Field(ge=0, le=config.NOISE_K_MAX, allow_inf_nan=False)] = config.DEFAULT_NOISE_K

    def model(self) -> NoiseModel:
        return NoiseModel(self.a, self.b, self.c, self.k)


_NoiseValue = Annotated[Optional[_Noise], BeforeValidator(_none_word)]


class _CameraEntry(BaseModel):
    """One entry of ``cameras``. Intrinsics may come from ``camera_info`` instead (the entry's own win)."""

    model_config = _STRICT
    name: _Name
    width: Optional[_Side] = None
    height: Optional[_Side] = None
    fx: Optional[_Focal] = None
    fy: Optional[_Focal] = None
    cx: Optional[_Centre] = None
    cy: Optional[_Centre] = None
    T_world_camera: list[list[_Finite]]  # 4x4 and rigid: checked by PinholeCamera
    depth_range: Optional[Annotated[list[float], Field(min_length=2, max_length=2)]] = None  # max may be .inf
    depth_scale: Optional[_DepthScale] = None
    noise: _NoiseValue = None
    camera_info: Optional[Annotated[str, Field(min_length=1)]] = None
    rectified: bool = False
    distortion: Optional[list[_Finite]] = None


class _RigFile(BaseModel):
    """The whole rig file (design §2)."""

    model_config = _STRICT
    depth_scale: _DepthScale = config.DEFAULT_DEPTH_SCALE
    principal: Optional[_Name] = None
    noise: _NoiseValue = None
    workspace: Optional[Annotated[list[Annotated[list[_Finite], Field(min_length=3, max_length=3)]],
                                  Field(min_length=2, max_length=2)]] = None
    cameras: Annotated[list[_CameraEntry], Field(min_length=1)]


#: Hints for unknown keys that mean something depthguard reads under another name.
_KEY_HINTS = {
    key: "distortion coefficients go under 'distortion', and must all be zero: depthguard needs rectified images"
    for key in ("D", "d", "distortion_coefficients", "k1", "k2", "p1", "p2", "k3")
}
_KEY_HINTS.update({key: "give the pose as 'T_world_camera' (4x4, optical frame -> world)"
                   for key in ("pose", "T", "extrinsics", "T_camera_world")})


# --------------------------------------------------------------------------------------------------- reading rigs


def load_rig(path) -> Rig:
    """Read a rig YAML file (safe loader; no code runs). Raises :class:`RigError` naming the camera and field."""
    path = check_path(path, "rig file", RigError)
    data = read_yaml(path, what="rig file", error=RigError)
    try:
        return rig_from_dict(data, base_dir=path.parent)
    except RigError as exc:
        raise exc.with_source(str(path)) from None


class _RigDumper(yaml.SafeDumper):
    """Safe YAML, with lists of plain numbers in flow style, so a 4x4 matrix reads as four rows."""


def _represent_list(dumper, data):
    flow = all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


_RigDumper.add_representer(list, _represent_list)


def save_rig(rig: Rig, path) -> None:
    """Write ``rig`` as a YAML file that :func:`load_rig` reads back to an equal rig; written whole or not at all
    (a process stopped while writing leaves the older file or none, never a rig with a camera cut off)."""
    if not isinstance(rig, Rig):
        raise RigError(f"save_rig needs a Rig, got {type(rig).__name__}")
    write_whole(check_path(path, "rig file", RigError), yaml.dump(rig.to_dict(), Dumper=_RigDumper, sort_keys=False))


def rig_from_dict(data, base_dir=".") -> Rig:
    """Build a :class:`Rig` from the parsed YAML contract of design §2 (keys: module docstring).

    ``data`` is what a YAML file holds (numpy arrays and scalars are accepted too); ``base_dir`` resolves relative
    ``camera_info`` paths. An unknown key, a wrong type or a value out of range raises :class:`RigError` naming the
    camera and the field.
    """
    if not isinstance(data, dict):
        raise RigError(f"a rig must be a mapping with a 'cameras' list, got {type(data).__name__}")
    base_dir = check_path(base_dir, "base_dir", RigError)
    plain = _plain(data)
    try:
        rig_file = _RigFile.model_validate(plain)
    except ValidationError as exc:
        raise _rig_error(exc, plain) from None
    rig_noise = NoiseModel()
    if "noise" in rig_file.model_fields_set:
        rig_noise = rig_file.noise.model() if rig_file.noise is not None else NoiseModel.none()
    cameras: dict[str, PinholeCamera] = {}
    for entry in rig_file.cameras:
        camera = _camera_from(entry, rig_file.depth_scale, rig_noise, base_dir)
        if camera.name in cameras:
            raise RigError("appears twice in the rig", camera=camera.name, field="name")
        cameras[camera.name] = camera
    return Rig(cameras=cameras, depth_scale=rig_file.depth_scale, principal=rig_file.principal,
               workspace=rig_file.workspace)


def _workspace_box(value) -> np.ndarray:
    """The rig's workspace as a read-only (2, 3) float64 array [lo, hi], world frame, metres: finite, within
    ``config.COORDINATE_LIMIT``, lo < hi on every axis; else :class:`RigError` naming the field."""
    try:
        box = np.array(value, dtype=np.float64)
    except NOT_A_NUMBER:
        raise RigError(f"must be [[x, y, z], [x, y, z]] (the box's lowest and highest corner, world frame, metres), "
                       f"got {short_repr(value)}", field="workspace") from None
    if box.shape != (2, 3) or not np.all(np.abs(box) <= config.COORDINATE_LIMIT):
        raise RigError(f"must be [[x, y, z], [x, y, z]] with finite coordinates within {config.COORDINATE_LIMIT:g} m "
                       f"(the box's lowest and highest corner, world frame), got {short_repr(value)}",
                       field="workspace")
    if not np.all(box[0] < box[1]):
        raise RigError(f"the lowest corner {box[0].tolist()} must lie below the highest {box[1].tolist()} on every "
                       "axis", field="workspace")
    box.setflags(write=False)
    return box


def _camera_from(entry: _CameraEntry, depth_scale: float, rig_noise: NoiseModel, base_dir: Path) -> PinholeCamera:
    name = entry.name
    intrinsics = {}
    if entry.camera_info is not None:
        intrinsics.update(load_camera_info(base_dir / entry.camera_info, camera=name, rectified=entry.rectified))
    for key in _INTRINSIC_KEYS:
        value = getattr(entry, key)
        if value is not None:
            intrinsics[key] = value
        if key not in intrinsics:
            raise RigError("is missing (give it, or a 'camera_info' file)", camera=name, field=key)
    if entry.distortion is not None:
        _refuse_distortion(entry.distortion, camera=name, field="distortion")
    noise = rig_noise
    if "noise" in entry.model_fields_set:
        noise = entry.noise.model() if entry.noise is not None else NoiseModel.none()
    return PinholeCamera(
        name=name,
        width=intrinsics["width"],
        height=intrinsics["height"],
        fx=intrinsics["fx"],
        fy=intrinsics["fy"],
        cx=intrinsics["cx"],
        cy=intrinsics["cy"],
        T_world_camera=entry.T_world_camera,
        depth_range=config.DEFAULT_DEPTH_RANGE if entry.depth_range is None else tuple(entry.depth_range),
        depth_scale=depth_scale if entry.depth_scale is None else entry.depth_scale,
        noise=noise,
    )


def _rig_error(exc: ValidationError, data: dict) -> RigError:
    """The first of pydantic's errors (unknown keys first) as a RigError naming the camera and the field."""
    errors = exc.errors(include_url=False)
    errors.sort(key=lambda e: e["type"] != "extra_forbidden")  # stable: otherwise in pydantic's order
    error = errors[0]
    loc = tuple(error["loc"])
    more = f" (and {len(errors) - 1} more problem{'s' if len(errors) > 2 else ''})" if len(errors) > 1 else ""
    camera, where, owner = None, "", _RigFile
    if loc and loc[0] == "cameras" and len(loc) >= 2:
        index = loc[1]
        entries = data.get("cameras")
        entry = entries[index] if isinstance(entries, list) and isinstance(index, int) else None
        name = entry.get("name") if isinstance(entry, dict) else None
        if isinstance(name, str) and 0 < len(name) <= config.MAX_NAME_LENGTH and name.isprintable():
            camera = name
        else:
            where = f"camera #{index}: "
        loc, owner = loc[2:], _CameraEntry
        if not loc:  # the entry itself is not a mapping
            return RigError(f"{where}must be a mapping of camera keys, got {short_repr(error['input'])}{more}",
                            camera=camera, field="cameras")
    field, path = loc[0], loc[1:]
    if error["type"] == "extra_forbidden":
        if path:  # a key inside a nested mapping: the noise model's
            known, key = tuple(_Noise.model_fields), path[-1]
        else:
            known, key = tuple(owner.model_fields), field
        message = f"unknown key {key!r}"
        if key in _KEY_HINTS:
            message += f" ({_KEY_HINTS[key]})"
        else:
            close = difflib.get_close_matches(str(key), known, n=1)
            if close:
                message += f" (did you mean {close[0]!r}?)"
        return RigError(f"{where}{message}; known keys: {', '.join(known)}{more}", camera=camera, field=field)
    return RigError(f"{where}{_describe(error, path)}{more}", camera=camera, field=field)


def _describe(error: dict, path: tuple) -> str:
    """One pydantic error as a phrase: 'is missing', '[2][3]: must be a finite number, got nan'."""
    kind = error["type"]
    if kind == "missing":
        text = "is missing"
    elif kind == "float_type" and isinstance(error["input"], int) and not isinstance(error["input"], bool):
        text = f"must be a finite number, got {short_repr(error['input'])} (beyond float range)"
    elif kind == "model_type":
        text = f"must be a mapping (or, for a noise model, 'none'), got {short_repr(error['input'])}"
    else:
        text = error["msg"].replace("Input should be", "must be").replace("Value should", "must")
        text += f", got {short_repr(error['input'])}"
    where = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in path).lstrip(".")
    return f"{where}: {text}" if where else text


def _plain(value, depth: int = 0):
    """``value`` with numpy arrays and scalars turned into lists and Python numbers and tuples into lists, so that
    the strict schema accepts what a program (not a YAML file) hands :func:`rig_from_dict`."""
    if depth > config.MAX_NESTING:
        return value  # deeper than any rig: the schema refuses it where it stands
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (list, tuple)):
        return [_plain(item, depth + 1) for item in value]
    if isinstance(value, dict):
        return {key: _plain(item, depth + 1) for key, item in value.items()}
    return value


# ------------------------------------------------------------------------------------------ ROS camera_info files


class _Matrix(BaseModel):
    """A matrix of a camera_info file: ``{rows, cols, data}`` (camera_calibration) or a plain list (a message)."""

    model_config = _STRICT
    rows: Optional[Annotated[int, Field(ge=1, le=4)]] = None
    cols: Optional[Annotated[int, Field(ge=1, le=16)]] = None
    data: list[_Finite]


def _matrix_mapping(value):
    return {"data": value} if isinstance(value, list) else value


_MatrixValue = Annotated[Optional[_Matrix], BeforeValidator(_matrix_mapping)]


class _Roi(BaseModel):
    model_config = _STRICT
    x_offset: Annotated[int, Field(ge=0)] = 0
    y_offset: Annotated[int, Field(ge=0)] = 0
    height: Annotated[int, Field(ge=0)] = 0
    width: Annotated[int, Field(ge=0)] = 0
    do_rectify: bool = False


class _CameraInfoFile(BaseModel):
    """Both layouts of a ROS camera_info YAML file (module docstring)."""

    model_config = _STRICT
    # camera_calibration (ost.yaml)
    image_width: Optional[_Side] = None
    image_height: Optional[_Side] = None
    camera_name: Optional[str] = None
    camera_matrix: _MatrixValue = None
    distortion_model: Optional[str] = None
    distortion_coefficients: _MatrixValue = None
    rectification_matrix: _MatrixValue = None
    projection_matrix: _MatrixValue = None
    # sensor_msgs/CameraInfo as YAML: ROS 2 lower case, ROS 1 upper case
    header: Optional[dict[str, Any]] = None
    width: Optional[_Side] = None
    height: Optional[_Side] = None
    d: _MatrixValue = None
    k: _MatrixValue = None
    r: _MatrixValue = None
    p: _MatrixValue = None
    D: _MatrixValue = None
    K: _MatrixValue = None
    R: _MatrixValue = None
    P: _MatrixValue = None
    binning_x: Optional[Annotated[int, Field(ge=0)]] = None
    binning_y: Optional[Annotated[int, Field(ge=0)]] = None
    roi: Optional[_Roi] = None


#: The same quantity under each layout's key; errors name it by the camera_calibration key.
_SYNONYMS = {
    "image_width": ("image_width", "width"),
    "image_height": ("image_height", "height"),
    "camera_matrix": ("camera_matrix", "k", "K"),
    "distortion_coefficients": ("distortion_coefficients", "d", "D"),
    "rectification_matrix": ("rectification_matrix", "r", "R"),
    "projection_matrix": ("projection_matrix", "p", "P"),
}
_FIELD_OF_KEY = {key: field for field, keys in _SYNONYMS.items() for key in keys}
#: The identity rotation, row-major: the only rectification matrix R accepted (load_camera_info).
_IDENTITY = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)


def load_camera_info(path, camera: str | None = None, rectified: bool = False) -> dict:
    """Read intrinsics from a ROS ``camera_info`` YAML file.

    Both layouts are accepted (module docstring): the ``camera_calibration`` file (``image_width``,
    ``camera_matrix: {data: [...]}``, ``distortion_coefficients``, ``projection_matrix``) and a
    ``sensor_msgs/CameraInfo`` message as YAML (``width``, ``k``, ``d``, ``p``, or ROS 1's ``K``, ``D``, ``P``).
    Other keys are refused, and so is one quantity given under two keys.

    ``rectified`` says which image the depth images are, as in ROS, and so which matrix holds their intrinsics:

    - ``rectified=False`` (ROS ``image_raw``): K. The distortion coefficients must all be zero and the model one whose
      zero is the pinhole camera: ``plumb_bob``, ``rational_polynomial`` (or none given). Any other model is refused
      even with zero coefficients: ``equidistant`` (fisheye) with zero coefficients still maps angles, not their
      tangents, to pixels, and an unknown model cannot be judged. P describes the rectified image and is not used.
    - ``rectified=True`` (ROS ``image_rect``): P's fx', fy', cx', cy' (K and the distortion describe the raw image,
      which rectification has undone; any model is accepted). P must be [fx' 0 cx' 0; 0 fy' cy' 0; 0 0 1 0]: a skew
      or a stereo baseline (Tx, Ty) is refused, and so is ``roi.do_rectify: true`` (the rectified image would be cut
      to a rectified region of interest, whose offset depthguard does not compute).

    In both cases:

    - R (rectification matrix), when given, must be the identity within ``config.ROTATION_TOLERANCE`` (a missing R
      is the identity). A rectified image lies in the camera frame turned by R, and a depth image computed by a
      stereo pair lies in that rectified frame whatever its topic is called; which frame the rig's T_world_camera
      is of, the file cannot say, so R is refused rather than applied or ignored (applying it to a camera whose pose
      was measured in the rectified frame, or ignoring it where the pose is the raw camera's, turns every ray by R).
    - binning_x, binning_y: 0 or 1 (no binning); more is refused (the intrinsics would be those of the full-size
      image, not of the binned one).
    - roi: all zero or the whole image; a smaller region of interest is refused.
    - header and camera_name are not used.

    Returns a dict with width, height (int) and fx, fy, cx, cy (float, pixels). Raises :class:`RigError` naming
    ``camera`` and the field (matrices by their camera_calibration names: camera_matrix, distortion_coefficients,
    rectification_matrix, projection_matrix).
    """
    path = check_path(path, "camera_info file", RigError, camera=camera, field="camera_info")
    where = f"camera_info {path}"
    data = read_yaml(path, what="camera_info file", error=RigError, camera=camera, field="camera_info")
    if not isinstance(data, dict):
        raise RigError(f"{where} is not a camera_info mapping, got {type(data).__name__}", camera=camera,
                       field="camera_info")
    try:
        info = _CameraInfoFile.model_validate(_plain(data))
    except ValidationError as exc:
        raise _camera_info_error(exc, where, camera) from None
    values = {}
    for field, keys in _SYNONYMS.items():
        given = [key for key in keys if key in info.model_fields_set and getattr(info, key) is not None]
        if len(given) > 1:
            raise RigError(f"{where}: gives {field} twice (keys {', '.join(given)}): keep one", camera=camera,
                           field=field)
        values[field] = getattr(info, given[0]) if given else None
    for key in ("binning_x", "binning_y"):
        if (getattr(info, key) or 0) > 1:
            raise RigError(f"{where}: binned images are not supported ({key} = {getattr(info, key)}): give the "
                           "intrinsics of the images you pass", camera=camera, field=key)
    width, height = values["image_width"], values["image_height"]
    if width is None or height is None:
        raise RigError(f"{where}: image width/height missing", camera=camera, field="camera_info")
    roi = info.roi
    if roi is not None and (roi.x_offset or roi.y_offset or (roi.width, roi.height) not in ((0, 0), (width, height))):
        raise RigError(f"{where}: a region of interest smaller than the image is not supported ({roi.width}x"
                       f"{roi.height} at {roi.x_offset}, {roi.y_offset})", camera=camera, field="roi")
    if rectified and roi is not None and roi.do_rectify:
        raise RigError(f"{where}: roi.do_rectify is true: the rectified image would be cut to a rectified region of "
                       "interest, whose offset depthguard does not compute; give the whole rectified image and "
                       "do_rectify: false", camera=camera, field="roi")
    if values["rectification_matrix"] is not None:
        R = _matrix(values["rectification_matrix"], 9, f"{where}: needs a 3x3 rectification matrix R", camera,
                    "rectification_matrix")
        if max(abs(r - i) for r, i in zip(R, _IDENTITY)) > config.ROTATION_TOLERANCE:
            raise RigError(f"{where}: rectification matrix R must be the identity, got {R}: depthguard cannot tell "
                           "whether the rig's T_world_camera is the pose of the raw camera frame or of the rectified "
                           "frame, which R turns; give fx, fy, cx, cy in the rig entry instead of 'camera_info', "
                           "with T_world_camera the pose of the depth image's own frame", camera=camera,
                           field="rectification_matrix")
    if rectified:
        P = _matrix(values["projection_matrix"], 12, f"{where}: 'rectified' needs a 3x4 projection matrix P", camera,
                    "projection_matrix")
        # [fx' 0 cx' Tx; 0 fy' cy' Ty; 0 0 1 0]: a skew or a stereo baseline (Tx, Ty) is not a pinhole depth camera
        if P[1] != 0.0 or P[3] != 0.0 or P[4] != 0.0 or P[7] != 0.0 or P[8:] != [0.0, 0.0, 1.0, 0.0]:
            raise RigError(f"{where}: projection matrix P must be [fx 0 cx 0; 0 fy cy 0; 0 0 1 0] (no skew, no "
                           f"stereo baseline), got {P}", camera=camera, field="projection_matrix")
        fx, fy, cx, cy = P[0], P[5], P[2], P[6]
    else:
        K = _matrix(values["camera_matrix"], 9, f"{where}: needs a 3x3 camera matrix K", camera, "camera_matrix")
        if K[1] != 0.0 or K[3] != 0.0 or K[6:] != [0.0, 0.0, 1.0]:
            raise RigError(f"{where}: camera matrix K must be [fx 0 cx; 0 fy cy; 0 0 1] (no skew), got {K}",
                           camera=camera, field="camera_matrix")
        if values["distortion_coefficients"] is not None:
            _refuse_distortion(values["distortion_coefficients"].data, camera=camera, field="distortion_coefficients")
        model = info.distortion_model
        if model not in (None, "") and model not in config.PINHOLE_DISTORTION_MODELS:
            raise RigError(f"{where}: distortion_model {short_repr(model)} with zero coefficients is not known to be a "
                           f"pinhole camera (equidistant's is a fisheye); an image that is not rectified is read only "
                           f"with {' or '.join(config.PINHOLE_DISTORTION_MODELS)}: rectify the images and set "
                           "'rectified: true' to use P", camera=camera, field="distortion_model")
        fx, fy, cx, cy = K[0], K[4], K[2], K[5]
    return dict(width=width, height=height, fx=fx, fy=fy, cx=cx, cy=cy)


def _camera_info_error(exc: ValidationError, where: str, camera) -> RigError:
    errors = exc.errors(include_url=False)
    errors.sort(key=lambda e: e["type"] != "extra_forbidden")
    error = errors[0]
    loc = tuple(error["loc"])
    key, path = loc[0], loc[1:]
    field = _FIELD_OF_KEY.get(key, key)
    named = f" (key {key!r})" if field != key else ""
    if error["type"] == "extra_forbidden":
        owner = {"roi": _Roi}.get(key, _Matrix) if path else _CameraInfoFile
        known = tuple(owner.model_fields)
        return RigError(f"{where}: unknown key {path[-1] if path else key!r}; known keys: {', '.join(known)}",
                        camera=camera, field=field if path else "camera_info")
    if error["type"] == "model_type" and not path:
        return RigError(f"{where}{named}: must be a list of numbers or a mapping {{rows, cols, data}}, got "
                        f"{short_repr(error['input'])}", camera=camera, field=field)
    return RigError(f"{where}{named}: {_describe(error, path)}", camera=camera, field=field)


def _matrix(value: _Matrix | None, size: int, what: str, camera, field) -> list[float]:
    """The matrix's ``size`` numbers (row-major), or a :class:`RigError` naming the field."""
    if value is None:
        raise RigError(what, camera=camera, field=field)
    if len(value.data) != size:
        raise RigError(f"{what} ({size} numbers), got {len(value.data)}", camera=camera, field=field)
    if value.rows is not None and value.cols is not None and value.rows * value.cols != size:
        raise RigError(f"{what}: rows x cols is {value.rows}x{value.cols}", camera=camera, field=field)
    return [float(x) for x in value.data]


def _refuse_distortion(coefficients: list[float], camera, field) -> None:
    if any(value != 0.0 for value in coefficients):
        raise RigError(
            "non-zero distortion coefficients: depthguard needs rectified images; undistort them first (for a ROS "
            "camera_info, pass the rectified image and set 'rectified: true' to use its projection matrix)",
            camera=camera,
            field=field,
        )
