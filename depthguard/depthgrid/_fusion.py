"""Online fusion of several depth cameras through the depth grid (design §8)."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from numba import parallel_chunksize

from depthguard import config
from depthguard.buffers import drop_spares, reusable
from depthguard.cameras import PinholeCamera, Rig
from depthguard.depth import DepthImage, OccupancyImage
from depthguard.kernels import depthgrid as grid_kernels
from depthguard.depthgrid._map import DepthGridMap
from depthguard.depthspace import query_arrays
from depthguard.validation import check_options, check_points, check_real, short_repr
from depthguard.errors import InputError
from depthguard.results import DistanceResult, Flag


def free_image(depth: DepthImage, camera: PinholeCamera) -> np.ndarray:
    """(h, w) float32 metres: how far ``camera`` saw along each pixel, its measured depth minus its noise margin;
    0 where it measured nothing. A secondary camera clears a cell only with this."""
    free = np.empty(camera.shape, dtype=np.float32)
    z_min, z_max = camera.depth_range
    m0, m1, m2 = camera.noise.coefficients()
    grid_kernels.free_depths(depth.data, float(depth.depth_scale), z_min, z_max, m0, m1, m2, free)
    return free


def seen_free(depth: DepthImage, occupancy: OccupancyImage) -> np.ndarray:
    """(h, w) float32 metres: how far a secondary camera saw along each pixel, like :func:`free_image`, except that
    small holes its ``neighbors`` policy filled (``occupancy``: the frame prepared by
    :func:`depthguard.prepare_depth`) see as far as the nearest surface around them: the lines sensors drop along
    depth edges, such as the robot's silhouette, then do not stop it clearing the cells they touch."""
    camera = occupancy.camera
    free = np.empty(camera.shape, dtype=np.float32)
    z_min, z_max = camera.depth_range
    invalid_start = np.float32(z_min) if occupancy.invalid_policy != "free" else np.float32(np.inf)
    grid_kernels.seen_free_depths(depth.data, float(depth.depth_scale), z_min, z_max, *camera.noise.coefficients(),
                              occupancy.z_start, occupancy.invalid, invalid_start, occupancy.blind, free)
    return free


def fused_distances(grid: DepthGridMap, rig: Rig, principal: OccupancyImage, secondaries: dict,
                    points_world, rho: float = config.DEFAULT_RHO, aggregate: str = config.DEFAULT_AGGREGATE,
                    unseen: str = config.DEFAULT_UNSEEN, robot_far: np.ndarray | None = None,
                    margin: float = config.DEFAULT_FUSION_MARGIN, pad: int = config.DEFAULT_FUSION_PIXELS,
                    robot_tolerance: float = config.SELF_FILTER_TOLERANCE, check: bool = True,
                    robot_near: np.ndarray | None = None, robot_exit: np.ndarray | None = None,
                    robot_shell: np.ndarray | None = None) -> DistanceResult:
    """Distances from control points to what the principal camera says is possibly occupied and no other camera
    clears (design §8, cases i-iv, with the corrected confirmation rule): one query of a :class:`FusedFrames`.
    To query the same frames again (a controller faster than its cameras), keep the :class:`FusedFrames`."""
    frames = FusedFrames(grid, rig, principal, secondaries, robot_far, margin, pad, robot_tolerance, check,
                         robot_near, robot_exit, robot_shell=robot_shell)
    return frames.distances(points_world, rho, aggregate, unseen, check)


