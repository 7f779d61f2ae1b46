"""Video input and output shared by the apps: :class:`VideoSource` (a video file or an image
folder, BGR uint8 HxWx3 frames) and :func:`open_writer` (a ``cv2.VideoWriter``)."""

from __future__ import annotations

import os

from ..errors import WarpvxValueError

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm")


class VideoSource:
    """Frames of a video file (anything OpenCV opens) or of an image folder (sorted names).

    Raises a warpvx error naming ``path`` when it is missing, unreadable or holds no frame.
    Attributes: ``size`` (w, h), ``fps``, ``count`` (frames to expect, or None), ``first``.
    """

    def __init__(self, path, max_frames=None):
        import cv2

        self.path = os.fspath(path)
        self.max_frames = max_frames
        self.fps = 25.0
        self._cap = None
        if os.path.isdir(self.path):
            self._files = sorted(os.path.join(self.path, f) for f in os.listdir(self.path)
                                 if f.lower().endswith(IMAGE_EXTENSIONS))
            if not self._files:
                raise WarpvxValueError(f"input: no images ({', '.join(IMAGE_EXTENSIONS)}) in folder {self.path!r}")
            self.count = len(self._files)
        elif os.path.isfile(self.path):
            self._files = None
            self._cap = cv2.VideoCapture(self.path)
            if not self._cap.isOpened():
                raise WarpvxValueError(f"input: OpenCV cannot open {self.path!r} as a video")
            self.fps = self._cap.get(cv2.CAP_PROP_FPS) or 25.0
            n = int(self._cap.get(cv2.CAP_PROP_FRAME_COUNT))
            self.count = n if n > 0 else None
        else:
            raise WarpvxValueError(f"input: no such file or folder {self.path!r}")
        self._it = self._read()
        self.first = next(self._it, None)
        if self.first is None:
            raise WarpvxValueError(f"input: {self.path!r} holds no readable frame")
        self.size = self.first.shape[1::-1]
        if max_frames is not None and (self.count is None or self.count > max_frames):
            self.count = max_frames

    def _read(self):
        import cv2

        n = 0
        while self.max_frames is None or n < self.max_frames:
            if self._files is not None:
                if n >= len(self._files):
                    return
                frame = cv2.imread(self._files[n], cv2.IMREAD_COLOR)
                if frame is None:
                    raise WarpvxValueError(f"input: cannot read image {self._files[n]!r}")
            else:
                ok, frame = self._cap.read()
                if not ok:
                    return
            n += 1
            yield frame

    def __iter__(self):
        if self.first is not None:
            yield self.first
            self.first = None
        yield from self._it


def open_writer(path, size, fps):
    """A ``cv2.VideoWriter`` for ``path``: MJPG for ``.avi``, mp4v otherwise (the codecs the
    headless OpenCV wheels write)."""
    import cv2

    fourcc = "MJPG" if str(path).lower().endswith(".avi") else "mp4v"
    writer = cv2.VideoWriter(os.fspath(path), cv2.VideoWriter_fourcc(*fourcc), fps, tuple(size))
    if not writer.isOpened():
        raise WarpvxValueError(f"output: OpenCV cannot write a {fourcc} video to {os.fspath(path)!r}")
    return writer


__all__ = ["IMAGE_EXTENSIONS", "VideoSource", "open_writer"]
