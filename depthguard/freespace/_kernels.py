"""Numba kernels of the time-bounded free space (SPEC section 8a). They trust their inputs; ``_memory.py`` checks them.

Two jobs:

- Which voxels of a box some camera sees entirely free now (:func:`seen_free_voxels`), by the depth grid's
  confirmation rule (SPEC section 8): all 8 corners of the voxel in front of the camera, every pixel whose footprint
  meets the corners' projected bounding box (grown by ``pad`` pixels) inside the image, and each of them free at
  least up to the voxel's largest corner depth plus ``margin``. A per-row sparse table of each free image (the
  minimum over every run of 2^l pixels of a row) answers "the smallest free value of row r between columns a and b"
  with two reads, so a voxel costs a few operations per row of its footprint.
- The exact squared Euclidean distance transform of Felzenszwalb and Huttenlocher ("Distance transforms of sampled
  functions", Theory of Computing 8, 2012): one pass per axis, the last axis by two sweeps, the others by the lower
  envelope of parabolas. The box is padded by one layer of "possibly occupied" voxels on every side (a person may
  come from outside), which each 1-D transform sees as two sites of value 0 at positions -1 and n. Squared distances
  are in voxel units (whole numbers; ``int32`` keeps up to 2^31 - 1, far above 3 * (config.FREESPACE_MAX_SIDE + 1)^2).
"""

import numpy as np
from numba import prange

from depthguard._jit import kernel

# ------------------------------------------------------------------------------------------------- seen free voxels


@kernel(parallel=True)
def row_min_tables(free, levels, table):
    """table[l, q, r] = the smallest free[r, q : q + 2^l], for l < levels and q + 2^l <= w (the rest is not
    written): a sparse table of each row, stored column-major so that the rows of one footprint lie side by side.
    free: (h, w) float32; table: (>= levels, >= w, >= h) float32."""
    h, w = free.shape
    for p in prange(w):
        q = np.int64(p)
        for r in range(h):
            table[0, q, r] = free[r, q]
    for level in range(1, levels):
        half = np.int64(1) << (level - 1)
        for p in prange(w - 2 * half + 1):
            q = np.int64(p)
            for r in range(h):
                table[level, q, r] = min(table[level - 1, q, r], table[level - 1, q + half, r])


@kernel(inline=True)
def row_min(table, floor_log2, r, a, b):
    """The smallest value of row r between columns a and b (inclusive, a <= b) of the image ``table`` holds."""
    level = floor_log2[b - a + 1]
    return min(table[level, a, r], table[level, b - (np.int64(1) << level) + 1, r])


@kernel(inline=True)
def project_plane(lo, voxel, i, pose, intrinsics, plane):
    """plane[j, k] = (u, v, z): the lattice point lo + (i, j, k) * voxel (world, metres) in one camera, its image
    coordinates (pixels; garbage where z <= 0) and optical depth (metres), for j <= ny, k <= nz.

    pose: (12,) the world -> optical rotation row by row, then the translation. intrinsics: (4,) fx, fy, cx, cy.
    Each point is placed, transformed and projected as written, in this order, as ``seen_free_voxels``' docstring
    says (the tests' judge does the same arithmetic). Neighbouring voxels share corners: each is projected once."""
    fx = intrinsics[0]
    fy = intrinsics[1]
    cx = intrinsics[2]
    cy = intrinsics[3]
    x = lo[0] + i * voxel
    for j in range(plane.shape[0]):
        y = lo[1] + j * voxel
        for k in range(plane.shape[1]):
            z = lo[2] + k * voxel
            pz = pose[6] * x + pose[7] * y + pose[8] * z + pose[11]
            px = pose[0] * x + pose[1] * y + pose[2] * z + pose[9]
            py = pose[3] * x + pose[4] * y + pose[5] * z + pose[10]
            plane[j, k, 0] = fx * px / pz + cx
            plane[j, k, 1] = fy * py / pz + cy
            plane[j, k, 2] = pz


@kernel(inline=True)
def camera_sees_voxel(near, far_side, j, k, z_near, width, height, table, floor_log2, margin, pad):
    """Whether one camera sees voxel (i, j, k) entirely free, from its corners projected in that camera: the planes
    x = i (``near``) and x = i + 1 (``far_side``) of :func:`project_plane`."""
    x_lo = np.inf
    x_hi = -np.inf
    y_lo = np.inf
    y_hi = -np.inf
    far = 0.0
    for corner in range(8):
        plane = far_side if corner & 1 else near
        jj = j + ((corner >> 1) & 1)
        kk = k + ((corner >> 2) & 1)
        pz = plane[jj, kk, 2]
        if not pz >= z_near:  # NaN-safe: a NaN depth is not in front
            return False
        u = plane[jj, kk, 0]
        v = plane[jj, kk, 1]
        x_lo = min(x_lo, u)
        x_hi = max(x_hi, u)
        y_lo = min(y_lo, v)
        y_hi = max(y_hi, v)
        far = max(far, pz)
    # The pixels whose footprints [q - 1/2, q + 1/2] meet [x_lo - pad, x_hi + pad]: q_lo..q_hi; likewise rows. Each
    # bound is compared as a float before it becomes an index (a corner near the camera projects very far; NaN fails).
    q_lo = np.ceil(x_lo - 0.5) - pad
    q_hi = np.floor(x_hi + 0.5) + pad
    r_lo = np.ceil(y_lo - 0.5) - pad
    r_hi = np.floor(y_hi + 0.5) + pad
    if not (q_lo >= 0.0 and r_lo >= 0.0 and q_hi <= width - 1.0 and r_hi <= height - 1.0):
        return False
    need = far + margin
    a = np.int64(q_lo)
    b = np.int64(q_hi)
    for r in range(np.int64(r_lo), np.int64(r_hi) + 1):
        if not row_min(table, floor_log2, r, a, b) >= need:
            return False
    return True


