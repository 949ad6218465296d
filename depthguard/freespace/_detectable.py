"""Possibly occupied space as speed and separation monitoring may count it: only where a ball of diameter d, the
sensors' detection capability, fits (ISO 13855).

SSM's protective separation distance S_p counts the intrusion distance C = 8 (d - 14) mm: how far a body part thinner
than d may reach, unseen, beyond the detected body it belongs to (design §9). A region of possibly occupied space
in which no ball of diameter d fits can hold only such a part: the band a depth camera's noise margin leaves along a
solid's edge, the sliver behind a pixel dropped at the robot's silhouette. For SSM the distance to the *opening* of
the possibly occupied set U by a ball of radius r = d / 2 is therefore enough:

    E(U) = {c : the ball B(c, r) lies in U}          (the erosion: where a ball of diameter d fits)
    O(U) = the union of the balls B(c, r), c in E(U)  (the opening)
    dist(P, O(U)) = max(dist(P, E(U)) - r, 0)

Every part of a person at least d thick lies in O(U), and a thinner part reaches at most C beyond it, which S_p
counts. The papers' avoidance has no C: its distances must not use this (``DistanceMonitor.query`` does not).

What it gives up, stated: an object thinner than d everywhere that is not part of a body (a sheet, a board seen
edge-on by every camera, a rod) is left out too, as a sensor of detection capability d is not required to see it;
C bounds how far a body part reaches, not a carried tool. What such an object hides from the cameras still counts
(a sheet's shadow is as thick as the sheet is wide).

In voxels. ``free`` marks the voxels of a :class:`~depthguard.freespace.VoxelBox` (side s <= r) certified free
entirely (seen free by some camera, inside the robot's zone, inside a known solid); U is covered by the others and by
everything outside the box (a person may come from outside). A voxel v is kept in E_vox unless some free voxel lies at
an integer offset o from it with |o| s <= r: then every point c of v has a free point within r (along each axis the
farthest two such points are |o_i| s apart), so no ball of radius r round c lies in U. Hence E(U) lies in the union of
E_vox's cubes, and

    reported(P) = max(min(dist(P, E_vox's cubes), dist(P, outside the box)) - r, 0) <= dist(P, O(U))

(the space outside the box counts as E: a ball fits anywhere there). The voxels cost the opening up to about s * (1 +
sqrt 3) of what it removes, never more than it may: a band of possibly occupied space thinner than d - 2 s is always
removed, one thicker than d + 2 s sqrt 3 never.
"""

from __future__ import annotations

import math

import numpy as np
from numba import prange

from depthguard import config
from depthguard._jit import kernel
from depthguard.errors import InputError
from depthguard.validation import check_limit, check_real
from depthguard.freespace._memory import VoxelBox, _check_box

#: Voxels a side of the blocks whose counts let a distance query skip the empty parts of the box.
BLOCK = 8


