"""The collision test of Henrich & Gecks (design §10, steps 4-6) on tile images: the obstacle image (paper
Table I), the revised obstacle image (Table III, for C cameras and occlusion threshold theta), the intersection with
a robot image (Table II) and the verdict with its class A-D (Table IV, section 3.5).

Every image is at tile resolution: a (rows, cols) array with one value per tile of a :class:`TileGrid`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from depthguard.collision._epipolar import EpipolarBands
from depthguard.errors import InputError
from depthguard.validation import check_unseen

#: Tile labels of the obstacle image (Table I) and of the revised obstacle image (Table III).
BACKGROUND, OBSTACLE, UNKNOWN, ERROR, POSSIBLE = 0, 1, 2, 3, 4
LABELS = ("background", "obstacle", "unknown", "error", "possible obstacle")


def _mask(image, name: str, shape=None) -> np.ndarray:
    array = np.asarray(image)
    if array.dtype != np.bool_ or array.ndim != 2 or (shape is not None and array.shape != shape):
        want = "2-D bool" if shape is None else f"{shape} bool"
        raise InputError(f"{name} must be a {want} tile image, got {array.dtype} {array.shape}", field=name)
    return array


def obstacle_image(foreground, robot, unexplained=None) -> np.ndarray:
    """Table I: (rows, cols) uint8 labels from the difference image ``foreground`` and the current robot image
    ``robot`` (both (rows, cols) bool): background where neither is set, obstacle where only the difference is,
    unknown where both are (an obstacle may be in front of or behind the robot), error where only the robot is (the
    background is seen where the robot should be). ``unexplained`` ((rows, cols) bool, depth images:
    :func:`unexplained_tiles`): foreground tiles whose change the robot cannot explain pixel by pixel are obstacles
    under the robot's tile image too (more obstacles, never fewer)."""
    foreground = _mask(foreground, "foreground")
    robot = _mask(robot, "robot", foreground.shape)
    if unexplained is not None:
        robot = robot & ~(_mask(unexplained, "unexplained", foreground.shape) & foreground)
    return (np.where(foreground, np.where(robot, UNKNOWN, OBSTACLE), np.where(robot, ERROR, BACKGROUND))
            .astype(np.uint8))


def revised_obstacle_images(obstacles: Sequence[np.ndarray], bands: EpipolarBands, theta: int) -> list[np.ndarray]:
    """Table III for C cameras: each unknown or error tile becomes a possible obstacle when at least C - theta of the
    other cameras have an obstacle tile in its epipolar band, else background; the other tiles keep their label.

    obstacles: per camera, its :func:`obstacle_image` (the grids of ``bands``, in their order). theta: the occlusion
    threshold, the most cameras in which the robot may hide an obstacle at once, in [0, C - 1].
    """
    c = len(obstacles)
    if len(bands.grids) != c or c < 1:
        raise InputError(f"{c} obstacle images for {len(bands.grids)} cameras", field="obstacles")
    theta = _theta(theta, c)
    packed = []
    for k, (image, grid) in enumerate(zip(obstacles, bands.grids)):
        image = np.asarray(image)
        if image.shape != (grid.rows, grid.cols) or image.dtype != np.uint8 or image.max(initial=0) > ERROR:
            raise InputError(f"obstacle image {k} must be ({grid.rows}, {grid.cols}) uint8 labels of Table I",
                             camera=grid.camera.name, field="obstacles")
        packed.append(grid.pack(image == OBSTACLE))
    out = []
    for a, image in enumerate(obstacles):
        revised = np.array(image, dtype=np.uint8, copy=True)
        tiles = np.flatnonzero((image == UNKNOWN) | (image == ERROR))
        if len(tiles):
            seen = np.zeros(len(tiles), dtype=np.int64)
            for b in range(c):
                if b != a:
                    seen += np.any(bands.bits[(a, b)][tiles] & packed[b], axis=1)
            flat = revised.reshape(-1)
            flat[tiles] = np.where(seen >= c - theta, POSSIBLE, BACKGROUND)
        out.append(revised)
    return out


def intersection_image(revised, robot) -> np.ndarray:
    """Table II: (rows, cols) bool, true where the (future) robot image ``robot`` meets an obstacle or a possible
    obstacle of the revised obstacle image."""
    revised = np.asarray(revised)
    robot = _mask(robot, "robot", revised.shape)
    return robot & ((revised == OBSTACLE) | (revised == POSSIBLE))


def camera_collisions(revised, robot) -> tuple[bool, bool]:
    """(Coll_RO, Coll_RP) of one camera: whether the robot pixel set meets the obstacle set, and the possible
    obstacle set (section 3.5)."""
    revised = np.asarray(revised)
    robot = _mask(robot, "robot", revised.shape)
    return bool(np.any(robot & (revised == OBSTACLE))), bool(np.any(robot & (revised == POSSIBLE)))


