"""Time-bounded free space (SPEC section 8a): which voxels the cameras see free now, and a memory of when a person
could next be in each voxel, so that space seen free a moment ago stays free while no one can have reached it."""

from depthguard.freespace._memory import FreeSpaceMemory, VoxelBox, seen_free_voxels, squared_distance_transform

__all__ = ["FreeSpaceMemory", "VoxelBox", "seen_free_voxels", "squared_distance_transform"]