class FusedFrames:
    """The frames of one moment fused through the principal camera's depth grid (design §8), for any number of
    queries.

    A query classifies the grid cells it looks at and keeps their classes for the later queries on the same frames:
    a cell is classified at most once per frame.

    Args:
        grid: the depth grid map of ``rig`` for the principal camera (:func:`build_map`).
        rig: the cameras.
        principal: the principal camera's prepared frame (:func:`depthguard.prepare_depth`, robot filtered out
            if there is one).
        secondaries: secondary camera name -> its :func:`free_image`, or None for a camera that is blind (stale or
            missing): a blind camera clears nothing.
        robot_far: (h, w) float32 metres, the principal's rendered robot: where its body ends along each pixel
            (0 where it is not). The space behind the robot (case iv) starts there; the robot's own volume is
            not an obstacle. Needed when ``principal`` was self-filtered.
        robot_near: (h, w) float32 metres, where the rendered robot starts along each pixel (0 where it is not).
            Optional: with it, the robot's body is not an obstacle where a surface in front of it hides it either
            (a person between the principal camera and the robot), so the cameras need not clear the space inside
            the robot, which none of them can.
        robot_exit: (h, w) float32 metres, where each pixel's ray first leaves the robot's padded geometry
            (:meth:`depthguard.self_filter.RobotSilhouette.render_first_exit`). Optional: with it, the space
            between that and robot_far, which may lie between two links, is checked cell by cell like the space
            behind the robot (design §11a); without it, fusion takes all of it for the robot.
        robot_shell: (n, 7) float64, world frame, metres: capsules (p0 (3), p1 (3), radius) that hold the rendered
            robot when the principal frame was captured (the padded capsules, their radii grown by how far the
            rendered geometry reaches beyond them). With robot_exit, a cell between the links that lies wholly
            within ``robot_tolerance`` plus the principal's noise margin of one of them counts as that link, as
            much as the principal takes behind a link for it (the self-filter's shell; the caller flags it
            ``robot_shell``). Without it, the links a ray meets after its first are obstacles to it.
        margin: metres a secondary camera must have seen beyond a cell (calibration error; on top of its noise
            margin). pad: pixels by which a cell's footprint grows in a secondary camera.
        robot_tolerance: the self-filter's tolerance. Self-filtering counts a measurement up to this (plus the noise
            margin) in front of the rendered robot as the robot; fusion counts the same depth behind where the
            robot's body ends as the robot too. No camera can clear space that near a surface it sees (its noise
            margin forbids it), so without this every point on the robot would find "occupied" cells at its own
            surface.
        remembered: optional (free, box): the voxels of ``box`` (:class:`depthguard.freespace.VoxelBox`) that the
            free-space memory certifies free at these frames' time (``free``: box.shape bool, from
            :meth:`depthguard.freespace.FreeSpaceMemory.free_at`). A cell that no secondary camera clears is then free
            when every voxel it touches is (design §8a). The caller flags the answers that rest on it.
        robot_zone: optional (capsules, thickness): capsules (n, 7) float64, world frame, metres, the robot's padded
            capsules when the principal frame was captured (p0 (3), p1 (3), radius with the padding;
            :meth:`RobotModel.capsules_world`), and thickness, metres. A cell within ``thickness`` of one of them is
            the robot's (the robot zone, :func:`depthguard.kernels.depthgrid.zoned_cells`): an object wholly inside
            it is not seen, and one that reaches into it may be reported up to ``thickness`` too far.
    """

    def __init__(self, grid: DepthGridMap, rig: Rig, principal: OccupancyImage, secondaries: dict,
                 robot_far: np.ndarray | None = None, margin: float = config.DEFAULT_FUSION_MARGIN,
                 pad: int = config.DEFAULT_FUSION_PIXELS, robot_tolerance: float = config.SELF_FILTER_TOLERANCE,
                 check: bool = True, robot_near: np.ndarray | None = None,
                 robot_exit: np.ndarray | None = None, remembered=None, robot_zone=None, robot_shell=None):
        if check:
            if not isinstance(grid, DepthGridMap) or not isinstance(rig, Rig) or \
                    not isinstance(principal, OccupancyImage):
                raise InputError("FusedFrames needs a DepthGridMap, a Rig and the principal's OccupancyImage (got "
                                 f"{type(grid).__name__}, {type(rig).__name__}, {type(principal).__name__})")
            if not isinstance(secondaries, Mapping):
                raise InputError(f"secondaries must map camera names to free images (or None), got "
                                 f"{short_repr(secondaries)}", field="secondaries")
            grid.check_rig(rig)
            if principal.camera.name != grid.principal:
                raise InputError(f"the map's principal camera is {grid.principal!r}, the frame is camera "
                                 f"{principal.camera.name!r}")
            unknown = set(secondaries) - set(grid.secondaries)
            if unknown:
                raise InputError(f"cameras {sorted(unknown)} are not secondary cameras of this map "
                                 f"({', '.join(grid.secondaries)})")
            margin = check_real(margin, "margin", minimum=0.0, unit="metres", field="margin")
            robot_tolerance = check_real(robot_tolerance, "robot_tolerance", minimum=0.0,
                                         maximum=config.SELF_FILTER_TOLERANCE_MAX, unit="metres",
                                         field="robot_tolerance")
            if isinstance(pad, bool) or not isinstance(pad, (int, np.integer)) or \
                    not 0 <= pad <= config.MAX_FUSION_PIXELS:
                raise InputError(f"pad must be a whole number of pixels in [0, {config.MAX_FUSION_PIXELS}], got "
                                 f"{short_repr(pad)}", field="pad")
            if principal.robot_pixels and robot_far is None:
                raise InputError("the principal frame was self-filtered: pass robot_far, where the robot's body ends")
            if robot_near is not None and robot_far is None:
                raise InputError("robot_near needs robot_far: where the robot's body ends")
        if not 0 < grid.n_cells <= config.DEPTH_GRID_MAX_CELLS:  # the cell cache below holds a byte per cell
            raise InputError(f"the depth grid has {grid.n_cells} cells per pixel; at most "
                             f"{config.DEPTH_GRID_MAX_CELLS} are supported (config.DEPTH_GRID_MAX_CELLS)",
                             field="n_cells")
        self.grid = grid
        self.principal = principal
        camera = principal.camera
        used = [i for i, name in enumerate(grid.secondaries) if secondaries.get(name) is not None]
        cams = [rig.cameras[grid.secondaries[i]] for i in used]
        h_max = max([c.height for c in cams], default=1)
        w_max = max([c.width for c in cams], default=1)
        free = np.zeros((len(used), h_max, w_max), dtype=np.float32)
        for k, (i, cam) in enumerate(zip(used, cams)):
            image = secondaries[grid.secondaries[i]]
            if not isinstance(image, np.ndarray) or image.shape != cam.shape:
                raise InputError(f"the free image of camera {cam.name!r} must be a {cam.shape} array, got "
                                 f"{getattr(image, 'shape', type(image).__name__)}", camera=cam.name,
                                 field="secondaries")
            free[k, : cam.height, : cam.width] = image
        self.secondaries = tuple(grid.secondaries[i] for i in used)
        self._stale = len(used) < len(grid.secondaries)
        self._sizes = np.array([[c.width, c.height] for c in cams], dtype=np.int64).reshape(-1, 2)
        self._z_near = np.array([max(c.depth_range[0], 1e-6) for c in cams], dtype=np.float64)
        self._corners, self._offsets = grid.kernel_arrays(tuple(used))
        self._margin = float(margin)
        # Each pixel's smallest free depth within pad pixels: a cell's grown footprint is then its own pixels.
        self._eroded = np.empty_like(free)
        grid_kernels.erode_free(free, self._sizes, int(pad), self._eroded)
        self._certain = np.empty(camera.shape, dtype=np.uint8)
        self._z_end = np.empty(camera.shape, dtype=np.float32)
        self._blind_from = np.empty(camera.shape, dtype=np.float32)
        self._shell_lo = np.empty(camera.shape, dtype=np.float32)
        self._shell_hi = np.empty(camera.shape, dtype=np.float32)
        none = np.zeros(camera.shape, dtype=np.float32)
        far = none if robot_far is None else np.ascontiguousarray(robot_far, dtype=np.float32)
        near = none if robot_near is None else np.ascontiguousarray(robot_near, dtype=np.float32)
        exit_ = none if robot_exit is None else np.ascontiguousarray(robot_exit, dtype=np.float32)
        grid_kernels.principal_arrays(principal.z_start, principal.z_end, principal.invalid,
                                  np.float32(camera.depth_range[0]), principal.blind, near, far, exit_,
                                  float(robot_tolerance), *camera.noise.coefficients(), self._certain, self._z_end,
                                  self._blind_from, self._shell_lo, self._shell_hi)
        # The cells' classes so far, a byte each: 0 unknown, 1 free, 2 occupied, 3 free by the memory
        # (classify_run), and per pixel whether they were written. One array reused from set to set (a new one's
        # pages, zeroed by the operating system as they are first touched, cost 4-5 ms a set; memory grows with the
        # cells looked at, not with the grid): what its last owner wrote is cleared.
        self._cells, runs, self._touched = _cell_cache(camera.shape, grid.n_cells, self)
        # Per pixel, one run of cells known free in its gray area and one behind the robot, to skip without reading
        # them: (first << 32) | last.
        self._free_run, self._behind_run = runs
        self._memory = _NO_MEMORY if remembered is None else _memory_tuple(remembered, camera)
        self._zone = _zone_arrays(robot_zone, camera)
        self._shell = NO_ZONE if robot_shell is None else \
            _capsule_arrays(robot_shell, robot_tolerance, camera, camera.noise.coefficients(), "robot_shell")

    def distances(self, points_world, rho: float = config.DEFAULT_RHO, aggregate: str = config.DEFAULT_AGGREGATE,
                  unseen: str = config.DEFAULT_UNSEEN, check: bool = True) -> DistanceResult:
        """Distances of control points, as :func:`depthguard.single_camera_distances` gives them for one camera.

        points_world: (n, 3) float64, metres, world frame. rho, aggregate, unseen: as there.

        A principal frame whose timestamp is NaN or infinite is stale: every point gets distance 0 and
        ``STALE_CAMERA`` (a secondary camera's staleness is its caller's to decide: pass None for it).
        """
        if check:
            check_options(rho, aggregate, unseen, "exact")
            points_world = check_points(points_world)
        principal = self.principal
        camera = principal.camera
        grid = self.grid
        timestamp = principal.timestamp
        if timestamp is not None and not math.isfinite(timestamp):  # design §8 "Time": stale, never fresh
            return DistanceResult.blind(len(points_world), Flag.STALE_CAMERA, {camera.name: timestamp})
        points_camera, distance, direction_camera, count, invalid_count, flags = query_arrays(camera, points_world)
        if len(points_world):
            z_min, z_max = camera.depth_range
            view = grid_kernels.PrincipalView(principal.z_start, self._z_end, self._certain, self._blind_from,
                                              camera.fx, camera.fy, camera.cx, camera.cy, z_min, z_max)
            options = grid_kernels.QueryOptions(config.AGGREGATES.index(aggregate), unseen == "occupied",
                                            config.NEAR_PLANE_EPSILON, config.INSIDE_TOLERANCE,
                                            config.MIN_DIRECTION_NORM, config.FUSION_ROW_CHUNKS)
            state = self.kernel_state()
            out = grid_kernels.FusedOutput(distance, direction_camera, count, invalid_count, flags)
            with parallel_chunksize(1):
                grid_kernels.fused_query_points(points_camera, float(rho), view, options, state, out)
        stale = Flag.STALE_CAMERA if self._stale else Flag(0)
        # The region's depths [Z - rho, Z + rho], within the camera's range, that the grid does not span.
        z = points_camera[:, 2]
        z_lo, z_hi = camera.depth_range
        with np.errstate(invalid="ignore"):
            leaves = (np.minimum(z + rho, z_hi) > grid.d_max) | (np.maximum(z - rho, z_lo) < grid.d_min)
        outside = (Flag(0), Flag.OUTSIDE_GRID)
        return DistanceResult(
            distance=distance,
            direction=direction_camera @ camera.T_world_camera[:3, :3].T,
            count=count,
            invalid_count=invalid_count,
            flags=tuple(Flag(int(f)) | stale | outside[bool(out)] for f, out in zip(flags, leaves)),
            timestamps={camera.name: principal.timestamp},
            cameras=(camera.name,) + self.secondaries,
            invalid_pixels={camera.name: principal.invalid_pixels},
        )

    def kernel_state(self, free_run=None, behind_run=None) -> grid_kernels.GridState:
        """The fused kernels' :class:`~depthguard.kernels.depthgrid.GridState` of these frames (their cells' classes
        so far included); ``free_run``, ``behind_run``: (H, W) int64 runs in place of the frames' own (for tests and
        probes)."""
        grid = self.grid
        return grid_kernels.GridState(grid.d_min, grid.delta_d, grid.n_cells, self._corners, self._offsets,
                                      self._eroded, self._sizes, self._z_near, self._margin, self._cells,
                                      self._touched,
                                      *self._memory, self._free_run if free_run is None else free_run,
                                      self._behind_run if behind_run is None else behind_run, *self._zone,
                                      *self._shell, self._shell_lo, self._shell_hi)


