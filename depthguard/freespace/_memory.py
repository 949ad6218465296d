"""The free-space memory of design §8a: a voxel box, which voxels the cameras see entirely free now, and for
each voxel the earliest time a person could be in it.

design §8a's recursion F_k = erode(F_{k-1}, v_max (t_k - t_{k-1})) u Seen_k u Robot_k is kept in its complement: U_k,
where a person may be at t_k, is dilate(U_{k-1}, v_max (t_k - t_{k-1})) minus (Seen_k u Robot_k), starting from
U_0 = everything (never seen = possibly occupied), and space outside the box always counts as U (a person may come
from outside). It is stored as an arrival time per voxel, a lower bound of the earliest time a person could be
anywhere in it: a voxel is certified free at time t when its arrival time is later than t.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from depthguard import config
from depthguard.cameras import PinholeCamera
from depthguard.errors import InputError
from depthguard.validation import NOT_A_NUMBER, check_real, short_repr
from depthguard.kernels import freespace as freespace_kernels
from depthguard.buffers import reusable



class VoxelBox:
    """A world-aligned box cut into cubes of side ``voxel``.

    Voxel (i, j, k) spans [lo + (i, j, k) * voxel, lo + (i + 1, j + 1, k + 1) * voxel] (metres, world frame). The box
    asked for is grown to whole voxels along each axis: ``shape`` = ceil((hi - lo) / voxel) (a side within
    ``config.FREESPACE_FIT_TOLERANCE`` voxels of a whole number is not grown by a sliver), and ``hi`` is the grown
    box's far corner.

    Args:
        lo, hi: (3,) metres, world frame: the box's near and far corners, finite, within
            ``config.COORDINATE_LIMIT`` of the origin, hi > lo on every axis.
        voxel: the cubes' side, metres, > 0.

    Raises :class:`InputError` naming the field (``lo``, ``hi``, ``voxel``) for anything else, and for a box of
    more than ``config.FREESPACE_MAX_VOXELS`` voxels or more than ``config.FREESPACE_MAX_SIDE`` along one axis.
    """

    def __init__(self, lo, hi, voxel: float):
        lo = _corner(lo, "lo")
        hi = _corner(hi, "hi")
        if not np.all(hi > lo):
            raise InputError(f"hi must exceed lo on every axis, got lo {lo.tolist()}, hi {hi.tolist()}", field="hi")
        voxel = check_real(voxel, "voxel", minimum=0.0, above_minimum=True, unit="metres", field="voxel")
        sides = (hi - lo) / voxel
        if not np.all(sides <= config.FREESPACE_MAX_SIDE + config.FREESPACE_FIT_TOLERANCE):
            raise InputError(f"a box of {(hi - lo).tolist()} m in voxels of {voxel!r} m has more than "
                             f"{config.FREESPACE_MAX_SIDE} voxels along an axis (config.FREESPACE_MAX_SIDE)",
                             field="voxel")
        shape = tuple(max(int(math.ceil(s - config.FREESPACE_FIT_TOLERANCE)), 1) for s in sides)
        size = shape[0] * shape[1] * shape[2]
        if size > config.FREESPACE_MAX_VOXELS:
            raise InputError(f"a box of {(hi - lo).tolist()} m in voxels of {voxel!r} m has {size} voxels, more than "
                             f"{config.FREESPACE_MAX_VOXELS} (config.FREESPACE_MAX_VOXELS)", field="voxel")
        self.lo = lo
        self.voxel = voxel
        self.shape = shape
        self.hi = lo + np.array(shape) * voxel
        self.lo.setflags(write=False)
        self.hi.setflags(write=False)

    @property
    def size(self) -> int:
        """The number of voxels."""
        return self.shape[0] * self.shape[1] * self.shape[2]

    def axis_centres(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The voxel centres' x, y and z: three (n_axis,) float64 arrays, metres, world frame."""
        return tuple(self.lo[a] + (np.arange(self.shape[a]) + 0.5) * self.voxel for a in range(3))

    def __repr__(self) -> str:
        return f"VoxelBox(lo={self.lo.tolist()}, hi={self.hi.tolist()}, voxel={self.voxel!r}, shape={self.shape})"


