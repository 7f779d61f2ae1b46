"""Shared assertions and helpers for the kernel tests (one definition, used everywhere)."""

from __future__ import annotations

import numpy as np

from warpvx.backend import init_warp, resolve_backend


def assert_images_match(out, ref, *, max_diff: int = 1, min_equal: float = 0.999):
    """SPEC §4 bar for images: every pixel within ``max_diff`` of OpenCV's; and, since our
    arithmetic reproduces OpenCV's, at least ``min_equal`` of the pixels exactly equal."""
    out = np.asarray(out)
    assert out.shape == ref.shape and out.dtype == ref.dtype, (out.shape, out.dtype, ref.shape, ref.dtype)
    diff = np.abs(out.astype(np.int16) - ref.astype(np.int16))
    assert diff.max() <= max_diff, f"max diff {diff.max()}"
    assert (diff == 0).mean() >= min_equal, f"equal: {(diff == 0).mean():.5f}"


def crop(img: np.ndarray, h: int, w: int) -> np.ndarray:
    """A C-contiguous top-left ``h`` x ``w`` crop (odd sizes from real photos)."""
    return np.ascontiguousarray(img[:h, :w])


def on_device(img: np.ndarray, backend: str):
    """``img`` as the backend takes it natively: NumPy for ``cpu``, else a ``wp.array``."""
    be = resolve_backend(backend)
    return img if be.kind == "cpu" else init_warp().array(img, device=be.device)


def assert_bench_cases_match_opencv(cases, backend: str, *, n_cases: int, peers=("cvcuda", "kornia")):
    """Each benchmark case computes what its OpenCV twin computes (so the bench compares like
    with like), declares the bytes it moves, and offers the expected peers."""
    from warpvx.arrays import to_numpy

    assert len(cases) == n_cases
    for case in cases:
        assert case.bytes_moved and case.bytes_moved > 0
        ours = to_numpy(case.prepare(backend)())
        ref = case.opencv()()
        diff = np.abs(ours.astype(np.int16) - ref.astype(np.int16))
        assert ours.shape == ref.shape and diff.max() <= 1, case.label
        assert set(case.peers) == set(peers)
