"""``warpvx ros-stabilize`` and ``warpvx ros-orbslam`` as node processes on a real roscore:
what they publish equals the offline computation on the same frames."""

from __future__ import annotations

import numpy as np
import pytest

from tests.ros.conftest import Inbox, stop, wait_connected
from tests.ros.test_client import publish


def test_ros_stabilize_equals_the_offline_app(rospy, bikes, node_process):
    from sensor_msgs.msg import Image
    from std_msgs.msg import Float64MultiArray

    from warpvx.apps.stabilize import StabilizerConfig, stabilize
    from warpvx.ros import image_to_array, multiarray_to_matrix

    n, config = len(bikes), StabilizerConfig(window=5, mode="centered")
    images, warps = Inbox(rospy, "/stab/image", Image), Inbox(rospy, "/stab/warp", Float64MultiArray)
    proc = node_process("ros-stabilize", "__name:=stab", "image:=/camera/image", "_window:=5",
                        "_mode:=centered", f"_queue_size:={n}", f"_publish_queue:={n}")
    publish(rospy, "/camera/image", bikes, wait_for=(images.sub, warps.sub))
    got, got_warps = images.wait(n - config.lag), warps.wait(n - config.lag)
    output = stop(proc)
    offline = list(stabilize(bikes, config, backend="cpu"))
    for k, (msg, warp) in enumerate(zip(got, got_warps)):
        assert msg.header.stamp == rospy.Time(1000 + k)  # frame k shows input frame k
        np.testing.assert_array_equal(image_to_array(msg), offline[k].image)
        np.testing.assert_array_equal(multiarray_to_matrix(warp), offline[k].warp)
    assert len(got) == n - config.lag  # the live node does not flush the centred window
    assert f"received {n}, processed {n}" in output and "dropped 0" in output, output[-2000:]


def test_ros_orbslam_equals_the_offline_front_end(rospy, castle, node_process):
    """The node's poses are the ORB-SLAM front end app's (warpvx.apps.orbslam) run offline on
    the same frames with the K the node got from CameraInfo; two frames in flight."""
    from geometry_msgs.msg import PoseStamped
    from nav_msgs.msg import Path
    from sensor_msgs.msg import CameraInfo
    from std_msgs.msg import UInt32

    import warpvx
    from warpvx.apps.orbslam import Camera, TrackerConfig, track_frames
    from warpvx.ros import pose_matrix

    frames, K = castle
    n = len(frames)
    poses, path, counts = (Inbox(rospy, "/slam/pose", PoseStamped), Inbox(rospy, "/slam/path", Path),
                           Inbox(rospy, "/slam/keypoints", UInt32))
    info = rospy.Publisher("/cam/camera_info", CameraInfo, queue_size=1, latch=True)
    info.publish(CameraInfo(K=K.ravel().tolist(), width=frames[0].shape[1], height=frames[0].shape[0]))
    proc = node_process("ros-orbslam", "__name:=slam", "image:=/cam/image",
                        "camera_info:=/cam/camera_info", "_n_features:=1000", "_depth:=2",
                        f"_queue_size:={n}", f"_publish_queue:={n}")
    wait_connected(info)
    publish(rospy, "/cam/image", frames, encoding="mono8", wait_for=(poses.sub, path.sub, counts.sub))
    got = poses.wait(n)
    got_counts = [m.data for m in counts.wait(n)]
    last_path = path.wait(n)[-1]
    output = stop(proc)
    offline = list(track_frames(({"image": f} for f in frames), Camera(K, frames[0].shape[::-1]),
                                TrackerConfig(n_features=1000), backend="cpu"))
    assert got_counts == [len(warpvx.orb(f, n_features=1000, backend="cpu")[0]) for f in frames]
    for k, (msg, frame) in enumerate(zip(got, offline)):
        assert msg.header.stamp == rospy.Time(1000 + k) and msg.header.frame_id == "world"
        np.testing.assert_allclose(pose_matrix(msg), frame.pose, rtol=0, atol=1e-9)
    # The camera moved, and the node's first pose is the identity, so the world is frame 0.
    assert not np.allclose(offline[-1].pose, np.eye(4)) and np.allclose(pose_matrix(got[0]), np.eye(4))
    assert [m.header.stamp for m in last_path.poses] == [m.header.stamp for m in got]
    assert f"received {n}, processed {n}" in output, output[-2000:]


def test_node_help_and_bad_arguments(roscore):
    from tests.isolated import run_python

    code = "import sys; from warpvx.cli import main; sys.exit(main(sys.argv[1:]))"
    for node in ("ros-stabilize", "ros-orbslam"):
        done = run_python(f"import sys; sys.argv[1:] = ['{node}', '--help']; {code}", ".", timeout=60)
        assert done.returncode == 0 and "~backend" in done.stdout and "~queue_size" in done.stdout
    done = run_python(f"import sys; sys.argv[1:] = ['ros-stabilize', 'stray']; {code}", ".", timeout=60)
    assert done.returncode == 2 and "unexpected arguments ['stray']" in done.stderr
