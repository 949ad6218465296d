"""A depth image tied to its camera and its capture time."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from depthguard.cameras import PinholeCamera
from depthguard.depth._io import read_depth_file
from depthguard.errors import DepthImageError


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

    Build it with :func:`depth_image` or :func:`load_depth`, which check it against its camera.
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
    (converted to ``float32``). The array is copied once and made read-only, so later changes by the caller cannot
    alter a frame that a monitor has already prepared. Raises :class:`DepthImageError` naming the camera and field.
    """
    if isinstance(data, DepthImage):
        data = data.data
    array = np.asarray(data)
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
        scale = camera.depth_scale
        array = np.array(array, dtype=np.uint16, order="C", copy=True)
    elif np.issubdtype(array.dtype, np.floating):
        scale = 1.0
        array = np.array(array, dtype=np.float32, order="C", copy=True)
    else:
        raise DepthImageError(f"must be uint16 (units of depth_scale) or float metres, got {array.dtype}",
                              camera=camera.name, field="dtype")
    if timestamp is not None:
        if isinstance(timestamp, bool) or not isinstance(timestamp, (int, float, np.floating, np.integer)) or \
                not math.isfinite(timestamp):
            raise DepthImageError(f"must be a finite number of seconds, got {timestamp!r}", camera=camera.name,
                                  field="timestamp")
        timestamp = float(timestamp)
    array.setflags(write=False)
    return DepthImage(camera=camera.name, data=array, depth_scale=scale, timestamp=timestamp)


def load_depth(path, camera: PinholeCamera, timestamp: float | None = None) -> DepthImage:
    """Read a depth image file (see :func:`read_depth_file`) for ``camera``.

    A ``uint16`` file is in units of ``camera.depth_scale``; a float file is in metres.
    """
    try:
        return depth_image(read_depth_file(path), camera, timestamp)
    except DepthImageError as exc:
        raise exc.with_source(str(path)) from None
