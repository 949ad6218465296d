"""Rigs: several named cameras in one world frame, read from and written to YAML (SPEC section 2)."""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from depthguard import config
from depthguard.cameras._noise import NoiseModel
from depthguard.cameras._pinhole import PinholeCamera
from depthguard.errors import RigError

_INTRINSIC_KEYS = ("width", "height", "fx", "fy", "cx", "cy")


@dataclass(frozen=True, eq=False)
class Rig:
    """Cameras by name, in the order of the rig file.

    Attributes:
        cameras: name -> :class:`PinholeCamera`.
        depth_scale: metres per unit of ``uint16`` depth images (cameras may override it).
        principal: the principal camera's name for the depth grid, or None.
    """

    cameras: dict[str, PinholeCamera]
    depth_scale: float = config.DEFAULT_DEPTH_SCALE
    principal: str | None = None

    def __post_init__(self):
        if not self.cameras:
            raise RigError("a rig needs at least one camera", field="cameras")
        for name, camera in self.cameras.items():
            if camera.name != name:
                raise RigError(f"is filed under the name {name!r}", camera=camera.name, field="name")
        if self.principal is not None and self.principal not in self.cameras:
            raise RigError(f"{self.principal!r} names no camera of the rig (cameras: {', '.join(self.cameras)})",
                           field="principal")

    def camera(self, name: str) -> PinholeCamera:
        """The camera called ``name``; a :class:`RigError` listing the rig's cameras if there is none."""
        try:
            return self.cameras[name]
        except KeyError:
            raise RigError(f"no such camera in the rig (cameras: {', '.join(self.cameras)})", camera=name,
                           field="name") from None

    def to_dict(self) -> dict:
        """The rig as plain Python types, ready for ``yaml.safe_dump``."""
        d = {"depth_scale": self.depth_scale}
        if self.principal is not None:
            d["principal"] = self.principal
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


