"""A primitive's kept scratch (``_launch.workspace``) is never allocated inside a CUDA graph
capture: there its memory would be the graph's, valid only inside that graph, yet the cache
would hand it to later calls outside it (on the H100: CUDA error 700, an illegal address, in
the graph bench at 1920x1080, where a segment was captured on another thread than its
uncaptured run). A capture that would allocate fails with ``CaptureAllocationError``; the
executor's segment capture then makes the scratch uncaptured on its own thread and captures
again.

No CUDA here: the device and stream are stand-ins with the two attributes the cache reads;
what CUDA does inside a capture is checked on the GPU machine (graph_bench at 1920x1080).
"""

from __future__ import annotations

import types

import pytest

from warpvx.errors import CaptureAllocationError, WarpvxError, caused_by
from warpvx.kernels_warp import _launch
from warpvx.runtime.capture import NotCapturable, SegmentGraph


class _Device:
    """A CUDA device stand-in: not the CPU, its current stream capturing or not."""

    is_cpu = False

    def __init__(self, capturing: bool, handle: int):
        self.stream = types.SimpleNamespace(cuda_stream=handle, is_capturing=capturing)

    def __str__(self):
        return "cuda:0"


_device = _Device


@pytest.fixture
def fresh_cache(monkeypatch):
    monkeypatch.setattr(_launch, "_WORKSPACES", type(_launch._WORKSPACES)())


def test_workspace_is_not_built_inside_a_capture(fresh_cache):
    built = []
    with pytest.raises(CaptureAllocationError, match="inside a CUDA graph capture"):
        _launch.workspace("kind", (4,), _device(True, 11), lambda: built.append(1) or "ws")
    assert built == []  # nothing allocated
    assert len(_launch._WORKSPACES) == 0


def test_workspace_built_uncaptured_is_reused_inside_a_capture(fresh_cache):
    ws = _launch.workspace("kind", (4,), _device(False, 11), lambda: ["scratch"])
    # The same stream (handle) and thread, now capturing: the kept scratch, nothing built.
    again = _launch.workspace("kind", (4,), _device(True, 11), lambda: pytest.fail("built"))
    assert again is ws
    # Another stream has none yet: refused, not built inside the capture.
    with pytest.raises(CaptureAllocationError):
        _launch.workspace("kind", (4,), _device(True, 12), lambda: pytest.fail("built"))


def test_capture_allocation_error_is_a_warpvx_runtime_error():
    assert issubclass(CaptureAllocationError, WarpvxError)
    assert issubclass(CaptureAllocationError, RuntimeError)


def test_caused_by_walks_the_exception_chain():
    try:
        try:
            raise CaptureAllocationError("fast: scratch")
        except CaptureAllocationError as inner:
            raise NotCapturable("RuntimeError: wrapped") from inner
    except NotCapturable as exc:
        assert caused_by(exc, CaptureAllocationError)
        assert not caused_by(exc, KeyError)
    assert not caused_by(NotCapturable("a host sync inside"), CaptureAllocationError)


def _segment_graph(record):
    """A SegmentGraph whose capture records with ``record`` (raising or returning a graph)
    and whose uncaptured runs are logged."""
    sg = object.__new__(SegmentGraph)
    sg.sets = [types.SimpleNamespace(graph=None)]
    sg.last = -1  # (next: set 0)
    sg.segment = types.SimpleNamespace(tasks=[types.SimpleNamespace(name="fastL")])
    sg.runs = []
    sg._record = record
    sg._run_tasks = lambda s, fresh=False, streams=None: sg.runs.append(s)
    return sg


def test_segment_capture_makes_missing_scratch_uncaptured_then_captures():
    tries = []

    def record(device, streams):
        tries.append(device)
        if len(tries) == 1:
            try:
                raise CaptureAllocationError("fast: scratch inside a capture")
            except CaptureAllocationError as exc:
                raise NotCapturable("CaptureAllocationError: ...") from exc
        return "graph"

    sg = _segment_graph(record)
    sg.capture("cuda:0", None)
    assert tries == ["cuda:0", "cuda:0"]
    assert sg.runs == [0]  # one uncaptured run between the two captures
    assert sg.sets[0].graph == "graph"


def test_segment_capture_retry_may_capture_a_recorded_launch_under_the_capture_lock():
    """The executor captures a segment holding ``capture_lock``; the uncaptured run of the
    retry may replay a recorded launch a second time, which captures it under the same lock
    on the same thread (a non-reentrant lock hung the graph bench on the H100 at 1280x720)."""
    import threading

    tries = []

    def record(device, streams):
        tries.append(device)
        if len(tries) == 1:
            raise NotCapturable("scratch") from CaptureAllocationError("lk: scratch")
        return "graph"

    sg = _segment_graph(record)
    got = []

    def run_tasks(s, fresh=False, streams=None):
        ok = _launch.capture_lock.acquire(timeout=2)  # as _launch._capture does
        got.append(ok)
        if ok:
            _launch.capture_lock.release()

    sg._run_tasks = run_tasks
    done = threading.Event()

    def capture():
        with _launch.capture_lock:  # as SegmentRunner._segment_graph holds it
            sg.capture("cuda:0", None)
        done.set()

    th = threading.Thread(target=capture, daemon=True)
    th.start()
    assert done.wait(10), "segment capture hung"
    assert got == [True]
    assert sg.sets[0].graph == "graph"


def test_segment_capture_retry_task_failure_runs_the_segment_eagerly():
    """A task failing in the retry's uncaptured run fails the capture (NotCapturable: the
    executor runs the segment eagerly), as it would have inside the capture."""
    def record(device, streams):
        raise NotCapturable("scratch") from CaptureAllocationError("lk: scratch")

    sg = _segment_graph(record)

    def run_tasks(s, fresh=False, streams=None):
        raise ValueError("lkL: bad points")

    sg._run_tasks = run_tasks
    with pytest.raises(NotCapturable, match="ValueError: lkL: bad points"):
        sg.capture("cuda:0", None)
    assert sg.sets[0].graph is None


def test_segment_capture_other_failures_are_not_retried():
    def record(device, streams):
        raise NotCapturable("a host sync inside")

    sg = _segment_graph(record)
    with pytest.raises(NotCapturable, match="host sync"):
        sg.capture("cuda:0", None)
    assert sg.runs == []
    assert sg.sets[0].graph is None