@kernel(parallel=True)
def seen_free_voxels(lo, voxel, poses, intrinsics, z_near, sizes, tables, floor_log2, margin, pad, chunks, out):
    """out[i, j, k] = whether some camera sees voxel (i, j, k) of the box with corner ``lo`` ((3,) metres, world)
    and side ``voxel`` entirely free.

    Per camera c: poses[c] (12,) world -> optical (rotation rows, translation); intrinsics[c] (fx, fy, cx, cy);
    z_near[c] the nearest depth a corner may have (metres); sizes[c] (width, height); tables[c] its free image's
    row-minimum table (:func:`row_min_tables`). floor_log2[n] = floor(log2(n)) for n >= 1. margin: metres;
    pad: pixels (float64, a whole number). out: (nx, ny, nz) bool.

    The slabs i = 0..nx-1 are cut into ``chunks`` runs, one task each; a task walks its slabs in order, projecting
    each plane of lattice points once per camera (the plane x = i + 1 of slab i is the plane x = i of slab i + 1).
    Within a column, the camera that saw the last voxel is asked first (the answer is the same; it comes sooner)."""
    nx, ny, nz = out.shape
    n_cameras = poses.shape[0]
    n_chunks = max(min(chunks, nx), 1)
    for p in prange(n_chunks):
        chunk = np.int64(p)
        first = chunk * nx // n_chunks
        stop = (chunk + 1) * nx // n_chunks
        planes = np.empty((n_cameras, 2, ny + 1, nz + 1, 3))
        for c in range(n_cameras):
            project_plane(lo, voxel, first, poses[c], intrinsics[c], planes[c, first % 2])
        for i in range(first, stop):
            for c in range(n_cameras):
                project_plane(lo, voxel, i + 1, poses[c], intrinsics[c], planes[c, (i + 1) % 2])
            for j in range(ny):
                last = 0
                for k in range(nz):
                    seen = False
                    for m in range(n_cameras):
                        c = (last + m) % n_cameras
                        if camera_sees_voxel(planes[c, i % 2], planes[c, (i + 1) % 2], j, k, z_near[c], sizes[c, 0],
                                             sizes[c, 1], tables[c], floor_log2, margin, pad):
                            seen = True
                            last = c
                            break
                    out[i, j, k] = seen


# ----------------------------------------------------------------------------------------- the distance transform


@kernel(inline=True)
def _sweep_back(d2, i, j, nz):
    """The last axis' second sweep: d2[i, j, k] holds the distance (in voxels) to the nearest site at or before k
    (0 on a site); make it the squared distance to the nearest site either side, position nz counting as one."""
    last = nz
    for k in range(nz - 1, -1, -1):
        d = d2[i, j, k]
        if d == 0:
            last = k
        d = min(d, last - k)
        d2[i, j, k] = d * d


@kernel(parallel=True)
def last_axis_of_mask(mask, d2):
    """Pass 1 for a mask: d2[i, j, k] = squared distance (voxels) along the last axis to the nearest True voxel or
    to the padding (positions -1 and nz). mask: (nx, ny, nz) bool; d2: (nx, ny, nz) int32."""
    nx, ny, nz = mask.shape
    for p in prange(nx * ny):
        ij = np.int64(p)
        i = ij // ny
        j = ij - i * ny
        last = -1
        for k in range(nz):
            if mask[i, j, k]:
                last = k
            d2[i, j, k] = k - last
        _sweep_back(d2, i, j, nz)


@kernel(parallel=True)
def last_axis_of_memory(arrival, seen, robot, use_robot, t, d2):
    """Pass 1 for the memory's update at time t: the sites are U = (arrival <= t) & ~seen & ~robot (robot only when
    use_robot), the voxels where a person may be now. arrival: (nx, ny, nz) float64 seconds; seen, robot: bool
    (robot may be any shape when not use_robot); d2: (nx, ny, nz) int32."""
    nx, ny, nz = arrival.shape
    for p in prange(nx * ny):
        ij = np.int64(p)
        i = ij // ny
        j = ij - i * ny
        last = -1
        for k in range(nz):
            if arrival[i, j, k] <= t and not seen[i, j, k] and not (use_robot and robot[i, j, k]):
                last = k
            d2[i, j, k] = k - last
        _sweep_back(d2, i, j, nz)


