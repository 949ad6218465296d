"""From a depth image to what one camera says is possibly occupied (design §3).

Pixel (u, v) is possibly occupied along its frustum from ``z_start[v, u]`` on: the measured depth minus the noise
margin m(d) for a valid pixel; for a pixel without a valid measurement, what the invalid-pixel policy says:

- ``"occupied"`` (fail-safe default): from the camera's minimum range on;
- ``"neighbors"``: a hole of at most ``hole_pixels`` 8-connected pixels, or one nowhere more than 2 pixels thick
  (the lines depth cameras drop along depth edges), takes the smallest valid depth around it (minus its margin);
  larger holes stay occupied;
- ``"free"``: nothing (``inf``), what the papers do.

With the robot rendered into the camera (design §7, :func:`prepare_depth`'s ``robot_near``), pixels that show
the robot are free up to it and blind behind it, and a pixel without a measurement is occupied only up to the robot.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from depthguard import config
from depthguard.cameras import PinholeCamera
from depthguard.kernels import depth as depth_kernels
from depthguard.depth._image import DepthImage
from depthguard.errors import InputError
from depthguard.validation import check_real, short_repr


@dataclass(frozen=True, eq=False)
class OccupancyImage:
    """What one depth frame says is possibly occupied, ready for the distance kernels.

    Attributes:
        camera: the camera.
        z_start: (height, width) float32 metres, optical frame: pixel (u, v) is possibly occupied along its frustum
            for z_start[v, u] <= z <= z_end[v, u]; ``inf`` where it says nothing.
        z_end: (height, width) float32 metres: where that occupied segment ends; ``inf`` except in front of the
            robot on pixels without a measurement.
        blind: (height, width) float32 metres: where the space hidden behind the robot starts along the pixel, the
            front of the rendered robot (``inf``: no robot there). Queries report how close it comes.
        invalid: (height, width) uint8, 1 where the pixel had no valid measurement (whatever the policy made of it).
        block_min: (ceil(h/B), ceil(w/B)) float32, the minimum of z_start over blocks of B x B pixels
            (B = ``config.BLOCK_SIZE``); kernels use it to skip whole blocks.
        blind_block_min: the same for ``blind``.
        invalid_policy: the policy that made z_start.
        timestamp: the frame's capture time in seconds, or None.
        invalid_pixels: number of pixels without a valid measurement.
        robot_pixels: number of pixels that show the robot (0 without self-filtering).
        filled: None, or (height, width) float32 metres: where ``invalid="neighbors"`` filled a hole, the depth up to
            which the fill counted the pixel's frustum free although nothing was measured there (the fill's start,
            or the rendered robot where the fill was taken for the robot), 0 elsewhere: the space the concession
            counted free (design §11a, flag ``hole_filled``). None when no hole was filled.
    """

    camera: PinholeCamera
    z_start: np.ndarray
    z_end: np.ndarray
    blind: np.ndarray
    invalid: np.ndarray
    block_min: np.ndarray
    blind_block_min: np.ndarray
    invalid_policy: str
    timestamp: float | None
    invalid_pixels: int
    robot_pixels: int = 0
    filled: np.ndarray | None = None


def prepare_depth(depth: DepthImage, camera: PinholeCamera, invalid: str = config.DEFAULT_INVALID,
                  hole_pixels: int = config.DEFAULT_NEIGHBOR_HOLE_PIXELS, robot_near: np.ndarray | None = None,
                  robot_tolerance: float = config.SELF_FILTER_TOLERANCE,
                  robot_far: np.ndarray | None = None) -> OccupancyImage:
    """Turn a checked :class:`DepthImage` of ``camera`` into an :class:`OccupancyImage` (one pass, numba).

    Args:
        depth: the frame. invalid, hole_pixels: the invalid-pixel policy (module docstring).
        robot_near: optional (height, width) float32 metres, the robot's padded collision geometry rendered into
            this camera at the frame's joint positions (nearest surface; 0 where the robot is not). Enables
            self-filtering. The space behind it is the robot's blind spot: it starts at the rendered surface, not
            where the robot's body ends, because the padded geometry is larger than the robot and an obstacle may
            sit in the difference.
        robot_tolerance: metres by which a measurement may lie in front of the rendered robot and still be the
            robot (calibration, joint-state timing), on top of the noise margin.
        robot_far: optional, with ``robot_near``: where the rendered robot ends along each pixel (its farthest
            surface; 0 where it is not). A measurement farther than that (plus the tolerance and the noise margin)
            saw past the padded geometry and stays a surface instead of making the space behind the robot blind.
    """
    # Cheap checks only (no pass over the pixels): the kernels trust what they get. A DepthImage built by hand is
    # checked in full by depth_image / checked_frame, which the monitor calls.
    if not isinstance(camera, PinholeCamera):
        raise InputError(f"camera must be a PinholeCamera, got {type(camera).__name__}", field="camera")
    if not isinstance(depth, DepthImage):
        raise InputError(f"depth must be a DepthImage (depthguard.depth_image), got {type(depth).__name__}",
                         camera=camera.name, field="depth")
    if not isinstance(invalid, str) or invalid not in config.INVALID_POLICIES:
        raise InputError(f"invalid-pixel policy must be one of {config.INVALID_POLICIES}, got {short_repr(invalid)}",
                         field="invalid")
    data = depth.data
    if not (isinstance(data, np.ndarray) and not isinstance(data, np.ma.MaskedArray)
            and data.dtype in (np.dtype(np.uint16), np.dtype(np.float32)) and data.flags.c_contiguous):
        raise InputError("depth.data must be a C-contiguous uint16 or float32 array: build the frame with "
                         "depthguard.depth_image", camera=camera.name, field="depth")
    if depth.camera != camera.name or data.shape != camera.shape:
        raise InputError(f"depth image of camera {short_repr(depth.camera)} {data.shape} given for camera "
                         f"{camera.name!r} {camera.shape}")
    scale = depth.depth_scale
    if isinstance(scale, bool) or not isinstance(scale, (int, float, np.integer, np.floating)) or \
            not 0.0 < float(scale) <= config.DEPTH_SCALE_MAX:
        raise InputError(f"depth_scale must be in (0, {config.DEPTH_SCALE_MAX:g}] metres per unit, got "
                         f"{short_repr(scale)}", camera=camera.name, field="depth_scale")
    if isinstance(hole_pixels, bool) or not isinstance(hole_pixels, (int, np.integer)) or \
            not 0 <= hole_pixels <= config.MAX_HOLE_PIXELS:
        raise InputError(f"hole_pixels must be a whole number of pixels in [0, {config.MAX_HOLE_PIXELS}], got "
                         f"{short_repr(hole_pixels)}", field="hole_pixels")
    h, w = camera.shape
    z_min, z_max = camera.depth_range
    m0, m1, m2 = camera.noise.coefficients()
    z_start = np.empty((h, w), dtype=np.float32)
    z_end = np.empty((h, w), dtype=np.float32)
    blind = np.empty((h, w), dtype=np.float32)
    invalid_mask = np.empty((h, w), dtype=np.uint8)
    invalid_start = np.inf if invalid == "free" else z_min
    depth_kernels.start_depths(depth.data, float(depth.depth_scale), z_min, z_max, m0, m1, m2, invalid_start, z_start,
                          invalid_mask, z_end, blind)
    n_invalid = int(np.count_nonzero(invalid_mask))
    if robot_near is not None:
        near = _robot_image(robot_near, camera, "robot_near")
        robot_tolerance = check_real(robot_tolerance, "robot_tolerance", minimum=0.0,
                                     maximum=config.SELF_FILTER_TOLERANCE_MAX, unit="metres", field="robot_tolerance")
        far = near if robot_far is None else _robot_image(robot_far, camera, "robot_far")
        depth_kernels.robot_filter(z_start, invalid_mask, np.float32(invalid_start), near, far, robot_far is not None,
                              float(robot_tolerance), m0, m1, m2, z_end, blind)
    filled = None
    if invalid == "neighbors" and n_invalid:
        before = z_start.copy()
        depth_kernels.fill_small_holes(depth.data, float(depth.depth_scale), invalid_mask, int(hole_pixels), m0, m1, m2,
                                  z_start, z_end, blind, np.empty((h, w), dtype=np.uint8),
                                  np.empty(h * w, dtype=np.int64))
        changed = (z_start != before) & (invalid_mask != 0)
        if changed.any():  # a hole filled from the robot is free up to the robot (z_start inf, blind there)
            filled = np.where(changed, np.where(np.isfinite(z_start), z_start, blind), np.float32(0.0))
            filled = filled.astype(np.float32)
        if robot_near is not None:
            # A hole's fill stands for the measurement the pixel lost, and is self-filtered as one: a fill from a
            # surface beside the robot (the pedestal round its base) that lies behind the robot's front along a
            # pixel the robot covers shows the robot there, not a surface inside it.
            depth_kernels.robot_filter_fills(z_start, invalid_mask, np.float32(invalid_start), near, far,
                                        robot_far is not None, float(robot_tolerance), m0, m1, m2, z_end, blind)
            if filled is not None:  # a fill taken for the robot counts its pixel free up to the robot
                filled = np.where((filled > 0) & ~np.isfinite(z_start), blind, filled).astype(np.float32)
    robot_pixels = 0 if robot_near is None else int(np.count_nonzero(np.isfinite(blind)))
    block = config.BLOCK_SIZE
    shape = ((h + block - 1) // block, (w + block - 1) // block)
    block_min = np.empty(shape, dtype=np.float32)
    depth_kernels.block_minimum(z_start, block, block_min)
    blind_block_min = np.full(shape, np.inf, dtype=np.float32)
    if robot_pixels:
        depth_kernels.block_minimum(blind, block, blind_block_min)
    for array in (z_start, z_end, blind, invalid_mask, block_min, blind_block_min) + \
            (() if filled is None else (filled,)):
        array.setflags(write=False)
    return OccupancyImage(camera=camera, z_start=z_start, z_end=z_end, blind=blind, invalid=invalid_mask,
                          block_min=block_min, blind_block_min=blind_block_min, invalid_policy=invalid,
                          timestamp=depth.timestamp, invalid_pixels=n_invalid, robot_pixels=robot_pixels,
                          filled=filled)


def filled_space(occupancy: OccupancyImage) -> OccupancyImage | None:
    """The space ``occupancy``'s filled holes counted free (:attr:`OccupancyImage.filled`) as an occupancy image of
    the same camera whose only segments are that space: each filled pixel's frustum from the camera's minimum range
    up to where its fill starts. Distances to it (``single_camera_distances``, ``unseen="free"``) say how near the
    concession comes to a point. None when no hole was filled."""
    if occupancy.filled is None:
        return None
    camera = occupancy.camera
    filled = occupancy.filled > 0
    z_start = np.where(filled, np.float32(camera.depth_range[0]), np.float32(np.inf)).astype(np.float32)
    z_end = np.where(filled, occupancy.filled, np.float32(np.inf)).astype(np.float32)
    block = config.BLOCK_SIZE
    h, w = camera.shape
    shape = ((h + block - 1) // block, (w + block - 1) // block)
    block_min = np.empty(shape, dtype=np.float32)
    depth_kernels.block_minimum(z_start, block, block_min)
    none = np.full((h, w), np.inf, dtype=np.float32)
    invalid = np.zeros((h, w), dtype=np.uint8)
    blind_block_min = np.full(shape, np.inf, dtype=np.float32)
    # read-only, as prepare_depth's: the kernels see the same argument types (one compile, which the warm-up makes)
    for array in (z_start, z_end, none, invalid, block_min, blind_block_min):
        array.setflags(write=False)
    return OccupancyImage(camera=camera, z_start=z_start, z_end=z_end, blind=none, invalid=invalid,
                          block_min=block_min, blind_block_min=blind_block_min, invalid_policy="occupied",
                          timestamp=occupancy.timestamp, invalid_pixels=0)


def _robot_image(image, camera: PinholeCamera, field: str) -> np.ndarray:
    array = np.asarray(image)
    if array.shape != camera.shape:
        raise InputError(f"{field} of camera {camera.name!r} is {array.shape}, the camera is {camera.shape}")
    array = np.ascontiguousarray(array, dtype=np.float32)
    if array.size and not (array.min() >= 0 and np.isfinite(array.max())):  # min is NaN if any element is
        raise InputError(f"{field} of camera {camera.name!r} must be finite depths >= 0 (0 = no robot)")
    return array
