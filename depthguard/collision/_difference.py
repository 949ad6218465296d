"""Steps 1-3 of the collision test (design §10; Henrich & Gecks sections 3.1-3.3) at tile resolution: the
reference image, the tiles' features and the difference image, and the robot's tile image.

Images are (height, width) arrays of one camera; tile images are (rows, cols) arrays of its :class:`TileGrid`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy import ndimage

from depthguard.kernels import collision as collision_kernels
from depthguard.collision._epipolar import TileGrid
from depthguard import config
from depthguard.errors import InputError
from depthguard.validation import NOT_A_NUMBER, check_real

#: The 4-neighbourhood of the morphological closing (section 3.2).
FOUR_NEIGHBOURS = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], dtype=bool)


def _image(image, grid: TileGrid, name: str) -> np.ndarray:
    array = np.asarray(image)
    cam = grid.camera
    if array.shape != cam.shape or array.dtype.kind not in "uif" or \
            (array.dtype.kind == "f" and not np.all(np.isfinite(array))):
        raise InputError(f"{name} must be a {cam.shape} array of finite numbers, got {array.dtype} {array.shape}",
                         camera=cam.name, field=name)
    return array


def reference_image(images: Sequence[np.ndarray], grid: TileGrid, robot=None, pixels=None) -> np.ndarray:
    """Step 1: the per-pixel median of ``images`` (each (height, width), intensity or depth) taken with the robot in
    different configurations, so that its mobile parts, seen in fewer than half of them at any pixel, disappear.
    Returns (height, width) float64.

    ``robot``: optionally, per image, the (rows, cols) bool tiles the robot covers in it (:class:`RobotProjector`).
    Then each pixel's median is taken over the images whose robot does not cover its tile, so that the robot
    disappears wherever at least one image shows the room behind it (however the configurations overlap); where
    every image's robot covers the tile (the base, which never moves), over all of them.

    ``pixels``: instead of ``robot``, per image the (height, width) bool pixels the robot may cover in it (its render,
    grown by a pixel): the same rule pixel by pixel, so that a pixel next to the robot in every image (a tile it
    always touches) still gets the room behind it."""
    stack = [_image(image, grid, f"images[{k}]") for k, image in enumerate(images)]
    if not stack:
        raise InputError("the reference needs at least one image", camera=grid.camera.name, field="images")
    values = np.stack(stack).astype(np.float64)
    if robot is None and pixels is None:
        return np.median(values, axis=0)
    given, field = (robot, "robot") if pixels is None else (pixels, "pixels")
    if len(given) != len(stack):
        raise InputError(f"{len(given)} robot {field} images for {len(stack)} images", camera=grid.camera.name,
                         field=field)
    if pixels is None:
        covered = np.stack([grid.pixels(tiles) for tiles in robot])
    else:
        covered = np.stack([np.asarray(mask, dtype=bool) for mask in pixels])
        if covered.shape[1:] != grid.camera.shape:
            raise InputError(f"robot pixels must be {grid.camera.shape} masks, got {covered.shape[1:]}",
                             camera=grid.camera.name, field="pixels")
    covered &= ~np.all(covered, axis=0)  # a pixel covered in every image: its median over all of them
    values[covered] = np.nan
    return np.nanmedian(values, axis=0)


def _tile_sums(values: np.ndarray, grid: TileGrid) -> np.ndarray:
    """(rows, cols) sums of ``values`` (height, width) over each tile's pixels."""
    rows = np.add.reduceat(values, grid.first_row[:-1], axis=0)
    return np.add.reduceat(rows, grid.first_col[:-1], axis=1)


def _read_only(image: np.ndarray) -> np.ndarray:
    """A C-contiguous read-only view of ``image`` (a copy only where it is not contiguous): frames arrive read-only
    and references writable, and the kernels are compiled (and warmed up) for read-only arrays alone."""
    view = np.ascontiguousarray(image).view()
    view.flags.writeable = False
    return view


