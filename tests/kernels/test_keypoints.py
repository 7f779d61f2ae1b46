"""warpvx.Keypoints: construction, cv2.KeyPoint round trips, host and device forms."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import warpvx
from warpvx.backend import init_warp, resolve_backend
from warpvx.errors import ShapeError, WarpvxTypeError
from warpvx.keypoints import FIELDS, Keypoints
from tests.images import gray


def _sample():
    return Keypoints.from_arrays(x=[1.5, 20.0, 7.25], y=[2.0, 3.5, 40.0],
                                 response=[9.0, 30.0, 0.5], size=[7.0, 31.0, 12.0],
                                 angle=[-1.0, 45.5, 359.0], octave=[0, 2, 7])


def _equal(a, b):
    a, b = a.numpy(), b.numpy()
    return all(np.array_equal(getattr(a, f), getattr(b, f)) for f in FIELDS)


def test_empty():
    e = Keypoints.empty()
    assert len(e) == 0 and e.is_host and e.device == "host"
    assert e.to_cv() == [] and e.xy().shape == (0, 2)
    assert {f: getattr(e, f).dtype for f in FIELDS} == {
        "x": np.float32, "y": np.float32, "response": np.float32, "size": np.float32,
        "angle": np.float32, "octave": np.int32}


def test_from_arrays_defaults_are_opencvs():
    k = Keypoints.from_arrays([1, 2], [3, 4])
    assert k.x.dtype == np.float32 and k.octave.dtype == np.int32
    assert np.all(k.size == 7) and np.all(k.angle == -1) and np.all(k.response == 0)
    assert np.all(k.octave == 0)
    ref = cv2.KeyPoint(1.0, 3.0, 7.0)
    assert (ref.angle, ref.response, ref.octave) == (-1.0, 0.0, 0)


def test_from_arrays_length_mismatch():
    with pytest.raises(ShapeError, match="y"):
        Keypoints.from_arrays([1, 2, 3], [1, 2])
    with pytest.raises(ShapeError, match="octave"):
        Keypoints.from_arrays([1, 2], [1, 2], octave=[0])


def test_to_cv_from_cv_round_trip():
    k = _sample()
    cvk = k.to_cv()
    assert all(isinstance(p, cv2.KeyPoint) for p in cvk)
    assert [(p.pt, p.size, p.angle, p.response, p.octave) for p in cvk] == [
        ((1.5, 2.0), 7.0, -1.0, 9.0, 0), ((20.0, 3.5), 31.0, 45.5, 30.0, 2),
        ((7.25, 40.0), 12.0, 359.0, 0.5, 7)]
    assert _equal(Keypoints.from_cv(cvk), k)


def test_from_cv_of_opencv_detections():
    ref = cv2.ORB_create(200).detect(gray("camera"))
    k = Keypoints.from_cv(ref)
    assert len(k) == len(ref) > 50
    back = k.to_cv()
    assert [(p.pt, p.size, p.angle, p.response, p.octave) for p in back] == [
        (p.pt, p.size, p.angle, p.response, p.octave) for p in ref]


def test_from_cv_rejects_other_items():
    with pytest.raises(WarpvxTypeError, match="keypoints"):
        Keypoints.from_cv([cv2.KeyPoint(1, 2, 3), (1, 2)])


def test_xy_and_take():
    k = _sample()
    assert np.array_equal(k.xy(), np.array([[1.5, 2.0], [20.0, 3.5], [7.25, 40.0]], np.float32))
    t = k.take(np.array([2, 0]))
    assert np.array_equal(t.x, [7.25, 1.5]) and np.array_equal(t.octave, [7, 0])
    m = k.take(np.array([False, True, False]))
    assert len(m) == 1 and m.angle[0] == np.float32(45.5)


def test_device_round_trip(warp_backend):
    wp = init_warp()
    device = resolve_backend(warp_backend).device
    k = _sample()
    d = k.to(device)
    assert not d.is_host and d.device == str(wp.get_device(device))
    assert all(isinstance(getattr(d, f), wp.array) for f in FIELDS)
    assert d.octave.dtype == wp.int32 and d.x.dtype == wp.float32
    assert d.to(device) is d  # already there: no copy
    assert _equal(d.to("host"), k) and _equal(d.numpy(), k)
    assert np.array_equal(d.xy(), k.xy())
    assert _equal(d.take(np.array([1])), k.take(np.array([1])))
    assert [p.pt for p in d.to_cv()] == [p.pt for p in k.to_cv()]


def test_opencv_detections_through_device(warp_backend):
    """OpenCV's own keypoints on a real photo come back from the device field for field."""
    ref = cv2.ORB_create(300).detect(gray("coffee"))
    back = Keypoints.from_cv(ref).to(resolve_backend(warp_backend).device).to_cv()
    assert len(back) == len(ref) > 100
    assert [(p.pt, p.size, p.angle, p.response, p.octave) for p in back] == [
        (p.pt, p.size, p.angle, p.response, p.octave) for p in ref]


def test_empty_on_device(warp_backend):
    d = Keypoints.empty().to(resolve_backend(warp_backend).device)
    assert len(d) == 0 and not d.is_host and len(d.numpy()) == 0


def test_host_to_host_is_identity():
    k = _sample()
    assert k.to("host") is k and k.numpy() is k


def test_detector_output_round_trips(backend):
    kps = warpvx.fast_corners(gray("brick"), 20, backend=backend)
    assert _equal(Keypoints.from_cv(kps.to_cv()), kps)
