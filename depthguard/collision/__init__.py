"""The image-based multi-camera collision test of Henrich & Gecks (SPEC section 10; issue 10, in progress).

Built so far: tile grids and the epipolar bands between cameras (step 5's geometry), the obstacle image (Table I), the
revised obstacle image (Table III, C cameras, occlusion threshold theta), the intersection image (Table II) and the
verdict with its class A-D (Table IV). Not yet: the difference images from intensity or depth (steps 1-2), the robot's
tile images (step 3), swept volumes, pick-and-place, the configuration-space tables and the planner, the command line.
"""

from depthguard.collision._epipolar import EpipolarBands, TileGrid, workspace_depths
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
    "ERROR",
    "EpipolarBands",
    "LABELS",
    "OBSTACLE",
    "POSSIBLE",
    "TileGrid",
    "UNKNOWN",
    "Verdict",
    "camera_collisions",
    "intersection_image",
    "obstacle_image",
    "revised_obstacle_images",
    "verdict",
    "workspace_depths",
]
