"""Distances computed directly in one camera's depth space (2015 paper, corrected by design §4-6)."""

from depthguard.depthspace._distance import query_arrays, single_camera_distances
from depthguard.validation import check_options, check_points
from depthguard.depthspace._frustum import frustum_distance, paper_frustum_distance

__all__ = ["check_options", "check_points", "frustum_distance", "paper_frustum_distance", "query_arrays",
           "single_camera_distances"]
