"""sensor_msgs/Image <-> arrays: views without copies, encodings, bad input (no roscore)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.images import bgr
from warpvx.errors import ShapeError, UnsupportedError, WarpvxTypeError

ENCODED = {"bgr8": lambda im: im, "rgb8": lambda im: cv2.cvtColor(im, cv2.COLOR_BGR2RGB),
           "mono8": lambda im: cv2.cvtColor(im, cv2.COLOR_BGR2GRAY)}


@pytest.fixture(scope="module")
def ros(ros_available):
    import warpvx.ros

    warpvx.ros.import_rospy()
    return warpvx.ros


@pytest.mark.parametrize("encoding", sorted(ENCODED))
def test_round_trip_is_a_view(ros, encoding):
    image = ENCODED[encoding](bgr("chelsea"))  # 451 wide: odd
    msg = ros.array_to_image(image, encoding)
    assert (msg.encoding, msg.height, msg.width, msg.step) == (
        encoding, 300, 451, 451 * (1 if encoding == "mono8" else 3))
    back = ros.image_to_array(msg)
    np.testing.assert_array_equal(back, image)
    # No copy: the array reads the message's bytes.
    assert np.shares_memory(back, np.frombuffer(msg.data, np.uint8))
    assert not back.flags.writeable


@pytest.mark.parametrize("src", sorted(ENCODED))
@pytest.mark.parametrize("dst", sorted(ENCODED))
def test_conversion_matches_opencv(ros, src, dst):
    image = bgr("rocket")
    out = ros.image_to_array(ros.array_to_image(ENCODED[src](image), src), dst)
    if src == "mono8" and dst != "mono8":  # gray stays gray in every channel
        expected = np.repeat(ENCODED["mono8"](image)[..., None], 3, axis=2)
    else:
        expected = ENCODED[dst](image)
    np.testing.assert_array_equal(out, expected)


def test_padded_rows(ros):
    """A row stride longer than the row (aligned rows) is read as a strided view."""
    image = bgr("coffee")
    h, w, _ = image.shape
    padded = np.zeros((h, w * 3 + 13), np.uint8)
    padded[:, :w * 3] = image.reshape(h, -1)
    msg = ros.array_to_image(image, "bgr8")
    msg.step, msg.data = w * 3 + 13, padded.tobytes()
    view = ros.image_to_array(msg)
    np.testing.assert_array_equal(view, image)
    assert np.shares_memory(view, np.frombuffer(msg.data, np.uint8))


@pytest.mark.parametrize("encoding", ["bgr16", "32FC1", "bayer_rggb8", "yuv422", ""])
def test_unsupported_encoding(ros, encoding):
    msg = ros.array_to_image(bgr("coffee"), "bgr8")
    msg.encoding = encoding
    with pytest.raises(UnsupportedError, match=r"msg\.encoding.*mono8"):
        ros.image_to_array(msg)
    with pytest.raises(UnsupportedError, match="encoding"):
        ros.image_to_array(ros.array_to_image(bgr("coffee")), encoding)


def test_bad_messages_and_arrays(ros):
    msg = ros.array_to_image(bgr("coffee"), "bgr8")
    msg.step = msg.width * 3 - 1
    with pytest.raises(ShapeError, match=r"msg\.step"):
        ros.image_to_array(msg)
    msg = ros.array_to_image(bgr("coffee"), "bgr8")
    msg.data = msg.data[:-1]
    with pytest.raises(ShapeError, match=r"msg\.data"):
        ros.image_to_array(msg)
    with pytest.raises(ShapeError, match="image"):
        ros.array_to_image(bgr("coffee"), "mono8")
    with pytest.raises(UnsupportedError, match="uint8"):
        ros.array_to_image(bgr("coffee").astype(np.uint16))
    with pytest.raises(WarpvxTypeError, match="image"):
        ros.array_to_image([[1, 2]])


def test_camera_matrix_and_multiarray(ros):
    from sensor_msgs.msg import CameraInfo

    K = np.array([[700.0, 0, 320], [0, 701, 240], [0, 0, 1]])
    np.testing.assert_array_equal(ros.camera_matrix(CameraInfo(K=K.ravel().tolist())), K)
    with pytest.raises(ShapeError, match=r"camera_info\.K"):
        ros.camera_matrix(CameraInfo())  # uncalibrated: zeros
    M = np.arange(12.0).reshape(3, 4) / 7
    np.testing.assert_array_equal(ros.multiarray_to_matrix(ros.matrix_to_multiarray(M)), M)