def _corner(value, name: str) -> np.ndarray:
    try:
        array = np.asarray(value)
    except NOT_A_NUMBER:
        array = None
    if array is None or array.dtype.kind not in "fiu" or array.shape != (3,):
        raise InputError(f"{name} must be 3 real numbers (metres, world frame), got {short_repr(value)}", field=name)
    array = np.array(array, dtype=np.float64)
    if not (np.all(np.isfinite(array)) and np.all(np.abs(array) <= config.COORDINATE_LIMIT)):
        raise InputError(f"{name} must be finite and within +-{config.COORDINATE_LIMIT:g} m "
                         f"(config.COORDINATE_LIMIT), got {array.tolist()}", field=name)
    return array


def _check_box(box) -> VoxelBox:
    if not isinstance(box, VoxelBox):
        raise InputError(f"box must be a VoxelBox, got {type(box).__name__}", field="box")
    return box


# ------------------------------------------------------------------------------------------------- seen free voxels


def seen_free_voxels(box: VoxelBox, cameras: Sequence[PinholeCamera], free_images: Sequence, margin: float = 0.0,
                     pad: int = 0, check: bool = True) -> np.ndarray:
    """Which voxels of ``box`` some camera sees entirely free now: (nx, ny, nz) bool.

    Camera j sees voxel x free when (the depth grid's confirmation rule, design §8):

    - all 8 corners of x lie in front of it: optical z >= max(depth_range[0], ``config.NEAR_PLANE_EPSILON``);
    - the bounding box of the corners' projections, grown by ``pad`` pixels on every side, lies in the image: every
      pixel (u, v) whose footprint [u - 1/2, u + 1/2] x [v - 1/2, v + 1/2] meets it exists;
    - every such pixel saw free at least up to the voxel's far depth plus ``margin``: free[v, u] >= z_far + margin,
      z_far the largest corner depth (no point of the convex voxel lies deeper along any ray).

    A corner (i + a, j + b, k + c) is at lo + (i + a, j + b, k + c) * voxel, its optical coordinates are
    R[r, 0] * x + R[r, 1] * y + R[r, 2] * z + t[r] with (R, t) = ``T_camera_world``, and it projects to
    u = fx * x / z + cx, v = fy * y / z + cy (design §1). Blocks of ``config.FREESPACE_BLOCK`` voxels a side
    are tested whole first: a camera that sees a whole block free sees each of its voxels free (their corners
    project inside the block's projection and lie no deeper than its deepest corner), so this changes how fast,
    not what (up to rounding in the last bits of a projection).

    Cost: per camera, a table of 4 bytes x width x height x (log2(width) + 1) built per call (12 MB for 640x480),
    then a few operations per image row of each box tested.

    Args:
        box: the voxels.
        cameras: the cameras (:class:`~depthguard.PinholeCamera`).
        free_images: for each camera, in the same order, an (h, w) float32 array, metres: how far that camera saw
            free along each pixel (0 = nothing), as :func:`depthguard.depthgrid.free_image` and
            :func:`~depthguard.depthgrid.seen_free` give (their noise margin already subtracted); or None for a
            camera that is blind now (stale or missing frame): it sees nothing free.
        margin: metres a camera must have seen beyond a voxel (calibration error), >= 0.
        pad: pixels by which a voxel's footprint grows (calibration error), a whole number >= 0.
        check: validate the arguments (False skips it, for a hot loop whose inputs are known to be good).

    Raises :class:`InputError` naming the field (``box``, ``cameras``, ``free_images``, ``margin``, ``pad``).
    """
    if check:
        _check_box(box)
        cameras, free_images = _check_views(cameras, free_images)
        margin = check_real(margin, "margin", minimum=0.0, maximum=config.COORDINATE_LIMIT, unit="metres",
                            field="margin")
        if isinstance(pad, bool) or not isinstance(pad, (int, np.integer)) or \
                not 0 <= pad <= config.MAX_FUSION_PIXELS:
            raise InputError(f"pad must be a whole number of pixels in [0, {config.MAX_FUSION_PIXELS}], got "
                             f"{short_repr(pad)}", field="pad")
    return _seen_by(box, CameraViews.of(cameras, free_images, margin, pad))


