"""Several depth cameras fused through the principal camera's depth grid (2016 paper, corrected by design §8)."""

from depthguard.depthgrid._fusion import FusedFrames, free_image, fused_distances, seen_free
from depthguard.depthgrid._map import DepthGridMap, MapError, build_map, grid_range, load_map, save_map

__all__ = ["DepthGridMap", "FusedFrames", "MapError", "build_map", "free_image", "fused_distances", "grid_range",
           "load_map", "save_map", "seen_free"]
