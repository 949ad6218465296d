"""Single-camera depth-space distances: validation around the numba kernels."""

from __future__ import annotations

import math

import numpy as np
from numba import parallel_chunksize

from depthguard import config
from depthguard.depth import OccupancyImage
from depthguard.depthspace import _kernels
from depthguard.errors import InputError, check_real, short_repr
from depthguard.results import DistanceResult, Flag


def check_points(points_world) -> np.ndarray:
    """Return control points as a C-contiguous (n, 3) float64 array (metres, world frame).

    Accepts a sequence or array of real numbers of shape (n, 3), or (3,) for a single point; an empty list or an
    array of shape (0,) or (0, 3) gives a (0, 3) array. Raises :class:`InputError` for anything else: a string,
    a masked array, complex, bool, object or text values, another shape (an (n, 0) array among them), a coordinate
    that is not finite or beyond ``config.COORDINATE_LIMIT`` metres (naming the point's index).
    """
    if isinstance(points_world, (str, bytes)):
        raise InputError(f"points must be numbers of shape (n, 3) (metres, world frame), got a string "
                         f"{short_repr(points_world)}", field="points")
    if isinstance(points_world, np.ma.MaskedArray):
        raise InputError("points must not be a masked array: a masked coordinate has no value (pass the points you "
                         "mean, as a plain array)", field="points")
    try:
        array = np.asarray(points_world)
    except (TypeError, ValueError) as exc:  # ragged lists, objects numpy cannot read
        raise InputError(f"points must be numbers of shape (n, 3) ({' '.join(str(exc).split())[:120]})",
                         field="points") from None
    if array.dtype.kind not in "fiu":  # checked before converting: complex, bool, object and text never pass
        raise InputError(f"points must be real numbers (float or int), got dtype {array.dtype}", field="points")
    points = np.array(array, dtype=np.float64)
    if points.ndim == 1 and points.shape[0] in (0, 3):
        points = points.reshape(-1, 3)
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputError(f"points must have shape (n, 3) (metres, world frame), got {points.shape}", field="points")
    bad = ~np.all(np.isfinite(points), axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise InputError(f"point #{i} is not finite: {points[i].tolist()}", field="points")
    far = np.any(np.abs(points) > config.COORDINATE_LIMIT, axis=1)
    if far.any():
        i = int(np.argmax(far))
        raise InputError(f"point #{i} {points[i].tolist()} is beyond +-{config.COORDINATE_LIMIT:g} m "
                         "(config.COORDINATE_LIMIT)", field="points")
    return np.ascontiguousarray(points)


def check_options(rho: float, aggregate: str, unseen: str, method: str) -> float:
    """Raise :class:`InputError` for an unknown policy or a rho that is not a number of metres in
    [``config.RHO_MIN``, ``config.RHO_MAX``]; return rho as a float."""
    rho = check_real(rho, "rho", minimum=config.RHO_MIN, maximum=config.RHO_MAX, unit="metres", field="rho")
    for name, value, allowed in (("aggregate", aggregate, config.AGGREGATES),
                                 ("unseen", unseen, config.UNSEEN_POLICIES), ("method", method, config.METHODS)):
        if not isinstance(value, str) or value not in allowed:
            raise InputError(f"{name} must be one of {allowed}, got {short_repr(value)}", field=name)
    return rho


def query_arrays(camera, points_world: np.ndarray):
    """The kernels' inputs and outputs for n checked points: (points in ``camera``'s optical frame (n, 3),
    distance (n,), direction (n, 3) zeros, count (n,), invalid_count (n,), flags (n,) int64)."""
    n = points_world.shape[0]
    points_camera = np.ascontiguousarray(camera.world_to_camera(points_world)) if n else np.zeros((0, 3))
    return (points_camera, np.empty(n), np.zeros((n, 3)), np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64),
            np.empty(n, dtype=np.int64))


def single_camera_distances(occupancy: OccupancyImage, points_world, rho: float = config.DEFAULT_RHO,
                            aggregate: str = config.DEFAULT_AGGREGATE, unseen: str = config.DEFAULT_UNSEEN,
                            method: str = config.DEFAULT_METHOD, check: bool = True) -> DistanceResult:
    """Distances from control points to what one camera says is possibly occupied (design §3-6).

    Args:
        occupancy: the prepared frame (:func:`depthguard.depth.prepare_depth`).
        points_world: (n, 3) float64, metres, world frame.
        rho: radius of the surveillance region, metres.
        aggregate: ``"min"``, ``"mean"`` or ``"hybrid"``.
        unseen: ``"occupied"`` (fail-safe) or ``"free"``.
        method: ``"exact"`` (design) or ``"paper"`` (the 2015 paper's unsafe formulas, for comparison only).
        check: validate arguments; ``False`` skips it for a hot loop that already holds checked arrays.

    A frame whose timestamp is NaN or infinite is stale: every point gets distance 0 and ``STALE_CAMERA``.
    """
    if check:
        if not isinstance(occupancy, OccupancyImage):
            raise InputError(f"occupancy must be an OccupancyImage (depthguard.prepare_depth), got "
                             f"{type(occupancy).__name__}", field="occupancy")
        rho = check_options(rho, aggregate, unseen, method)
        points_world = check_points(points_world)
    camera = occupancy.camera
    n = points_world.shape[0]
    timestamp = occupancy.timestamp
    if timestamp is not None and not math.isfinite(timestamp):  # design §8 "Time": such a frame is stale, never fresh
        return DistanceResult.blind(n, Flag.STALE_CAMERA, {camera.name: timestamp})
    points_camera, distance, direction_camera, count, invalid_count, flags = query_arrays(camera, points_world)
    blind_distance = np.full(n, np.inf)
    if n:
        z_min, z_max = camera.depth_range
        args = (points_camera, float(rho), occupancy.z_start, occupancy.z_end, occupancy.invalid, occupancy.block_min,
                occupancy.blind, occupancy.blind_block_min, occupancy.robot_pixels > 0, config.BLOCK_SIZE, camera.fx,
                camera.fy, camera.cx, camera.cy, z_min, z_max,
                config.AGGREGATES.index(aggregate), unseen == "occupied", method == "paper", config.NEAR_PLANE_EPSILON,
                config.INSIDE_TOLERANCE, config.MIN_DIRECTION_NORM, distance, direction_camera, count, invalid_count,
                flags, blind_distance)
        if n == 1:
            _kernels.query_points_serial(*args)
        else:
            with parallel_chunksize(1):  # points differ a lot in cost: hand them to threads one at a time
                _kernels.query_points(*args)
    direction = direction_camera @ camera.T_world_camera[:3, :3].T
    return DistanceResult(
        distance=distance,
        direction=direction,
        count=count,
        invalid_count=invalid_count,
        flags=tuple(Flag(int(f)) for f in flags),
        timestamps={camera.name: occupancy.timestamp},
        cameras=(camera.name,),
        invalid_pixels={camera.name: occupancy.invalid_pixels},
        blind_distance=blind_distance,
        principal=(camera.name,) * len(distance),
    )
