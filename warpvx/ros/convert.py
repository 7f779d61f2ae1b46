"""ROS messages to and from NumPy arrays: ``sensor_msgs`` images and camera info,
``std_msgs`` matrices, ``geometry_msgs``/``nav_msgs`` poses and paths.

Incoming images are read without a copy where the encoding allows: the array is a read-only
view of ``msg.data`` (the bytes rospy deserialised), rows ``msg.step`` bytes apart, so a padded
row stride is a strided view (the graph copies a strided input once, to a contiguous one).
Converting to another channel order or to gray is one ``cv2.cvtColor``. Outgoing images cost
one copy (``ndarray.tobytes``): genpy serialises ``uint8[]`` fields from ``bytes`` only.

Encodings: ``mono8`` (uint8 HxW), ``bgr8`` and ``rgb8`` (uint8 HxWx3), the ``sensor_msgs/
image_encodings`` names; any other raises :class:`~warpvx.errors.UnsupportedError`.
"""

from __future__ import annotations

import numpy as np

from ..errors import ShapeError, UnsupportedError, WarpvxTypeError
from ._env import msg as _msg

#: Channels per supported encoding.
ENCODINGS = {"mono8": 1, "bgr8": 3, "rgb8": 3}

# cv2 colour codes between supported encodings (source, destination).
_CONVERSIONS = {
    ("mono8", "bgr8"): "COLOR_GRAY2BGR", ("mono8", "rgb8"): "COLOR_GRAY2RGB",
    ("bgr8", "mono8"): "COLOR_BGR2GRAY", ("rgb8", "mono8"): "COLOR_RGB2GRAY",
    ("bgr8", "rgb8"): "COLOR_BGR2RGB", ("rgb8", "bgr8"): "COLOR_RGB2BGR",
}


def check_encoding(encoding, name: str = "encoding") -> int:
    """Channels of a supported ``encoding``; raises UnsupportedError naming ``name`` otherwise."""
    if encoding not in ENCODINGS:
        raise UnsupportedError(f"{name}: image encoding {encoding!r} is not supported; "
                               f"expected one of {sorted(ENCODINGS)}")
    return ENCODINGS[encoding]


def image_to_array(msg, encoding: str | None = None) -> np.ndarray:
    """The pixels of a ``sensor_msgs/Image`` as uint8 HxW (mono8) or HxWx3 (bgr8, rgb8).

    Parameters
    ----------
    msg : sensor_msgs/Image
        ``height``, ``width``, ``encoding``, ``step`` (bytes per row, >= width x channels),
        ``data`` (at least ``step x height`` bytes).
    encoding : str, optional
        Wanted encoding; None keeps the message's own. Equal to the message's: a read-only
        view of ``msg.data`` (no copy). Different: one ``cv2.cvtColor`` into a new array.

    Raises
    ------
    UnsupportedError
        ``msg.encoding`` or ``encoding`` outside mono8/bgr8/rgb8.
    ShapeError
        ``msg.step`` shorter than a row, ``msg.data`` shorter than ``step x height``.
    """
    channels = check_encoding(msg.encoding, "msg.encoding")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    if h < 1 or w < 1:
        raise ShapeError(f"msg: expected an image of at least 1x1, got {w}x{h}")
    if step < w * channels:
        raise ShapeError(f"msg.step: expected >= width x channels = {w * channels} bytes for "
                         f"{msg.encoding} {w}x{h}, got {step}")
    data = msg.data
    if isinstance(data, (list, tuple)):  # a message built by hand with a list of ints
        data = bytes(data)
    if len(data) < step * h:
        raise ShapeError(f"msg.data: expected >= step x height = {step * h} bytes, got {len(data)}")
    shape = (h, w) if channels == 1 else (h, w, channels)
    strides = (step, 1) if channels == 1 else (step, channels, 1)
    view = np.ndarray(shape, np.uint8, buffer=data, strides=strides)
    if encoding is None or encoding == msg.encoding:
        return view
    check_encoding(encoding)
    import cv2

    return cv2.cvtColor(view, getattr(cv2, _CONVERSIONS[(msg.encoding, encoding)]))