def tile_features(image, grid: TileGrid) -> np.ndarray:
    """Step 2's features of every tile, (rows, cols, 2) float64: the mean grey value, and the y coordinate of the
    grey-value balance point within the tile (0 at its first pixel row's centre, 1 at its last; 0.5 for a tile
    whose values are all 0)."""
    image = _image(image, grid, "image")
    if image.dtype not in (np.uint8, np.uint16, np.float32, np.float64):
        image = image.astype(np.float64)
    cam = grid.camera
    tile_row, _ = grid.tile_of_pixels()
    counts = _tile_sizes(grid)
    # Each pixel row's position within its tile, 0 .. 1.
    first = grid.first_row[tile_row]
    last = grid.first_row[tile_row + 1] - 1
    y = np.where(last > first, (np.arange(cam.height) - first) / np.maximum(last - first, 1), 0.5)
    moments = np.empty((grid.rows, grid.cols, 2))
    collision_kernels.tile_moments(_read_only(image), grid.first_row, grid.first_col, y, moments)
    total, moment = moments[..., 0], moments[..., 1]
    with np.errstate(invalid="ignore", divide="ignore"):
        balance = np.where(total > 0.0, moment / np.where(total > 0.0, total, 1.0), 0.5)
    return np.stack([total / counts, balance], axis=-1)


def depth_metres(image, grid: TileGrid, name: str = "image") -> np.ndarray:
    """A depth image as (height, width) float64 metres, 0 where there is no measurement: ``uint16`` in units of the
    camera's depth_scale (ROS 16UC1), or floats in metres (ROS 32FC1; NaN and inf read as no measurement)."""
    array = np.asarray(image)
    cam = grid.camera
    if array.shape != cam.shape or array.dtype.kind not in "uif":
        raise InputError(f"{name} must be a {cam.shape} depth image (uint16 in depth_scale units or float metres), "
                         f"got {array.dtype} {array.shape}", camera=cam.name, field=name)
    if array.dtype.kind == "f":  # NaN, +-inf, 0 and negative values: no measurement (ROS 32FC1 conventions)
        metres = np.where(np.isfinite(array) & (array > 0.0), array, 0.0).astype(np.float64)
    else:
        if array.min(initial=0) < 0:
            raise InputError(f"{name}: negative depth values", camera=cam.name, field=name)
        metres = array.astype(np.float64) * cam.depth_scale
    return metres


def tile_free_depth(image, grid: TileGrid) -> np.ndarray:
    """(rows, cols) float64 metres: per tile, the optical depth up to which every pixel of the tile saw its frustum
    free (design §3, §10): the least d - m(d) over its pixels (d: the measured depth, m: the camera's noise margin),
    0 where a pixel of the tile has no measurement (nothing is proven free there). Whatever this camera cannot see
    lies behind it; a robot wholly in front of it along a tile's pixels meets nothing there (the depth order of the
    collision test, :class:`ImageCollisionTest`). ``image``: as :func:`depth_metres` takes it."""
    metres = depth_metres(image, grid)
    free = np.where(metres > 0.0, np.maximum(metres - grid.camera.noise.margin(metres), 0.0), 0.0)
    return np.minimum.reduceat(np.minimum.reduceat(free, grid.first_row[:-1], axis=0), grid.first_col[:-1], axis=1)


