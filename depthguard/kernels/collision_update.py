"""Numba kernel of the reference image update (design §10, step 8; Henrich & Gecks section 4.1): the tiles of one
camera that boxes (work pieces) may be seen in. It trusts its inputs; ``depthguard/collision/_update.py`` checks
them."""

import numpy as np

from depthguard.kernels.jit import kernel
from depthguard.kernels.collision import clear_bits, hull_work, mark_projected_points


@kernel()
def box_tile_bits(corners, R, t, fx, fy, cx, cy, near, col_edges, row_edges, words, out):
    """For each of K boxes, the tiles of one camera whose footprint meets the convex hull of the box's 8 projected
    corners, as bits in out (K, words) uint64 (written; tile index r * cols + c; tile (r, c) spans col_edges[c] to
    col_edges[c + 1] and row_edges[r] to row_edges[r + 1], pixels, as in ``collision.tile_bands``).

    corners: (K, 8, 3) float64, the boxes' corners, world frame, metres; R (3, 3) float64, t (3,) float64 metres:
    world -> the camera's optical frame (x right, y down, z forward); fx, fy, cx, cy: float, its intrinsics, pixels;
    col_edges (cols + 1,), row_edges (rows + 1,): float64, pixels, its tile grid's edges (each tile's first pixel
    minus 1/2, the last entry the image's width or height minus 1/2; :class:`depthguard.collision.TileGrid`); words:
    int, the uint64 words of one bitset, (rows * cols + 63) // 64. A box is the convex hull of its corners, so its
    projection is the convex hull of theirs (exact, not a bound, while the box lies in front of the camera). A box
    with a corner at optical depth <= ``near`` (float, metres; the caller passes 1 mm: within 1 mm of the camera's
    plane, or behind it) sets every tile: it may be seen anywhere."""
    xs, ys, hull_x, hull_y = hull_work()
    for k in range(corners.shape[0]):
        clear_bits(out, k, words)
        mark_projected_points(corners[k], R, t, fx, fy, cx, cy, near, col_edges, row_edges, out, k, xs, ys, hull_x,
                              hull_y)
