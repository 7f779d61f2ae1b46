"""Keypoints as a struct of arrays, convertible to and from ``cv2.KeyPoint`` lists."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .arrays import is_warp_array
from .backend import init_warp
from .errors import DTypeError, ShapeError, WarpvxTypeError, WarpvxValueError

FIELDS = ("x", "y", "response", "size", "angle", "octave")
_DTYPES = {"x": np.float32, "y": np.float32, "response": np.float32, "size": np.float32,
           "angle": np.float32, "octave": np.int32}


@dataclass
class Keypoints:
    """N keypoints as parallel arrays (all NumPy, or all ``wp.array`` on one device).

    Validated at construction (:meth:`validate`): six 1-D arrays of one length, of the dtypes
    below, all host or all on one device; host coordinates finite. Fields may be reassigned
    later, so public calls taking Keypoints validate them again (:func:`check_keypoints`).

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

    def __post_init__(self):
        self.validate()

    def validate(self, name: str = "keypoints") -> "Keypoints":
        """Check the fields' kinds, shapes, dtypes and lengths (cheap: no copy, no sync), and
        on the host that ``x`` and ``y`` are finite; device values are checked where a public
        call reads them (:func:`check_keypoints`). Returns ``self``.

        Raises
        ------
        WarpvxTypeError, DTypeError, ShapeError, WarpvxValueError
            Naming ``name.field``: not an array, mixed host/device, not 1-D, wrong dtype,
            lengths that differ, NaN/inf coordinates.
        """
        arrays = [getattr(self, f) for f in FIELDS]
        host = isinstance(arrays[0], np.ndarray)
        device = None if host else getattr(arrays[0], "device", None)
        for f, a in zip(FIELDS, arrays):
            if not (isinstance(a, np.ndarray) or is_warp_array(a)):
                raise WarpvxTypeError(f"{name}.{f}: expected a NumPy array or wp.array, got "
                                      f"{type(a).__name__}")
            if isinstance(a, np.ndarray) != host or (not host and a.device != device):
                want = "a NumPy array" if host else f"a wp.array on {device}"
                got = "a NumPy array" if isinstance(a, np.ndarray) else f"a wp.array on {a.device}"
                raise WarpvxValueError(f"{name}.{f}: expected {want} like {name}.x, got {got}")
            if a.ndim != 1:
                raise ShapeError(f"{name}.{f}: expected a 1-D array, got shape {tuple(a.shape)}")
            if not _has_dtype(a, f):
                got = a.dtype if host else getattr(a.dtype, "__name__", a.dtype)
                raise DTypeError(f"{name}.{f}: expected dtype {np.dtype(_DTYPES[f])}, got {got}")
        lengths = [int(a.shape[0]) for a in arrays]
        if len(set(lengths)) > 1:
            each = ", ".join(f"{f} {n}" for f, n in zip(FIELDS, lengths))
            raise ShapeError(f"{name}: expected fields of one length, got {each}")
        if host:
            _check_finite(self, name)
        return self

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
        """Keypoints from :meth:`__warpvx_flatten__`'s arrays (possibly moved or copied), not
        validated again: they are the fields of validated keypoints, moved, copied or cut to
        their count by the runtime (a host check of ``x`` and ``y`` per move was ~0.1 ms of the
        GPU thread per keypoint output per frame in a pipelined graph)."""
        kp = object.__new__(cls)
        kp.__dict__.update(zip(FIELDS, arrays))
        return kp

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


def _has_dtype(a, field: str) -> bool:
    """``a`` (NumPy or Warp, validated kind) has ``field``'s dtype exactly (Warp vector
    dtypes such as ``wp.vec2`` do not pass as their scalar)."""
    if isinstance(a, np.ndarray):
        return a.dtype == _DTYPES[field]
    wp = init_warp()
    return a.dtype is (wp.int32 if field == "octave" else wp.float32)


def _check_finite(kps: Keypoints, name: str) -> None:
    """Host ``kps.x`` and ``kps.y`` hold no NaN or inf."""
    for f in ("x", "y"):
        a = getattr(kps, f)
        if a.size and not np.isfinite(a).all():
            bad = int(np.flatnonzero(~np.isfinite(a))[0])
            raise WarpvxValueError(f"{name}.{f}: expected finite coordinates, got {a[bad]} at "
                                   f"index {bad}")


def check_keypoints(keypoints, name: str = "keypoints", *, n_levels=None) -> Keypoints:
    """Validate Keypoints entering a public call and return them on the host.

    The fields may have been reassigned since construction, so the structure is checked again
    (:meth:`Keypoints.validate`), then on a host copy (one download for device keypoints,
    which every caller makes anyway): finite ``x``, ``y``, and ``0 <= octave < n_levels``
    when the call knows its number of levels.

    Raises
    ------
    WarpvxTypeError
        ``keypoints`` is not a :class:`Keypoints`.
    DTypeError, ShapeError, WarpvxValueError
        As :meth:`Keypoints.validate`; an octave out of range.
    """
    if not isinstance(keypoints, Keypoints):
        raise WarpvxTypeError(f"{name}: expected Keypoints, got {type(keypoints).__name__}")
    host = keypoints.validate(name).to("host")
    if not keypoints.is_host:
        _check_finite(host, name)
    if n_levels is not None and len(host):
        lo, hi = int(host.octave.min()), int(host.octave.max())
        if lo < 0 or hi >= n_levels:
            bad = lo if lo < 0 else hi
            raise WarpvxValueError(f"{name}.octave: expected values in [0, {n_levels - 1}], "
                                   f"got {bad}")
    return host