def array_to_image(image, encoding: str | None = None, header=None):
    """A ``sensor_msgs/Image`` of uint8 ``image`` (HxW: mono8; HxWx3: bgr8 unless ``encoding``
    says rgb8), ``step`` = width x channels, ``header`` copied when given.

    Raises
    ------
    WarpvxTypeError
        ``image`` is not a NumPy array.
    UnsupportedError, ShapeError
        An unsupported ``encoding``, or one whose channel count ``image`` does not have; a
        dtype other than uint8 (mono16 and float encodings are not supported).
    """
    if not isinstance(image, np.ndarray):
        raise WarpvxTypeError(f"image: expected a NumPy array, got {type(image).__name__}")
    if encoding is None:
        encoding = "mono8" if image.ndim == 2 else "bgr8"
    channels = check_encoding(encoding)
    if image.dtype != np.uint8:
        raise UnsupportedError(f"image: expected uint8 for {encoding}, got {image.dtype}")
    want = (2,) if channels == 1 else (3,)
    if image.ndim not in want or (channels > 1 and image.shape[2] != channels) or 0 in image.shape:
        raise ShapeError(f"image: expected {'HxW' if channels == 1 else 'HxWx3'} for {encoding}, "
                         f"got shape {image.shape}")
    out = _msg("sensor_msgs", "Image")()
    if header is not None:
        out.header = header
    out.height, out.width = image.shape[:2]
    out.encoding = encoding
    out.is_bigendian = 0
    out.step = image.shape[1] * channels
    out.data = image.tobytes()
    return out


def camera_matrix(info) -> np.ndarray:
    """The intrinsics K of a ``sensor_msgs/CameraInfo`` as float64 3x3 (row-major ``info.K``).

    Raises
    ------
    ShapeError
        ``info.K`` is not 9 numbers, or fx, fy are not positive (an uncalibrated camera sends
        zeros).
    """
    k = np.asarray(info.K, np.float64)
    if k.shape != (9,) or not np.isfinite(k).all() or k[0] <= 0 or k[4] <= 0:
        raise ShapeError(f"camera_info.K: expected 9 finite numbers with fx, fy > 0 (a calibrated "
                         f"camera), got {list(k)}")
    return k.reshape(3, 3)


def matrix_to_multiarray(matrix):
    """A ``std_msgs/Float64MultiArray`` of a 2-D array (layout dims ``rows``, ``cols``)."""
    m = np.asarray(matrix, np.float64)
    out = _msg("std_msgs", "Float64MultiArray")()
    dim = _msg("std_msgs", "MultiArrayDimension")
    out.layout.dim = [dim(label="rows", size=m.shape[0], stride=m.size),
                      dim(label="cols", size=m.shape[1], stride=m.shape[1])]
    out.data = m.ravel().tolist()
    return out


def multiarray_to_matrix(msg) -> np.ndarray:
    """The float64 2-D array of a ``std_msgs/Float64MultiArray`` from :func:`matrix_to_multiarray`."""
    dims = [d.size for d in msg.layout.dim]
    return np.asarray(msg.data, np.float64).reshape(dims)


def pose_message(pose, header, frame_id: str):
    """A geometry_msgs/PoseStamped of camera-to-world 4x4 ``pose`` (stamp from ``header``)."""
    import cv2

    out = _msg("geometry_msgs", "PoseStamped")()
    out.header.stamp, out.header.frame_id = header.stamp, frame_id
    rvec = cv2.Rodrigues(np.ascontiguousarray(pose[:3, :3]))[0].ravel()
    angle = float(np.linalg.norm(rvec))
    axis = rvec / angle if angle > 0 else np.zeros(3)
    q = out.pose.orientation
    q.x, q.y, q.z = (axis * np.sin(angle / 2)).tolist()
    q.w = float(np.cos(angle / 2))
    p = out.pose.position
    p.x, p.y, p.z = pose[:3, 3].tolist()
    return out


def pose_matrix(msg) -> np.ndarray:
    """The camera-to-world float64 4x4 of a geometry_msgs/Pose(Stamped)."""
    import cv2

    pose = getattr(msg, "pose", msg)
    q, p = pose.orientation, pose.position
    half = np.arccos(np.clip(q.w, -1.0, 1.0))
    s = np.sin(half)
    rvec = np.array([q.x, q.y, q.z]) / s * 2 * half if s > 1e-12 else np.zeros(3)
    out = np.eye(4)
    out[:3, :3] = cv2.Rodrigues(rvec)[0]
    out[:3, 3] = p.x, p.y, p.z
    return out


def path_message(poses: list, frame_id: str):
    """A nav_msgs/Path of PoseStamped messages ``poses`` (the header: the last pose's stamp)."""
    out = _msg("nav_msgs", "Path")()
    out.header.frame_id = frame_id
    if poses:
        out.header.stamp = poses[-1].header.stamp
    out.poses = list(poses)
    return out
