"""Live input (design §12b): depth frames and joint states from ROS 2 topics, through zenoh, answered as they come.

- :class:`FrameSetLoop`, :class:`JointHistory`: the one frame-set loop of ``live`` and ``replay`` (grouping by
  stamp, carried frames, the joint history), with no middleware in it.
- :mod:`depthguard.live.wire`: rmw_zenoh's and zenoh-bridge-ros2dds' keys, type hashes, attachments and liveliness
  tokens, and CDR through ``rosbags``: strings and bytes, no middleware.
- :class:`LiveNode`: the node ``depthguard live`` runs (zenoh subscribers, one worker, the outputs).

The middleware (``eclipse-zenoh``) is an optional extra, ``pip install 'depthguard[live]'``, imported only when a
:class:`LiveNode` is made.
"""

from depthguard.live import wire
from depthguard.live._node import LiveNode, LiveOptions, Topics
from depthguard.live._sets import RESULT_COLUMNS, FrameSet, FrameSetLoop, JointHistory, SetAnswer, answer_set

__all__ = ["RESULT_COLUMNS", "FrameSet", "FrameSetLoop", "JointHistory", "LiveNode", "LiveOptions", "SetAnswer", "Topics",
           "answer_set", "wire"]
