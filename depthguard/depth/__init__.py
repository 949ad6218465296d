"""Depth images: files, frames tied to cameras and times, and what each pixel says is possibly occupied."""

from depthguard.depth._image import DepthImage, depth_image, load_depth
from depthguard.depth._io import read_depth_file, read_intensity_png, write_depth_pgm, write_depth_png
from depthguard.depth._prepare import OccupancyImage, prepare_depth

__all__ = [
    "DepthImage",
    "OccupancyImage",
    "depth_image",
    "load_depth",
    "prepare_depth",
    "read_depth_file",
    "read_intensity_png",
    "write_depth_pgm",
    "write_depth_png",
]