def _seen_by(box: VoxelBox, views: "CameraViews") -> np.ndarray:
    """(nx, ny, nz) bool: the voxels of ``box`` that one of ``views`` sees entirely free (:func:`seen_free_voxels`)."""
    out = np.zeros(box.shape, dtype=bool)
    if views.count:
        freespace_kernels.seen_free_voxels(box.lo, box.voxel, *views.kernel_arguments(), config.FREESPACE_BLOCK, out)
    return out


class CameraViews:
    """What :func:`seen_free_voxels`' kernels need of the cameras that see now, built once per set of frames: each
    camera's pose (world -> optical, (n, 12) float64, rotation rows then translation in metres), intrinsics ((n, 4)
    fx, fy, cx, cy, pixels), nearest corner depth ((n,) metres), image size ((n, 2) width, height) and the
    row-minimum table of its free image ((n, levels, w, h) float32, metres; 4 bytes x width x height x
    (log2(width) + 1), 12 MB for 640x480), with the margin (metres) and pad (pixels) of the confirmation rule."""

    def __init__(self, poses, intrinsics, z_near, sizes, tables, floor_log2, margin: float, pad: float):
        self.poses, self.intrinsics, self.z_near, self.sizes = poses, intrinsics, z_near, sizes
        self.tables, self.floor_log2, self.margin, self.pad = tables, floor_log2, margin, pad
        self.count = len(poses)

    @classmethod
    def of(cls, cameras: Sequence[PinholeCamera], free_images: Sequence, margin: float = 0.0,
           pad: int = 0) -> "CameraViews":
        """The views of ``cameras`` whose free image (as :func:`seen_free_voxels` takes them, unchecked) is not
        None."""
        seeing = [(camera, free) for camera, free in zip(cameras, free_images) if free is not None]
        n = len(seeing)
        height = max((camera.height for camera, _ in seeing), default=1)
        width = max((camera.width for camera, _ in seeing), default=1)
        levels = width.bit_length()  # runs of 1, 2, 4, ... up to the widest image's width
        floor_log2 = np.zeros(width + 1, dtype=np.int64)  # floor(log2(m)) for m >= 1: frexp's exponent, exactly
        floor_log2[1:] = np.frexp(np.arange(1.0, width + 1.0))[1] - 1
        views = cls(np.empty((n, 12)), np.empty((n, 4)), np.empty(n), np.empty((n, 2), dtype=np.int64), None,
                    floor_log2, float(margin), float(pad))
        views.tables = reusable((n, levels, width, height), np.float32, views)  # given back with the views
        stacked = np.empty((n, height, width), dtype=np.float32)
        for c, (camera, free) in enumerate(seeing):
            T_camera_world = camera.T_camera_world
            views.poses[c, :9] = T_camera_world[:3, :3].ravel()
            views.poses[c, 9:] = T_camera_world[:3, 3]
            views.intrinsics[c] = (camera.fx, camera.fy, camera.cx, camera.cy)
            views.z_near[c] = max(camera.depth_range[0], config.NEAR_PLANE_EPSILON)
            views.sizes[c] = (camera.width, camera.height)
            stacked[c, :camera.height, :camera.width] = free
        if n:
            freespace_kernels.row_min_tables(stacked, views.sizes, views.tables)
        return views

    def kernel_arguments(self) -> tuple:
        """(poses, intrinsics, z_near, sizes, tables, floor_log2, margin, pad), in the kernels' order."""
        return (self.poses, self.intrinsics, self.z_near, self.sizes, self.tables, self.floor_log2, self.margin,
                self.pad)


