"""Depth images: files, frames tied to cameras and times, and what each pixel says is possibly occupied."""

from depthguard.depth._image import DepthImage, checked_frame, depth_image, load_depth
from depthguard.io.images import npy_header, read_depth_file, read_intensity_png, write_depth_pgm, write_depth_png
from depthguard.kernels.depth import block_minimum
from depthguard.depth._prepare import OccupancyImage, filled_space, prepare_depth

__all__ = [
    "DepthImage",
    "OccupancyImage",
    "block_minimum",
    "checked_frame",
    "depth_image",
    "filled_space",
    "load_depth",
    "npy_header",
    "prepare_depth",
    "read_depth_file",
    "read_intensity_png",
    "write_depth_pgm",
    "write_depth_png",
]
