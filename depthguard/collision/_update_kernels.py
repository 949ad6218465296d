"""Numba kernel of the reference image update (SPEC section 10, step 8; Henrich & Gecks section 4.1): the tiles of one
camera that boxes (work pieces) may be seen in. It trusts its inputs; ``_update.py`` checks them."""

import numpy as np

from depthguard._jit import kernel
from depthguard.collision._kernels import mark_every_tile, mark_hull_tiles


@kernel()
def box_tile_bits(corners, R, t, fx, fy, cx, cy, near, col_edges, row_edges, words, out):
    """For each of K boxes, the tiles of one camera whose footprint meets the convex hull of the box's 8 projected
    corners, as bits in out (K, words) uint64 (written; tile index r * cols + c; tile (r, c) spans col_edges[c] to
    col_edges[c + 1] and row_edges[r] to row_edges[r + 1], pixels, as in ``_kernels.tile_bands``).

    corners: (K, 8, 3) float64, the boxes' corners, world frame, metres; R, t: world -> the camera's optical frame
    (x right, y down, z forward); fx, fy, cx, cy: its intrinsics, pixels. A box is the convex hull of its corners, so
    its projection is the convex hull of theirs (exact, not a bound, while the box lies in front of the camera). A box
    with a corner at optical depth <= ``near`` (metres; within 1 mm of the camera's plane, or behind it) sets every
    tile: it may be seen anywhere."""
    n_boxes = corners.shape[0]
    cols = col_edges.shape[0] - 1
    rows = row_edges.shape[0] - 1
    xs = np.empty(8)
    ys = np.empty(8)
    hull_x = np.empty(16)
    hull_y = np.empty(16)
    for k in range(n_boxes):
        for w in range(words):
            out[k, w] = np.uint64(0)
        behind = False
        for i in range(8):
            px = corners[k, i, 0]
            py = corners[k, i, 1]
            pz = corners[k, i, 2]
            x = R[0, 0] * px + R[0, 1] * py + R[0, 2] * pz + t[0]
            y = R[1, 0] * px + R[1, 1] * py + R[1, 2] * pz + t[1]
            z = R[2, 0] * px + R[2, 1] * py + R[2, 2] * pz + t[2]
            if not z > near:
                behind = True
                break
            xs[i] = fx * x / z + cx
            ys[i] = fy * y / z + cy
        if behind:
            mark_every_tile(rows * cols, out, k)
        else:
            mark_hull_tiles(xs, ys, hull_x, hull_y, col_edges, row_edges, out, k)
