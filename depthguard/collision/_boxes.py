"""Boxes seen at tile resolution (design §10): a box's corners, a box moved between frames, and the tiles of a
camera's tile grid a box may be seen in. The reference update's work piece and the collision test's gripped piece
both use them."""

from __future__ import annotations

import itertools

import numpy as np

from depthguard import config
from depthguard.kernels import collision_update as update_kernels
from depthguard.collision._epipolar import TileGrid
from depthguard.errors import InputError
from depthguard.validation import NOT_A_NUMBER, real_vector
from depthguard.scenes import Box

#: metres, optical depth: a box with a corner this near the camera's plane (or behind it) may be seen in every tile
#: (the value the capsule and band kernels of ``depthguard.kernels.collision`` use).
NEAR_PLANE = 1e-3

#: (8, 3) the corners of the unit cube [-1, 1]^3, scaled by a box's half extents.
_SIGNS = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))


# ------------------------------------------------------------------------------------------------------ boxes

def _checked_box(box, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(center (3,), half_extents (3,), rotation (3, 3)) of ``box``, checked: a Box of finite numbers, half extents
    >= 0, a rotation (orthonormal, det +1 within ``config.ROTATION_TOLERANCE``); else InputError naming ``name``."""
    if not isinstance(box, Box):
        raise InputError(f"{name} must be a depthguard.scenes.Box, got {type(box).__name__}", field=name)
    center = real_vector(box.center, 3, f"{name}.center", "metres")
    half = real_vector(box.half_extents, 3, f"{name}.half_extents", "metres")
    for field, value in ((f"{name}.center", center), (f"{name}.half_extents", half)):
        if value.shape != (3,) or not np.all(np.isfinite(value)):
            raise InputError(f"{field} must be 3 finite numbers (metres), got shape {value.shape}", field=field)
    if not np.all(half >= 0.0):
        raise InputError(f"{name}.half_extents must be >= 0 metres, got {half.tolist()}", field=f"{name}.half_extents")
    try:
        R = np.array(box.R_world_box, dtype=np.float64)
    except NOT_A_NUMBER:
        R = None
    if R is None or R.shape != (3, 3) or not np.all(np.isfinite(R)) or \
            np.abs(R.T @ R - np.eye(3)).max() > config.ROTATION_TOLERANCE or \
            abs(np.linalg.det(R) - 1.0) > config.ROTATION_TOLERANCE:
        raise InputError(f"{name}.R_world_box must be a (3, 3) rotation (orthonormal, determinant +1), got "
                         f"{np.shape(box.R_world_box)}", field=f"{name}.R_world_box")
    return center, half, R


def box_corners(box, name: str = "box") -> np.ndarray:
    """(8, 3) float64, metres: the corners of ``box``, in its frame (InputError naming ``name`` when it is not a
    well-formed Box)."""
    center, half, R = _checked_box(box, name)
    return center + (_SIGNS * half) @ R.T


def moved_box(box: Box, T_a_b: np.ndarray) -> Box:
    """``box`` given in frame b, expressed in frame a: ``T_a_b`` (4, 4) float64 maps b to a."""
    R = np.asarray(T_a_b)[:3, :3]
    center = R @ np.asarray(box.center, dtype=np.float64) + np.asarray(T_a_b)[:3, 3]
    return Box(tuple(center), tuple(np.asarray(box.half_extents, dtype=np.float64)),
               R @ np.asarray(box.R_world_box, dtype=np.float64))


def grid_bits(grid: TileGrid, corners: np.ndarray) -> np.ndarray:
    """(K, words) uint64: the tiles of ``grid`` that each of the (K, 8, 3) world-frame boxes' corners' hull meets."""
    cam = grid.camera
    T = cam.T_camera_world
    out = np.zeros((corners.shape[0], grid.words), dtype=np.uint64)
    update_kernels.box_tile_bits(np.ascontiguousarray(corners, dtype=np.float64), np.ascontiguousarray(T[:3, :3]),
                                  np.ascontiguousarray(T[:3, 3]), float(cam.fx), float(cam.fy), float(cam.cx),
                                  float(cam.cy), NEAR_PLANE, grid.col_edges, grid.row_edges, grid.words, out)
    return out


def box_tiles(grid: TileGrid, box: Box) -> np.ndarray:
    """The tiles of ``grid``'s camera that ``box`` (world frame, metres) may be seen in: (rows, cols) bool.

    A tile is set when its footprint (its pixels' footprints, :class:`TileGrid`) meets the convex hull of the box's 8
    projected corners, the box's exact projection: a superset of the tiles any pixel of a rendering of the box falls
    in (conservative; tests/test_pick_and_place.py compares it with a ray-cast rendering). A box with a corner within
    1 mm of the camera's plane (``NEAR_PLANE``) or behind it may be seen anywhere: every tile is set. Nothing decides
    what lies in front of the box: these are the tiles where it may show, not where it does.

    Raises InputError naming ``grid`` or ``box`` (its ``center``, ``half_extents`` or ``R_world_box``).
    """
    if not isinstance(grid, TileGrid):
        raise InputError(f"grid must be a TileGrid, got {type(grid).__name__}", field="grid")
    return grid.unpack(grid_bits(grid, box_corners(box, "box")[None])[0])
