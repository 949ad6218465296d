"""From a depth image to what one camera says is possibly occupied (SPEC section 3).

Pixel (u, v) is possibly occupied along its frustum from ``z_start[v, u]`` on: the measured depth minus the noise
margin m(d) for a valid pixel; for a pixel without a valid measurement, what the invalid-pixel policy says:

- ``"occupied"`` (fail-safe default): from the camera's minimum range on;
- ``"neighbors"``: a hole of at most ``hole_pixels`` 8-connected pixels takes the smallest valid depth around it
  (minus its margin); larger holes stay occupied;
- ``"free"``: nothing (``inf``), what the papers do.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from depthguard import config
from depthguard.cameras import PinholeCamera
from depthguard.depth import _kernels
from depthguard.depth._image import DepthImage
from depthguard.errors import InputError


@dataclass(frozen=True, eq=False)
class OccupancyImage:
    """What one depth frame says is possibly occupied, ready for the distance kernels.

    Attributes:
        camera: the camera.
        z_start: (height, width) float32 metres, optical frame: pixel (u, v) is possibly occupied along its frustum
            for z >= z_start[v, u]; ``inf`` where it says nothing.
        invalid: (height, width) uint8, 1 where the pixel had no valid measurement (whatever the policy made of it).
        block_min: (ceil(h/B), ceil(w/B)) float32, the minimum of z_start over blocks of B x B pixels
            (B = ``config.BLOCK_SIZE``); kernels use it to skip whole blocks.
        invalid_policy: the policy that made z_start.
        timestamp: the frame's capture time in seconds, or None.
        invalid_pixels: number of pixels without a valid measurement.
    """

    camera: PinholeCamera
    z_start: np.ndarray
    invalid: np.ndarray
    block_min: np.ndarray
    invalid_policy: str
    timestamp: float | None
    invalid_pixels: int


def prepare_depth(depth: DepthImage, camera: PinholeCamera, invalid: str = config.DEFAULT_INVALID,
                  hole_pixels: int = config.DEFAULT_NEIGHBOR_HOLE_PIXELS) -> OccupancyImage:
    """Turn a checked :class:`DepthImage` of ``camera`` into an :class:`OccupancyImage` (one pass, numba)."""
    if invalid not in config.INVALID_POLICIES:
        raise InputError(f"invalid-pixel policy must be one of {config.INVALID_POLICIES}, got {invalid!r}")
    if depth.camera != camera.name or depth.shape != camera.shape:
        raise InputError(f"depth image of camera {depth.camera!r} {depth.shape} given for camera {camera.name!r} "
                         f"{camera.shape}")
    h, w = camera.shape
    z_min, z_max = camera.depth_range
    m0, m1, m2 = camera.noise.coefficients()
    z_start = np.empty((h, w), dtype=np.float32)
    invalid_mask = np.empty((h, w), dtype=np.uint8)
    invalid_start = np.inf if invalid == "free" else z_min
    _kernels.start_depths(depth.data, float(depth.depth_scale), z_min, z_max, m0, m1, m2, invalid_start, z_start,
                          invalid_mask)
    n_invalid = int(np.count_nonzero(invalid_mask))
    if invalid == "neighbors" and n_invalid:
        _fill_small_holes(z_start, invalid_mask, depth, camera, hole_pixels)
    block = config.BLOCK_SIZE
    block_min = np.empty(((h + block - 1) // block, (w + block - 1) // block), dtype=np.float32)
    _kernels.block_minimum(z_start, block, block_min)
    for array in (z_start, invalid_mask, block_min):
        array.setflags(write=False)
    return OccupancyImage(camera=camera, z_start=z_start, invalid=invalid_mask, block_min=block_min,
                          invalid_policy=invalid, timestamp=depth.timestamp, invalid_pixels=n_invalid)


def _fill_small_holes(z_start, invalid_mask, depth: DepthImage, camera: PinholeCamera, hole_pixels: int) -> None:
    """``invalid="neighbors"``: holes of at most ``hole_pixels`` pixels take the smallest valid depth around them."""
    holes = invalid_mask.astype(bool)
    labels, n = ndimage.label(holes, structure=np.ones((3, 3), dtype=bool))
    sizes = np.bincount(labels.ravel(), minlength=n + 1)
    measured = np.where(holes, np.inf, depth.data.astype(np.float64) * depth.depth_scale)
    around = ndimage.minimum_filter(measured, size=3, mode="constant", cval=np.inf)
    index = np.arange(1, n + 1)
    nearest = np.asarray(ndimage.minimum(around, labels, index), dtype=np.float64).reshape(-1)
    fill = np.full(n + 1, np.nan)
    small = (sizes[1:] <= hole_pixels) & np.isfinite(nearest)
    fill[1:][small] = nearest[small] - camera.noise.margin(nearest[small])
    values = fill[labels]
    take = holes & np.isfinite(values)
    z_start[take] = np.maximum(values[take], 0.0).astype(np.float32)
