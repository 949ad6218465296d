"""A depth image tied to its camera and its capture time."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from depthguard import config
from depthguard.cameras import PinholeCamera
from depthguard.io.images import read_depth_file
from depthguard.errors import DepthImageError, InputError
from depthguard.validation import NOT_A_NUMBER, check_count, check_path, real_or_nan, short_repr


@dataclass(frozen=True, eq=False)
class DepthImage:
    """One depth frame of one camera.

    Attributes:
        camera: name of the camera that took it.
        data: (height, width) read-only array; ``uint16`` in units of ``depth_scale`` metres (0 = no measurement),
            as ROS ``16UC1``, or ``float32`` metres (0, NaN or inf = no measurement), as ROS ``32FC1``. Negative
            values also count as no measurement.
        depth_scale: metres per unit of ``data`` (1.0 for ``float32``).
        timestamp: capture time in seconds (any clock shared with the caller's ``now``), or None if unknown.

    Build it with :func:`depth_image` or :func:`load_depth`, which check it against its camera. One built directly
    is not trusted: :class:`depthguard.DistanceMonitor` checks it again (:func:`checked_frame`) and reads a private
    copy of its data.
    """

    camera: str
    data: np.ndarray
    depth_scale: float
    timestamp: float | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return self.data.shape

    def metres(self) -> np.ndarray:
        """(height, width) float32 metres; NaN where there is no measurement."""
        d = self.data.astype(np.float32) * np.float32(self.depth_scale)
        d[~(np.isfinite(d) & (d > 0))] = np.nan
        return d

    def valid_fraction(self) -> float:
        """Fraction of pixels holding a measurement (finite and > 0)."""
        d = self.data
        ok = (d > 0) & np.isfinite(d) if d.dtype.kind == "f" else d > 0
        return float(ok.mean())


def depth_image(data, camera: PinholeCamera, timestamp: float | None = None) -> DepthImage:
    """Check ``data`` against ``camera`` and wrap it as a :class:`DepthImage`.

    ``data``: (camera.height, camera.width) ``uint16`` (units of ``camera.depth_scale``) or floating point metres
    (converted to ``float32``). A masked array (``numpy.ma``) is read with its masked pixels as "no measurement"
    (0 for ``uint16``, NaN for float). The array is copied once and made read-only, so later changes by the caller
    cannot alter a frame that a monitor has already prepared. ``timestamp``: None or a finite number of seconds.
    Raises :class:`DepthImageError` naming the camera and field (``shape``, ``width/height``, ``dtype``,
    ``timestamp``).
    """
    if not isinstance(camera, PinholeCamera):
        raise InputError(f"camera must be a PinholeCamera, got {type(camera).__name__}", field="camera")
    if isinstance(data, DepthImage):
        data = data.data
    array = _checked_data(data, camera)
    if timestamp is not None:
        timestamp = _seconds(timestamp, camera.name)
        if not math.isfinite(timestamp):
            raise DepthImageError(f"must be a finite number of seconds, got {short_repr(timestamp)}",
                                  camera=camera.name, field="timestamp")
    scale = camera.depth_scale if array.dtype == np.uint16 else 1.0
    return DepthImage(camera=camera.name, data=array, depth_scale=scale, timestamp=timestamp)


def checked_frame(frame: DepthImage, camera: PinholeCamera) -> DepthImage:
    """A :class:`DepthImage` that someone else built (it is a plain dataclass, so it may bypass
    :func:`depth_image`), checked again against ``camera``: a private read-only copy of its data (2-D, the camera's
    size, ``uint16`` or float), its own ``depth_scale`` (a number in (0, ``config.DEPTH_SCALE_MAX``]) and its
    timestamp (None or a real number). A timestamp that is NaN or infinite is kept as it is: the monitor treats such
    a frame as stale, never fresh. Raises :class:`DepthImageError` naming the camera and field.
    """
    name = camera.name
    if frame.camera != name:
        raise InputError(f"the frame given for camera {name!r} was taken by camera {short_repr(frame.camera)}",
                         camera=name, field="camera")
    array = _checked_data(frame.data, camera)
    scale = frame.depth_scale
    scale_value = real_or_nan(scale)
    if not 0.0 < scale_value <= config.DEPTH_SCALE_MAX:
        raise DepthImageError(f"must be a number of metres per unit in (0, {config.DEPTH_SCALE_MAX:g}], got "
                              f"{short_repr(scale)}", camera=name, field="depth_scale")
    timestamp = None if frame.timestamp is None else _seconds(frame.timestamp, name)
    return DepthImage(camera=name, data=array, depth_scale=scale_value, timestamp=timestamp)


def _checked_data(data, camera: PinholeCamera) -> np.ndarray:
    """``data`` as a private, read-only, C-contiguous (h, w) ``uint16`` or ``float32`` array, masked pixels set to
    "no measurement"."""
    mask = None
    if isinstance(data, np.ma.MaskedArray):
        mask = np.ma.getmaskarray(data)
        data = np.ma.getdata(data)
    if not isinstance(data, np.ndarray):  # a list is refused before numpy converts it (an array is already there)
        check_count(data, camera.height, "shape", "the camera's height", DepthImageError, camera=camera.name)
    try:
        array = np.asarray(data)
    except NOT_A_NUMBER as exc:  # ragged nested lists, objects numpy cannot read
        raise DepthImageError(f"not an image array ({' '.join(str(exc).split())[:120]})", camera=camera.name,
                              field="dtype") from None
    if array.ndim != 2:
        raise DepthImageError(f"must be a 2-D image, got {array.ndim} dimensions (shape {array.shape})",
                              camera=camera.name, field="shape")
    if array.shape != camera.shape:
        raise DepthImageError(
            f"image is {array.shape[1]}x{array.shape[0]} (width x height) but the camera is "
            f"{camera.width}x{camera.height}",
            camera=camera.name,
            field="width/height",
        )
    if array.dtype.kind == "u" and array.dtype.itemsize == 2:  # uint16, either byte order
        array = np.array(array, dtype=np.uint16, order="C", copy=True)
        missing = 0
    elif array.dtype.kind == "f":
        array = np.array(array, dtype=np.float32, order="C", copy=True)
        missing = np.nan
    else:
        raise DepthImageError(f"must be uint16 (units of depth_scale) or float metres, got {array.dtype}",
                              camera=camera.name, field="dtype")
    if mask is not None and mask.any():
        array[mask] = missing
    array.setflags(write=False)
    return array


def _seconds(value, camera: str) -> float:
    """A timestamp as a float (NaN and infinities pass; the caller decides); DepthImageError if not a number."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise DepthImageError(f"must be a number of seconds, got {short_repr(value)}", camera=camera,
                              field="timestamp")
    try:
        return float(value)
    except OverflowError:
        return math.inf if value > 0 else -math.inf


def load_depth(path, camera: PinholeCamera, timestamp: float | None = None) -> DepthImage:
    """Read a depth image file (see :func:`read_depth_file`) for ``camera``.

    A ``uint16`` file is in units of ``camera.depth_scale``; a float file is in metres.
    """
    if not isinstance(camera, PinholeCamera):
        raise InputError(f"camera must be a PinholeCamera, got {type(camera).__name__}", field="camera")
    path = check_path(path, "depth image", DepthImageError, camera=camera.name)
    try:
        return depth_image(read_depth_file(path, camera), camera, timestamp)
    except DepthImageError as exc:
        raise exc.with_source(str(path)) from None
