"""CPU nodes in worker processes (``Graph.user(..., process=True)``,
:mod:`warpvx.runtime.processes`): the same outputs as in this process on a real photo, run
in another process, one per CPU worker; errors raised there reach the caller, a worker that
dies is reported by node without a hang, and ``close`` ends the processes."""

from __future__ import annotations

import os
import threading

import numpy as np
import pytest

import warpvx
from tests.images import bgr
from tests.runtime import _process_nodes as pn
from warpvx.errors import GraphError, NodeExecutionError, WarpvxError
from warpvx.runtime.processes import ProcessCall


def _graph(fn, process):
    g = warpvx.Graph("proc")
    x = g.input("frame", shape=(96, 128, 3), dtype=np.uint8)
    out, pid = g.user(fn, [x], ["out", "pid"], name="blur", process=process)
    g.output("out", out)
    g.output("pid", pid)
    return g


def _frames(n):
    img = bgr("astronaut")
    import cv2

    return [{"frame": cv2.resize(np.roll(img, 7 * i, axis=1), (128, 96))} for i in range(n)]


@pytest.mark.timeout(120)
def test_a_process_node_gives_the_in_process_outputs_from_another_process():
    frames = _frames(6)
    outs = {}
    for process in (False, True):
        g = _graph(pn.blur, process)
        try:
            g.verify(frames[0])
            g.schedule("baseline", n_cpus=2, gpu=False)
            outs[process] = list(g.stream(frames, depth=2))
            if process:
                fn = g.node("blur").fn
                assert isinstance(fn, ProcessCall) and fn.workers >= 1
        finally:
            g.close()
        if process:
            assert fn.workers == 0  # close ended them
    for a, b in zip(outs[False], outs[True]):
        np.testing.assert_array_equal(a["out"], b["out"])  # exact: the same OpenCV call
    assert all(int(o["pid"]) == os.getpid() for o in outs[False])
    assert all(int(o["pid"]) != os.getpid() for o in outs[True])


@pytest.mark.timeout(120)
def test_an_error_in_the_worker_reaches_the_caller_and_a_dead_worker_is_named():
    frames = _frames(1)
    g = warpvx.Graph("proc-errors")
    x = g.input("frame", shape=(96, 128, 3), dtype=np.uint8)
    g.output("out", g.user(pn.fails, [x], "out", name="failing", process=True))
    with pytest.raises(GraphError) as err:  # verification runs it too
        g.verify(frames[0])
    assert "failing" in str(err.value) and "bad frame of shape (96, 128, 3)" in str(err.value)
    g.close()
    call = ProcessCall(pn.dies, "node 'dies'")
    with pytest.raises(NodeExecutionError, match=r"node 'dies': its worker process ended \(exit code 3\)"):
        call(frames[0]["frame"])
    assert call.workers == 0
    # A later call starts a new worker.
    assert ProcessCall(pn.blur)(frames[0]["frame"])[0].shape == (96, 128, 3)
    # What cannot cross the pipe is named, either way, and the worker goes on serving.
    call = ProcessCall(pn.unpicklable_result, "node 'odd'")
    with pytest.raises(NodeExecutionError, match="could not be sent back.*does not pickle"):
        call(frames[0]["frame"])
    with pytest.raises(NodeExecutionError, match="node 'odd': its inputs cannot be sent"):
        call(threading.Lock())
    assert call.workers == 1
    call.close()


def test_a_callable_that_does_not_pickle_is_refused_by_name():
    g = warpvx.Graph("proc-bad")
    x = g.input("frame", shape=(4,), dtype=np.float32)
    with pytest.raises(GraphError, match="node 'lam'.*does not pickle"):
        g.user(lambda v: v, [x], "out", name="lam", process=True)
    with pytest.raises(GraphError, match="node 'num'.*expected a callable, got int"):
        g.user(5, [x], "out", name="num", process=True)
    with pytest.raises(GraphError, match="node 'gpu_only'.*no fn"):
        g.user(None, [x], "out", warp_fn=pn.blur, name="gpu_only", process=True)
    with pytest.raises(WarpvxError, match="process"):
        g.user(pn.blur, [x], "out", name="flag", process="yes")


@pytest.mark.timeout(300)
def test_the_two_camera_graph_with_its_homographies_in_processes_gives_the_same_outputs():
    """On Warp's CPU device, captured, staged downloads on, pipelined (3 in flight): the
    homographies in worker processes give the in-process run's outputs bit for bit (their
    inputs come from the GPU role's staged downloads; the delayed corners too)."""
    import sys
    from pathlib import Path

    from tests.runtime.test_staged_downloads import SIZE, _cams, _same
    from warpvx.runtime import Executor

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
    import graph_bench

    cams = _cams(10)
    saved = Executor.STAGE_ON_HOST
    Executor.STAGE_ON_HOST = True
    try:
        outs = {}
        for process in (False, True):
            g = graph_bench.build_graph(SIZE, max_corners=100, homography_process=process)
            try:
                g.verify(cams[:2])
                g.schedule("baseline", n_cpus=2, gpu="warp-cpu")
                outs[process] = list(g.stream(cams, depth=3, capture=True))
                assert isinstance(g.node("homographyL").fn, ProcessCall) == process
            finally:
                g.close()
    finally:
        Executor.STAGE_ON_HOST = saved
    assert len(outs[True]) == len(outs[False]) == 10
    for a, b in zip(outs[False], outs[True]):
        assert _same(a, b)
    assert any(not np.allclose(o["HL"], np.eye(3)) for o in outs[True])  # RANSAC ran