@kernel(inline=True)
def _lower_envelope(f, n, v, fv, zn, zd, out):
    """out[q] = min over sites p of (q - p)^2 + f(p), for q in 0..n-1 (Felzenszwalb-Huttenlocher). Sites: p in
    0..n-1 with f(p) = f[p] (whole numbers), and the padding p = -1 and p = n with f = 0. Work space, (n + 2,) int64
    each: v, fv the envelope's parabolas and their values; zn / zd where each starts, as a fraction (zd > 0), so that
    every comparison is exact in integers (|zn * den| stays below 2^63 for sides up to config.FREESPACE_MAX_SIDE)."""
    top = 0
    v[0] = -1
    fv[0] = 0
    zn[0] = -1  # the padding's parabola starts at -inf: it is never popped (top > 0 below)
    zd[0] = 0
    for q in range(n + 1):
        fq = np.int64(0) if q == n else np.int64(f[q])
        while True:  # pop the parabolas the new one hides: where it starts, s = num / den, is at or before theirs
            p = v[top]
            num = (fq + q * q) - (fv[top] + p * p)
            den = 2 * (q - p)
            if top > 0 and num * zd[top] <= zn[top] * den:
                top -= 1
            else:
                break
        top += 1
        v[top] = q
        fv[top] = fq
        zn[top] = num
        zd[top] = den
    last = top
    top = 0
    for q in range(n):
        while top < last and zn[top + 1] < q * zd[top + 1]:
            top += 1
        d = q - v[top]
        out[q] = d * d + fv[top]


@kernel(inline=True)
def _envelope_slab(slab, lines, f, v, fv, zn, zd, out):
    """Transform every line along the first axis of ``slab`` ((m, nz) int32 view) in place, through ``lines`` ((nz,
    m) int64 work space: the slab transposed so each line is contiguous)."""
    m, nz = slab.shape
    for q in range(m):
        for k in range(nz):
            lines[k, q] = slab[q, k]
    for k in range(nz):
        for q in range(m):
            f[q] = lines[k, q]
        _lower_envelope(f, m, v, fv, zn, zd, out)
        for q in range(m):
            lines[k, q] = out[q]
    for q in range(m):
        for k in range(nz):
            slab[q, k] = lines[k, q]


@kernel(parallel=True)
def middle_axis(d2):
    """Pass 2: the lower envelope along the second axis, in place, one (ny, nz) slab per task. d2: int32."""
    nx, ny, nz = d2.shape
    for p in prange(nx):
        i = np.int64(p)
        lines = np.empty((nz, ny), dtype=np.int64)
        f = np.empty(ny, dtype=np.int64)
        out = np.empty(ny, dtype=np.int64)
        v = np.empty(ny + 2, dtype=np.int64)
        fv = np.empty(ny + 2, dtype=np.int64)
        zn = np.empty(ny + 2, dtype=np.int64)
        zd = np.empty(ny + 2, dtype=np.int64)
        _envelope_slab(d2[i], lines, f, v, fv, zn, zd, out)


@kernel(parallel=True)
def first_axis(d2):
    """Pass 3: the lower envelope along the first axis, in place, one (nx, nz) slab per task. d2: int32."""
    nx, ny, nz = d2.shape
    for p in prange(ny):
        j = np.int64(p)
        lines = np.empty((nz, nx), dtype=np.int64)
        f = np.empty(nx, dtype=np.int64)
        out = np.empty(nx, dtype=np.int64)
        v = np.empty(nx + 2, dtype=np.int64)
        fv = np.empty(nx + 2, dtype=np.int64)
        zn = np.empty(nx + 2, dtype=np.int64)
        zd = np.empty(nx + 2, dtype=np.int64)
        _envelope_slab(d2[:, j, :], lines, f, v, fv, zn, zd, out)


@kernel(parallel=True)
def advance_arrival(d2, t, voxel, clearance, v_max, rounding, arrival):
    """arrival = max(arrival, t + max(0, D - clearance) / v_max), D = voxel * sqrt(d2) metres between voxel centres,
    lowered by ``rounding`` * D metres and one unit in the last place of the sum so that float rounding never makes
    it later than the exact value. d2: (nx, ny, nz) int32 squared distances (voxels); arrival: float64 seconds."""
    nx, ny, nz = arrival.shape
    for p in prange(nx):
        i = np.int64(p)
        for j in range(ny):
            for k in range(nz):
                distance = voxel * np.sqrt(np.float64(d2[i, j, k]))
                reach = distance - clearance - rounding * distance
                a = t
                if reach > 0.0:
                    a = np.nextafter(t + reach / v_max, -np.inf)
                arrival[i, j, k] = max(arrival[i, j, k], a)
