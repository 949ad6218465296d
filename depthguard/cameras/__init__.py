"""Cameras and rigs: pinhole intrinsics, poses, valid ranges, noise models, rig and camera_info files."""

from depthguard.cameras._noise import NoiseModel
from depthguard.cameras._pinhole import PinholeCamera
from depthguard.cameras._rig import Rig, load_camera_info, load_rig, rig_from_dict, save_rig

__all__ = ["NoiseModel", "PinholeCamera", "Rig", "load_camera_info", "load_rig", "rig_from_dict", "save_rig"]
