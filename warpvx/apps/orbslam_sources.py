"""Camera sequences for the ORB-SLAM2 front end (:mod:`warpvx.apps.orbslam`): KITTI odometry and
TUM RGB-D folders, image folders and videos (:func:`open_source`), and the intrinsics they need
(:func:`parse_intrinsics`: ``fx,fy,cx,cy``, OpenCV YAML/XML, KITTI ``calib.txt``)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from ..errors import WarpvxValueError
from .orbslam import Camera
from .video_io import IMAGE_EXTENSIONS, VideoSource


def parse_intrinsics(text) -> np.ndarray:
    """K (float64 3x3) from ``"fx,fy,cx,cy"`` or a file: OpenCV YAML/XML with ``camera_matrix``
    (or ``K``, ``cameraMatrix``), a KITTI ``calib.txt`` (its P0), or text starting with
    ``fx fy cx cy``."""
    text = os.fspath(text)
    if not os.path.isfile(text):
        try:
            fx, fy, cx, cy = (float(v) for v in text.split(","))
        except ValueError:
            raise WarpvxValueError(f"intrinsics: expected fx,fy,cx,cy or a file, got {text!r}") from None
        K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    elif text.lower().endswith((".yml", ".yaml", ".xml")):
        import cv2

        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ)
        node = next((fs.getNode(k) for k in ("camera_matrix", "K", "cameraMatrix")
                     if not fs.getNode(k).empty()), None)
        K = None if node is None else node.mat()
        fs.release()
        if K is None or np.asarray(K).size != 9:
            raise WarpvxValueError(f"intrinsics: {text!r} has no 3x3 camera_matrix (or K) node")
        K = np.asarray(K, np.float64).reshape(3, 3)
    else:
        calib = _read_calib(text, required=False)
        if "P0" in calib:
            K = np.ascontiguousarray(calib["P0"][:, :3])  # OpenCV's USAC refuses a strided K
        else:
            try:
                values = [float(v) for v in open(text).read().replace(",", " ").split()[:4]]
            except ValueError:
                values = []
            if len(values) != 4:
                raise WarpvxValueError(f"intrinsics: {text!r}: expected 'fx fy cx cy' numbers")
            fx, fy, cx, cy = values
            K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    if not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise WarpvxValueError(f"intrinsics: expected positive finite focal lengths, got {K[0, 0]}, {K[1, 1]}")
    return K


def _read_calib(path, required=True) -> dict:
    """``{"P0": 3x4, ...}`` from a KITTI ``calib.txt``."""
    out = {}
    with open(path) as f:
        for line in f:
            key, _, rest = line.partition(":")
            if not rest:
                continue
            try:
                values = [float(v) for v in rest.split()]
            except ValueError:
                raise WarpvxValueError(f"calib: {os.fspath(path)!r}: line {key!r} is not numbers") from None
            if key.strip().startswith("P"):
                if len(values) != 12:
                    raise WarpvxValueError(f"calib: {os.fspath(path)!r}: {key.strip()} needs 12 numbers, "
                                           f"got {len(values)}")
                out[key.strip()] = np.asarray(values).reshape(3, 4)
    if required and "P0" not in out:
        raise WarpvxValueError(f"calib: {os.fspath(path)!r} has no 'P0:' line")
    return out


def _images(folder):
    return sorted(str(p) for p in Path(folder).iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS)


class Sequence:
    """A camera sequence: ``camera`` (:class:`Camera`), ``times`` (float64 [N] s), ``count``,
    ``kind`` (``"kitti"``, ``"tum"``, ``"images"``, ``"video"``); iterate for input dicts
    (gray uint8 ``image`` [and ``right``]). Read with :func:`open_source`."""

    def __init__(self, kind, camera, times, left, right=None, video=None):
        self.kind, self.camera, self.times = kind, camera, np.asarray(times, np.float64)
        self._left, self._right, self._video = left, right, video
        self.count = len(self.times)
        self.read_ms = 0.0

    def _read(self, path):
        import cv2

        img = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise WarpvxValueError(f"source: cannot read image {path!r}")
        if img.shape[::-1] != tuple(self.camera.size):
            raise WarpvxValueError(f"source: {path!r} is {img.shape[1]}x{img.shape[0]}, expected "
                                   f"{self.camera.size[0]}x{self.camera.size[1]} like the first image")
        return img

    def __iter__(self):
        import cv2

        if self._video is not None:
            for k, frame in zip(range(self.count), self._video):
                t = time.perf_counter()
                img = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
                self.read_ms += 1e3 * (time.perf_counter() - t)
                yield {"image": img}
            return
        for k in range(self.count):
            t = time.perf_counter()
            item = {"image": self._read(self._left[k])}
            if self._right is not None:
                item["right"] = self._read(self._right[k])
            self.read_ms += 1e3 * (time.perf_counter() - t)
            yield item


def open_source(path, intrinsics=None, max_frames=None) -> Sequence:
    """Open SOURCE: a KITTI odometry folder (``image_0/``, ``calib.txt``, optional
    ``times.txt``, ``image_1/`` for stereo), a TUM RGB-D folder (``rgb.txt``), an image folder,
    or a video; the last three need ``intrinsics`` (see :func:`parse_intrinsics`).

    Raises a warpvx error naming what is wrong (missing folder or calibration, no images,
    a video OpenCV cannot open, missing intrinsics)."""
    import cv2

    path = os.fspath(path)
    if not os.path.exists(path):
        raise WarpvxValueError(f"source: no such file or folder {path!r}")
    K = parse_intrinsics(intrinsics) if intrinsics is not None else None
    cap = lambda n: n if max_frames is None else min(n, max_frames)  # noqa: E731
    root = Path(path)
    if root.is_dir() and (root / "image_0").is_dir():
        left = _images(root / "image_0")
        if not left:
            raise WarpvxValueError(f"source: no images in {str(root / 'image_0')!r}")
        if not (root / "calib.txt").is_file():
            raise WarpvxValueError(f"source: KITTI folder {path!r} has no calib.txt")
        calib = _read_calib(root / "calib.txt")
        K = calib["P0"][:, :3] if K is None else K
        right, baseline = None, None
        if (root / "image_1").is_dir():
            right = _images(root / "image_1")
            if "P1" not in calib:
                raise WarpvxValueError(f"calib: {str(root / 'calib.txt')!r} has no 'P1:' line for image_1/")
            baseline = -calib["P1"][0, 3] / calib["P1"][0, 0]
            if not baseline > 0 or len(right) < len(left):
                raise WarpvxValueError(f"calib: expected a positive baseline and one image_1/ image "
                                       f"per image_0/ image, got baseline {baseline:g}, "
                                       f"{len(right)} vs {len(left)} images")
        n = cap(len(left))
        times = np.arange(n) * 0.1
        if (root / "times.txt").is_file():
            t = np.loadtxt(root / "times.txt", ndmin=1)
            if len(t) >= n:
                times = t[:n]
        first = cv2.imread(left[0], cv2.IMREAD_GRAYSCALE)
        if first is None:
            raise WarpvxValueError(f"source: cannot read image {left[0]!r}")
        return Sequence("kitti", Camera(K, first.shape[::-1], baseline), times, left, right)
    if K is None:
        raise WarpvxValueError(f"intrinsics: {path!r} is not a KITTI folder; give --intrinsics "
                               f"fx,fy,cx,cy (or a file)")
    if root.is_dir() and (root / "rgb.txt").is_file():
        rows = [ln.split() for ln in (root / "rgb.txt").read_text().splitlines()
                if ln.strip() and not ln.startswith("#")]
        if not rows:
            raise WarpvxValueError(f"source: {str(root / 'rgb.txt')!r} lists no image")
        rows = rows[:cap(len(rows))]
        files = [str(root / r[1]) for r in rows]
        first = cv2.imread(files[0], cv2.IMREAD_GRAYSCALE)
        if first is None:
            raise WarpvxValueError(f"source: cannot read image {files[0]!r}")
        return Sequence("tum", Camera(K, first.shape[::-1]), [float(r[0]) for r in rows], files)
    video = VideoSource(path, max_frames)
    kind = "images" if root.is_dir() else "video"
    count = video.count if video.count is not None else (max_frames or 10 ** 9)
    return Sequence(kind, Camera(K, tuple(video.size)), np.arange(count) / video.fps, None, video=video)


__all__ = ["parse_intrinsics", "Sequence", "open_source"]