def depth_difference_image(image, reference, grid: TileGrid, thresholds=(0.05, 0.25)) -> np.ndarray:
    """The depth variant's difference image (beyond the paper), (rows, cols) bool: a pixel changed when it has a
    measurement in one of ``image`` and ``reference`` but not the other, or when both measure and differ by more than
    max(thresholds[0] metres, the camera's noise margin m(d) at the reference's depth); a tile is foreground when more
    than thresholds[1] of its pixels changed; then the closing of :func:`difference_image`.

    ``image``: as :func:`depth_metres` takes it; ``reference``: (height, width) float metres, 0 (or NaN) = no
    measurement (the median of reference images in metres, :func:`reference_image`). Comparing pixel by pixel, not tile means,
    keeps a tile whose measured pixels change (an edge's dropouts, a hole) from reading as a depth change."""
    cam = grid.camera
    now = np.asarray(image)
    if now.shape != cam.shape or now.dtype not in (np.uint16, np.float32, np.float64):
        now = depth_metres(image, grid)  # checks it (naming the camera); other integer types as depth_scale units
    ref = np.asarray(reference)
    if ref.shape != cam.shape or ref.dtype != np.float64:  # the reference_image median is used as it is
        ref = depth_metres(reference, grid, "reference")
    thresholds = _thresholds(thresholds, cam)
    scale = cam.depth_scale if now.dtype == np.uint16 else 1.0
    changed = np.empty((grid.rows, grid.cols))
    k0, k1, k2 = cam.noise.coefficients()
    collision_kernels.depth_changes(_read_only(now), scale, _read_only(ref), thresholds[0], k0, k1, k2,
                                    grid.first_row, grid.first_col, changed)
    return _closed(changed / _tile_sizes(grid) > thresholds[1])


def unexplained_tiles(image, reference, near, grid: TileGrid, thresholds=(0.05, 0.25),
                      tolerance: float = config.SELF_FILTER_TOLERANCE, tiles=None) -> np.ndarray:
    """(rows, cols) bool: the depth variant's tiles where more than thresholds[1] of the pixels changed (as
    :func:`depth_difference_image` decides a pixel) in a way the current robot cannot explain: no robot rendered
    within a pixel of it, or a measurement nearer than the rendered robot by more than ``tolerance`` and the noise
    margin (design §7's self-filter rule). Such a tile shows an obstacle even where the robot's tile image covers it
    (Table I would call it unknown): a hand lying next to a link. ``near``: (height, width) float32 metres, the
    robot's padded geometry rendered at the images' joints (:meth:`depthguard.self_filter.RobotSilhouette.render`),
    0 where it is not; ``image``, ``reference`` as for :func:`depth_difference_image`; ``tiles``: (rows, cols) bool,
    the tiles to look at (default all; the others are False)."""
    cam = grid.camera
    now = np.asarray(image)
    if now.shape != cam.shape or now.dtype not in (np.uint16, np.float32, np.float64):
        now = depth_metres(image, grid)
    ref = np.asarray(reference)
    if ref.shape != cam.shape or ref.dtype != np.float64:
        ref = depth_metres(reference, grid, "reference")
    near = _near(near, grid)
    thresholds = _thresholds(thresholds, cam)
    tolerance = check_real(tolerance, "tolerance", minimum=0.0, maximum=config.SELF_FILTER_TOLERANCE_MAX,
                           unit="metres", camera=cam.name, field="tolerance")
    scale = cam.depth_scale if now.dtype == np.uint16 else 1.0
    counts = np.empty((grid.rows, grid.cols))
    k0, k1, k2 = cam.noise.coefficients()
    collision_kernels.unexplained_changes(_read_only(now), scale, _read_only(ref), thresholds[0], k0, k1, k2,
                                          near, tolerance, grid.first_row, grid.first_col, _wanted(tiles, grid),
                                          counts)
    return counts / _tile_sizes(grid) > thresholds[1]


def _thresholds(thresholds, cam) -> np.ndarray:
    """The depth variant's (metres, fraction of a tile) as two finite numbers >= 0, else a named refusal."""
    try:
        thresholds = np.asarray(thresholds, dtype=np.float64)
    except NOT_A_NUMBER:  # words
        thresholds = np.full(1, np.nan)
    if thresholds.shape != (2,) or not np.all(np.isfinite(thresholds)) or not np.all(thresholds >= 0.0):
        raise InputError(f"thresholds must be two finite numbers >= 0 (metres, fraction of a tile), got "
                         f"{thresholds.tolist()}", camera=cam.name, field="thresholds")
    return thresholds


def _near(near, grid: TileGrid) -> np.ndarray:
    near = np.asarray(near, dtype=np.float32)
    if near.shape != grid.camera.shape:
        raise InputError(f"near must be the robot's {grid.camera.shape} render, got {near.shape}",
                         camera=grid.camera.name, field="near")
    return _read_only(near)


