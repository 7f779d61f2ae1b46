"""Repeated public calls on device arrays (warpvx.callmemo) and recorded plans replayed as CUDA
graphs (warpvx.kernels_warp._launch): the replayed call computes what OpenCV computes on the
*current* contents of its inputs, and a call that differs in anything validation sees is
validated again."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from warpvx import check, color, geometry
from warpvx.backend import resolve_backend
from warpvx.errors import ShapeError, WarpvxTypeError

from .images import bgr, clip_frames


def _frames(n):
    """``n`` consecutive real video frames, BGR."""
    return clip_frames(n, size=(640, 272))


def test_replayed_calls_follow_the_input_contents(warp_backend):
    import warp as wp

    frames = _frames(4)
    h, w = frames[0].shape[:2]
    device = resolve_backend(warp_backend).device
    src = wp.array(frames[0], device=device)
    out = wp.empty((h, w), dtype=wp.uint8, device=device)
    warped = wp.empty((h, w, 3), dtype=wp.uint8, device=device)
    M = np.array([[1.01, 0.02, -3.0], [-0.015, 0.99, 2.5], [1e-5, -2e-5, 1.0]])
    for frame in frames:  # same arrays every call, new contents each frame
        src.assign(frame)
        got = color.color_convert(src, "BGR2GRAY", out=out)
        assert got is out
        np.testing.assert_array_equal(out.numpy(), cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY))
        geometry.warp_perspective(src, M, (w, h), out=warped)
        want = cv2.warpPerspective(frame, M, (w, h), flags=cv2.INTER_LINEAR)
        # SPEC §4: exact except on OpenCV's scalar tail columns (documented in geometry).
        assert np.mean(warped.numpy() != want) < 1e-3
        assert np.abs(warped.numpy().astype(int) - want).max() <= 1


def test_second_identical_call_skips_validation(monkeypatch):
    import warp as wp

    img = bgr("coffee")
    src = wp.array(img, device="cpu")
    out = wp.empty(img.shape[:2], dtype=wp.uint8, device="cpu")
    color.color_convert(src, "BGR2GRAY", out=out, backend="warp-cpu")

    def refuse(*a, **k):
        raise AssertionError("validated again")

    monkeypatch.setattr(color, "check_image", refuse)
    color.color_convert(src, "BGR2GRAY", out=out, backend="warp-cpu")  # replayed
    with pytest.raises(AssertionError, match="validated again"):  # another code: validated
        color.color_convert(src, "RGB2GRAY", out=out, backend="warp-cpu")


def test_a_bad_call_after_a_good_one_still_fails(warp_backend):
    import warp as wp

    img = bgr("coffee")
    device = resolve_backend(warp_backend).device
    src = wp.array(img, device=device)
    out = wp.empty(img.shape[:2], dtype=wp.uint8, device=device)
    for _ in range(3):
        color.color_convert(src, "BGR2GRAY", out=out)
    small = wp.empty((img.shape[0] - 1, img.shape[1]), dtype=wp.uint8, device=device)
    with pytest.raises(ShapeError, match="out"):
        color.color_convert(src, "BGR2GRAY", out=small)
    warped = wp.empty(img.shape, dtype=wp.uint8, device=device)
    M = np.eye(3)
    for _ in range(3):
        geometry.warp_perspective(src, M, (img.shape[1], img.shape[0]), out=warped)
    with pytest.raises(WarpvxTypeError, match="inverse_map"):  # 1 == True, but not a bool
        geometry.warp_perspective(src, M, (img.shape[1], img.shape[0]), inverse_map=1, out=warped)


def test_device_matrix_is_never_memoised():
    """A device M may change between calls: its call is keyed by nothing and validated."""
    import warp as wp

    memo = geometry._warp_perspective_memo
    img = bgr("coffee")
    src = wp.array(img, device="cpu")
    out = wp.empty(img.shape, dtype=wp.uint8, device="cpu")
    m_dev = wp.array(np.eye(3, dtype=np.float32), device="cpu")
    assert memo.key((src,), (m_dev,), out, "warp-cpu", None) is None
    assert memo.key((src,), (np.eye(3),), out, "warp-cpu", None) is not None
    assert memo.key((img,), (np.eye(3),), out, "warp-cpu", None) is None  # a host array
    assert memo.key((src,), (np.eye(3),), out, "warp-cpu", "a stream") is None


def test_check_still_names_the_argument():
    """The checker the slow path uses is unchanged (guards the monkeypatch above)."""
    with pytest.raises(ShapeError, match="src"):
        check.check_image(np.zeros((2, 2, 2), np.uint8), "src")