def _check_views(cameras, free_images) -> tuple[list, list]:
    if isinstance(cameras, (str, bytes)) or not isinstance(cameras, Sequence):
        raise InputError(f"cameras must be a list of PinholeCamera, got {type(cameras).__name__}", field="cameras")
    if isinstance(free_images, (str, bytes, np.ndarray)) or not isinstance(free_images, Sequence):
        raise InputError(f"free_images must be a list with one (h, w) float32 array (or None) per camera, got "
                         f"{type(free_images).__name__}", field="free_images")
    if len(free_images) != len(cameras):
        raise InputError(f"free_images must hold one image per camera: {len(cameras)} cameras, "
                         f"{len(free_images)} images", field="free_images")
    for index, camera in enumerate(cameras):
        if not isinstance(camera, PinholeCamera):
            raise InputError(f"cameras[{index}] must be a PinholeCamera, got {type(camera).__name__}",
                             field="cameras")
    for camera, free in zip(cameras, free_images):
        if free is None:
            continue
        if not isinstance(free, np.ndarray) or free.dtype != np.float32 or free.shape != camera.shape:
            got = f"dtype {free.dtype}, shape {free.shape}" if isinstance(free, np.ndarray) else type(free).__name__
            raise InputError(f"must be a float32 array of the camera's shape {camera.shape} (metres seen free), got "
                             f"{got}", camera=camera.name, field="free_images")
        if np.isnan(free).any():
            raise InputError("holds NaN: a pixel that saw nothing is 0", camera=camera.name, field="free_images")
    return list(cameras), list(free_images)


# ----------------------------------------------------------------------------------------- the distance transform


def squared_distance_transform(sites) -> np.ndarray:
    """(nx, ny, nz) int32: for each voxel, the squared Euclidean distance (in voxels, between voxel centres) to the
    nearest True voxel of ``sites`` ((nx, ny, nz) bool) or to the layer of voxels just outside the array, which
    counts as True (Felzenszwalb and Huttenlocher's exact transform, parallel over lines). It equals
    ``scipy.ndimage.distance_transform_edt(~np.pad(sites, 1, constant_values=True))[1:-1, 1:-1, 1:-1] ** 2``.
    Raises :class:`InputError` for anything but a 3-D bool array with sides of 1 to ``config.FREESPACE_MAX_SIDE``
    and at most ``config.FREESPACE_MAX_VOXELS`` voxels."""
    if not isinstance(sites, np.ndarray) or sites.dtype != np.bool_ or sites.ndim != 3 or min(sites.shape) < 1 or \
            max(sites.shape) > config.FREESPACE_MAX_SIDE or sites.size > config.FREESPACE_MAX_VOXELS:
        got = f"dtype {sites.dtype}, shape {sites.shape}" if isinstance(sites, np.ndarray) else type(sites).__name__
        raise InputError(f"sites must be a 3-D bool array of at most {config.FREESPACE_MAX_VOXELS} voxels, got {got}",
                         field="sites")
    d2 = np.empty(sites.shape, dtype=np.int32)
    freespace_kernels.last_axis_of_mask(np.require(sites, np.bool_, ["C", "W"]), d2)
    freespace_kernels.middle_axis(d2)
    freespace_kernels.first_axis(d2)
    return d2


# ----------------------------------------------------------------------------------------------------- the memory


