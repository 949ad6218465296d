"""Time-bounded free space (design §8a): which voxels the cameras see free now, and a memory of when a person
could next be in each voxel, so that space seen free a moment ago stays free while no one can have reached it; and,
for speed and separation monitoring, where in the possibly occupied space a ball the size of the cameras' detection
capability fits."""

from depthguard.freespace._detectable import (
    closed_faces,
    DetectableSpace,
    FreeSources,
    robot_inside_voxels,
    robot_voxels,
    solid_voxels,
)
from depthguard.kernels.detectable import or_coarse
from depthguard.freespace._near import surface_voxels, voxels_within
from depthguard.freespace._memory import (
    CameraViews,
    FreeSpaceMemory,
    VoxelBox,
    remember_frames,
    seen_free_voxels,
    squared_distance_transform,
)

__all__ = [
    "CameraViews",
    "DetectableSpace",
    "FreeSources",
    "FreeSpaceMemory",
    "VoxelBox",
    "closed_faces",
    "or_coarse",
    "remember_frames",
    "robot_inside_voxels",
    "robot_voxels",
    "seen_free_voxels",
    "solid_voxels",
    "squared_distance_transform",
    "surface_voxels",
    "voxels_within",
]