_cell_cache_uses = 0  # cell arrays handed out since the spares were last dropped (config.CELL_CACHE_RENEWAL)


def _cell_cache(shape: tuple, n_cells: int, owner) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(cells, runs, touched) for a principal of ``shape`` (h, w) pixels: the cell classes ((h, w, n_cells) uint8,
    all 0), the free runs ((2, h, w) int64, free_run and behind_run, all NO_FREE_RUN) and marks of the pixels whose
    cells or runs were written ((h, w) uint8, all 0), in one array reused from the sets of frames before
    (:func:`depthguard.buffers.reusable`, given back when ``owner`` is collected): only the pixels its last owner
    marked are cleared. Every ``config.CELL_CACHE_RENEWAL`` calls the spares are dropped, so that the pages earlier
    sets touched do not stay resident for good."""
    global _cell_cache_uses
    kind = shape + (n_cells + 17,)  # per pixel: its cells, 16 bytes of runs, a mark
    _cell_cache_uses += 1
    if _cell_cache_uses >= config.CELL_CACHE_RENEWAL:  # the pages of old sets back to the operating system
        _cell_cache_uses = 0
        drop_spares(kind, np.uint8)
    cells, runs, touched = _cell_cache_parts(reusable(kind, np.uint8, owner, new=_new_cell_cache))
    grid_kernels.clear_touched(cells, runs, touched)
    return cells, runs, touched


def _cell_cache_parts(array: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(cells, runs, touched): views of one (h, w, n_cells + 17) uint8 array of :func:`_cell_cache`, laid out as
    the runs ((2, h, w) int64, first: numpy aligns an array's start), the cells ((h, w, n_cells) uint8) and the marks
    ((h, w) uint8)."""
    h, w, n = array.shape
    n_cells, pixels = n - 17, h * w
    flat = array.reshape(-1)
    runs = flat[:16 * pixels].view(np.int64).reshape(2, h, w)
    cells = flat[16 * pixels:16 * pixels + pixels * n_cells].reshape(h, w, n_cells)
    touched = flat[16 * pixels + pixels * n_cells:].reshape(h, w)
    return cells, runs, touched


