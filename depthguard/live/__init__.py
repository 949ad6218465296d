"""Live input (design §12b): depth frames and joint states from ROS 2 topics, through zenoh, answered as they come.

- :class:`FrameSetLoop`, :class:`JointHistory`: the one frame-set loop of ``live`` and ``replay`` (grouping by stamp, the joint
  history, ages), with no middleware in it.

The middleware (``eclipse-zenoh``) is an optional extra, ``pip install 'depthguard[live]'``, imported only by the
node that needs it.
"""

from depthguard.live._sets import FrameSet, FrameSetLoop, JointHistory

__all__ = ["FrameSet", "FrameSetLoop", "JointHistory"]