class FreeSpaceMemory:
    """Remembered free space (design §8a): for each voxel of a box, the earliest time a person could be in it.

    ``arrival[x]`` is a lower bound of the earliest time (seconds, the frames' clock) at which a person moving at
    most ``v_max`` could be anywhere in voxel x, given everything the cameras have seen; voxel x is certified free at
    time t when ``arrival[x] > t``. It starts at -inf: space never seen is possibly occupied. Each :meth:`update` at
    time t_k with the voxels seen entirely free now and those entirely inside the robot makes

        U_k = (arrival <= t_k) & ~seen & ~robot                     (where a person may be now)
        arrival[x] = max(arrival[x], t_k + D(x, U_k) / v_max)

    with D the distance from voxel x's cube to the nearest cube of U_k or to the outside of the box (a person may come
    from outside): the exact box-to-box distance, found as the distance between voxel centres to the nearest voxel of
    U_k grown by one voxel in every direction (along each axis, two cubes |d| voxels apart are max(|d| - 1, 0) apart;
    the exact Euclidean distance transform of that grown set, in integers). So the new term is the true arrival from
    U_k; the old arrival time stays a lower bound too (what is seen later only rules out more), so the larger of the
    two is kept. Keeping it means a frame that adds nothing (a stale camera) leaves the memory as it was. U_k voxels
    and their neighbours get t_k.

    Args:
        box: the voxels (:class:`VoxelBox`).
        v_max: the fastest a person may move, metres/second, finite and > 0 (``config.FREESPACE_V_MAX``). A body part
            moving faster is outside the guarantee.

    Memory: 8 bytes a voxel for ``arrival``, 4 for the distance transform's work space, 2 for the grown set, 1 for
    the last update's seen-free and robot voxels and 1 for those of every update (``nbytes``, ``never_seen``).
    """

    def __init__(self, box: VoxelBox, v_max: float = config.FREESPACE_V_MAX):
        self.box = _check_box(box)
        self.v_max = check_real(v_max, "v_max", minimum=0.0, above_minimum=True, unit="metres/second",
                                field="v_max")
        self._arrival = np.full(box.shape, -np.inf)
        self._d2 = np.empty(box.shape, dtype=np.int32)
        self._grown = np.empty(box.shape, dtype=bool)  # U grown by one voxel (the distance transform's sites)
        self._scratch = np.empty(box.shape, dtype=bool)
        self._now = np.zeros(box.shape, dtype=bool)  # Seen_k | Robot_k of the last update: free at its time
        self._known = np.zeros(box.shape, dtype=bool)  # the union of every update's Seen_k | Robot_k
        self._time: float | None = None
        self._no_robot = np.zeros((1, 1, 1), dtype=bool)

    @property
    def arrival(self) -> np.ndarray:
        """(nx, ny, nz) float64 seconds, read-only view: each voxel's earliest possible arrival of a person."""
        view = self._arrival.view()
        view.setflags(write=False)
        return view

    @property
    def taken_now(self) -> np.ndarray:
        """(nx, ny, nz) bool, read-only view: the voxels the last :meth:`update` took as seen free or inside the robot
        (free at its time whatever the memory held; :meth:`free_at`)."""
        view = self._now.view()
        view.setflags(write=False)
        return view

    @property
    def never_seen(self) -> np.ndarray:
        """(nx, ny, nz) bool: the voxels that no update has taken as seen free or inside the robot since the memory
        was made (what start-up has not shown yet, or no camera ever sees)."""
        return ~self._known

    @property
    def time(self) -> float | None:
        """The time of the last :meth:`update` (seconds), None before the first."""
        return self._time

    @property
    def nbytes(self) -> int:
        """Bytes the memory holds: the arrival times and the distance transform's work space."""
        return (self._arrival.nbytes + self._d2.nbytes + self._grown.nbytes + self._scratch.nbytes + self._now.nbytes
                + self._known.nbytes)

    def update(self, t: float, seen: np.ndarray, robot: np.ndarray | None = None, check: bool = True) -> None:
        """Take in the frames of time ``t``.

        Args:
            t: capture time, seconds, finite, at least the last update's (equal is allowed).
            seen: (nx, ny, nz) bool: the voxels some camera sees entirely free at t (:func:`seen_free_voxels`); all
                False for a frame in which no camera saw anything (the memory then only ages).
            robot: (nx, ny, nz) bool or None: the voxels entirely inside the robot's links at t (no person can be
                there).
            check: validate the arguments (False skips it, for a hot loop whose inputs are known to be good).

        Raises :class:`InputError` naming ``t``, ``seen`` or ``robot``.
        """
        if check:
            t = check_real(t, "t", unit="seconds", field="t")
            if self._time is not None and t < self._time:
                raise InputError(f"t must be at least the last update's time {self._time!r} (frames in time order), "
                                 f"got {t!r}", field="t")
            seen = self._check_mask(seen, "seen")
            if robot is not None:
                robot = self._check_mask(robot, "robot")
        t = float(t)
        use_robot = robot is not None
        seen = np.require(seen, np.bool_, ["C", "W"])  # as in seen_free_voxels: one type for numba
        if use_robot:
            robot = np.require(robot, np.bool_, ["C", "W"])
        freespace_kernels.grown_possibly_occupied(self._arrival, seen, robot if use_robot else self._no_robot,
                                                  use_robot, t, self._grown, self._scratch)
        freespace_kernels.last_axis_of_mask(self._grown, self._d2)
        freespace_kernels.middle_axis(self._d2)
        freespace_kernels.first_axis(self._d2)
        freespace_kernels.advance_arrival(self._d2, t, self.box.voxel, 0.0, self.v_max, config.FREESPACE_ROUNDING,
                                          self._arrival)
        np.logical_or(seen, robot, out=self._now) if use_robot else np.copyto(self._now, seen)
        np.logical_or(self._known, self._now, out=self._known)
        self._time = t

    def forget(self, occupied: np.ndarray) -> None:
        """Take the voxels ``occupied`` ((nx, ny, nz) bool) to hold something now: their arrival times become -inf,
        so the next :meth:`update` counts them where a person may be (unless a camera sees them entirely free then).
        The monitor passes the voxels in which a camera measures a surface: an object seen where the memory
        remembers free space moved faster than v_max, and is at least not cleared where it is seen."""
        occupied = self._check_mask(occupied, "occupied")
        self._arrival[occupied] = -np.inf
        self._now[occupied] = False

    def free_at(self, t: float) -> np.ndarray:
        """(nx, ny, nz) bool: the voxels certified free at time ``t`` (seconds, at least the last update's; no voxel
        before the first update): those no person can have reached (``arrival > t``) and, at exactly the last
        update's time t_k, also those it took as seen free or inside the robot then (F_k contains Seen_k and Robot_k,
        even where a person may be in the voxel next to it: one instant later, no longer). Valid until the next
        update: a later update can only certify more."""
        t = check_real(t, "t", unit="seconds", field="t")
        if self._time is None:
            return np.zeros(self.box.shape, dtype=bool)
        if t < self._time:
            raise InputError(f"t must be at least the last update's time {self._time!r} (the memory does not know "
                             f"the past), got {t!r}", field="t")
        free = self._arrival > t
        if t == self._time:
            free |= self._now
        return free

    def _check_mask(self, mask, name: str) -> np.ndarray:
        if not isinstance(mask, np.ndarray) or mask.dtype != np.bool_ or mask.shape != self.box.shape:
            got = f"dtype {mask.dtype}, shape {mask.shape}" if isinstance(mask, np.ndarray) else type(mask).__name__
            raise InputError(f"{name} must be a bool array of the box's shape {self.box.shape}, got {got}", field=name)
        return mask