def _new_cell_cache(shape: tuple, dtype) -> np.ndarray:
    """A new array for :func:`_cell_cache`: zeros (their pages come from the operating system as they are first
    touched), the runs NO_FREE_RUN."""
    out = np.zeros(shape, dtype=dtype)
    _cell_cache_parts(out)[1][:] = grid_kernels.NO_FREE_RUN
    return out


_NO_MEMORY = (np.zeros((0, 0, 0), dtype=np.uint8), np.zeros(grid_kernels.MEM_GEOMETRY_SIZE))
NO_ZONE = (np.zeros((0, 7)), np.zeros(grid_kernels.CAPSULE_PARAMS))


def _zone_arrays(robot_zone, camera: PinholeCamera) -> tuple[np.ndarray, np.ndarray]:
    """The kernels' form of the robot zone (capsules, thickness) for principal ``camera``: ((n, 7) capsules in its
    optical frame, zone_params); :data:`NO_ZONE` for None."""
    if robot_zone is None:
        return NO_ZONE
    try:
        capsules, thickness = robot_zone
    except (TypeError, ValueError):
        raise InputError("robot_zone must be (capsules, thickness)", field="robot_zone") from None
    return _capsule_arrays(capsules, thickness, camera, (0.0, 0.0, 0.0), "robot_zone")