def load_rig(path) -> Rig:
    """Read a rig YAML file (safe loader; no code runs). Raises :class:`RigError` naming the camera and field."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise RigError(f"cannot read rig file ({exc.strerror or exc})", source=str(path)) from None
    except UnicodeDecodeError:
        raise RigError("rig file is not UTF-8 text", source=str(path)) from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise RigError(f"malformed YAML ({_one_line(exc)})", source=str(path)) from None
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
    """Write ``rig`` as a YAML file that :func:`load_rig` reads back to an equal rig."""
    Path(path).write_text(yaml.dump(rig.to_dict(), Dumper=_RigDumper, sort_keys=False))


def rig_from_dict(data, base_dir=".") -> Rig:
    """Build a :class:`Rig` from the parsed YAML contract of SPEC section 2.

    ``base_dir`` resolves relative ``camera_info`` paths. Keys beyond the contract are ignored.
    """
    if not isinstance(data, dict):
        raise RigError(f"a rig must be a mapping with a 'cameras' list, got {type(data).__name__}")
    depth_scale = data.get("depth_scale", config.DEFAULT_DEPTH_SCALE)
    if isinstance(depth_scale, bool) or not isinstance(depth_scale, (int, float)) or not (
        math.isfinite(depth_scale) and depth_scale > 0
    ):
        raise RigError(f"must be a positive number of metres per unit, got {depth_scale!r}", field="depth_scale")
    rig_noise = _noise_from(data.get("noise"), camera=None) if "noise" in data else NoiseModel()
    entries = data.get("cameras")
    if not isinstance(entries, list) or not entries:
        raise RigError("must be a non-empty list of cameras", field="cameras")
    cameras: dict[str, PinholeCamera] = {}
    for index, entry in enumerate(entries):
        camera = _camera_from(entry, index, float(depth_scale), rig_noise, Path(base_dir))
        if camera.name in cameras:
            raise RigError("appears twice in the rig", camera=camera.name, field="name")
        cameras[camera.name] = camera
    principal = data.get("principal")
    if principal is not None and not isinstance(principal, str):
        raise RigError(f"must be a camera name, got {principal!r}", field="principal")
    return Rig(cameras=cameras, depth_scale=float(depth_scale), principal=principal)


def _camera_from(entry, index: int, depth_scale: float, rig_noise: NoiseModel, base_dir: Path) -> PinholeCamera:
    if not isinstance(entry, dict):
        raise RigError(f"camera #{index} must be a mapping, got {type(entry).__name__}", field="cameras")
    name = entry.get("name")
    if not isinstance(name, str) or not name:
        raise RigError(f"camera #{index} needs a non-empty string 'name'", field="name")
    intrinsics = {}
    if "camera_info" in entry:
        info_path = base_dir / str(entry["camera_info"])
        rectified = entry.get("rectified", False)
        if not isinstance(rectified, bool):
            raise RigError(f"must be true or false, got {rectified!r}", camera=name, field="rectified")
        intrinsics.update(load_camera_info(info_path, camera=name, rectified=rectified))
    for key in _INTRINSIC_KEYS:
        if key in entry:
            intrinsics[key] = entry[key]
        if key not in intrinsics:
            raise RigError("is missing (give it, or a 'camera_info' file)", camera=name, field=key)
    distortion = entry.get("distortion")
    if distortion is not None:
        _refuse_distortion(distortion, camera=name, field="distortion")
    if "T_world_camera" not in entry:
        raise RigError("is missing (4x4 camera-to-world transform)", camera=name, field="T_world_camera")
    depth_range = entry.get("depth_range", config.DEFAULT_DEPTH_RANGE)
    if not isinstance(depth_range, (list, tuple)) or len(depth_range) != 2:
        raise RigError(f"must be [min, max] in metres, got {depth_range!r}", camera=name, field="depth_range")
    noise = _noise_from(entry["noise"], camera=name) if "noise" in entry else rig_noise
    return PinholeCamera(
        name=name,
        width=intrinsics["width"],
        height=intrinsics["height"],
        fx=intrinsics["fx"],
        fy=intrinsics["fy"],
        cx=intrinsics["cx"],
        cy=intrinsics["cy"],
        T_world_camera=entry["T_world_camera"],
        depth_range=tuple(depth_range),
        depth_scale=entry.get("depth_scale", depth_scale),
        noise=noise,
    )


def _noise_from(value, camera: str | None) -> NoiseModel:
    """A noise model from ``none`` / ``null`` (no margin) or a mapping with a, b, c (metres) and k."""
    if value is None or value == "none":
        return NoiseModel.none()
    if not isinstance(value, dict):
        raise RigError(f"must be 'none' or a mapping with a, b, c, k, got {value!r}", camera=camera, field="noise")
    unknown = set(value) - {"a", "b", "c", "k"}
    if unknown:
        raise RigError(f"unknown keys {sorted(unknown)} (expected a, b, c, k)", camera=camera, field="noise")
    try:
        return NoiseModel(**{k: float(v) for k, v in value.items()})
    except (TypeError, ValueError) as exc:
        raise RigError(str(exc), camera=camera, field="noise") from None


def load_camera_info(path, camera: str | None = None, rectified: bool = False) -> dict:
    """Read intrinsics from a ROS ``camera_info`` YAML file.

    Both layouts are accepted: the ``camera_calibration`` file (``image_width``, ``camera_matrix: {data: [...]}``,
    ``distortion_coefficients``, ``projection_matrix``) and a ``sensor_msgs/CameraInfo`` message as YAML (``width``,
    ``k``, ``d``, ``p``, or ROS 1's ``K``, ``D``, ``P``).

    With ``rectified=False`` the intrinsics come from K and the distortion coefficients must all be zero: depthguard
    never silently ignores distortion. With ``rectified=True`` the images are taken to be rectified (ROS
    ``image_rect``) and the intrinsics come from the projection matrix P.

    Returns a dict with width, height (int) and fx, fy, cx, cy (float, pixels).
    """
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise RigError(f"cannot read camera_info file {path} ({exc.strerror or exc})", camera=camera,
                       field="camera_info") from None
    except UnicodeDecodeError:
        raise RigError(f"camera_info file {path} is not UTF-8 text", camera=camera, field="camera_info") from None
    except yaml.YAMLError as exc:
        raise RigError(f"malformed YAML in {path} ({_one_line(exc)})", camera=camera, field="camera_info") from None
    if not isinstance(data, dict):
        raise RigError(f"{path} is not a camera_info mapping", camera=camera, field="camera_info")

    def pick(*keys):
        for key in keys:
            if key in data:
                value = data[key]
                return value["data"] if isinstance(value, dict) and "data" in value else value
        return None

    width, height = pick("image_width", "width"), pick("image_height", "height")
    K, D, P = pick("camera_matrix", "k", "K"), pick("distortion_coefficients", "d", "D"), pick("projection_matrix",
                                                                                                "p", "P")
    where = f"camera_info {path.name}"
    if width is None or height is None:
        raise RigError(f"{where}: image width/height missing", camera=camera, field="camera_info")
    if rectified:
        if P is None:
            raise RigError(f"{where}: 'rectified' needs a 3x4 projection matrix P", camera=camera,
                           field="projection_matrix")
        P = _matrix(P, 12, f"{where}: 'rectified' needs a 3x4 projection matrix P", camera, "projection_matrix")
        fx, fy, cx, cy = P[0], P[5], P[2], P[6]
    else:
        if K is None:
            raise RigError(f"{where}: needs a 3x3 camera matrix K", camera=camera, field="camera_matrix")
        K = _matrix(K, 9, f"{where}: needs a 3x3 camera matrix K", camera, "camera_matrix")
        if D is not None:
            _refuse_distortion(D, camera=camera, field="distortion_coefficients")
        fx, fy, cx, cy = K[0], K[4], K[2], K[5]
    return dict(width=width, height=height, fx=fx, fy=fy, cx=cx, cy=cy)


def _matrix(value, size: int, what: str, camera, field) -> list[float]:
    """``value`` as a flat list of ``size`` finite floats (row-major), or a :class:`RigError` naming the field."""
    try:
        values = np.asarray(value, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        raise RigError(f"{what}, got {value!r}", camera=camera, field=field) from None
    if values.size != size:
        raise RigError(f"{what} ({size} numbers), got {values.size}", camera=camera, field=field)
    if not np.all(np.isfinite(values)):
        raise RigError(f"{what}: contains NaN or infinity", camera=camera, field=field)
    return [float(x) for x in values]


def _refuse_distortion(coefficients, camera, field) -> None:
    try:
        values = np.asarray(coefficients, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        raise RigError(f"must be a list of numbers, got {coefficients!r}", camera=camera, field=field) from None
    if np.any(values != 0.0):
        raise RigError(
            "non-zero distortion coefficients: depthguard needs rectified images; undistort them first (for a ROS "
            "camera_info, pass the rectified image and set 'rectified: true' to use its projection matrix)",
            camera=camera,
            field=field,
        )


def _one_line(exc: Exception) -> str:
    return " ".join(str(exc).split())
