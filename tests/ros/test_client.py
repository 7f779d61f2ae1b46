"""The client model against a real roscore: frames published on a topic, the graph's outputs
received back and compared with running the graph directly; drops, bad frames, a silent camera."""

from __future__ import annotations

import itertools
import time

import numpy as np
import pytest

from tests.ros.conftest import Inbox, wait_connected

_names = itertools.count()


def blur_graph(shape, delay=0.0):
    """gray -> 5x5 Gaussian blur, plus the gray frame; ``delay`` s per frame."""
    import warpvx

    g = warpvx.Graph("ros-test")
    frame = g.input("frame", shape=shape, dtype=np.uint8)
    gray = g.color_convert(frame, code="BGR2GRAY", name="gray")
    if delay:
        def slow(x):
            time.sleep(delay)
            return x.copy()

        gray = g.user(slow, [gray], name="slow")
    g.output("gray", gray)
    g.output("small", g.gaussian_blur(gray, ksize=5, sigma=1.5, name="blur"))
    return g


def topics():
    n = next(_names)
    return f"/test{n}/image", f"/test{n}/out"


def make_client(rospy, graph, topic, out, encoding="bgr8", **kw):
    from warpvx.ros import GraphClient, image_input, image_output

    return GraphClient(graph, {"frame": image_input(topic, encoding)},
                       {"gray": image_output(out + "/gray"), "small": image_output(out + "/small")},
                       dropped_topic=out + "/dropped", publish_queue=50, **kw)


def publish(rospy, topic, frames, encoding="bgr8", period=0.0, wait_for=(), queue_size=None):
    """A publisher of ``frames`` on ``topic`` (stamps 1000, 1001, ...), returned for more;
    its queue holds ``queue_size`` messages (default: the frames and one), more published
    before its thread sends them drop the oldest."""
    from sensor_msgs.msg import Image

    from warpvx.ros import array_to_image

    pub = rospy.Publisher(topic, Image, queue_size=queue_size or len(frames) + 1)
    wait_connected(pub, *wait_for)
    for i, f in enumerate(frames):
        msg = array_to_image(f, encoding)
        msg.header.stamp = rospy.Time(1000 + i)
        pub.publish(msg)
        time.sleep(period)
    return pub


@pytest.mark.parametrize("encoding", ["bgr8", "rgb8"])
def test_outputs_equal_the_graph_run_directly(rospy, bikes, encoding):
    import cv2
    from sensor_msgs.msg import Image

    from warpvx.ros import image_to_array

    topic, out = topics()
    gray_in, small_in = Inbox(rospy, out + "/gray", Image), Inbox(rospy, out + "/small", Image)
    client = make_client(rospy, blur_graph(bikes[0].shape), topic, out, queue_size=len(bikes))
    sent = bikes if encoding == "bgr8" else [cv2.cvtColor(f, cv2.COLOR_BGR2RGB) for f in bikes]
    publish(rospy, topic, sent, encoding, wait_for=(gray_in.sub, small_in.sub))
    grays, smalls = gray_in.wait(len(bikes)), small_in.wait(len(bikes))
    client.close()
    reference = blur_graph(bikes[0].shape)
    for i, (frame, g, s) in enumerate(zip(bikes, grays, smalls)):
        expected = reference.process({"frame": frame})
        assert g.header.stamp == rospy.Time(1000 + i)  # in order, stamped with their frame
        np.testing.assert_array_equal(image_to_array(g), expected["gray"])
        np.testing.assert_array_equal(image_to_array(s), expected["small"])
    assert (client.stats.received, client.stats.processed, client.stats.dropped) == (len(bikes),) * 2 + (0,)


def test_slow_graph_drops_the_oldest_frames_and_counts_them(rospy, bikes):
    from sensor_msgs.msg import Image
    from std_msgs.msg import UInt64

    from warpvx.ros import image_to_array

    topic, out = topics()
    frames = (bikes * 2)[:20]
    gray_in, dropped_in = Inbox(rospy, out + "/gray", Image), Inbox(rospy, out + "/dropped", UInt64)
    # 60 ms per frame, frames every 5 ms, room for one waiting frame: the live-camera case.
    client = make_client(rospy, blur_graph(bikes[0].shape, delay=0.06), topic, out, queue_size=1, depth=1)
    publish(rospy, topic, frames, period=0.005, wait_for=(gray_in.sub, dropped_in.sub))
    deadline = time.monotonic() + 10
    while client.stats.received + 0 < len(frames) or client.stats.processed + client.stats.dropped < len(frames):
        assert time.monotonic() < deadline, client.stats.summary()
        time.sleep(0.02)
    client.close()
    stats = client.stats
    assert stats.received == len(frames) and stats.rejected == 0
    assert stats.dropped >= len(frames) // 2, stats.summary()
    assert stats.processed + stats.dropped == stats.received
    grays = gray_in.wait(stats.processed)
    # The newest frame is never the one dropped; what was processed came in order.
    stamps = [m.header.stamp.secs - 1000 for m in grays]
    assert stamps[-1] == len(frames) - 1 and stamps == sorted(stamps)
    np.testing.assert_array_equal(image_to_array(grays[-1]),
                                  blur_graph(bikes[0].shape).process({"frame": frames[-1]})["gray"])
    assert dropped_in.wait(stats.processed)[-1].data == stats.dropped
    assert f"dropped {stats.dropped}" in stats.summary()


def test_bad_frames_are_rejected_and_logged_and_the_stream_goes_on(rospy, bikes, monkeypatch):
    import cv2
    from sensor_msgs.msg import Image

    from warpvx.ros import array_to_image

    logged = []
    monkeypatch.setattr(rospy, "logerr_throttle_identical", lambda period, text: logged.append(text))
    topic, out = topics()
    gray_in = Inbox(rospy, out + "/gray", Image)
    client = make_client(rospy, blur_graph(bikes[0].shape), topic, out, queue_size=20)
    # Room for all five: three more go out right after these two (a queue of three dropped
    # one on a loaded 2-core machine).
    pub = publish(rospy, topic, bikes[:2], wait_for=(gray_in.sub,), queue_size=6)
    bad = array_to_image(bikes[2], "bgr8")
    bad.encoding = "bgr16"
    pub.publish(bad)
    pub.publish(array_to_image(cv2.resize(bikes[3], (160, 68))))  # the size changes mid-stream
    pub.publish(array_to_image(bikes[4]))
    gray_in.wait(3)
    client.close()
    assert (client.stats.received, client.stats.rejected, client.stats.processed) == (5, 2, 3)
    assert any("frame rejected" in t and "'bgr16'" in t for t in logged), logged
    assert any("frame rejected" in t and "expected shape" in t and "size" in t for t in logged), logged


def test_silent_camera_is_logged_once(rospy, bikes, monkeypatch):
    warnings = []
    monkeypatch.setattr(rospy, "logwarn", warnings.append)
    topic, out = topics()
    client = make_client(rospy, blur_graph(bikes[0].shape), topic, out, watchdog=0.2)
    time.sleep(0.7)
    client.close(timeout=5)
    assert len(warnings) == 1 and "no frame for 0.2 s" in warnings[0] and topic in warnings[0]


def test_frame_queue_drops_the_oldest():
    from warpvx.errors import WarpvxValueError
    from warpvx.ros import FrameQueue

    q = FrameQueue(2)
    assert [q.put(i) for i in range(4)] == [False, False, True, True]
    assert [q.get(0), q.get(0), q.get(0)] == [2, 3, None]
    q.close()
    assert q.get() is FrameQueue.CLOSED
    with pytest.raises(WarpvxValueError, match="queue_size"):
        FrameQueue(0)
