"""warpvx graphs as ROS 1 nodes (thesis §4.6): the client and the server model.

* Client model (:class:`GraphClient`): subscribe a camera topic, run the graph per message
  (frames in flight, a bounded queue that drops and counts the oldest frame when the graph
  falls behind), publish the outputs. Nodes: ``warpvx ros-stabilize``, ``warpvx ros-orbslam``
  (:mod:`warpvx.ros.nodes`).
* Server model (:class:`GraphServer`): a ROS service (``warpvx/ProcessImage``) runs the graph
  per request; :func:`call_process_image` calls it.
* Conversions (:mod:`warpvx.ros.convert`): sensor_msgs/Image <-> uint8 arrays without a copy
  where the encoding allows (mono8, bgr8, rgb8); poses <-> geometry_msgs/PoseStamped.

An optional part: nothing else in warpvx imports it. ROS 1 comes from the distribution
(``apt-get install python3-rospy ros-core python3-sensor-msgs python3-geometry-msgs
python3-nav-msgs python3-std-msgs``); :func:`~warpvx.ros._env.import_rospy` is the one place
that puts its ``dist-packages`` on ``sys.path`` for other interpreters of the same Python
version. Importing this package needs no ROS; building a client, server or message does.
"""

from ._env import import_rospy
from .client import (FrameQueue, FrameStats, GraphClient, Topic, camera_info_input, image_input,
                     image_output, matrix_output)
from .convert import (ENCODINGS, array_to_image, camera_matrix, image_to_array,
                      matrix_to_multiarray, multiarray_to_matrix, path_message, pose_matrix,
                      pose_message)
from .master import MasterWatchdog
from .server import GraphServer, call_process_image, process_image_service

__all__ = [
    "import_rospy", "MasterWatchdog", "GraphClient", "GraphServer", "call_process_image", "process_image_service",
    "FrameQueue", "FrameStats", "Topic", "image_input", "camera_info_input", "image_output",
    "matrix_output", "ENCODINGS", "image_to_array", "array_to_image", "camera_matrix",
    "matrix_to_multiarray", "multiarray_to_matrix", "pose_message", "pose_matrix", "path_message",
]
