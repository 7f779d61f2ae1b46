"""Keypoints as a struct of arrays, convertible to and from ``cv2.KeyPoint`` lists."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .arrays import is_warp_array
from .backend import init_warp
from .errors import ShapeError, WarpvxTypeError

FIELDS = ("x", "y", "response", "size", "angle", "octave")
_DTYPES = {"x": np.float32, "y": np.float32, "response": np.float32, "size": np.float32,
           "angle": np.float32, "octave": np.int32}


@dataclass
class Keypoints:
    """N keypoints as parallel arrays (all NumPy, or all ``wp.array`` on one device).

    Attributes
    ----------
    x, y : float32 [N]
        Position in pixels, level-0 coordinates, pixel centres at integers (OpenCV's).
    response : float32 [N]
        Detector score (FAST score, Harris response).
    size : float32 [N]
        Diameter of the meaningful neighbourhood in pixels.
    angle : float32 [N]
        Orientation in degrees [0, 360), -1 when none.
    octave : int32 [N]
        Pyramid level the keypoint was found on.
    """

    x: object
    y: object
    response: object
    size: object
    angle: object
    octave: object

    @classmethod
    def empty(cls) -> "Keypoints":
        return cls(**{f: np.zeros(0, _DTYPES[f]) for f in FIELDS})

    @classmethod
    def from_arrays(cls, x, y, response=None, size=None, angle=None, octave=None,
                    default_size=7.0) -> "Keypoints":
        """Host keypoints from coordinates; missing fields get OpenCV's defaults."""
        x = np.ascontiguousarray(x, np.float32).reshape(-1)
        n = x.shape[0]

        def col(v, fill, name):
            if v is None:
                return np.full(n, fill, _DTYPES[name])
            arr = np.ascontiguousarray(v, _DTYPES[name]).reshape(-1)
            if arr.shape[0] != n:
                raise ShapeError(f"{name}: expected {n} values (one per x), got {arr.shape[0]}")
            return arr

        return cls(x=x, y=col(y, 0, "y"), response=col(response, 0, "response"),
                   size=col(size, default_size, "size"), angle=col(angle, -1, "angle"),
                   octave=col(octave, 0, "octave"))

    def __warpvx_flatten__(self) -> tuple:
        """``(arrays, aux)``: the six field arrays in :data:`FIELDS` order, no aux (the
        runtime's flatten protocol, :func:`warpvx.runtime.tree_map`)."""
        return tuple(getattr(self, f) for f in FIELDS), None

    @classmethod
    def __warpvx_unflatten__(cls, aux, arrays) -> "Keypoints":
        """Keypoints from :meth:`__warpvx_flatten__`'s arrays (possibly moved or copied)."""
        return cls(*arrays)

    def __len__(self) -> int:
        return int(self.x.shape[0])

    @property
    def is_host(self) -> bool:
        return isinstance(self.x, np.ndarray)

    @property
    def device(self) -> str:
        return "host" if self.is_host else str(self.x.device)

    def to(self, device: str) -> "Keypoints":
        """Copy to ``"host"`` (NumPy) or a Warp device (``"cpu"``, ``"cuda:0"``)."""
        if device == "host":
            if self.is_host:
                return self
            return Keypoints(**{f: getattr(self, f).numpy() for f in FIELDS})
        wp = init_warp()
        target = wp.get_device(device)
        fields = [getattr(self, f) for f in FIELDS]
        if all(is_warp_array(a) and a.device is target for a in fields):
            return self  # already there: the common case on a device pipeline's hot path
        out = {}
        for f, a in zip(FIELDS, fields):
            if is_warp_array(a):
                out[f] = a if a.device is target else a.to(target)
            else:
                out[f] = wp.array(np.ascontiguousarray(a), device=target)
        return Keypoints(**out)

    def numpy(self) -> "Keypoints":
        return self.to("host")

    def xy(self) -> np.ndarray:
        """float32 [N, 2] host array of (x, y)."""
        h = self.to("host")
        return np.stack([h.x, h.y], axis=1).astype(np.float32)

    def take(self, index) -> "Keypoints":
        """Host keypoints at ``index`` (an integer array or boolean mask)."""
        h = self.to("host")
        return Keypoints(**{f: np.ascontiguousarray(getattr(h, f)[index]) for f in FIELDS})

    def to_cv(self) -> list:
        """A list of ``cv2.KeyPoint``."""
        import cv2

        h = self.to("host")
        return [
            cv2.KeyPoint(float(h.x[i]), float(h.y[i]), float(h.size[i]), float(h.angle[i]),
                         float(h.response[i]), int(h.octave[i]))
            for i in range(len(h))
        ]

    @classmethod
    def from_cv(cls, keypoints) -> "Keypoints":
        """From an iterable of ``cv2.KeyPoint`` (host arrays)."""
        kps = list(keypoints)
        for k in kps:
            if not hasattr(k, "pt"):
                raise WarpvxTypeError(f"keypoints: expected cv2.KeyPoint items, got {type(k).__name__}")
        return cls(
            x=np.array([k.pt[0] for k in kps], np.float32),
            y=np.array([k.pt[1] for k in kps], np.float32),
            response=np.array([k.response for k in kps], np.float32),
            size=np.array([k.size for k in kps], np.float32),
            angle=np.array([k.angle for k in kps], np.float32),
            octave=np.array([k.octave for k in kps], np.int32),
        )
