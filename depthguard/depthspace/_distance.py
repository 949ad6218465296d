"""Single-camera depth-space distances: validation around the numba kernels."""

from __future__ import annotations

import numpy as np
from numba import parallel_chunksize

from depthguard import config
from depthguard.depth import OccupancyImage
from depthguard.depthspace import _kernels
from depthguard.errors import InputError
from depthguard.results import DistanceResult, Flag


def check_points(points_world) -> np.ndarray:
    """Return control points as a C-contiguous (n, 3) float64 array; :class:`InputError` if malformed or not finite.

    Accepts (3,) for a single point. An empty list gives a (0, 3) array.
    """
    try:
        points = np.array(points_world, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"points must be numbers of shape (n, 3) ({exc})") from None
    if points.ndim == 1 and points.shape[0] == 3:
        points = points[None, :]
    if points.size == 0:
        return np.zeros((0, 3))
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputError(f"points must have shape (n, 3) (metres, world frame), got {points.shape}")
    bad = ~np.all(np.isfinite(points), axis=1)
    if bad.any():
        raise InputError(f"point #{int(np.argmax(bad))} is not finite: {points[np.argmax(bad)].tolist()}")
    return np.ascontiguousarray(points)


def check_options(rho: float, aggregate: str, unseen: str, method: str) -> None:
    """Raise :class:`InputError` for an unknown policy or a rho that is not a positive finite number of metres."""
    if isinstance(rho, bool) or not isinstance(rho, (int, float, np.floating)) or not (np.isfinite(rho) and rho > 0):
        raise InputError(f"rho must be a positive number of metres, got {rho!r}")
    if aggregate not in config.AGGREGATES:
        raise InputError(f"aggregate must be one of {config.AGGREGATES}, got {aggregate!r}")
    if unseen not in config.UNSEEN_POLICIES:
        raise InputError(f"unseen must be one of {config.UNSEEN_POLICIES}, got {unseen!r}")
    if method not in config.METHODS:
        raise InputError(f"method must be one of {config.METHODS}, got {method!r}")


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
    """Distances from control points to what one camera says is possibly occupied (SPEC sections 3-6).

    Args:
        occupancy: the prepared frame (:func:`depthguard.depth.prepare_depth`).
        points_world: (n, 3) float64, metres, world frame.
        rho: radius of the surveillance region, metres.
        aggregate: ``"min"``, ``"mean"`` or ``"hybrid"``.
        unseen: ``"occupied"`` (fail-safe) or ``"free"``.
        method: ``"exact"`` (SPEC) or ``"paper"`` (the 2015 paper's unsafe formulas, for comparison only).
        check: validate arguments; ``False`` skips it for a hot loop that already holds checked arrays.
    """
    if check:
        check_options(rho, aggregate, unseen, method)
        points_world = check_points(points_world)
    camera = occupancy.camera
    n = points_world.shape[0]
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
    )
