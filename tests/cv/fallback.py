"""Test helper: a warpvx.cv call handed to cv2 (CvFallbackWarning naming the argument)."""

from __future__ import annotations

import contextlib
import re

import pytest

from warpvx.cv import CvFallbackWarning
from warpvx.cv import _fallback


@contextlib.contextmanager
def runs_on_cv2(arg: str):
    """The block's warpvx.cv call must run on cv2, warning that ``arg`` is why (the once-only
    registry is cleared first so the warning is seen)."""
    _fallback._warned.clear()
    with pytest.warns(CvFallbackWarning, match=rf"\({re.escape(arg)}\) runs on cv2"):
        yield