def _wanted(tiles, grid: TileGrid) -> np.ndarray:
    """The tiles to look at: (rows, cols) bool, C-contiguous (all of them for None)."""
    if tiles is None:
        return np.ones((grid.rows, grid.cols), dtype=bool)
    tiles = np.asarray(tiles)
    if tiles.dtype != np.bool_ or tiles.shape != (grid.rows, grid.cols):
        raise InputError(f"tiles must be a ({grid.rows}, {grid.cols}) bool tile image, got {tiles.dtype} "
                         f"{tiles.shape}", camera=grid.camera.name, field="tiles")
    return np.ascontiguousarray(tiles)


def _tile_sizes(grid: TileGrid) -> np.ndarray:
    """(rows, cols) float64: how many pixels each tile holds."""
    return np.outer(np.diff(grid.first_row), np.diff(grid.first_col)).astype(np.float64)


#: The intensity variant's pixel rule (:func:`unexplained_intensity_tiles`): a pixel changed when its grey value,
#: divided by the light gain, differs from the reference image's by more than this many grey levels; a tile counts
#: when more than the fraction of its pixels changed outside the robot.
UNEXPLAINED_GREY = 12.0
UNEXPLAINED_FRACTION = 0.25


def unexplained_intensity_tiles(image, reference, gain: float, near, grid: TileGrid,
                                grey: float = UNEXPLAINED_GREY, fraction: float = UNEXPLAINED_FRACTION,
                                tiles=None) -> np.ndarray:
    """(rows, cols) bool: the intensity variant's tiles where more than ``fraction`` of the pixels changed where the
    current robot cannot be: a grey value (divided by ``gain``, :func:`light_gain`) more than ``grey`` levels from the
    reference image's (:func:`reference_image`), at a pixel with nothing of the robot rendered within one pixel
    (``near``: (height, width) float32 metres, the robot's padded geometry rendered at the image's joints, 0 where it
    is not). Without depth, a change inside the robot's silhouette may be the robot; one outside cannot (its shadow
    could: such a tile becomes an obstacle, the conservative answer). A NaN gain (no estimate of the light) makes
    every tile count. ``tiles``: (rows, cols) bool, the tiles to look at (default all; the others are False)."""
    pixels = _image(image, grid, "image")
    ref = np.asarray(reference, dtype=np.float64)
    if ref.shape != grid.camera.shape:
        raise InputError(f"reference must be a {grid.camera.shape} image, got {ref.shape}", camera=grid.camera.name,
                         field="reference")
    near = _near(near, grid)
    wanted = _wanted(tiles, grid)
    grey = check_real(grey, "grey", minimum=0.0, unit="grey levels", camera=grid.camera.name, field="grey")
    fraction = check_real(fraction, "fraction", minimum=0.0, maximum=1.0, camera=grid.camera.name,
                          field="fraction")
    gain = float(gain) if isinstance(gain, (int, float, np.floating, np.integer)) and not isinstance(gain, bool) \
        else math.nan  # anything but a number: no estimate of the light, every tile counts
    if not math.isfinite(gain) or gain <= 0.0:
        return wanted.copy()
    counts = np.empty((grid.rows, grid.cols))
    pixels = pixels if pixels.dtype == np.uint8 else pixels.astype(np.float64)  # 8 bits, else any as floats
    collision_kernels.unexplained_grey(_read_only(pixels), _read_only(ref), gain, grey, near,
                                       grid.first_row, grid.first_col, wanted, counts)
    return counts / _tile_sizes(grid) > fraction


def light_gain(features, reference_features, darkest: float = 10.0) -> float:
    """How much brighter the whole image is than the reference (a change of the room's light): the median, over the
    tiles whose reference mean is at least ``darkest`` grey levels, of the ratio of their mean grey values. NaN when
    fewer than a quarter of the tiles are that bright (no estimate). A median: it holds while fewer than half of the
    bright tiles show something new (an obstacle, the robot)."""
    mean = np.asarray(features, dtype=np.float64)[..., 0]
    reference = np.asarray(reference_features, dtype=np.float64)[..., 0]
    bright = reference >= darkest
    if bright.sum() < 0.25 * bright.size:
        return math.nan
    return float(np.median(mean[bright] / reference[bright]))


