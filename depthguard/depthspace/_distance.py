"""Single-camera depth-space distances: validation around the numba kernels."""

from __future__ import annotations

import math

import numpy as np
from numba import parallel_chunksize

from depthguard import config
from depthguard.depth import OccupancyImage
from depthguard.kernels import depthspace as depthspace_kernels
from depthguard.errors import InputError
from depthguard.validation import check_options, check_points
from depthguard.results import DistanceResult, Flag


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
            depthspace_kernels.query_points_serial(*args)
        else:
            with parallel_chunksize(1):  # points differ a lot in cost: hand them to threads one at a time
                depthspace_kernels.query_points(*args)
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
