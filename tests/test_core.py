"""Core: backends, the checker's errors, array interop and registry dispatch."""

import numpy as np
import pytest

import warpvx
from warpvx import check, registry
from warpvx.backend import resolve_backend
from warpvx.errors import BackendError, DTypeError, ShapeError, WarpvxTypeError, WarpvxValueError

from .images import gray


@pytest.fixture
def invert():
    """``_test_invert`` in the (process-wide) registry for one test, removed after it."""
    registry.register(
        "_test_invert",
        public="tests._dispatch_impls:invert_cpu",
        cpu="tests._dispatch_impls:invert_cpu",
        warp="tests._dispatch_impls:invert_warp",
    )
    yield "_test_invert"
    del registry.REGISTRY["_test_invert"]


def test_errors_subclass_builtins():
    assert issubclass(ShapeError, ValueError) and issubclass(DTypeError, TypeError)
    assert issubclass(BackendError, warpvx.WarpvxError)


@pytest.mark.parametrize("bad", ["gpu", "cuda:x", "", 3, "opencl"])
def test_unknown_backend_names_argument(bad):
    with pytest.raises(BackendError, match="backend"):
        resolve_backend(bad)


def test_cuda_backend_without_gpu_is_clear():
    if warpvx.cuda_available():
        pytest.skip("a GPU is present; this checks the no-GPU message")
    with pytest.raises(BackendError, match="no CUDA device"):
        resolve_backend("cuda")


def test_set_backend_default_and_reset():
    try:
        warpvx.set_backend("warp-cpu")
        assert warpvx.get_backend().name == "warp-cpu"
        with pytest.raises(BackendError):
            warpvx.set_backend("nope")
    finally:
        warpvx.set_backend(None)
    assert warpvx.get_backend().name in ("cpu", "cuda:0")


def test_warp_array_selects_its_device():
    import warp as wp

    a = wp.zeros((4, 4), dtype=wp.uint8, device="cpu")
    assert resolve_backend(None, like=a).name == "warp-cpu"


def test_check_image_errors_name_argument():
    img = gray("camera")
    with pytest.raises(DTypeError, match="frame: expected dtype uint8, got float32"):
        check.check_image(img.astype(np.float32), "frame")
    with pytest.raises(ShapeError, match="frame.*channel"):
        check.check_image(np.zeros((4, 4, 2), np.uint8), "frame")
    with pytest.raises(ShapeError, match="frame.*empty"):
        check.check_image(np.zeros((0, 4), np.uint8), "frame")
    with pytest.raises(WarpvxValueError, match="frame.*contiguous"):
        check.check_image(img[:, ::2], "frame")
    with pytest.raises(WarpvxTypeError, match="frame"):
        check.check_image([[1, 2], [3, 4]], "frame")
    with pytest.raises(ShapeError, match="frame.*minimum"):
        check.check_image(np.zeros((4, 4), np.uint8), "frame", min_size=(8, 8))


def test_check_matrix_rejects_singular_and_nan():
    with pytest.raises(WarpvxValueError, match="M.*singular"):
        check.check_matrix(np.zeros((3, 3)), "M", invertible=True)
    with pytest.raises(WarpvxValueError, match="M.*NaN"):
        check.check_matrix(np.full((3, 3), np.nan), "M")
    with pytest.raises(ShapeError, match="M"):
        check.check_matrix(np.eye(2), "M")


def test_check_scalars():
    assert check.check_size((640, 480)) == (640, 480)
    with pytest.raises(WarpvxValueError, match="dsize"):
        check.check_size((0, 480))
    with pytest.raises(WarpvxTypeError, match="levels"):
        check.check_int(2.5, "levels")
    with pytest.raises(WarpvxValueError, match="scale_factor"):
        check.check_float(1.0, "scale_factor", min_value=1.0, strict_min=True)


def test_registry_knows_processing_elements():
    prim = registry.get_primitive("color_convert")
    assert prim.processing_elements == {"cpu", "gpu"} and not prim.exclusive
    with pytest.raises(WarpvxValueError, match="primitive"):
        registry.get_primitive("does_not_exist")