class BayesTileClassifier:
    """Step 2's statistical classifier (the paper's section 3.2 and its reference [3]): a tile is foreground when the
    posterior probability of "foreground" given its feature distances to the reference reaches ``threshold``.

    Each class (background, foreground) is a 2-D Gaussian over the distances (|change of the mean grey value| in
    grey levels, |change of the balance point| in tile heights) with its own mean and covariance, and a prior from
    the training set's share; :meth:`fit` learns them from labelled tiles (e.g. a simulation's exact labels:
    :func:`labelled_tiles`). ``threshold`` below 0.5 leans towards foreground (a missed obstacle tile costs more than a
    false one); default 0.2.
    """

    def __init__(self, threshold: float = 0.2):
        if isinstance(threshold, bool) or not isinstance(threshold, (int, float)) or not 0.0 < threshold < 1.0:
            raise InputError(f"threshold must be a probability in (0, 1), got {threshold!r}", field="threshold")
        self.threshold = float(threshold)
        self.means = self.covariances = self.priors = None

    def fit(self, distances, foreground) -> "BayesTileClassifier":
        """Learn from ``distances`` (N, 2) (as :meth:`foreground` takes them) and ``foreground`` (N,) bool labels;
        each class needs at least 3 tiles. Returns self."""
        x = np.asarray(distances, dtype=np.float64)
        y = np.asarray(foreground)
        if x.ndim != 2 or x.shape[1] != 2 or y.shape != (len(x),) or y.dtype != np.bool_ or \
                not np.all(np.isfinite(x)):
            raise InputError(f"distances must be (N, 2) finite and foreground (N,) bool, got {x.shape} and "
                             f"{y.dtype} {y.shape}", field="distances")
        if min(y.sum(), (~y).sum()) < 3:
            raise InputError(f"each class needs at least 3 labelled tiles, got {int(y.sum())} foreground and "
                             f"{int((~y).sum())} background", field="foreground")
        self.means = np.array([x[~y].mean(axis=0), x[y].mean(axis=0)])
        # a small ridge keeps a class whose tiles barely vary (noise-free simulation) invertible
        self.covariances = np.array([np.cov(x[~y].T) + np.eye(2) * 1e-6, np.cov(x[y].T) + np.eye(2) * 1e-6])
        self.priors = np.array([(~y).mean(), y.mean()])
        return self

    def foreground(self, distances) -> np.ndarray:
        """(...) bool from (..., 2) feature distances: P(foreground | distances) >= threshold; a tile whose
        distances are not finite (NaN, inf) is foreground (the conservative answer)."""
        if self.means is None:
            raise InputError("fit the classifier first", field="classifier")
        x = np.asarray(distances, dtype=np.float64)
        log_p = []
        for mean, cov, prior in zip(self.means, self.covariances, self.priors):
            d = x - mean
            inverse = np.linalg.inv(cov)
            mahalanobis = np.einsum("...i,ij,...j->...", d, inverse, d)
            log_p.append(math.log(prior) - 0.5 * (mahalanobis + math.log(np.linalg.det(cov))))
        # P(fg) >= t  <=>  log p_fg - log p_bg >= log(t / (1 - t)); distances that are not finite: foreground
        decided = log_p[1] - log_p[0] >= math.log(self.threshold / (1.0 - self.threshold))
        return decided | ~np.all(np.isfinite(x), axis=-1)


