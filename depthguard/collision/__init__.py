"""The image-based multi-camera collision test of Henrich & Gecks (SPEC section 10; issue 10, in progress).

Built so far: tile grids and the epipolar bands between cameras (step 5's geometry); the reference image, the tiles'
features, the difference image and the robot's tile image (steps 1-3, thresholds as the linear classifier); the
obstacle image (Table I), the revised obstacle image (Table III, C cameras, occlusion threshold theta), the
intersection image (Table II) and the verdict with its class A-D (Table IV); :class:`ImageCollisionTest` runs them
together with the robot's tile images rendered from its padded geometry; :class:`ConfigurationTable` holds many
configurations' tile images as bitsets and gives all their verdicts at once. Not yet: the Bayes classifier, the depth
variant, swept volumes, pick-and-place, the planner, the command line.
"""

from depthguard.collision._difference import (
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
)
from depthguard.collision._epipolar import EpipolarBands, TileGrid, workspace_depths
from depthguard.collision._plan import MAX_GRID_CELLS, ConfigurationGrid, plan_path, wave_propagation
from depthguard.collision._robot_image import RobotProjector
from depthguard.collision._test import ConfigurationTable, ImageCollisionTest
from depthguard.collision._tables import (
    BACKGROUND,
    ERROR,
    LABELS,
    OBSTACLE,
    POSSIBLE,
    UNKNOWN,
    Verdict,
    camera_collisions,
    intersection_image,
    obstacle_image,
    revised_obstacle_images,
    verdict,
)

__all__ = [
    "BACKGROUND",
    "BayesTileClassifier",
    "ConfigurationGrid",
    "ConfigurationTable",
    "ERROR",
    "EpipolarBands",
    "FOUR_NEIGHBOURS",
    "ImageCollisionTest",
    "LABELS",
    "MAX_GRID_CELLS",
    "OBSTACLE",
    "POSSIBLE",
    "RobotProjector",
    "TileGrid",
    "UNKNOWN",
    "Verdict",
    "camera_collisions",
    "depth_metres",
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
    "verdict",
    "wave_propagation",
    "workspace_depths",
]
