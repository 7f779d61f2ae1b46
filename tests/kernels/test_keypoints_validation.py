"""Keypoints validate themselves, and public calls re-check them (issue 10, items 2 and 3).

Construction refuses fields of different lengths, wrong dtypes, non-arrays, mixed host and
device arrays and NaN/inf host coordinates. ``orb_compute`` validates again (fields may have
been reassigned) before any launch, and bounds the octaves before sizing a pyramid: the cases
that once read out of bounds or ran for seconds run in a subprocess with a timeout.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import warpvx
from warpvx import DTypeError, Keypoints, ShapeError, WarpvxTypeError, WarpvxValueError
from warpvx.backend import init_warp, resolve_backend
from warpvx.keypoints import FIELDS, check_keypoints
from warpvx.orb_extractor import orb_compute
from tests.isolated import run_isolated
from tests.images import gray


def _fields(n=3, **over):
    """Valid host fields for ``n`` keypoints, with ``over`` replacing some."""
    f = dict(x=np.linspace(40, 60, n, dtype=np.float32), y=np.full(n, 50, np.float32),
             response=np.zeros(n, np.float32), size=np.full(n, 31, np.float32),
             angle=np.zeros(n, np.float32), octave=np.zeros(n, np.int32))
    f.update(over)
    return f


# --- construction ------------------------------------------------------------------------------

@pytest.mark.parametrize("field", FIELDS)
@pytest.mark.parametrize("n", [2, 4])
def test_construction_refuses_unequal_lengths(field, n):
    good = _fields(3)
    with pytest.raises(ShapeError, match=rf"keypoints: .*{field} {n}"):
        Keypoints(**_fields(3, **{field: np.zeros(n, good[field].dtype)}))


@pytest.mark.parametrize("field,dtype", [("x", np.float64), ("y", np.int32),
                                         ("angle", np.float16), ("octave", np.float32),
                                         ("octave", np.int64), ("response", np.uint8)])
def test_construction_refuses_wrong_dtypes(field, dtype):
    with pytest.raises(DTypeError, match=rf"keypoints\.{field}: expected dtype"):
        Keypoints(**_fields(3, **{field: np.zeros(3, dtype)}))


def test_construction_refuses_non_arrays_and_2d():
    with pytest.raises(WarpvxTypeError, match=r"keypoints\.size"):
        Keypoints(**_fields(3, size=[31.0, 31.0, 31.0]))
    with pytest.raises(ShapeError, match=r"keypoints\.x: expected a 1-D array"):
        Keypoints(**_fields(3, x=np.zeros((3, 1), np.float32)))


@pytest.mark.parametrize("field", ["x", "y"])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_construction_refuses_non_finite_coordinates(field, bad):
    values = np.array([1.0, bad, 3.0], np.float32)
    with pytest.raises(WarpvxValueError, match=rf"keypoints\.{field}: expected finite .*index 1"):
        Keypoints(**_fields(3, **{field: values}))
    with pytest.raises(WarpvxValueError, match=rf"keypoints\.{field}"):
        Keypoints.from_arrays(**{"x": [1.0, 2.0, 3.0], "y": [1.0, 2.0, 3.0], field: values})


def test_from_cv_refuses_non_finite_points():
    with pytest.raises(WarpvxValueError, match=r"keypoints\.x"):
        Keypoints.from_cv([cv2.KeyPoint(float("nan"), 2.0, 7.0)])


def test_construction_refuses_mixed_host_and_device(warp_backend):
    wp = init_warp()
    device = resolve_backend(warp_backend).device
    f = _fields(3)
    dev = {k: wp.array(v, device=device) for k, v in f.items()}
    with pytest.raises(WarpvxValueError, match=r"keypoints\.angle: expected a wp\.array"):
        Keypoints(**dict(dev, angle=f["angle"]))
    with pytest.raises(WarpvxValueError, match=r"keypoints\.y: expected a NumPy array"):
        Keypoints(**dict(f, y=dev["y"]))


def test_construction_refuses_warp_vector_dtypes(warp_backend):
    """A ``wp.vec2`` array has shape [N] like a float32 one: its dtype, not its shape, is wrong."""
    wp = init_warp()
    device = resolve_backend(warp_backend).device
    dev = {k: wp.array(v, device=device) for k, v in _fields(3).items()}
    dev["x"] = wp.zeros(3, dtype=wp.vec2, device=device)
    with pytest.raises(DTypeError, match=r"keypoints\.x"):
        Keypoints(**dev)


def test_valid_keypoints_construct_everywhere(warp_backend):
    k = Keypoints(**_fields(4))
    d = k.to(resolve_backend(warp_backend).device)
    assert len(d) == 4 and d.validate() is d and len(check_keypoints(d)) == 4
    assert len(Keypoints.empty().validate()) == 0


def test_check_keypoints_refuses_other_types():
    with pytest.raises(WarpvxTypeError, match="points: expected Keypoints"):
        check_keypoints(np.zeros((3, 2), np.float32), "points")


def test_check_keypoints_octave_range():
    k = Keypoints(**_fields(3, octave=np.array([0, 3, 1], np.int32)))
    assert check_keypoints(k, n_levels=4) is k
    with pytest.raises(WarpvxValueError, match=r"keypoints\.octave: expected values in \[0, 2\], got 3"):
        check_keypoints(k, n_levels=3)
    k.octave = np.array([0, -2, 1], np.int32)
    with pytest.raises(WarpvxValueError, match=r"got -2"):
        check_keypoints(k, n_levels=8)


# --- orb_compute re-checks, on every backend ----------------------------------------------------

def test_orb_compute_refuses_device_keypoints_with_nan(backend):
    """Device fields are not read at construction; orb_compute reads them, and refuses NaN."""
    wp = init_warp()
    f = _fields(3, y=np.array([50, np.nan, 60], np.float32))
    dev = Keypoints(**{k: wp.array(v, device="cpu") for k, v in f.items()})
    with pytest.raises(WarpvxValueError, match=r"keypoints\.y"):
        orb_compute(gray("camera"), dev, backend=backend)


def test_orb_compute_refuses_mutated_keypoints(backend):
    """Fields reassigned after construction (item 2): the Warp kernel launched a thread per
    ``octave`` entry and read x, y, angle and wrote the output out of bounds; cpu raised a bare
    IndexError; x longer than octave gave zero rows silently. Each case in a subprocess."""
    lines = run_isolated(f"""
        import numpy as np, warpvx
        from warpvx import Keypoints
        from warpvx.backend import init_warp, resolve_backend
        from warpvx.orb_extractor import orb_compute
        from tests.images import gray

        img = gray("camera")
        be = resolve_backend({backend!r})

        def mutated(field, value, device=None):
            k = Keypoints.from_arrays(np.linspace(40, 400, 50), np.full(50, 200.0),
                                      angle=np.zeros(50), octave=np.arange(50) % 4)
            if device is not None:
                k = k.to(device)
                value = init_warp().array(value, device=device)
            setattr(k, field, value)
            return lambda: orb_compute(img, k, 1.2, backend={backend!r})

        outcome(mutated("x", np.zeros(5000, np.float32)))
        outcome(mutated("octave", np.zeros(5000, np.int32)))
        outcome(mutated("angle", np.zeros(3, np.float32)))
        outcome(mutated("x", np.zeros(50, np.float64)))
        outcome(mutated("octave", np.zeros(50, np.float32)))
        if be.kind != "cpu":
            outcome(mutated("octave", np.zeros(5000, np.int32), be.device))
        """).splitlines()
    assert lines[0].startswith("ShapeError: keypoints:") and "x 5000" in lines[0]
    assert lines[1].startswith("ShapeError: keypoints:") and "octave 5000" in lines[1]
    assert lines[2].startswith("ShapeError: keypoints:") and "angle 3" in lines[2]
    assert lines[3].startswith("DTypeError: keypoints.x: expected dtype float32")
    assert lines[4].startswith("DTypeError: keypoints.octave: expected dtype int32")
    if resolve_backend(backend).kind != "cpu":
        assert lines[5].startswith("ShapeError: keypoints:") and "octave 5000" in lines[5]
        assert len(lines) == 6
    else:
        assert len(lines) == 5


def test_orb_compute_bounds_octaves_first(backend):
    """Item 3: an octave of 2^31-1 sized 2^31 pyramid levels before any check (memory grew
    without end) and 10^7 took 14 s to raise. Octaves are refused against orb's 32-level
    limit before anything is sized, in milliseconds."""
    lines = run_isolated(f"""
        import time
        import cv2, numpy as np
        from warpvx import Keypoints
        from warpvx.orb_extractor import orb_compute
        from tests.images import gray

        img = gray("camera")
        orb_compute(img, Keypoints.from_arrays([256.0], [256.0], octave=[0]),
                    backend={backend!r})  # warm-up: imports and compiles outside the timing
        for octave in (2**31 - 1, 10**7, 32, -1, -2**31):
            kps = Keypoints.from_arrays([256.0], [256.0], angle=[0.0], octave=[octave])
            t = time.perf_counter()
            outcome(lambda: orb_compute(img, kps, 1.2, backend={backend!r}))
            print(f"{{time.perf_counter() - t:.3f}}")
        cv_kps = [cv2.KeyPoint(256.0, 256.0, 31.0, 0.0, 0.0, 2**31 - 1)]
        outcome(lambda: orb_compute(img, cv_kps, backend={backend!r}))
        """).splitlines()
    results, seconds = lines[0:10:2], [float(s) for s in lines[1:10:2]]
    for line, octave in zip(results, (2**31 - 1, 10**7, 32, -1, -2**31)):
        assert line == f"WarpvxValueError: keypoints.octave: expected values in [0, 31], got {octave}"
    assert max(seconds) < 1.0, seconds
    assert lines[10].startswith("WarpvxValueError: keypoints.octave")


def test_orb_compute_accepts_the_deepest_octave(backend):
    """Octave 31 is in range; on a 512x512 image level 31 (2x2 px) exists and is described."""
    kps = Keypoints.from_arrays([256.0, 100.0], [256.0, 300.0], angle=[0.0, 90.0],
                                octave=[31, 0])
    desc = orb_compute(gray("camera"), kps, 1.2, backend=backend)
    desc = desc if isinstance(desc, np.ndarray) else desc.numpy()
    assert desc.shape == (2, 32) and desc.dtype == np.uint8
    # The octave-0 row is what it is alone: the deep level does not disturb it.
    alone = orb_compute(gray("camera"), kps.take(np.array([1])), 1.2, backend="cpu")
    assert np.array_equal(desc[1], alone[0])
    with pytest.raises(ShapeError, match="src.*octave 31"):
        orb_compute(np.ascontiguousarray(gray("camera")[:40, :40]), kps, 1.2, backend=backend)


def test_cv_orb_compute_refuses_huge_octaves(backend):
    img = gray("camera")
    kp = [cv2.KeyPoint(256.0, 256.0, 31.0, 0.0, 0.0, 10**7)]
    with pytest.raises(WarpvxValueError, match=r"keypoints\.octave"):
        warpvx.cv.ORB_create(backend=backend).compute(img, kp)
