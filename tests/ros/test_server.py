"""The server model against a real roscore: a ``warpvx/ProcessImage`` service answers with
what the graph computes, fails a bad request clearly and keeps serving."""

from __future__ import annotations

import numpy as np
import pytest

from tests.images import bgr
from tests.ros.test_client import blur_graph


@pytest.fixture(scope="module")
def server(rospy):
    from warpvx.ros import GraphServer

    image = bgr("coffee")
    srv = GraphServer(blur_graph(image.shape), "/test_server/process", input="frame",
                      output="small", encoding="bgr8")
    yield srv
    srv.close()


def test_answers_with_the_graph_result(server, rospy):
    import cv2

    from warpvx.ros import call_process_image

    image = bgr("coffee")
    expected = blur_graph(image.shape).process({"frame": image})["small"]
    np.testing.assert_array_equal(call_process_image("/test_server/process", image), expected)
    # An rgb8 request is converted to what the graph takes.
    rgb = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(call_process_image("/test_server/process", rgb, encoding="rgb8"),
                                  expected)


def test_bad_request_fails_clearly_and_the_server_goes_on(server, rospy):
    from warpvx.ros import call_process_image

    calls, failures = server.calls, server.failures
    with pytest.raises(rospy.ServiceException, match="expected shape"):
        call_process_image("/test_server/process", bgr("chelsea"))  # another size
    from warpvx.ros import array_to_image, process_image_service

    bad = array_to_image(bgr("coffee"))
    bad.encoding = "16UC1"
    proxy = rospy.ServiceProxy("/test_server/process", process_image_service())
    with pytest.raises(rospy.ServiceException, match="'16UC1' is not supported"):
        proxy(image=bad)
    proxy.close()
    assert (server.calls - calls, server.failures - failures) == (2, 2)
    assert call_process_image("/test_server/process", bgr("coffee")).shape == (400, 600)


def test_missing_service_times_out(rospy):
    from warpvx.ros import call_process_image

    with pytest.raises(rospy.ROSException, match="timeout"):
        call_process_image("/no/such/service", bgr("coffee"), timeout=0.3)


def test_service_type_md5_is_that_of_the_srv_text(ros_available):
    """The generated type hashes as genmsg hashes a ProcessImage.srv of the documented text,
    so a compiled client in another language interoperates."""
    import hashlib

    from sensor_msgs.msg import Image

    from warpvx.ros import process_image_service

    service = process_image_service()
    request = f"{Image._md5sum} image"  # genmsg's MD5 text of "sensor_msgs/Image image"
    assert service._md5sum == hashlib.md5((request + request).encode()).hexdigest()
    assert service._request_class._type == "warpvx/ProcessImageRequest"