def mixed_voxels(box: VoxelBox, views: "CameraViews", candidates: np.ndarray, inner: np.ndarray,
                 levels: int = config.FREESPACE_MIXED_LEVELS) -> np.ndarray:
    """(m,) bool: which of the voxels ``candidates`` ((m, 3) int indices into ``box``) are wholly free now, every
    point of them seen free by some camera or inside the robot (design §8a: the two combine within one voxel), cut
    into pieces of voxel / 2^``levels`` a side: each piece seen entirely free by one camera (the rule of
    :func:`seen_free_voxels`) or wholly inside one of the capsules ``inner`` ((k, 7) p0, p1, radius, metres, world:
    :meth:`~depthguard.robots.RobotModel.inner_capsules_world` at the frames' joints). Sound: a voxel passes only
    when all its pieces do; finer ``levels`` pass more of the voxels that touch the robot, at 8 times the work each."""
    out = np.zeros(len(candidates), dtype=bool)
    if len(candidates):
        freespace_kernels.certify_mixed_voxels(box.lo, box.voxel, np.ascontiguousarray(candidates, dtype=np.int64),
                                               *views.kernel_arguments(),
                                               np.ascontiguousarray(inner, dtype=np.float64).reshape(-1, 7),
                                               int(levels), out)
    return out


