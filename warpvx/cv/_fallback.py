"""Calls warpvx.cv does not accelerate run on cv2 itself, with a one-time warning.

A drop-in must not break working OpenCV code: an argument, mode or dtype outside warpvx's subset
(``cvtColor(img, COLOR_BGR2HSV)``, a float image, a ``cv2.UMat``, ORB's ``WTA_K=3``...) hands
that call to the same-named cv2 function or method, and :class:`CvFallbackWarning` says so once
per function and argument. Input cv2 rejects as well still raises warpvx's error naming the
argument; calls on Warp arrays are never handed over (cv2 cannot read them).
"""

from __future__ import annotations

import functools
import warnings

import cv2 as _cv2

from ..arrays import is_warp_array
from ..errors import DTypeError, UnsupportedError

# Errors that mean "outside warpvx's subset" rather than "bad input": cv2 gets the call.
_HANDED_OVER = (UnsupportedError, DTypeError)
_warned: set = set()


class CvFallbackWarning(UserWarning):
    """A warpvx.cv call ran on cv2 (an argument, mode or dtype warpvx does not accelerate)."""


def warn_once(func: str, reason: str) -> None:
    """Warn once per ``func`` and argument (the text of ``reason`` before its first colon)."""
    arg = reason.split(":", 1)[0].strip()
    if (func, arg) in _warned:
        return
    _warned.add((func, arg))
    warnings.warn(f"{func}({arg}) runs on cv2: {reason}", CvFallbackWarning, stacklevel=4)


def _values(args, kwargs):
    for v in (*args, *kwargs.values()):
        yield from (v if isinstance(v, (list, tuple)) else (v,))


def _has_umat(args, kwargs) -> bool:
    return any(isinstance(v, _cv2.UMat) for v in _values(args, kwargs))


def _has_warp(args, kwargs) -> bool:
    return any(is_warp_array(v) for v in _values(args, kwargs))


def _call(func, accelerated, cv2_callable, args, kwargs):
    """``accelerated(*args, **kwargs)``, or cv2's on UMat input or an error of _HANDED_OVER."""
    if _has_umat(args, kwargs):
        warn_once(func, "UMat: cv2.UMat input")
        return cv2_callable()(*args, **kwargs)
    try:
        return accelerated()
    except _HANDED_OVER as e:
        if _has_warp(args, kwargs):
            raise
        try:
            result = cv2_callable()(*args, **kwargs)
        except _cv2.error as cv_error:
            raise e from cv_error  # bad for cv2 too: warpvx's error names the argument
        warn_once(func, str(e))
        return result


def function(fn):
    """Decorate a drop-in of the same-named cv2 function (``backend=`` is warpvx's alone)."""
    name = fn.__name__

    @functools.wraps(fn)
    def call(*args, backend=None, **kwargs):
        return _call(name, lambda: fn(*args, backend=backend, **kwargs),
                     lambda: getattr(_cv2, name), args, kwargs)

    return call


def method(fn):
    """Decorate a method of a drop-in class whose ``_cv2_twin()`` builds the equivalent cv2
    object (same parameters): that object's same-named method gets handed-over calls."""
    name = fn.__name__

    @functools.wraps(fn)
    def call(self, *args, **kwargs):
        return _call(f"{type(self).__name__}.{name}", lambda: fn(self, *args, **kwargs),
                     lambda: getattr(self._cv2_twin(), name), args, kwargs)

    return call


__all__ = ["CvFallbackWarning"]
