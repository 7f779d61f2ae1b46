"""Batched ORB extraction (``warpvx.orb`` on a list or a [B, H, W] stack): each image's result
is bit for bit the single-image call's, on every backend, for every input form; bad batches
raise warpvx errors naming ``src[i]``."""

from __future__ import annotations

import os

import cv2
import numpy as np
import pytest

import warpvx
from warpvx import DTypeError, ShapeError, WarpvxTypeError, WarpvxValueError
from tests.images import clip_frames, gray

FIELDS = ("x", "y", "response", "size", "angle", "octave")
KITTI = (1241, 376)  # KITTI's left camera (w, h)
CASTLE = "/work/shared/data/real/castle_simu/image_0"


def _host(result):
    kps, desc = result
    return kps.to("host"), desc if isinstance(desc, np.ndarray) else desc.numpy()


def _device(backend):
    return "cpu" if backend == "warp-cpu" else backend


def assert_identical(got, want):
    """Every keypoint field and descriptor byte equal, bit for bit (floats compared as bits)."""
    (kg, dg), (kw, dw) = _host(got), _host(want)
    for f in FIELDS:
        a, b = np.asarray(getattr(kg, f)), np.asarray(getattr(kw, f))
        assert a.dtype == b.dtype and a.shape == b.shape, f
        assert a.tobytes() == b.tobytes(), f
    assert dg.shape == dw.shape and dg.tobytes() == dw.tobytes()


def assert_batch_equals_single(images, backend, batch_input=None):
    """``warpvx.orb`` on the batch (``images`` as a list, or ``batch_input``) against each image
    alone; returns the per-image keypoint counts."""
    results = warpvx.orb(images if batch_input is None else batch_input, backend=backend)
    assert isinstance(results, list) and len(results) == len(images)
    counts = []
    for i, (img, got) in enumerate(zip(images, results)):
        want = warpvx.orb(img, backend=backend)
        assert_identical(got, want)
        counts.append(len(_host(want)[0]))
    return counts


@pytest.fixture(scope="module")
def kitti_frames():
    """Three consecutive 1241x376 frames of a KITTI-layout sequence rendered from the bundled
    photos (orbslam_synth: a camera moving through a room textured with real images)."""
    from warpvx.apps.orbslam_synth import render_sequence

    left, _, _, _ = render_sequence(3, size=KITTI)
    return [np.ascontiguousarray(f) for f in left]


def _video(n):
    return [cv2.cvtColor(f, cv2.COLOR_BGR2GRAY) for f in clip_frames(n, size=(640, 272))]


def _photos():
    return [cv2.resize(gray(n), (512, 384), interpolation=cv2.INTER_AREA)
            for n in ("astronaut", "coffee", "camera")]


@pytest.mark.parametrize("batch", [1, 2, 3])
def test_kitti_batch_equals_single(backend, kitti_frames, batch):
    """Batches of 1, 2 and 3 (odd) KITTI-sized frames, as a list."""
    counts = assert_batch_equals_single(kitti_frames[:batch], backend)
    assert min(counts) > 1000  # real texture: the extractor has work in every image


@pytest.mark.parametrize("source", ["video", "photos"])
def test_stacked_batch_equals_single(backend, source):
    """A stacked uint8 [B, H, W] host array: consecutive video frames, different photos."""
    images = _video(3) if source == "video" else _photos()
    assert_batch_equals_single(images, backend, np.stack(images))


def test_device_batches_equal_single(warp_backend):
    """Device inputs: a stacked [B, H, W] wp.array and a list of wp.arrays give device results
    equal to the host single-image calls."""
    wp = pytest.importorskip("warp")
    images = _photos()[:2]
    dev = _device(warp_backend)
    stack = wp.array(np.stack(images), dtype=wp.uint8, device=dev)
    listed = [wp.array(img, dtype=wp.uint8, device=dev) for img in images]
    for batch in (stack, listed):
        results = warpvx.orb(batch, backend=warp_backend)
        for img, (kps, desc) in zip(images, results):
            assert isinstance(desc, wp.array) and str(desc.device) == str(stack.device)
            assert_identical((kps, desc), warpvx.orb(img, backend=warp_backend))


