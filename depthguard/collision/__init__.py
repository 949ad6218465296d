"""The image-based multi-camera collision test of Henrich & Gecks (design §10).

- Tile grids and the epipolar bands between cameras (:class:`TileGrid`, :class:`EpipolarBands`).
- Steps 1-2: the reference image (:func:`reference_image`, optionally leaving the robot out where the joints say it
  stood), the tiles' features and the difference image (:func:`tile_features`, :func:`difference_image` with the
  thresholds or a :class:`BayesTileClassifier`, following the room's light: :func:`light_gain`); the depth
  variant (:func:`depth_difference_image`).
- Step 3 and 7: the robot's tile images from its padded capsules, projected without rendering, and swept volumes
  (:class:`RobotProjector`).
- Steps 4-6: Tables I-IV (:func:`obstacle_image`, :func:`revised_obstacle_images`, :func:`intersection_image`,
  :func:`verdict`); fail-safe by default (theta = C - 1, class B collides).
- :class:`ImageCollisionTest` runs them over a rig; :class:`ConfigurationTable` gives many configurations' verdicts
  by bitwise operations.
- The depth grid's verdict on the distances' frames (:class:`DepthGridCollisionTest`): a second opinion.
- Step 9: :class:`ConfigurationGrid`, :func:`wave_propagation`, :func:`plan_path`.
- Step 8, pick-and-place: :mod:`depthguard.collision._update` (:class:`ReferenceUpdate`).

The command line (``depthguard collide``, ``depthguard plan``) lives in :mod:`depthguard.cli.collide` and :mod:`depthguard.cli.plan`.
"""

from depthguard.collision._difference import (
    BALANCE_MIN_MEAN,
    FOUR_NEIGHBOURS,
    BayesTileClassifier,
    depth_metres,
    depth_difference_image,
    difference_image,
    feature_distances,
    labelled_tiles,
    light_gain,
    reference_image,
    robot_tiles,
    tile_features,
    tile_free_depth,
    unexplained_intensity_tiles,
    unexplained_tiles,
)
from depthguard.collision._grid import DepthGridCollisionTest, GridVerdicts
from depthguard.collision._epipolar import EpipolarBands, TileGrid, workspace_depths
from depthguard.collision._plan import MAX_GRID_CELLS, ConfigurationGrid, plan_path, wave_propagation
from depthguard.collision._robot_image import RobotProjector
from depthguard.collision._test import ConfigurationTable, ImageCollisionTest
from depthguard.collision._boxes import box_tiles
from depthguard.collision._update import ReferenceUpdate
from depthguard.collision._tables import (
    BACKGROUND,
    ERROR,
    LABELS,
    OBSTACLE,
    POSSIBLE,
    UNKNOWN,
    Verdict,
    camera_collisions,
    depth_ordered_collisions,
    intersection_image,
    obstacle_image,
    revised_obstacle_images,
    verdict,
)

__all__ = [
    "BACKGROUND",
    "BALANCE_MIN_MEAN",
    "BayesTileClassifier",
    "ConfigurationGrid",
    "ConfigurationTable",
    "DepthGridCollisionTest",
    "ERROR",
    "EpipolarBands",
    "FOUR_NEIGHBOURS",
    "GridVerdicts",
    "ImageCollisionTest",
    "LABELS",
    "MAX_GRID_CELLS",
    "OBSTACLE",
    "POSSIBLE",
    "ReferenceUpdate",
    "RobotProjector",
    "TileGrid",
    "UNKNOWN",
    "Verdict",
    "box_tiles",
    "camera_collisions",
    "depth_metres",
    "depth_ordered_collisions",
    "depth_difference_image",
    "difference_image",
    "feature_distances",
    "labelled_tiles",
    "light_gain",
    "intersection_image",
    "obstacle_image",
    "plan_path",
    "reference_image",
    "revised_obstacle_images",
    "robot_tiles",
    "tile_features",
    "tile_free_depth",
    "unexplained_intensity_tiles",
    "unexplained_tiles",
    "verdict",
    "wave_propagation",
    "workspace_depths",
]
