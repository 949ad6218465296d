"""The pinhole depth camera: intrinsics, pose, valid range and noise."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from depthguard import config
from depthguard.cameras._noise import NoiseModel
from depthguard.errors import RigError
from depthguard.validation import check_transform, short_repr
from depthguard.transforms import invert


@dataclass(frozen=True, eq=False)
class PinholeCamera:
    """A calibrated, rectified (distortion-free) depth camera.

    Axes of its optical frame (ROS REP 103): **x right, y down, z forward**. Pixel (u, v) is column u, row v; its
    centre is at image coordinates (u, v) and its footprint is [u - 1/2, u + 1/2] x [v - 1/2, v + 1/2], as in OpenCV
    and ROS. A point (x, y, z) in the optical frame projects to u = fx*x/z + cx, v = fy*y/z + cy. A depth value is
    the z coordinate of the surface (not the ray length).

    Attributes:
        name: the camera's name in its rig.
        width, height: image size, pixels.
        fx, fy: focal lengths, pixels. cx, cy: principal point, pixels.
        T_world_camera: (4, 4) float64, maps optical-frame coordinates (metres) to world coordinates (metres).
        depth_range: (min, max) valid measurement depth, metres; outside it a measurement counts as missing and the
            space counts as unseen. ``(0, inf)`` when the rig does not say.
        depth_scale: metres per unit of this camera's ``uint16`` depth images.
        noise: the depth noise model that gives the margin m(d).

    Every field is checked on construction; a wrong type or a value out of range raises
    :class:`~depthguard.errors.RigError` naming the camera and the field. Ranges (``depthguard.config``): name, at
    most ``MAX_NAME_LENGTH`` printable characters; width, height in [1, ``MAX_IMAGE_SIDE``]; fx, fy in
    [``FOCAL_LENGTH_MIN``, ``INTRINSICS_LIMIT``]; |cx|, |cy| <= ``INTRINSICS_LIMIT``; a rigid ``T_world_camera`` whose
    position lies within ``COORDINATE_LIMIT`` metres on each axis; 0 <= depth_range min < max (max may be inf);
    depth_scale in (0, ``DEPTH_SCALE_MAX``].
    """

    name: str
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    T_world_camera: np.ndarray
    depth_range: tuple[float, float] = config.DEFAULT_DEPTH_RANGE
    depth_scale: float = config.DEFAULT_DEPTH_SCALE
    noise: NoiseModel = field(default_factory=NoiseModel)

    def __post_init__(self):
        name = self.name
        if not isinstance(name, str) or not name or len(name) > config.MAX_NAME_LENGTH or not name.isprintable():
            raise RigError(f"camera name must be a non-empty string of at most {config.MAX_NAME_LENGTH} printable "
                           f"characters, got {short_repr(name)}", camera=short_repr(name), field="name")
        for key in ("width", "height"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or \
                    not 0 < value <= config.MAX_IMAGE_SIDE:
                raise RigError(f"must be a whole number of pixels in [1, {config.MAX_IMAGE_SIDE}], got "
                               f"{short_repr(value)}", camera=name, field=key)
            object.__setattr__(self, key, int(value))
        limit = config.INTRINSICS_LIMIT
        for key in ("fx", "fy", "cx", "cy"):
            value = _number(getattr(self, key), name, key)
            if key in ("fx", "fy") and not config.FOCAL_LENGTH_MIN <= value <= limit:
                if value <= 0.0:
                    raise RigError(f"focal length must be positive, got {value!r}", camera=name, field=key)
                raise RigError(f"focal length must be in [{config.FOCAL_LENGTH_MIN:g}, {limit:g}] pixels, got "
                               f"{value!r}", camera=name, field=key)
            if key in ("cx", "cy") and not abs(value) <= limit:
                raise RigError(f"principal point must be within +-{limit:g} pixels, got {value!r}", camera=name,
                               field=key)
            object.__setattr__(self, key, value)
        T = check_transform(self.T_world_camera, camera=name, field="T_world_camera")
        if np.abs(T[:3, 3]).max() > config.COORDINATE_LIMIT:
            raise RigError(f"camera position {T[:3, 3].tolist()} is beyond +-{config.COORDINATE_LIMIT:g} m",
                           camera=name, field="T_world_camera")
        T.setflags(write=False)
        object.__setattr__(self, "T_world_camera", T)
        T_cw = invert(T)
        T_cw.setflags(write=False)
        object.__setattr__(self, "_T_camera_world", T_cw)
        depth_range = self.depth_range
        if isinstance(depth_range, (str, bytes)) or not hasattr(depth_range, "__len__") or len(depth_range) != 2:
            raise RigError(f"must be [min, max] in metres, got {short_repr(depth_range)}", camera=name,
                           field="depth_range")
        lo, hi = (_number(x, name, "depth_range", finite=False) for x in depth_range)
        if not (math.isfinite(lo) and lo >= 0.0 and hi > lo) or math.isnan(hi):
            raise RigError(f"must satisfy 0 <= min < max (min finite; max may be .inf), got [{lo}, {hi}]",
                           camera=name, field="depth_range")
        object.__setattr__(self, "depth_range", (lo, hi))
        scale = _number(self.depth_scale, name, "depth_scale")
        if not 0.0 < scale <= config.DEPTH_SCALE_MAX:
            raise RigError(f"must be a positive number of metres per unit, at most {config.DEPTH_SCALE_MAX:g}, got "
                           f"{scale!r}", camera=name, field="depth_scale")
        object.__setattr__(self, "depth_scale", scale)
        if not isinstance(self.noise, NoiseModel):
            raise RigError(f"must be a NoiseModel, got {type(self.noise).__name__}", camera=name, field="noise")

    @property
    def T_camera_world(self) -> np.ndarray:
        """(4, 4) float64: maps world coordinates to this camera's optical frame."""
        return self._T_camera_world

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width): the shape of this camera's images."""
        return (self.height, self.width)

    @property
    def K(self) -> np.ndarray:
        """(3, 3) float64 intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def world_to_camera(self, points_world) -> np.ndarray:
        """(n, 3) metres, world frame -> (n, 3) metres, optical frame."""
        T = self._T_camera_world
        return np.asarray(points_world, dtype=np.float64) @ T[:3, :3].T + T[:3, 3]

    def camera_to_world(self, points_camera) -> np.ndarray:
        """(n, 3) metres, optical frame -> (n, 3) metres, world frame."""
        T = self.T_world_camera
        return np.asarray(points_camera, dtype=np.float64) @ T[:3, :3].T + T[:3, 3]

    def project(self, points_camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Project (n, 3) optical-frame points (metres) to image coordinates.

        Returns (u, v, z): (n,) float64 column and row coordinates (pixels; NaN for z <= 0) and depth z (metres).
        """
        p = np.asarray(points_camera, dtype=np.float64).reshape(-1, 3)
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            ok = z > 0
            u = np.where(ok, self.fx * p[:, 0] / z + self.cx, np.nan)
            v = np.where(ok, self.fy * p[:, 1] / z + self.cy, np.nan)
        return u, v, z

    def back_project(self, u, v, depth) -> np.ndarray:
        """Optical-frame points (..., 3), metres, of image coordinates ``u``, ``v`` (pixels) at depth z (metres)."""
        u, v, depth = np.broadcast_arrays(np.asarray(u, np.float64), np.asarray(v, np.float64),
                                          np.asarray(depth, np.float64))
        return np.stack([(u - self.cx) / self.fx * depth, (v - self.cy) / self.fy * depth, depth], axis=-1)

    def pixel_grid(self) -> tuple[np.ndarray, np.ndarray]:
        """(u, v): two (height, width) float64 arrays holding each pixel's column and row."""
        v, u = np.mgrid[0 : self.height, 0 : self.width]
        return u.astype(np.float64), v.astype(np.float64)

    def depth_to_points(self, depth_m: np.ndarray) -> np.ndarray:
        """Back-project a (height, width) depth image in metres to (height, width, 3) optical-frame points."""
        u, v = self.pixel_grid()
        return self.back_project(u, v, depth_m)

    def replace(self, **changes) -> "PinholeCamera":
        """A copy with some fields changed (validated again)."""
        fields = dict(name=self.name, width=self.width, height=self.height, fx=self.fx, fy=self.fy, cx=self.cx,
                      cy=self.cy, T_world_camera=self.T_world_camera, depth_range=self.depth_range,
                      depth_scale=self.depth_scale, noise=self.noise)
        fields.update(changes)
        return PinholeCamera(**fields)

    def to_dict(self) -> dict:
        """The camera as a rig-file entry (plain Python types)."""
        lo, hi = self.depth_range
        entry = dict(name=self.name, width=self.width, height=self.height, fx=self.fx, fy=self.fy, cx=self.cx,
                     cy=self.cy, T_world_camera=[[float(x) for x in row] for row in self.T_world_camera])
        if (lo, hi) != config.DEFAULT_DEPTH_RANGE:
            entry["depth_range"] = [lo, hi]
        entry["depth_scale"] = self.depth_scale
        entry["noise"] = dict(a=self.noise.a, b=self.noise.b, c=self.noise.c, k=self.noise.k)
        return entry

    def __repr__(self) -> str:
        return (f"PinholeCamera(name={self.name!r}, {self.width}x{self.height}, fx={self.fx:g}, fy={self.fy:g}, "
                f"cx={self.cx:g}, cy={self.cy:g})")


def _number(value, camera: str, field: str, finite: bool = True) -> float:
    """``value`` as a float: a real number (not a bool, a string or a complex), finite unless ``finite`` is False
    (then +-inf pass, NaN too: the caller's range check refuses it). :class:`RigError` naming the camera and field."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise RigError(f"must be a number, got {short_repr(value)}", camera=camera, field=field)
    try:
        number = float(value)
    except OverflowError:  # an integer beyond the float range: no number depthguard can use (not infinity)
        raise RigError(f"must be a number within the float range (about 1.8e308), got {short_repr(value)}",
                       camera=camera, field=field) from None
    if finite and not math.isfinite(number):
        raise RigError(f"must be finite, got {short_repr(value)}", camera=camera, field=field)
    return number
