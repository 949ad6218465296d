"""Distances computed directly in one camera's depth space (2015 paper, corrected by SPEC sections 4-6)."""

from depthguard.depthspace._distance import check_points, single_camera_distances
from depthguard.depthspace._frustum import frustum_distance, paper_frustum_distance

__all__ = ["check_points", "frustum_distance", "paper_frustum_distance", "single_camera_distances"]