def _capsule_arrays(capsules, thickness, camera: PinholeCamera, margin, field: str) -> tuple[np.ndarray, np.ndarray]:
    """The kernels' form of capsules ((n, 7) world frame: p0, p1, radius, metres) grown by ``thickness`` (metres) plus
    the noise margin with coefficients ``margin`` (m0, m1, m2) for principal ``camera``: ((n, 7) capsules in its
    optical frame, (CAPSULE_PARAMS,) parameters). Errors name ``field``."""
    thickness = check_real(thickness, f"{field} thickness", minimum=0.0, unit="metres", field=field)
    capsules = np.asarray(capsules, dtype=np.float64)
    if capsules.ndim != 2 or capsules.shape[1] != 7 or not np.all(np.isfinite(capsules)) or \
            np.any(capsules[:, 6] < 0.0):
        raise InputError(f"{field}'s capsules must be an (n, 7) array of finite capsules (p0, p1, radius >= 0), "
                         f"got {short_repr(capsules)}", field=field)
    T_camera_world = np.linalg.inv(camera.T_world_camera)
    R, t = T_camera_world[:3, :3], T_camera_world[:3, 3]
    zone = np.empty_like(capsules)
    zone[:, 0:3] = capsules[:, 0:3] @ R.T + t
    zone[:, 3:6] = capsules[:, 3:6] @ R.T + t
    zone[:, 6] = capsules[:, 6]
    params = np.empty(grid_kernels.CAPSULE_PARAMS)
    params[grid_kernels.CAPSULE_THICKNESS] = thickness
    params[grid_kernels.CAPSULE_MARGIN:grid_kernels.CAPSULE_MARGIN + 3] = margin
    params[grid_kernels.CAPSULE_INTRINSICS:] = (camera.fx, camera.fy, camera.cx, camera.cy)
    return np.ascontiguousarray(zone), params


