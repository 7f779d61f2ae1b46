"""Benchmark (and test) inputs made from a real photo: the photo at a size, its gray and NV12
versions, lens-undistortion maps and a mild homography."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def load_photo() -> np.ndarray:
    """The benchmark photo, BGR uint8: scikit-image's astronaut, else the bundled copy."""
    return load_photo_with_source()[0]


def load_photo_with_source() -> tuple[np.ndarray, dict]:
    """The benchmark photo (BGR uint8, HxWx3) and where it came from: ``{"name", "source",
    "size"}``, size as ``"WxH"`` before any resizing (recorded in ``warpvx bench``'s JSON)."""
    import cv2

    try:
        from skimage import data

        img = np.ascontiguousarray(cv2.cvtColor(data.astronaut(), cv2.COLOR_RGB2BGR))
        source = "skimage.data.astronaut()"
    except ImportError:
        path = Path(__file__).resolve().parent.parent / "data" / "astronaut_448.png"
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if img is None:
            raise FileNotFoundError(f"bundled benchmark image missing: {path}") from None
        source = "warpvx/data/astronaut_448.png (bundled; scikit-image not installed)"
    return img, {"name": "astronaut", "source": source, "size": f"{img.shape[1]}x{img.shape[0]}"}


def photo_at(photo: np.ndarray, size) -> np.ndarray:
    """``photo`` resized to (width, height), BGR uint8, C-contiguous."""
    import cv2

    w, h = size
    interp = cv2.INTER_AREA if w * h < photo.shape[0] * photo.shape[1] else cv2.INTER_CUBIC
    return np.ascontiguousarray(cv2.resize(photo, (w, h), interpolation=interp))


def gray_of(image_bgr: np.ndarray) -> np.ndarray:
    """``image_bgr`` (HxWx3 uint8) as a C-contiguous HxW uint8 gray image (``cv2.cvtColor``)."""
    import cv2

    return np.ascontiguousarray(cv2.cvtColor(image_bgr, cv2.COLOR_BGR2GRAY))


def bgr_to_nv12(image_bgr: np.ndarray) -> np.ndarray:
    """An NV12 plane ((H*3/2) x W) of a BGR image cropped to even size (OpenCV's encoder)."""
    import cv2

    h, w = image_bgr.shape[0] & ~1, image_bgr.shape[1] & ~1
    i420 = cv2.cvtColor(np.ascontiguousarray(image_bgr[:h, :w]), cv2.COLOR_BGR2YUV_I420)
    flat = i420.ravel()  # Y plane, then the U and V planes of (H/2)*(W/2) bytes each
    q = (h // 2) * (w // 2)
    u = flat[h * w:h * w + q].reshape(h // 2, w // 2)
    v = flat[h * w + q:].reshape(h // 2, w // 2)
    uv = np.stack([u, v], axis=-1).reshape(h // 2, w)
    return np.ascontiguousarray(np.vstack([i420[:h], uv]))


def undistort_maps(width: int, height: int):
    """float32 (map_x, map_y) undistorting a plausible wide-angle camera (for benchmarks/tests):
    focal 0.8*width, centre slightly off, k1 = -0.28, k2 = 0.08, small tangential terms."""
    import cv2

    k = np.array([[0.8 * width, 0, width / 2 + 3.5], [0, 0.8 * width, height / 2 - 2.25], [0, 0, 1]])
    dist = np.array([-0.28, 0.08, 1e-3, -5e-4, 0.0])
    return cv2.initUndistortRectifyMap(k, dist, None, k, (width, height), cv2.CV_32FC1)


def mild_homography(width: int, height: int) -> np.ndarray:
    """A mild src->dst homography (small rotation, scale, shear and perspective)."""
    a = np.deg2rad(3.0)
    return np.array([
        [1.02 * np.cos(a), -np.sin(a), 0.03 * width],
        [np.sin(a), 0.98 * np.cos(a), -0.02 * height],
        [2e-5, -3e-5, 1.0],
    ])