def depth_ordered_collisions(revised, free, bits, far, grid, chunk: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """(Coll_RO (K,), Coll_RP (K,)) bool of K configurations in one camera, with the depth order (design §10): a tile
    that a capsule covers counts only where the capsule reaches behind the depth up to which the camera saw that
    tile free (``far > free``): an obstacle, or whatever the current robot hides, lies behind that depth, so a capsule
    wholly in front of it along the tile's pixels meets nothing there.

    revised: (rows, cols) labels (Table III); free: (rows, cols) metres (:func:`tile_free_depth`; 0 proves nothing);
    bits: (K, m, words) uint64, each capsule's tiles; far: (K, m) metres, each capsule's deepest optical depth
    (:meth:`RobotProjector.capsule_bits`). Configurations are unpacked ``chunk`` at a time."""
    revised = np.asarray(revised)
    obstacle = (revised == OBSTACLE).reshape(-1)
    possible = (revised == POSSIBLE).reshape(-1)
    free = np.asarray(free, dtype=np.float64).reshape(-1)
    n = grid.n_tiles
    k_total = bits.shape[0]
    ro = np.zeros(k_total, dtype=bool)
    rp = np.zeros(k_total, dtype=bool)
    for start in range(0, k_total, chunk):
        part = np.ascontiguousarray(bits[start: start + chunk, :, : grid.words]).astype("<u8")
        covered = np.unpackbits(part.view(np.uint8), axis=-1, bitorder="little")[..., :n].astype(bool)
        hit = covered & (far[start: start + chunk, :, None] > free[None, None, :])  # (k, m, n_tiles)
        ro[start: start + chunk] = np.any(hit & obstacle, axis=(1, 2))
        rp[start: start + chunk] = np.any(hit & possible, axis=(1, 2))
    return ro, rp


@dataclass(frozen=True)
class Verdict:
    """The collision test of one robot configuration (or swept volume) over C cameras.

    Attributes:
        collision: with ``unseen="occupied"`` (the default): True iff every camera reports Coll_RO or Coll_RP
            (classes B, C, D); with ``unseen="free"`` (the paper's section 3.5): iff, besides, at least C - theta
            cameras report Coll_RO (classes C, D).
        klass: the paper's class: "A" (some camera sees no intersection at all: free), "B" (fewer than C - theta
            cameras see an obstacle: free only if every obstacle is seen by C - theta cameras), "C" (at least
            C - theta but not all do: a collision is assumed), "D" (all C do).
        obstacle: (C,) Coll_RO per camera; possible: (C,) Coll_RP per camera.
        shell: the concession it rests on (design §10): True on a verdict without a collision whose robot image meets
            the current robot's tile image in every camera. A camera takes what lies within the robot's shell for
            the robot (its tile image without the pixel rule; the padded hull + the self-filter's tolerance + the
            noise margin with it), and an object the robot hides from the other cameras lies under its image there
            too: such an object, unseen, could be hit. False otherwise (a robot image that leaves the current one in
            some camera cannot meet it).
    """

    collision: bool
    klass: str
    obstacle: tuple
    possible: tuple
    shell: bool = False


def verdict(obstacle: Sequence[bool], possible: Sequence[bool], theta: int, unseen: str = "occupied") -> Verdict:
    """The classes of Table IV generalised to C cameras (section 3.5) from each camera's (Coll_RO, Coll_RP).

    ``unseen``: what a configuration that meets possible obstacles (space the current robot hides from a camera)
    but fewer than C - theta cameras' obstacles is: "occupied" (fail-safe, design §11: class B collides) or
    "free" (the paper's rule: class B is collision-free because "any obstacle is visible in at least C - theta
    cameras"; false for a hand held next to the robot, which the robot's tiles cover in most cameras: scenario C's
    probe finds such misses, benchmarks/probe_collision_scenario_c.py)."""
    ro = tuple(bool(x) for x in obstacle)
    rp = tuple(bool(x) for x in possible)
    c = len(ro)
    if c < 1 or len(rp) != c:
        raise InputError(f"obstacle and possible must hold one flag per camera (got {len(ro)} and {len(rp)})",
                         field="obstacle")
    theta = _theta(theta, c)
    unseen = check_unseen(unseen)
    n_ro = sum(ro)
    if not all(a or b for a, b in zip(ro, rp)):
        klass = "A"
    elif n_ro < c - theta:
        klass = "B"
    elif n_ro < c:
        klass = "C"
    else:
        klass = "D"
    collides = ("B", "C", "D") if unseen == "occupied" else ("C", "D")
    return Verdict(collision=klass in collides, klass=klass, obstacle=ro, possible=rp)


def _theta(theta, c: int) -> int:
    if isinstance(theta, bool) or not isinstance(theta, (int, np.integer)) or not 0 <= theta <= c - 1:
        raise InputError(f"theta must be a whole number of cameras in [0, {c - 1}] for {c} cameras, got {theta!r}",
                         field="theta")
    return int(theta)