def test_registry_outputs_are_what_the_function_returns_and_the_graph_ports():
    """A primitive's registered ``outputs`` name each value its public function returns (on a
    real photo), and a graph node of it has exactly those output ports."""
    img = gray("camera")
    kps, desc = warpvx.orb(img, n_features=300, backend="cpu")
    moved = np.ascontiguousarray(np.roll(img, (1, 2), axis=(0, 1)))
    pts = np.stack([kps.x, kps.y], axis=1).astype(np.float32)
    calls = {
        "orb": ((img,), {"n_features": 300}),
        "optical_flow_pyr_lk": ((img, moved, pts), {}),
        "match_hamming": ((desc, desc[::-1].copy()), {}),
        "knn_match_hamming": ((desc, desc[::-1].copy()), {"k": 2}),
        "color_convert": ((np.dstack([img] * 3),), {"code": "BGR2GRAY"}),
    }
    for name, (args, kwargs) in calls.items():
        prim = registry.get_primitive(name)
        result = prim.function()(*args, **kwargs, backend="cpu")
        if len(prim.outputs) == 1:
            assert not isinstance(result, tuple), f"{name} returns several values"
        else:
            assert isinstance(result, tuple) and len(result) == len(prim.outputs), name
        g = warpvx.Graph(f"ports_{name}")
        data = [g.input(f"in{i}", value=a) for i, a in enumerate(args)]
        out = g.add(name, *data, **kwargs)
        node = (out[0] if isinstance(out, tuple) else out).producer
        assert tuple(node.outputs) == prim.outputs, name


def test_sized_by_inputs_primitives_take_out():
    """The graph preallocates ``out=`` only for primitives registered as sized by their inputs:
    each of those must take ``out``, and the data-dependent ones must not be marked."""
    import inspect

    sized = {n for n, p in registry.REGISTRY.items() if p.sized_by_inputs}
    for name in sized:
        assert "out" in inspect.signature(registry.get_primitive(name).function()).parameters, name
    assert not sized & {"fast_corners", "harris_corners", "orb", "orb_compute", "match_hamming",
                        "knn_match_hamming"}


def test_counted_rows_name_an_input_or_a_capacity_function():
    """Primitives with Counted outputs take out= and say where the capacity comes from: one
    of their inputs, or an importable function."""
    import importlib
    import inspect

    counted = {n: p for n, p in registry.REGISTRY.items() if p.counted_rows}
    assert set(counted) == {"fast_corners", "harris_corners", "optical_flow_pyr_lk"}
    for name, prim in counted.items():
        params = inspect.signature(prim.function()).parameters
        assert "out" in params, name
        if ":" in prim.counted_rows:
            module, attr = prim.counted_rows.split(":")
            assert callable(getattr(importlib.import_module(module), attr)), name
        else:
            assert prim.counted_rows in params, name


def test_dispatch_output_kind_follows_input(backend, invert):
    img = gray("camera")
    expected = 255 - img
    resolved = resolve_backend(backend)
    host = registry.dispatch(invert, resolved, img)
    assert isinstance(host, np.ndarray) and np.array_equal(host, expected)
    out = np.empty_like(img)
    res = registry.dispatch(invert, resolved, img, out=out)
    assert res is out and np.array_equal(out, expected)


def test_dispatch_device_array_stays_on_device(warp_backend, invert):
    import warp as wp

    img = gray("camera")
    resolved = resolve_backend(warp_backend)
    src = wp.array(img, dtype=wp.uint8, device=resolved.device)
    res = registry.dispatch(invert, resolved, src)
    assert isinstance(res, wp.array) and str(res.device) == str(src.device)
    assert np.array_equal(res.numpy(), 255 - img)
    # the CPU implementation fed a device array still returns a device array
    res_cpu = registry.dispatch(invert, resolve_backend("cpu"), src)
    assert isinstance(res_cpu, wp.array) and np.array_equal(res_cpu.numpy(), 255 - img)


def test_registry_holds_no_test_primitive():
    """Runs after the dispatch tests: what their fixture registered did not outlive them."""
    assert not [name for name in registry.REGISTRY if name.startswith("_test")]