def _memory_tuple(remembered, camera: PinholeCamera) -> tuple[np.ndarray, np.ndarray]:
    """The kernels' form of (free voxels, their box) for principal ``camera``: (uint8 voxels, geometry)."""
    from depthguard.freespace import VoxelBox

    try:
        free, box = remembered
    except (TypeError, ValueError):
        raise InputError("remembered must be (free voxels, VoxelBox)", field="remembered") from None
    if not isinstance(box, VoxelBox) or not isinstance(free, np.ndarray) or free.dtype != np.bool_ or \
            free.shape != box.shape:
        raise InputError("remembered must be (a bool array of the box's shape, the VoxelBox)", field="remembered")
    geometry = np.empty(grid_kernels.MEM_GEOMETRY_SIZE)
    geometry[grid_kernels.MEM_LO:grid_kernels.MEM_LO + 3] = box.lo
    geometry[grid_kernels.MEM_INV_VOXEL] = 1.0 / box.voxel
    geometry[grid_kernels.MEM_R:grid_kernels.MEM_R + 9] = camera.T_world_camera[:3, :3].ravel()
    geometry[grid_kernels.MEM_T:grid_kernels.MEM_T + 3] = camera.T_world_camera[:3, 3]
    geometry[grid_kernels.MEM_INTRINSICS:] = (1.0 / camera.fx, 1.0 / camera.fy, camera.cx, camera.cy)
    return np.ascontiguousarray(free, dtype=np.uint8), geometry
