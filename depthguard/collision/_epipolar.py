"""Epipolar bands between the tile grids of calibrated cameras (design §10, step 5; Henrich & Gecks section
3.4): for each tile of one camera, the tiles of another that could show what the first sees in that tile within the
workspace's depth range. A tile's "epipolar line" in the paper is this band: the projection of the tile's viewing
frustum, cut to the depths at which it can meet the workspace."""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np

from depthguard import config
from depthguard.cameras import PinholeCamera
from depthguard.kernels import collision as collision_kernels
from depthguard.errors import InputError
from depthguard.validation import NOT_A_NUMBER, short_repr


class TileGrid:
    """A camera's image divided into rows x cols tiles (the difference image's resolution).

    Tile (r, c) covers the pixels whose centres lie in rows [r * tile_h, (r + 1) * tile_h) and columns
    [c * tile_w, (c + 1) * tile_w); tile_w = width / cols and tile_h = height / rows may be fractional (the paper's
    704 x 576 images in 64 x 64 tiles: 11 x 9 pixels). Its index is r * cols + c. Its footprint is its pixels'
    footprints (pixel u covers [u - 0.5, u + 0.5]): columns col_edges[c] to col_edges[c + 1], rows row_edges[r] to
    row_edges[r + 1]."""

    def __init__(self, camera: PinholeCamera, rows: int, cols: int):
        for name, value, side in (("rows", rows, camera.height), ("cols", cols, camera.width)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 1 <= value <= side:
                raise InputError(f"camera {camera.name!r}: {name} must be a whole number of tiles in [1, {side}], "
                                 f"got {value!r}", camera=camera.name, field=name)
        self.camera = camera
        self.rows = int(rows)
        self.cols = int(cols)
        self.tile_w = camera.width / self.cols
        self.tile_h = camera.height / self.rows
        #: (cols + 1,), (rows + 1,) the first pixel of each tile (and the image's size): ceil(c * tile_w).
        self.first_col = np.minimum(np.ceil(np.arange(self.cols + 1) * self.tile_w - 1e-9), camera.width).astype(int)
        self.first_row = np.minimum(np.ceil(np.arange(self.rows + 1) * self.tile_h - 1e-9), camera.height).astype(int)
        self.col_edges = self.first_col - 0.5
        self.row_edges = self.first_row - 0.5

    @property
    def n_tiles(self) -> int:
        return self.rows * self.cols

    @property
    def words(self) -> int:
        """uint64 words of a bitset over the tiles."""
        return (self.n_tiles + 63) // 64

    def corner_rays(self) -> np.ndarray:
        """(n_tiles, 4, 3) the tiles' corner rays in the camera's optical frame (z = 1), metres per metre of depth."""
        cam = self.camera
        r, c = np.divmod(np.arange(self.n_tiles), self.cols)
        u = np.stack([self.col_edges[c], self.col_edges[c + 1]], axis=1)
        v = np.stack([self.row_edges[r], self.row_edges[r + 1]], axis=1)
        rays = np.empty((self.n_tiles, 4, 3))
        for k, (i, j) in enumerate(itertools.product(range(2), range(2))):
            rays[:, k, 0] = (u[:, i] - cam.cx) / cam.fx
            rays[:, k, 1] = (v[:, j] - cam.cy) / cam.fy
            rays[:, k, 2] = 1.0
        return rays

    def tile_of_pixels(self) -> tuple[np.ndarray, np.ndarray]:
        """((height,) tile row of each pixel row, (width,) tile column of each pixel column)."""
        cam = self.camera
        rows = np.searchsorted(self.first_row, np.arange(cam.height), side="right") - 1
        cols = np.searchsorted(self.first_col, np.arange(cam.width), side="right") - 1
        return rows, cols

    def pixels(self, tiles: np.ndarray) -> np.ndarray:
        """(rows, cols) tile image -> (height, width) bool: each pixel takes its tile's value."""
        rows, cols = self.tile_of_pixels()
        return np.asarray(tiles, dtype=bool)[rows[:, None], cols[None, :]]

    def pack(self, mask: np.ndarray) -> np.ndarray:
        """(rows, cols) bool -> (words,) uint64 bitset (tile index order)."""
        flat = np.zeros(self.words * 64, dtype=bool)
        flat[: self.n_tiles] = np.asarray(mask, dtype=bool).reshape(-1)
        return np.packbits(flat, bitorder="little").view("<u8").copy()

    def unpack(self, bits: np.ndarray) -> np.ndarray:
        """(words,) uint64 bitset (at least :attr:`words` words; tile index order) -> (rows, cols) bool."""
        words = np.ascontiguousarray(np.asarray(bits, dtype=np.uint64)[: self.words]).astype("<u8")
        flat = np.unpackbits(words.view(np.uint8), bitorder="little")
        return flat[: self.n_tiles].astype(bool).reshape(self.rows, self.cols)


def _box(workspace) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) corners of a workspace box given as [[x, y, z], [x, y, z]], metres: finite, within
    +-``config.COORDINATE_LIMIT``, low < high."""
    try:
        box = np.array(workspace, dtype=np.float64)
    except NOT_A_NUMBER:
        box = None
    if box is None or box.shape != (2, 3) or not np.all(np.abs(box) <= config.COORDINATE_LIMIT) or \
            not np.all(box[0] < box[1]):
        raise InputError(f"workspace must be [[x, y, z], [x, y, z]] (low and high corners, metres, within "
                         f"+-{config.COORDINATE_LIMIT:g}, low < high), got {short_repr(workspace)}", field="workspace")
    return box[0], box[1]


def workspace_depths(camera: PinholeCamera, workspace) -> tuple[float, float]:
    """The optical depths (metres) at which ``camera`` can see the axis-aligned box ``workspace`` ((2, 3): low and
    high corners, world frame): the range of its 8 corners' depths, at least the camera's nearest valid depth."""
    lo, hi = _box(workspace)
    corners = np.array(list(itertools.product(*zip(lo, hi))))
    z = camera.world_to_camera(corners)[:, 2]
    near = max(float(z.min()), camera.depth_range[0], 1e-3)
    far = float(z.max())
    if not far > near:
        raise InputError(f"camera {camera.name!r} does not look at the workspace (its depths {z.min():.3f} to "
                         f"{z.max():.3f} m)", camera=camera.name, field="workspace")
    return near, far


class EpipolarBands:
    """For every ordered pair of cameras (a, b), each tile of a's grid -> the bitset of b's tiles that may show the
    same point (its frustum between a's workspace depths, projected into b).

    Args:
        grids: one :class:`TileGrid` per camera, in the order the collision test numbers them.
        workspace: (2, 3) world-frame box (metres) within which obstacles and the robot lie; each camera's band is
            cut to the depths at which it sees the box (:func:`workspace_depths`).

    ``bits[(a, b)]`` is (grids[a].n_tiles, grids[b].words) uint64. Bands are conservative: every point of a tile's
    frustum within the depths projects into a set tile (``tests/test_collision.py`` checks it by sampling).
    """

    def __init__(self, grids: Sequence[TileGrid], workspace):
        self.grids = tuple(grids)
        if not self.grids or not all(isinstance(grid, TileGrid) for grid in self.grids):
            raise InputError("grids must be one or more TileGrid", field="grids")
        _box(workspace)
        self.bits: dict[tuple[int, int], np.ndarray] = {}
        for a, grid_a in enumerate(self.grids):
            near, far = workspace_depths(grid_a.camera, workspace)
            rays = grid_a.corner_rays()
            depths = np.tile([near, far], (grid_a.n_tiles, 1))
            for b, grid_b in enumerate(self.grids):
                if a == b:
                    continue
                cam_b = grid_b.camera
                T = np.linalg.inv(cam_b.T_world_camera) @ grid_a.camera.T_world_camera  # a's optical -> b's
                out = np.empty((grid_a.n_tiles, grid_b.words), dtype=np.uint64)
                collision_kernels.tile_bands(rays, depths, np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]),
                                    cam_b.fx, cam_b.fy, cam_b.cx, cam_b.cy, grid_b.col_edges, grid_b.row_edges,
                                    grid_b.words, out)
                self.bits[(a, b)] = out

    @classmethod
    def from_dense(cls, grids: Sequence[TileGrid], dense: dict) -> "EpipolarBands":
        """Bands given explicitly: dense[(a, b)] is (grids[a].n_tiles, grids[b].n_tiles) bool (for tests and for
        bands computed elsewhere)."""
        bands = cls.__new__(cls)
        bands.grids = tuple(grids)
        bands.bits = {}
        for (a, b), matrix in dense.items():
            matrix = np.asarray(matrix, dtype=bool)
            shape = (bands.grids[a].n_tiles, bands.grids[b].n_tiles)
            if matrix.shape != shape:
                raise InputError(f"band ({a}, {b}) must be {shape}, got {matrix.shape}", field="bands")
            bands.bits[(a, b)] = np.stack([bands.grids[b].pack(row.reshape(bands.grids[b].rows, -1))
                                           for row in matrix]) if len(matrix) else \
                np.zeros((0, bands.grids[b].words), dtype=np.uint64)
        return bands

    def band(self, a: int, b: int, tile: int) -> np.ndarray:
        """(rows_b, cols_b) bool: the tiles of camera b in the band of camera a's tile ``tile``."""
        grid = self.grids[b]
        words = self.bits[(a, b)][tile]
        flat = np.unpackbits(np.ascontiguousarray(words, dtype="<u8").view(np.uint8), bitorder="little").astype(bool)
        return flat[: grid.n_tiles].reshape(grid.rows, grid.cols)
