"""Faults a running node meets, against real ROS processes: its camera publisher dies
mid-stream and comes back; its roscore goes away and comes back. Each is one clear log line,
the node goes on, and nothing hangs (every wait is bounded)."""

from __future__ import annotations

import signal
import time

import numpy as np
import pytest

from tests.ros.conftest import (WAIT, Inbox, _free_port, kill_roscore, start_roscore, stop,
                                wait_connected, wait_output)
from tests.ros.test_client import blur_graph, make_client, publish, topics

#: A camera node in its own process: publishes the frame in argv[2] (a .npy file, bgr8) on
#: topic argv[1] every 20 ms, header stamps counting from 1000 s, until it is killed.
CAMERA = """
import sys, time
import numpy as np
from warpvx.ros import array_to_image, import_rospy
rospy = import_rospy()
from sensor_msgs.msg import Image
rospy.init_node("camera", anonymous=True)
pub = rospy.Publisher(sys.argv[1], Image, queue_size=1)
frame, k = np.load(sys.argv[2]), 0
while not rospy.is_shutdown():
    msg = array_to_image(frame, "bgr8")
    msg.header.stamp = rospy.Time(1000 + k)
    pub.publish(msg)
    k += 1
    time.sleep(0.02)
"""


def _until(condition, what, timeout=WAIT):
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            pytest.fail(f"{what} within {timeout} s")
        time.sleep(0.02)


def test_dead_publisher_is_logged_once_and_the_client_resumes(rospy, bikes, node_process,
                                                              tmp_path, monkeypatch):
    """The camera process is SIGKILLed mid-stream (no unregistering): one warning after the
    watchdog's silence, none while it stays dead; a new publisher's frames are processed again."""
    from sensor_msgs.msg import Image

    from warpvx.ros import image_to_array

    warnings, infos = [], []
    monkeypatch.setattr(rospy, "logwarn", warnings.append)
    monkeypatch.setattr(rospy, "loginfo", infos.append)
    topic, out = topics()
    gray_in = Inbox(rospy, out + "/gray", Image)
    client = make_client(rospy, blur_graph(bikes[0].shape), topic, out, watchdog=0.3)
    np.save(tmp_path / "frame.npy", bikes[0])
    camera = node_process(topic, str(tmp_path / "frame.npy"), code=CAMERA)
    _until(lambda: client.stats.processed >= 5, "5 frames of the camera process processed")
    warnings.clear()  # the silence while the camera process started is not this test's
    infos.clear()
    camera.send_signal(signal.SIGKILL)
    camera.wait(WAIT)
    processed = client.stats.processed
    _until(lambda: warnings, "a warning that the camera is silent")
    time.sleep(1.0)  # > 3 watchdog periods of silence: still one line
    assert len(warnings) == 1 and topic in warnings[0] and "publisher gone?" in warnings[0], warnings
    assert client.stats.processed == processed and not any("frames again" in t for t in infos)

    publish(rospy, topic, bikes[1:4], wait_for=(gray_in.sub,))  # a camera comes back
    _until(lambda: client.stats.processed >= processed + 3, "the new publisher's 3 frames processed")
    client.close()
    assert any("frames again" in t and topic in t for t in infos), infos
    assert len(warnings) == 1, warnings
    expected = blur_graph(bikes[0].shape).process({"frame": bikes[3]})["gray"]
    last = gray_in.wait(processed + 3)[-1]
    np.testing.assert_array_equal(image_to_array(last), expected)
    assert client.stats.rejected == client.stats.errors == 0


def test_roscore_going_away_is_logged_and_sigint_still_stops_the_node(ros_available, rospy, bikes,
                                                                      node_process, tmp_path):
    """A node on its own roscore: the roscore is killed (SIGKILL, a crash) -> one error line;
    restarted on the same port -> one line saying it is back but lost the node's registrations;
    killed again -> SIGINT stops the node within a bounded time, with its frame summary."""
    import rosgraph

    port = _free_port()
    uri = f"http://127.0.0.1:{port}"
    log = tmp_path / "roscore.log"
    core = start_roscore(port, log)
    try:
        node = node_process("ros-stabilize", "__name:=faulty", "image:=/faulty/camera",
                            "_master_check:=0.2", env={"ROS_MASTER_URI": uri})
        master = rosgraph.Master("/warpvx_fault_test", master_uri=uri)
        _until(lambda: node.poll() is None and ["/faulty/image", "sensor_msgs/Image"]
               in master.getPublishedTopics(""), "the node's /faulty/image registered")
        kill_roscore(core, signal.SIGKILL)
        wait_output(node, f"ROS master at {uri} unreachable")
        core = start_roscore(port, log)
        wait_output(node, f"ROS master at {uri} reachable again")
        kill_roscore(core, signal.SIGKILL)
        _until(lambda: sum("unreachable" in line for line in node.lines) == 2,
               "a second 'unreachable' line")
        started = time.monotonic()
        output = stop(node, timeout=15)
        took = time.monotonic() - started
    finally:
        kill_roscore(core)
    assert node.returncode == 0, output[-3000:]
    assert took < 15, f"SIGINT took {took:.1f} s without a master"
    assert output.count("unreachable") == 2 and output.count("reachable again") == 1, output[-3000:]
    assert "was restarted" in output and "restart the node" in output, output[-3000:]
    assert "received 0, processed 0" in output, output[-3000:]  # the client's summary at shutdown
