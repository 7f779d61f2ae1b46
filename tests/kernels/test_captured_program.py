"""``_launch.CapturedProgram``: a program of launches run eagerly once, then from a captured
graph (the ORB plan's and the stabilizer's device programs). On Warp's CPU device, whose
captures replay the same launches; what CUDA does is checked by the CUDA runs of the ORB and
stabilizer tests on the GPU machine."""

from __future__ import annotations

import numpy as np
import pytest

from warpvx.errors import CaptureAllocationError

wp = pytest.importorskip("warp")
_launch = pytest.importorskip("warpvx.kernels_warp._launch")


@wp.kernel
def _add_one(src: wp.array(dtype=wp.int32), dst: wp.array(dtype=wp.int32)):
    i = wp.tid()
    dst[i] = src[i] + 1


class _Program:
    """dst = src + 1, launched; ``fail`` (exception or None) raised by the calls listed in
    ``fail_on`` (0-based), before launching."""

    def __init__(self, fail=None, fail_on=()):
        self.device = wp.get_device("cpu")
        self.src = wp.array(np.arange(8, dtype=np.int32), device=self.device)
        self.dst = wp.zeros(8, dtype=wp.int32, device=self.device)
        self.fail, self.fail_on, self.calls = fail, set(fail_on), 0

    def __call__(self):
        call, self.calls = self.calls, self.calls + 1
        if call in self.fail_on:
            raise self.fail
        wp.launch(_add_one, dim=8, inputs=[self.src], outputs=[self.dst], device=self.device)

    def prepare(self, step):
        """Inputs of one step: src = step, dst cleared."""
        self.src.fill_(step)
        self.dst.zero_()


def _steps(prog, captured, n):
    """Run ``n`` steps through ``captured``; each must produce src + 1."""
    for step in range(n):
        prog.prepare(step)
        captured()
        assert (prog.dst.numpy() == step + 1).all(), f"step {step}"


def test_eager_first_then_captured_and_replayed():
    prog = _Program()
    captured = _launch.CapturedProgram(prog, prog.device)
    _steps(prog, captured, 1)
    assert captured.graph is None and prog.calls == 1  # the first call: eager
    _steps(prog, captured, 3)
    assert captured.graph is not None and captured.error is None
    assert prog.calls == 2  # captured once (the capture's call), replayed since


def test_warm_captures_on_the_first_call_and_disabled_never_captures():
    prog = _Program()
    warm = _launch.CapturedProgram(prog, prog.device, warm=True)
    _steps(prog, warm, 1)
    assert warm.graph is not None
    off = _launch.CapturedProgram(prog, prog.device, enabled=False)
    _steps(prog, off, 3)
    assert off.graph is None and off.error is None


def test_missing_scratch_runs_eagerly_once_then_captures():
    # Call 1 is the first capture: its scratch was missing. That step runs eagerly (call 2),
    # the next one captures (call 3) and is replayed after.
    prog = _Program(CaptureAllocationError("scratch"), fail_on={1})
    captured = _launch.CapturedProgram(prog, prog.device)
    _steps(prog, captured, 2)
    assert captured.graph is None and captured.enabled and captured.error is None
    _steps(prog, captured, 3)
    assert captured.graph is not None and prog.calls == 4


def test_missing_scratch_twice_turns_capture_off():
    prog = _Program(CaptureAllocationError("scratch"), fail_on={1, 3})
    captured = _launch.CapturedProgram(prog, prog.device)
    _steps(prog, captured, 5)  # every step still right, eagerly
    assert captured.graph is None and not captured.enabled
    assert "CaptureAllocationError" in captured.error


def test_other_capture_failure_turns_capture_off_at_once():
    prog = _Program(RuntimeError("a host sync inside"), fail_on={1})
    captured = _launch.CapturedProgram(prog, prog.device)
    _steps(prog, captured, 4)
    assert captured.graph is None and not captured.enabled
    assert "a host sync inside" in captured.error
    assert prog.calls == 5  # eager from then on: no capture tried again


def test_inside_a_callers_capture_runs_eagerly_without_giving_up():
    prog = _Program()
    captured = _launch.CapturedProgram(prog, prog.device)
    _steps(prog, captured, 1)

    class _Capturing:  # the device as a caller's capture shows it
        is_capturing = True

    captured.device = _Capturing()
    _steps(prog, captured, 2)
    assert captured.graph is None and captured.enabled
    captured.device = prog.device
    _steps(prog, captured, 2)
    assert captured.graph is not None


def test_capture_holds_the_capture_lock():
    # The capture is taken under _launch.capture_lock (the executor's records on the legacy
    # stream, which a capture in progress forbids, wait for it); an eager run is not. (Its
    # ``stream`` made current is CUDA's: checked by the stabilizer's CUDA tests.)
    prog = _Program()
    owned = []

    def program():
        owned.append(_launch.capture_lock._is_owned())
        prog()

    captured = _launch.CapturedProgram(program, prog.device)
    _steps(prog, captured, 3)
    assert owned == [False, True]  # eager, then the capture's call; replayed after