class DetectableSpace:
    """Where a ball of diameter ``capability`` fits in the possibly occupied space of a voxel box, and how far each
    point is from the nearest such ball: the distances SSM may use (module docstring).

    Args:
        box: the voxels (:class:`~depthguard.freespace.VoxelBox`), side at most ``capability / 2`` (a coarser voxel
            could remove nothing and is refused).
        capability: d, metres, > 0: the smallest object the cameras are taken to detect; SSM's
            ``SSMParams.detection_capability`` (its intrusion distance C must be counted by whoever uses these
            distances).
        beyond: None, or 6 metres >= 0, for the box's faces at lo x, hi x, lo y, hi y, lo z, hi z: how far beyond each
            face space is known to hold no person (the thickness of a known solid that covers the whole face, such
            as the floor under the box's bottom face). The space beyond that counts as possibly occupied, as all
            of the outside does with None (a person may come from outside).

    Call :meth:`update` with the voxels certified free, then :meth:`distances`. Memory: 1 byte a voxel from the first
    update on (the voxels a ball's centre may be in; the free mask is the caller's).
    """

    def __init__(self, box: VoxelBox, capability: float = config.SSM_DETECTION_CAPABILITY, beyond=None):
        self.box = _check_box(box)
        self.capability = check_real(capability, "capability", minimum=0.0, above_minimum=True,
                                     maximum=config.COORDINATE_LIMIT, unit="metres", field="capability")
        self.radius = 0.5 * self.capability
        if box.voxel > self.radius * (1.0 + 1e-9):
            raise InputError(f"the box's voxels ({box.voxel!r} m) must be at most half the detection capability "
                             f"({self.radius!r} m): coarser ones cannot tell a thin region from a thick one",
                             field="capability")
        reach = int(math.floor(self.radius / box.voxel + 1e-9))
        grid = np.arange(-reach, reach + 1)
        offsets = np.stack(np.meshgrid(grid, grid, grid, indexing="ij"), -1).reshape(-1, 3)
        keep = (offsets ** 2).sum(1) * box.voxel ** 2 <= self.radius ** 2 * (1.0 + 1e-9)
        self._offsets = np.ascontiguousarray(offsets[keep & np.any(offsets != 0, axis=1)], dtype=np.int64)
        self.beyond = np.zeros(6)
        if beyond is not None:
            try:
                self.beyond = np.array(beyond, dtype=np.float64).reshape(6)
            except (TypeError, ValueError):
                raise InputError(f"beyond must be 6 numbers of metres, got {beyond!r}", field="beyond") from None
            if not np.all(np.isfinite(self.beyond) & (self.beyond >= 0.0)):
                raise InputError(f"beyond must be 6 finite metres >= 0, got {self.beyond.tolist()}", field="beyond")
        self.beyond.setflags(write=False)
        self._fits = None  # made by the first update (a space never updated holds nothing but its settings)
        self._counts = None
        self._updated = False

    @property
    def fits(self) -> np.ndarray:
        """(nx, ny, nz) bool, read-only: E_vox, the voxels that may hold the centre of a ball of diameter d lying in
        possibly occupied space (all False before the first :meth:`update`)."""
        view = np.zeros(self.box.shape, dtype=np.bool_) if self._fits is None else self._fits.view()
        view.setflags(write=False)
        return view

    def update(self, free: np.ndarray) -> None:
        """Take the voxels certified free now: ``free`` (nx, ny, nz) bool (:func:`seen_free_voxels`, or'ed with
        :func:`robot_voxels`, :func:`solid_voxels` and whatever else is known free). Raises :class:`InputError` for
        anything but a bool array of the box's shape."""
        if not isinstance(free, np.ndarray) or free.dtype != np.bool_ or free.shape != self.box.shape:
            got = f"dtype {free.dtype}, shape {free.shape}" if isinstance(free, np.ndarray) else type(free).__name__
            raise InputError(f"free must be a bool array of the box's shape {self.box.shape}, got {got}", field="free")
        if self._fits is None:
            self._fits = np.empty(self.box.shape, dtype=np.bool_)
            self._counts = np.empty(tuple(-(-n // BLOCK) for n in self.box.shape), dtype=np.int32)
        _erode(np.ascontiguousarray(free), self._offsets, BLOCK, self._fits, self._counts)
        self._updated = True

    def distances(self, points_world, limit: float = math.inf) -> np.ndarray:
        """(n,) float64 metres: for each point ((n, 3), metres, world frame), a lower bound of its distance to every
        ball of diameter d lying in possibly occupied space (module docstring), or ``limit`` where that bound is at
        least ``limit`` (the search stops there). 0 before the first :meth:`update` and for a point outside the
        box."""
        points = np.ascontiguousarray(points_world, dtype=np.float64).reshape(-1, 3)
        if not np.all(np.isfinite(points)):
            raise InputError("points_world must be finite", field="points_world")
        limit = check_limit(limit)
        out = np.zeros(len(points))
        if self._updated and len(points):
            _nearest(self._fits, self._counts, BLOCK, np.asarray(self.box.lo, dtype=np.float64),
                     float(self.box.voxel), self.beyond, points, float(limit) + self.radius, out)
            out = np.minimum(np.maximum(out - self.radius, 0.0), limit)
        return out


def robot_voxels(box: VoxelBox, capsules: np.ndarray, zone: float, out: np.ndarray) -> None:
    """Mark in ``out`` (box.shape bool) the voxels that lie entirely within ``zone`` metres of the capsules
    ((n, 7): p0 (3), p1 (3), radius, metres, world frame): the robot and its zone, no person (as the monitor's
    ``robot_zone`` takes it). A voxel is marked when its centre is within radius + zone - s sqrt(3) / 2 of the
    segment."""
    capsules = np.ascontiguousarray(capsules, dtype=np.float64).reshape(-1, 7)
    _mark_capsules(np.asarray(box.lo, dtype=np.float64), float(box.voxel), capsules, float(zone), out)


def solid_voxels(box: VoxelBox, solids, out: np.ndarray, grow: float = 0.0) -> None:
    """Mark in ``out`` (box.shape bool) the voxels that lie entirely inside one of ``solids``
    (:class:`depthguard.scenes.Box`, world frame) grown by ``grow`` metres along each of its axes: a voxel is marked
    when its centre is at least s sqrt(3) / 2 inside every face of the grown box."""
    for solid in solids:
        _mark_box(np.asarray(box.lo, dtype=np.float64), float(box.voxel),
                  np.asarray(solid.center, dtype=np.float64), np.asarray(solid.half_extents, dtype=np.float64) + grow,
                  np.ascontiguousarray(solid.R_world_box, dtype=np.float64), out)


def closed_faces(box: VoxelBox, solids) -> np.ndarray:
    """(6,) metres: for each face of ``box`` (lo x, hi x, lo y, hi y, lo z, hi z), how far beyond it the solids
    (:class:`depthguard.scenes.Box`; those not aligned with the world's axes are left out) reach while covering the
    whole face: the ``beyond`` of :class:`DetectableSpace` (0 where none covers it)."""
    out = np.zeros(6)
    for solid in solids:
        if not np.allclose(np.asarray(solid.R_world_box, dtype=np.float64), np.eye(3), rtol=0.0, atol=1e-12):
            continue
        low = np.asarray(solid.center, dtype=np.float64) - np.asarray(solid.half_extents, dtype=np.float64)
        high = np.asarray(solid.center, dtype=np.float64) + np.asarray(solid.half_extents, dtype=np.float64)
        for axis in range(3):
            others = [a for a in range(3) if a != axis]
            if not all(low[a] <= box.lo[a] and high[a] >= box.hi[a] for a in others):
                continue
            if low[axis] <= box.lo[axis] <= high[axis]:
                out[2 * axis] = max(out[2 * axis], box.lo[axis] - low[axis])
            if low[axis] <= box.hi[axis] <= high[axis]:
                out[2 * axis + 1] = max(out[2 * axis + 1], high[axis] - box.hi[axis])
    return out


# -------------------------------------------------------------------------------------------------------- kernels


@kernel(parallel=True)
def _erode(free, offsets, block, fits, counts):
    """fits[v] = v is not free and no voxel at one of ``offsets`` ((k, 3) int64) from v is free (beyond the array:
    not free); counts[block] = how many True voxels of ``fits`` it holds (blocks of ``block`` voxels a side)."""
    nx, ny, nz = free.shape
    bx, by, bz = counts.shape
    for p in prange(bx * by * bz):
        c0 = p % bz
        b0 = (p // bz) % by
        a0 = p // (bz * by)
        n = 0
        for i in range(a0 * block, min((a0 + 1) * block, nx)):
            for j in range(b0 * block, min((b0 + 1) * block, ny)):
                for k in range(c0 * block, min((c0 + 1) * block, nz)):
                    keep = not free[i, j, k]
                    if keep:
                        for o in range(offsets.shape[0]):
                            a = i + offsets[o, 0]
                            b = j + offsets[o, 1]
                            c = k + offsets[o, 2]
                            if 0 <= a < nx and 0 <= b < ny and 0 <= c < nz and free[a, b, c]:
                                keep = False
                                break
                    fits[i, j, k] = keep
                    if keep:
                        n += 1
        counts[a0, b0, c0] = n


@kernel(parallel=True)
def or_coarse(free, coarse, ratio):
    """free[i, j, k] |= coarse[i // ratio, j // ratio, k // ratio] (a coarser box of voxels ``ratio`` times as big
    with the same near corner)."""
    nx, ny, nz = free.shape
    for i in prange(nx):
        for j in range(ny):
            for k in range(nz):
                if coarse[i // ratio, j // ratio, k // ratio]:
                    free[i, j, k] = True


@kernel(inline=True)
def _to_interval(x, lo, hi):
    return max(lo - x, 0.0, x - hi)


@kernel(parallel=True)
def _nearest(fits, counts, block, lo, voxel, beyond, points, limit, out):
    """out[p] = min(distance from points[p] to the nearest True voxel's cube, to the outside of the box (beyond[f]
    metres past face f), limit); 0 for a point outside the box."""
    nx, ny, nz = fits.shape
    bx, by, bz = counts.shape
    side = block * voxel
    for p in prange(points.shape[0]):
        x = points[p, 0] - lo[0]
        y = points[p, 1] - lo[1]
        z = points[p, 2] - lo[2]
        if min(x, nx * voxel - x, y, ny * voxel - y, z, nz * voxel - z) <= 0.0:
            out[p] = 0.0
            continue
        best = min(x + beyond[0], nx * voxel - x + beyond[1], y + beyond[2], ny * voxel - y + beyond[3],
                   z + beyond[4], nz * voxel - z + beyond[5], limit)
        near = np.empty(bx * by * bz)
        index = np.empty(bx * by * bz, dtype=np.int64)
        m = 0
        for a in range(bx):
            dx = _to_interval(x, a * side, (a + 1) * side)
            if dx >= best:
                continue
            for b in range(by):
                dy = _to_interval(y, b * side, (b + 1) * side)
                if dx * dx + dy * dy >= best * best:
                    continue
                for c in range(bz):
                    if counts[a, b, c] == 0:
                        continue
                    dz = _to_interval(z, c * side, (c + 1) * side)
                    d = math.sqrt(dx * dx + dy * dy + dz * dz)
                    if d < best:
                        near[m] = d
                        index[m] = (a * by + b) * bz + c
                        m += 1
        order = np.argsort(near[:m])
        for n in range(m):
            if near[order[n]] >= best:
                break
            flat = index[order[n]]
            c = flat % bz
            b = (flat // bz) % by
            a = flat // (bz * by)
            for i in range(a * block, min((a + 1) * block, nx)):
                dx = _to_interval(x, i * voxel, (i + 1) * voxel)
                if dx >= best:
                    continue
                for j in range(b * block, min((b + 1) * block, ny)):
                    dy = _to_interval(y, j * voxel, (j + 1) * voxel)
                    if dx * dx + dy * dy >= best * best:
                        continue
                    for k in range(c * block, min((c + 1) * block, nz)):
                        if fits[i, j, k]:
                            dz = _to_interval(z, k * voxel, (k + 1) * voxel)
                            d = math.sqrt(dx * dx + dy * dy + dz * dz)
                            if d < best:
                                best = d
        out[p] = best


@kernel()
def _mark_capsules(lo, voxel, capsules, zone, out):
    """out[v] = True for the voxels whose centre lies within radius + zone - voxel sqrt(3) / 2 of a capsule's
    segment (capsules (n, 7): p0, p1, radius)."""
    nx, ny, nz = out.shape
    half_diagonal = 0.5 * math.sqrt(3.0) * voxel
    for n in range(capsules.shape[0]):
        p0 = capsules[n, 0:3]
        p1 = capsules[n, 3:6]
        reach = capsules[n, 6] + zone - half_diagonal
        if not reach > 0.0:
            continue
        d = np.empty(3)
        for a in range(3):
            d[a] = p1[a] - p0[a]
        length2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
        i0 = max(int(math.floor((min(p0[0], p1[0]) - reach - lo[0]) / voxel)), 0)
        i1 = min(int(math.ceil((max(p0[0], p1[0]) + reach - lo[0]) / voxel)), nx - 1)
        j0 = max(int(math.floor((min(p0[1], p1[1]) - reach - lo[1]) / voxel)), 0)
        j1 = min(int(math.ceil((max(p0[1], p1[1]) + reach - lo[1]) / voxel)), ny - 1)
        k0 = max(int(math.floor((min(p0[2], p1[2]) - reach - lo[2]) / voxel)), 0)
        k1 = min(int(math.ceil((max(p0[2], p1[2]) + reach - lo[2]) / voxel)), nz - 1)
        for i in range(i0, i1 + 1):
            cx = lo[0] + (i + 0.5) * voxel - p0[0]
            for j in range(j0, j1 + 1):
                cy = lo[1] + (j + 0.5) * voxel - p0[1]
                for k in range(k0, k1 + 1):
                    cz = lo[2] + (k + 0.5) * voxel - p0[2]
                    t = 0.0
                    if length2 > 0.0:
                        t = min(max((cx * d[0] + cy * d[1] + cz * d[2]) / length2, 0.0), 1.0)
                    ex = cx - t * d[0]
                    ey = cy - t * d[1]
                    ez = cz - t * d[2]
                    if ex * ex + ey * ey + ez * ez <= reach * reach:
                        out[i, j, k] = True


@kernel(parallel=True)
def _mark_box(lo, voxel, center, half, R, out):
    """out[v] = True for the voxels whose centre lies at least voxel sqrt(3) / 2 inside every face of the box
    (centre, half extents, R_world_box)."""
    nx, ny, nz = out.shape
    inner = np.empty(3)
    for a in range(3):
        inner[a] = half[a] - 0.5 * math.sqrt(3.0) * voxel
    if inner[0] <= 0.0 or inner[1] <= 0.0 or inner[2] <= 0.0:
        return
    for i in prange(nx):
        x = lo[0] + (i + 0.5) * voxel - center[0]
        for j in range(ny):
            y = lo[1] + (j + 0.5) * voxel - center[1]
            for k in range(nz):
                z = lo[2] + (k + 0.5) * voxel - center[2]
                inside = True
                for a in range(3):
                    if abs(R[0, a] * x + R[1, a] * y + R[2, a] * z) > inner[a]:
                        inside = False
                        break
                if inside:
                    out[i, j, k] = True
