"""depthguard: how far a robot is from anything it does not know, computed in the depth space of its cameras.

Typical use::

    import depthguard as dg
    rig = dg.load_rig("rig.yaml")
    depth = dg.load_depth("frame.png", rig.cameras["right"])
    monitor = dg.DistanceMonitor(rig, rho=0.4, aggregate="hybrid")
    result = monitor.query({"right": depth}, points_world)   # (n, 3) metres, world frame
"""

from depthguard._background import LiveMonitor
from depthguard._monitor import DistanceMonitor, PreparedSet
from depthguard._settings import MonitorSettings
from depthguard.cameras import NoiseModel, PinholeCamera, Rig, load_camera_info, load_rig, rig_from_dict, save_rig
from depthguard.depth import DepthImage, OccupancyImage, depth_image, load_depth, prepare_depth, read_depth_file
from depthguard.depthspace import frustum_distance, paper_frustum_distance, single_camera_distances
from depthguard.errors import DepthguardError, DepthImageError, InputError, RigError, WriteError
from depthguard.results import DetectableResult, DistanceResult, Flag
from depthguard.io.recordings import Recording, open_recording

__version__ = "0.1.0"

__all__ = [
    "DepthImage",
    "DepthImageError",
    "DetectableResult",
    "DepthguardError",
    "DistanceMonitor",
    "DistanceResult",
    "Flag",
    "InputError",
    "LiveMonitor",
    "MonitorSettings",
    "NoiseModel",
    "OccupancyImage",
    "PinholeCamera",
    "PreparedSet",
    "Recording",
    "Rig",
    "RigError",
    "depth_image",
    "frustum_distance",
    "load_camera_info",
    "load_depth",
    "load_rig",
    "open_recording",
    "paper_frustum_distance",
    "prepare_depth",
    "read_depth_file",
    "rig_from_dict",
    "save_rig",
    "single_camera_distances",
    "WriteError",
]