def labelled_tiles(features, reference_features, truth, grid: TileGrid, gain: float = 1.0, exclude=None):
    """A training set for :class:`BayesTileClassifier` from one image: ((N, 2) feature distances, (N,) bool labels)
    of every tile, labelled foreground when ``truth`` ((height, width) bool, e.g. a simulation's exact labels of
    the obstacles) marks at least a tenth of its pixels, background when it marks none; tiles in between are left
    out (mixed), and so are the tiles of ``exclude`` ((rows, cols) bool, e.g. the robot's). ``gain``: the image's
    light gain (:func:`light_gain`)."""
    distances = feature_distances(features, reference_features, gain)
    truth = np.asarray(truth, dtype=bool)
    share = _tile_sums(truth.astype(np.int64), grid) / _tile_sizes(grid)
    keep = (share >= 0.1) | (share == 0.0)
    if exclude is not None:
        keep &= ~np.asarray(exclude, dtype=bool)
    return distances[keep], (share >= 0.1)[keep]


#: Grey levels: below this mean (in the image, after the gain, or in the reference) a tile's balance point is noise
#: (a near-black tile's few grey levels put it anywhere), and only its mean is compared.
BALANCE_MIN_MEAN = 8.0


def feature_distances(features, reference_features, gain: float = 1.0) -> np.ndarray:
    """(rows, cols, 2) |feature - reference feature| per tile, the mean grey value first divided by ``gain``; the
    balance point's distance is 0 where either mean is below :data:`BALANCE_MIN_MEAN`."""
    features = np.array(features, dtype=np.float64)
    reference_features = np.asarray(reference_features, dtype=np.float64)
    features[..., 0] /= gain
    distances = np.abs(features - reference_features)
    dark = np.minimum(features[..., 0], reference_features[..., 0]) < BALANCE_MIN_MEAN
    distances[..., 1] = np.where(dark, 0.0, distances[..., 1])
    return distances


def difference_image(features, reference_features, thresholds=(6.0, 0.05), gain: float = 1.0,
                     classifier: BayesTileClassifier | None = None) -> np.ndarray:
    """Step 2's difference image, (rows, cols) bool: a tile is foreground when any feature differs from the
    reference's by more than its threshold (mean grey levels, balance point in tile heights), then the
    morphological closing in the 4-neighbourhood fills one-tile gaps. The closing only adds: a foreground tile never
    becomes background (scipy's erosion would clear foreground on the image border).

    ``gain``: the image's brightness relative to the reference's (:func:`light_gain`); the mean grey values are
    divided by it before the comparison (the balance point does not change with it). Not a finite positive number
    (no estimate): every tile is foreground. ``classifier``: a fitted :class:`BayesTileClassifier` decides instead
    of the thresholds."""
    features = np.asarray(features, dtype=np.float64)
    reference_features = np.asarray(reference_features, dtype=np.float64)
    thresholds = np.asarray(thresholds, dtype=np.float64)
    if features.shape != reference_features.shape or features.ndim != 3 or \
            thresholds.shape != (features.shape[2],) or not np.all(thresholds >= 0.0):
        raise InputError(f"features {features.shape} and reference {reference_features.shape} must match, with one "
                         f"threshold >= 0 per feature (got {thresholds.tolist()})", field="thresholds")
    if not (isinstance(gain, (int, float, np.floating)) and math.isfinite(gain) and gain > 0.0):
        return np.ones(features.shape[:2], dtype=bool)
    distances = feature_distances(features, reference_features, gain)
    if classifier is not None:
        return _closed(classifier.foreground(distances))
    return _closed(np.any(distances > thresholds, axis=-1))


def _closed(changed: np.ndarray) -> np.ndarray:
    """The morphological closing in the 4-neighbourhood, keeping every tile that was set."""
    return changed | ndimage.binary_closing(changed, structure=FOUR_NEIGHBOURS)


def robot_tiles(robot_mask, grid: TileGrid) -> np.ndarray:
    """Step 3's robot image at tile resolution: (rows, cols) bool, true where any pixel of the tile shows the robot
    (``robot_mask``: (height, width) bool, e.g. where the rendered padded robot has a depth)."""
    mask = np.asarray(robot_mask)
    if mask.shape != grid.camera.shape or mask.dtype != np.bool_:
        raise InputError(f"robot_mask must be a {grid.camera.shape} bool image, got {mask.dtype} {mask.shape}",
                         camera=grid.camera.name, field="robot_mask")
    return _tile_sums(mask.astype(np.int64), grid) > 0