def test_mixed_batch_equals_single(backend):
    """Very different images in one batch: a photo, a nearly blank frame (a faint gradient
    and one small square: few or no corners on most levels), pure noise (more candidates than
    the Warp plan holds: that image alone takes the host quadtree) and a video frame."""
    photo = _photos()[0]
    blank = np.tile(np.linspace(100, 110, photo.shape[1]).astype(np.uint8), (photo.shape[0], 1))
    blank[180:200, 250:270] = 200
    noise = np.random.default_rng(7).integers(0, 256, photo.shape, dtype=np.uint8)
    frame = cv2.resize(_video(1)[0], photo.shape[::-1], interpolation=cv2.INTER_AREA)
    images = [photo, blank, noise, frame]
    counts = assert_batch_equals_single(images, backend)
    assert counts[1] < 50 < counts[0]  # the blank frame is nearly empty
    # Pure noise: more candidates than the Warp plan's capacity, so the fallback ran.
    assert counts[2] > 1000


def test_batch_matches_the_cpu_extractor(warp_backend):
    """The Warp batch equals the CPU extractor image by image, as the single-image Warp call
    does (tests/kernels/test_orb.py): every field but a last-bit angle difference on CUDA."""
    from tests.kernels.test_orb import assert_same_extraction

    images = _video(2)
    for img, got in zip(images, warpvx.orb(images, backend=warp_backend)):
        kc, dc = warpvx.orb(img, backend="cpu")
        kw, dw = _host(got)
        assert_same_extraction(kw, dw, kc, dc, warp_backend)


@pytest.mark.skipif(not os.path.isdir(CASTLE), reason="castle_simu data absent")
def test_castle_sequence_batch_equals_single(backend):
    """castle_simu's camera frames (640x480, a textured scene seen moving)."""
    names = sorted(os.listdir(CASTLE))[:3]
    images = [cv2.imread(os.path.join(CASTLE, n), cv2.IMREAD_GRAYSCALE) for n in names]
    assert_batch_equals_single(images, backend, np.stack(images))


@pytest.mark.parametrize("params", [(500, 1.3, 4, 25, 9), (800, 2.0, 3, 20, 7)])
def test_batch_parameters_apply_to_every_image(backend, params):
    """Non-default parameters reach every image of the batch; at scale 2 on 512x384 each
    level is exactly half the last (OpenCV's 2x INTER_AREA edge rule: resized image by
    image)."""
    images = _photos()[:2]
    results = warpvx.orb(images, *params, backend=backend)
    for img, got in zip(images, results):
        assert_identical(got, warpvx.orb(img, *params, backend=backend))
        assert _host(got)[0].octave.max() == params[2] - 1


# --- bad batches ---------------------------------------------------------------------------


def test_bad_batches_name_the_image(backend):
    """Each image of a list is validated, the error naming src[i]; a stack as a whole."""
    img = _photos()[0]
    with pytest.raises(ShapeError, match=r"src\[1\]: image of 511x384 .* src\[0\] is 512x384"):
        warpvx.orb([img, np.ascontiguousarray(img[:, :511])], backend=backend)
    with pytest.raises(DTypeError, match=r"src\[2\]"):
        warpvx.orb([img, img, img.astype(np.float32)], backend=backend)
    with pytest.raises(ShapeError, match=r"src\[1\]: expected a gray"):
        warpvx.orb([img, cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)], backend=backend)
    with pytest.raises(WarpvxTypeError, match=r"src\[1\]"):
        warpvx.orb([img, "not an image"], backend=backend)
    with pytest.raises(WarpvxValueError, match="empty batch"):
        warpvx.orb([], backend=backend)
    with pytest.raises(ShapeError, match="empty batch"):
        warpvx.orb(np.zeros((0, 384, 512), np.uint8), backend=backend)
    with pytest.raises(DTypeError, match="src"):
        warpvx.orb(np.zeros((2, 384, 512), np.float32), backend=backend)
    with pytest.raises(WarpvxValueError, match="C-contiguous"):
        warpvx.orb(np.stack([img, img])[:, :, ::2], backend=backend)
    with pytest.raises(ShapeError, match="too small"):
        warpvx.orb(np.zeros((2, 100, 100), np.uint8), backend=backend)
    # A 3-D array with 1, 3 or 4 on its last axis stays one image (gray HxWx1, colour refused).
    with pytest.raises(ShapeError, match="3 channels"):
        warpvx.orb(cv2.cvtColor(img, cv2.COLOR_GRAY2BGR), backend=backend)


def test_batch_mixing_host_and_device_is_refused(warp_backend):
    wp = pytest.importorskip("warp")
    img = _photos()[0]
    on_device = wp.array(img, dtype=wp.uint8, device=_device(warp_backend))
    with pytest.raises(WarpvxTypeError, match=r"src\[1\]: on .* src\[0\] is on the host"):
        warpvx.orb([img, on_device], backend=warp_backend)
