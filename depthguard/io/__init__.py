"""Every file format depthguard reads or writes, in one package.

- :mod:`depthguard.io.files`: the one place a user's file is opened. Bounded reads of regular files only, YAML and
  JSON parsed without running code, and writes that land whole or not at all (:func:`files.atomic_write`,
  :func:`files.write_whole`, :func:`files.atomic_folder`).
- :mod:`depthguard.io.images`: depth images (16-bit PNG and PGM in the camera's units, ``.npy``, float TIFF) and
  intensity PNGs, as arrays.
- :mod:`depthguard.io.points`: control points (CSV ``x,y,z`` or a JSON list, metres, world frame).
- :mod:`depthguard.io.ros_messages`: ROS 2 messages (``sensor_msgs/Image`` ``16UC1``/``32FC1``, ``CameraInfo``,
  ``JointState``) decoded and checked against the rig, and written: one decoder for bags and live topics.
- :mod:`depthguard.io.recordings`: recordings, as folders and as ROS 2 bags (MCAP or sqlite3, with ROS 2 message
  types: ``sensor_msgs/Image`` ``16UC1``/``32FC1``, ``CameraInfo``, ``JointState``), read and written.

The schemas of a rig (``depthguard.load_rig``), a depth grid map (``depthguard.depthgrid.load_map``) and a URDF
(``RobotModel.from_urdf``) are checked where those types live; their bytes are read through :mod:`files`.

This module imports only the lower three: ``recordings`` builds rigs and depth images, so import it as
``depthguard.io.recordings`` (or use ``depthguard.open_recording``).
"""

from depthguard.io import files, images, points

__all__ = ["files", "images", "points"]