def _region(near_region) -> tuple[slice, slice, slice]:
    """``remember_frames``' near_region, checked: three slices of step 1 (a slice beyond the box is cut at it)."""
    if not (isinstance(near_region, tuple) and len(near_region) == 3 and all(
            isinstance(part, slice) and part.step in (None, 1) for part in near_region)):
        raise InputError(f"near_region must be a tuple of three slices of step 1 (i, j, k), got "
                         f"{short_repr(near_region)}", field="near_region")
    return near_region


def remember_frames(memory: "FreeSpaceMemory", t: float, cameras: Sequence[PinholeCamera], free_images: Sequence,
                    surfaces_of: Sequence, margin: float, pad: int, robot: np.ndarray | None = None,
                    near_robot: np.ndarray | None = None, inner: np.ndarray | None = None,
                    near_region: tuple[slice, slice, slice] | None = None) -> np.ndarray:
    """The remember stage (design §8a): take one set of frames, captured no earlier than ``t`` (seconds), into
    ``memory``. ``cameras`` and ``free_images`` as :func:`seen_free_voxels`; ``surfaces_of``: for each camera, a
    function that marks in a (nx, ny, nz) bool array the voxels holding a surface that camera measures now and does
    not give to the robot (:func:`depthguard.freespace.surface_voxels`). A surface measured where the memory
    remembers free space moved faster than v_max: the memory forgets that voxel, and these frames do not clear it. A
    measurement of the robot neither clears nor forgets. ``robot``: (nx, ny, nz) bool or None, the voxels wholly
    inside the robot's links at t (Robot_k: no person is there; :func:`depthguard.freespace.robot_inside_voxels`).
    ``near_robot`` ((nx, ny, nz) bool or None) and ``inner`` ((k, 7) capsules inside the links at t, or None): the
    voxels next to the robot that no one camera sees wholly free and that are not wholly inside it are judged piece
    by piece (:func:`mixed_voxels`): free when every piece is seen free by some camera or lies inside the robot.
    ``near_region``: (i, j, k) slices of the box outside which ``near_robot`` is all False (what
    :func:`~depthguard.freespace.robot_voxels` returns), or None for the whole box: those voxels are looked for
    there only (the same voxels, in the same order; 4 % of the box on bench_frame_budget's cell).
    Returns the voxels these frames saw free, alone or with the robot ((nx, ny, nz) bool)."""
    views = CameraViews.of(cameras, free_images, margin, pad)
    seen = _seen_by(memory.box, views)
    if near_robot is not None and views.count:
        region = tuple(slice(0, n) for n in memory.box.shape) if near_region is None else _region(near_region)
        undecided = near_robot[region] & ~seen[region]
        if robot is not None:
            undecided &= ~robot[region]
        candidates = np.argwhere(undecided)
        candidates += [part.indices(n)[0] for part, n in zip(region, memory.box.shape)]
        passed = mixed_voxels(memory.box, views, candidates, np.zeros((0, 7)) if inner is None else inner)
        seen[tuple(candidates[passed].T)] = True
    surfaces = np.zeros(memory.box.shape, dtype=bool)
    for mark in surfaces_of:
        mark(surfaces)
    memory.forget(surfaces)
    seen &= ~surfaces
    memory.update(t, seen, robot, check=False)
    return seen
