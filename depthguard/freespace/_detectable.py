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

from depthguard import config
import threading
from dataclasses import dataclass

from depthguard.kernels import detectable as detectable_kernels
from depthguard.kernels.detectable import erode_fits, mark_box_voxels, mark_capsule_voxels, nearest_fit
from depthguard.errors import InputError
from depthguard.validation import NOT_A_NUMBER, check_limit, check_real
from depthguard.buffers import reusable
from depthguard.freespace._memory import CameraViews, VoxelBox, _check_box

#: Voxels a side of the blocks whose counts let a distance query skip the empty parts of the box.
BLOCK = 8


@dataclass(frozen=True)
class FreeSources:
    """What certifies a voxel of a :class:`DetectableSpace`'s box free now, for :meth:`DetectableSpace.watch`: the
    same as the mask :meth:`DetectableSpace.update` takes, decided voxel by voxel where a query needs it.

    - ``views``: the cameras that see now (:class:`~depthguard.freespace.CameraViews`): a voxel some camera sees
      entirely free (:func:`seen_free_voxels`'s rule); None for none.
    - ``static``: (nx, ny, nz) bool, the voxels inside a known solid (:func:`solid_voxels`), or None.
    - ``remembered``: (coarse, ratio): the memory's voxels certified free now ((mx, my, mz) bool, each ``ratio``
      of the box's voxels a side, the same near corner), or None.
    - ``robot``: (capsules, zone): (s, n, 7) float64 capsules (p0, p1, radius, metres, world) at each of s joint
      sets, and the zone in metres: a voxel that :func:`robot_voxels` marks at every one of them; or None.
    """

    views: CameraViews | None = None
    static: np.ndarray | None = None
    remembered: tuple | None = None
    robot: tuple | None = None

    def mask(self, box: VoxelBox) -> np.ndarray:
        """(nx, ny, nz) bool: every voxel of ``box`` these sources certify free, computed for the whole box by the
        whole-box kernels (what :meth:`DetectableSpace.update` takes; the tests' twin of a watched space)."""
        from depthguard.kernels import freespace as freespace_kernels

        free = np.zeros(box.shape, dtype=bool)
        if self.views is not None and self.views.count:
            freespace_kernels.seen_free_voxels(box.lo, box.voxel, *self.views.kernel_arguments(),
                                               config.FREESPACE_BLOCK, free)
        if self.static is not None:
            free |= self.static
        if self.remembered is not None:
            detectable_kernels.or_coarse(free, self.remembered[0], int(self.remembered[1]))
        if self.robot is not None:
            capsules, zone = self.robot
            if len(capsules):
                free |= robot_voxels_at_every(box, capsules, zone)
        return free


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

    Or call :meth:`watch` with what certifies a voxel free (:class:`FreeSources`): the voxels are then decided
    block by block (``config.FREESPACE_BLOCK`` voxels a side), only in the blocks a query reaches, by the same
    predicates in the same arithmetic, so every answer is the one :meth:`update` with the whole mask gives
    (``tests/test_detectable_space.py`` holds them equal). A query then costs what the blocks nearer than its answer
    cost, once per set of frames: the first query of a set pays for them, later ones reuse them. The per-block
    state is guarded by a lock (two threads may query one space).
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
            except NOT_A_NUMBER:
                raise InputError(f"beyond must be 6 numbers of metres, got {beyond!r}", field="beyond") from None
            if not np.all(np.isfinite(self.beyond) & (self.beyond >= 0.0)):
                raise InputError(f"beyond must be 6 finite metres >= 0, got {self.beyond.tolist()}", field="beyond")
        self.beyond.setflags(write=False)
        self._fits = None  # made by the first update (a space never updated holds nothing but its settings)
        self._counts = None
        self._updated = False
        self._watched = None  # (sources, free_b, fits_b, state) once watch() is called
        self._lock = threading.Lock()

    @property
    def fits(self) -> np.ndarray:
        """(nx, ny, nz) bool, read-only: E_vox, the voxels that may hold the centre of a ball of diameter d lying in
        possibly occupied space (all False before the first :meth:`update`)."""
        if self._watched is not None:
            with self._lock:
                _, free_b, fits_b, state = self._watched
                self._fill(np.arange(state.size, dtype=np.int64))
                b = fits_b.shape[3]
                whole = fits_b.transpose(0, 3, 1, 4, 2, 5).reshape(state.shape[0] * b, state.shape[1] * b,
                                                                   state.shape[2] * b)
                view = np.ascontiguousarray(whole[:self.box.shape[0], :self.box.shape[1], :self.box.shape[2]])
        else:
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
        erode_fits(np.ascontiguousarray(free), self._offsets, BLOCK, self._fits, self._counts)
        self._updated = True
        self._watched = None

    def watch(self, sources: FreeSources) -> None:
        """Take what certifies a voxel free now (:class:`FreeSources`, unchecked: the monitor builds it) instead of a
        whole mask: the blocks are decided when a query reaches them. Costs nothing until then but the block
        arrays' address space (2 bytes a voxel, touched block by block)."""
        block = config.FREESPACE_BLOCK
        blocks = tuple(-(-n // block) for n in self.box.shape)
        free_b = reusable(blocks + (block,) * 3, np.bool_, self)  # written block by block before it is read
        fits_b = reusable(blocks + (block,) * 3, np.bool_, self)
        state = np.zeros(blocks, dtype=np.uint8)
        self._counts = np.zeros(blocks, dtype=np.int32)
        self._watched = (sources, free_b, fits_b, state)
        self._updated = True
        self._fits = None

    def _fill(self, blocks: np.ndarray) -> None:
        """Decide E_vox in ``blocks`` ((m,) int64 flat block indices, each once) of a watched space: first the free
        voxels of them and their neighbours, then their fits. The caller holds the lock."""
        sources, free_b, fits_b, state = self._watched
        mark = np.zeros(state.size, dtype=np.uint8)
        to_free = detectable_kernels.blocks_to_free(blocks, state, mark)
        if len(to_free):
            views = sources.views
            cameras = views.kernel_arguments() if views is not None and views.count else _NO_CAMERAS
            static = sources.static if sources.static is not None else _NO_MASK
            coarse, ratio = sources.remembered if sources.remembered is not None else (_NO_MASK, 1)
            capsules, zone = sources.robot if sources.robot is not None else (_NO_CAPSULES, 0.0)
            detectable_kernels.fill_free_blocks(to_free, np.asarray(self.box.lo, dtype=np.float64),
                                                float(self.box.voxel), *cameras, static, coarse, int(ratio),
                                                capsules, float(zone), self._shape, free_b, state)
        detectable_kernels.fill_fit_blocks(blocks, self._offsets, self._shape, free_b, state, fits_b, self._counts)

    @property
    def _shape(self) -> np.ndarray:
        return np.asarray(self.box.shape, dtype=np.int64)

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
        if self._watched is not None and len(points):
            with self._lock:
                out = self._search(points, float(limit) + self.radius)
            out = np.minimum(np.maximum(out - self.radius, 0.0), limit)
        elif self._updated and len(points):
            nearest_fit(self._fits, self._counts, BLOCK, np.asarray(self.box.lo, dtype=np.float64),
                        float(self.box.voxel), self.beyond, points, float(limit) + self.radius, out)
            out = np.minimum(np.maximum(out - self.radius, 0.0), limit)
        return out


    def _search(self, points: np.ndarray, limit: float) -> np.ndarray:
        """:func:`nearest_fit`'s answer over a watched space: rounds of the ring search (the kernels'
        ``search_fits``), each followed by deciding the blocks the stalled points need. The caller holds the lock."""
        _, _, fits_b, state = self._watched
        voxel = float(self.box.voxel)
        lo = np.asarray(self.box.lo, dtype=np.float64)
        best = np.empty(len(points))
        pending = np.empty(len(points), dtype=np.bool_)
        detectable_kernels.search_start(points, lo, voxel, self._shape, self.beyond, limit, best, pending)
        ring = np.zeros(len(points), dtype=np.int64)
        need = np.empty((len(points), _NEED), dtype=np.int64)
        need_count = np.zeros(len(points), dtype=np.int64)
        rounds = 0
        while pending.any():
            # rings asked for beyond a stalled one: none for the first rounds (most answers lie a ring or two away;
            # each ring asked for too many costs blocks), then 1, 3, 7, ... (an answer far away costs few rounds)
            lookahead = (1 << max(rounds - 3, 0)) - 1
            detectable_kernels.search_fits(fits_b, self._counts, state, self._shape, lo, voxel, points, pending, ring,
                                           best, lookahead, need, need_count)
            rounds += 1
            if not pending.any():
                break
            blocks = np.unique(np.concatenate([need[p, :need_count[p]] for p in np.flatnonzero(need_count)]))
            self._fill(blocks)
        return best


#: Blocks a stalled point asks for at most in one round of a watched search.
_NEED = 512
_NO_CAMERAS = (np.zeros((0, 12)), np.zeros((0, 4)), np.zeros(0), np.zeros((0, 2), dtype=np.int64),
               np.zeros((0, 1, 1, 1), dtype=np.float32), np.zeros(2, dtype=np.int64), 0.0, 0.0)
_NO_MASK = np.zeros((0, 0, 0), dtype=np.bool_)
_NO_CAPSULES = np.zeros((0, 0, 7))


def robot_voxels(box: VoxelBox, capsules: np.ndarray, zone: float, out: np.ndarray) -> tuple[slice, slice, slice]:
    """Mark in ``out`` (box.shape bool) the voxels that lie entirely within ``zone`` metres of the capsules
    ((n, 7): p0 (3), p1 (3), radius, metres, world frame): the robot and its zone, no person (as the monitor's
    ``robot_zone`` takes it). A voxel is marked when its centre is within radius + zone - s sqrt(3) / 2 of the
    segment. Returns (i, j, k) slices of the box outside which nothing was marked: the capsules' bounding boxes
    grown by their reach and a voxel (the whole box where a capsule is not finite; empty slices when none reaches a
    voxel's centre), so that a caller may look for the marks there only."""
    capsules = np.ascontiguousarray(capsules, dtype=np.float64).reshape(-1, 7)
    mark_capsule_voxels(np.asarray(box.lo, dtype=np.float64), float(box.voxel), capsules, float(zone), out)
    return _capsule_region(box, capsules, float(zone))


def _capsule_region(box: VoxelBox, capsules: np.ndarray, zone: float) -> tuple[slice, slice, slice]:
    """The slices :func:`robot_voxels` returns: for the capsules whose reach (radius + zone - s sqrt(3) / 2, the
    kernel's) is positive, the voxels from floor((min corner - reach - lo) / s) - 1 to ceil((max corner + reach -
    lo) / s) + 1 (one voxel wider than the kernel's loops each way, against rounding), cut at the box."""
    if not (np.all(np.isfinite(capsules)) and math.isfinite(zone)):
        return tuple(slice(0, n) for n in box.shape)
    reach = capsules[:, 6] + zone - 0.5 * math.sqrt(3.0) * box.voxel
    reaching = capsules[reach > 0.0]
    if not len(reaching):
        return (slice(0, 0),) * 3
    r = reach[reach > 0.0][:, None]
    shape = np.asarray(box.shape)
    lo = np.asarray(box.lo, dtype=np.float64)
    low = (np.minimum(reaching[:, 0:3], reaching[:, 3:6]) - r - lo) / box.voxel
    high = (np.maximum(reaching[:, 0:3], reaching[:, 3:6]) + r - lo) / box.voxel
    start = np.clip(np.floor(low.min(axis=0)) - 1, 0, shape).astype(np.int64)
    stop = np.clip(np.ceil(high.max(axis=0)) + 2, 0, shape).astype(np.int64)
    return tuple(slice(int(a), int(max(a, b))) for a, b in zip(start, stop))


def robot_voxels_at_every(box: VoxelBox, poses, zone: float) -> np.ndarray:
    """(nx, ny, nz) bool: the voxels that :func:`robot_voxels` marks for every one of ``poses`` (each an (n, 7)
    capsule array, world frame, metres) with ``zone`` metres: the space the robot holds at all of those moments. All
    False for no pose."""
    out = None
    for capsules in poses:
        marked = np.zeros(box.shape, dtype=bool)
        robot_voxels(box, capsules, zone, marked)
        out = marked if out is None else out & marked
    return np.zeros(box.shape, dtype=bool) if out is None else out


def robot_inside_voxels(box: VoxelBox, inner) -> np.ndarray:
    """(nx, ny, nz) bool: the voxels of ``box`` that lie wholly inside the robot at each of several moments: for each
    (k, 7) array of ``inner`` (capsules inside the links, world frame, metres: p0, p1, radius;
    :meth:`depthguard.robots.RobotModel.inner_capsules_world`), the voxels wholly within one of its capsules, and of
    those the voxels marked at every moment. All False for no moment."""
    return robot_voxels_at_every(box, inner, 0.0)


def solid_voxels(box: VoxelBox, solids, out: np.ndarray, grow: float = 0.0) -> None:
    """Mark in ``out`` (box.shape bool) the voxels that lie entirely inside one of ``solids``
    (:class:`depthguard.scenes.Box`, world frame) grown by ``grow`` metres along each of its axes: a voxel is marked
    when its centre is at least s sqrt(3) / 2 inside every face of the grown box."""
    for solid in solids:
        mark_box_voxels(np.asarray(box.lo, dtype=np.float64), float(box.voxel),
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
