"""Distances computed directly in one camera's depth space (2015 paper, corrected by design §4-6)."""

from depthguard.depthspace._distance import check_options, check_points, query_arrays, single_camera_distances
from depthguard.depthspace._frustum import frustum_distance, paper_frustum_distance

__all__ = ["check_options", "check_points", "frustum_distance", "paper_frustum_distance", "query_arrays",
           "single_camera_distances"]
