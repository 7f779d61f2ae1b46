"""The runnable nodes: ``warpvx ros-stabilize`` and ``warpvx ros-orbslam``.

Both are client-model nodes (:class:`~warpvx.ros.client.GraphClient`) taking ROS remapping
arguments (``image:=/camera/image_raw``, ``__name:=stab``) and private parameters
(``_window:=31`` on the command line, or ``rosparam``/launch files)::

    warpvx ros-stabilize image:=/camera/image_raw _window:=15 _mode:=causal
    warpvx ros-orbslam image:=/camera/image_raw camera_info:=/camera/camera_info

``ros-stabilize`` subscribes ``image`` (sensor_msgs/Image: bgr8, rgb8 or mono8) and publishes
``~image`` (the stabilized frame, bgr8, stamped with the input frame it shows) and ``~warp``
(std_msgs/Float64MultiArray 3x3: the smoothed motion correction applied to that frame, input ->
output pixels). Parameters: ``~backend`` (cpu | warp-cpu | cuda), ``~window``, ``~mode``
(``causal`` by default: a live camera has no look-ahead; ``centered`` lags window // 2 frames),
``~crop``, ``~motion``, ``~detector``, and the client's ``~queue_size``, ``~depth``, ``~watchdog``,
``~publish_queue`` (:class:`~warpvx.ros.client.GraphClient`).

``ros-orbslam`` subscribes ``image`` and ``camera_info`` (sensor_msgs/CameraInfo; frames wait
for the first one) and publishes ``~pose`` (geometry_msgs/PoseStamped, camera in the first
camera's frame ``~world_frame``), ``~path`` (nav_msgs/Path, every pose so far) and
``~keypoints`` (std_msgs/UInt32). Parameters: ``~backend``, ``~n_features``, ``~world_frame``
and the client's. It runs the front end of ``warpvx orbslam`` (:mod:`warpvx.apps.orbslam`:
ORB on the GPU role, Hamming matching, tracking on the CPU with its state in a delay, so
``~depth`` frames may be in flight), monocular: the trajectory is right up to one global scale.
The graph is built on the first frame with the camera info's K; a later K is not applied.

Both publish ``~dropped`` (std_msgs/UInt64, frames skipped at the processing rate so far) and
log a frame summary at shutdown. Faults are logged and the node goes on: a camera publisher
that stops (a warning after ``~watchdog`` s of silence, a line when frames come again), and
roscore going away (``~master_check``: seconds between checks; one error line when the master is
unreachable, one when it is back, :class:`~warpvx.ros.master.MasterWatchdog`). Ctrl-C (SIGINT)
stops the node with or without a master.
"""

from __future__ import annotations

import sys

import numpy as np

from ._env import import_rospy, msg as _msg
from .client import GraphClient, Topic, camera_info_input, image_input, image_output, matrix_output
from .master import MasterWatchdog

NODES = ("ros-stabilize", "ros-orbslam")


def _params(rospy, defaults: dict) -> dict:
    """Private parameters ``~name`` over ``defaults`` (their types kept)."""
    return {name: type(value)(rospy.get_param(f"~{name}", value)) for name, value in defaults.items()}


_CLIENT = {"queue_size": 2, "depth": 2, "watchdog": 5.0, "publish_queue": 10}
#: Parameters of the node itself: seconds between checks that roscore is still there.
_NODE = {"master_check": 2.0}


def _client_args(p):
    return {k: p[k] for k in _CLIENT if k in p}


def stabilize_client(params: dict) -> GraphClient:
    """The ``ros-stabilize`` client for parameters ``params`` (keys as the ``~`` parameters)."""
    from ..apps.stabilize import StabilizerConfig, build_graph, schedule

    config = StabilizerConfig(window=params["window"], mode=params["mode"], crop=params["crop"],
                              motion=params["motion"], detector=params["detector"])
    backend = params["backend"]

    def make(first):
        graph = build_graph(first["frame"].shape[1::-1], config, backend=backend)
        schedule(graph, backend)
        return graph

    return GraphClient(make, {"frame": image_input("image", "bgr8")},
                       {"stabilized": image_output("~image", "bgr8"), "warp": matrix_output("~warp")},
                       constants={"live": np.ones(1, np.uint8)}, lag=config.lag, **_client_args(params))


STABILIZE_PARAMS = {"backend": "cpu", "window": 15, "mode": "causal", "crop": 0.1,
                    "motion": "homography", "detector": "harris", **_CLIENT, **_NODE}


def orbslam_client(params: dict) -> GraphClient:
    """The ``ros-orbslam`` client for parameters ``params`` (keys as the ``~`` parameters): the
    front-end graph of :mod:`warpvx.apps.orbslam` (monocular), built on the first frame with the
    intrinsics of the latest camera info."""
    from ..apps.orbslam import Camera, TrackerConfig, build_graph, schedule
    from .convert import path_message, pose_message

    backend, world = params["backend"], params["world_frame"]
    config = TrackerConfig(n_features=params["n_features"])
    poses = []

    def make(first):
        image = first["image"]
        graph = build_graph(Camera(first["K"], image.shape[::-1]), config, backend=backend)
        schedule(graph, backend)
        return graph

    def post(outputs, inputs, header):
        poses.append(pose_message(outputs["pose"], header, world))
        # The message replaces the graph's 4x4 "pose" output; stats[0] is n_keypoints.
        return {"pose": poses[-1], "path": poses, "count": int(outputs["stats"][0])}

    return GraphClient(
        make, {"image": image_input("image", "mono8"), "K": camera_info_input("camera_info")},
        {"pose": Topic("~pose", ("geometry_msgs", "PoseStamped"), lambda pose, header: pose),
         "path": Topic("~path", ("nav_msgs", "Path"), lambda path, header: path_message(path, world)),
         "count": Topic("~keypoints", ("std_msgs", "UInt32"),
                        lambda n, header: _msg("std_msgs", "UInt32")(n))},
        post=post, **_client_args(params))


ORBSLAM_PARAMS = {"backend": "cpu", "n_features": 2000, "world_frame": "world", **_CLIENT, **_NODE}

_NODES = {"ros-stabilize": ("warpvx_stabilize", STABILIZE_PARAMS, stabilize_client),
          "ros-orbslam": ("warpvx_orbslam", ORBSLAM_PARAMS, orbslam_client)}


def main(command: str, argv) -> int:
    """Run node ``command`` (one of :data:`NODES`) until ROS shuts down (Ctrl-C, rosnode
    kill); ``argv`` holds ROS remappings and ``_param:=value`` settings."""
    name, defaults, make = _NODES[command]
    if {"-h", "--help"} & set(argv):
        doc = __doc__.split("\n\n", 1)[1]
        params = ", ".join(f"~{k} ({v!r})" for k, v in defaults.items())
        print(f"usage: warpvx {command} [ROS remappings] [_param:=value ...]\n\n{doc}\n"
              f"Parameters and defaults: {params}")
        return 0
    rospy = import_rospy()
    rospy.init_node(name, argv=[f"warpvx-{command}", *argv])
    extra = rospy.myargv([f"warpvx-{command}", *argv])[1:]
    if extra:
        print(f"warpvx {command}: error: unexpected arguments {extra} (ROS remappings look like "
              f"name:=/topic, parameters _name:=value)", file=sys.stderr)
        return 2
    params = _params(rospy, defaults)
    master = MasterWatchdog(params["master_check"])
    client = make(params)
    rospy.on_shutdown(client.close)
    rospy.on_shutdown(master.close)
    rospy.loginfo(f"warpvx {command}: running on {rospy.resolve_name('image')}")
    rospy.spin()
    return 0
