"""CPU nodes run in worker processes: a node's Python callable off this process's GIL.

A pipelined graph's Python (the caller, the GPU role's thread, the CPU workers) shares one
GIL. A CPU node whose work is a native call that releases it (an OpenCV function) still
holds it for its NumPy glue and must take it back after the call, behind whichever thread
took it meanwhile: on the H100 the two-camera graph's two RANSAC homographies measured 0.3 ms
each alone and 0.4-0.8 ms inside the stream, and taking them away raised the stream's frame
rate by 27% (``benchmarks/results/graph/h100-2026-11-25-s12/pipeline_bottleneck.md``).

:class:`ProcessCall` wraps such a callable (``Graph.user(..., process=True)``): each thread
that calls it gets a worker process of its own (started with ``spawn``: this process has
CUDA and threads, which ``fork`` would copy half-way), the arguments and results travel
pickled through a pipe (the calling thread waits without the GIL), and an exception in the
worker is raised again in the caller. The callable must be picklable by reference (a
module-level function of an importable module: not a lambda, a closure or a bound method of
an unpicklable object). As with any ``spawn`` worker, a script that runs such nodes guards its
entry point with ``if __name__ == "__main__":`` (the worker imports the script's module).
"""

from __future__ import annotations

import multiprocessing
import pickle
import threading
import weakref

from ..errors import NodeExecutionError


def _serve(conn):
    """A worker process's loop: ``(fn, args)`` in, ``(True, fn(*args))`` or ``(False,
    exception)`` out, until the pipe closes or ``None`` comes."""
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg is None:
            return
        fn, args = msg
        try:
            reply = (True, fn(*args))
        except BaseException as exc:  # noqa: BLE001 - sent back to the caller
            reply = (False, exc)
        try:
            conn.send(reply)
        except Exception as exc:  # noqa: BLE001 - the result or exception did not pickle
            conn.send((False, NodeExecutionError(
                f"its result could not be sent back from its worker process (it does not "
                f"pickle: {exc})")))


class _Worker:
    """One worker process and its end of the pipe."""

    def __init__(self, ctx, label: str):
        self.closed = False  # by close(): its thread starts another on its next call
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=_serve, args=(child,), daemon=True,
                                name=f"warpvx-{label}")
        self.proc.start()
        child.close()

    def call(self, fn, args, label: str):
        try:
            message = pickle.dumps((fn, args))
        except Exception as exc:  # noqa: BLE001 - pickle raises several kinds
            raise NodeExecutionError(f"{label}: its inputs cannot be sent to its worker process "
                                     f"(they do not pickle: {exc})") from None
        try:
            self.conn.send_bytes(message)
            ok, value = self.conn.recv()
        except (EOFError, OSError):  # (BrokenPipeError is an OSError)
            self.close()  # (joins it: its exit code is known after)
            code = self.proc.exitcode
            raise NodeExecutionError(f"{label}: its worker process ended (exit code {code}) "
                                     "before returning a result") from None
        if ok:
            return value
        raise value

    def close(self):
        self.closed = True
        try:
            self.conn.send(None)
        except (OSError, ValueError):
            pass
        self.conn.close()
        self.proc.join(timeout=2.0)
        if self.proc.is_alive():
            self.proc.terminate()
            self.proc.join(timeout=2.0)


class ProcessCall:
    """``fn`` called in a worker process of the calling thread's (see the module docstring):
    ``ProcessCall(fn, label)(*args)`` is ``fn(*args)``. ``label`` names it in errors and
    in the processes' names. :meth:`close` ends the workers (they start again on the next
    call); garbage, or at interpreter exit, they end too.

    Raises
    ------
    TypeError
        ``fn`` is not callable, or cannot be pickled by reference.
    """

    def __init__(self, fn, label: str = "node"):
        if not callable(fn):
            raise TypeError(f"expected a callable, got {type(fn).__name__}")
        try:
            pickle.dumps(fn)
        except Exception as exc:  # noqa: BLE001 - pickle raises several kinds
            raise TypeError(f"{fn!r} cannot run in a worker process: it does not pickle "
                            f"({exc}); use a module-level function") from None
        self.fn = fn
        self.label = label
        self._local = threading.local()
        self._workers: list = []
        self._lock = threading.Lock()
        self._ctx = multiprocessing.get_context("spawn")
        weakref.finalize(self, _close_all, self._workers, self._lock)

    def __call__(self, *args):
        worker = getattr(self._local, "worker", None)
        if worker is None or worker.closed:  # (a flag, not a waitpid per call)
            worker = self._local.worker = _Worker(self._ctx, self.label)
            with self._lock:
                self._workers.append(worker)
        return worker.call(self.fn, args, self.label)

    def close(self):
        """End the worker processes (a later call starts its thread's again)."""
        _close_all(self._workers, self._lock)

    @property
    def workers(self) -> int:
        """Worker processes alive now."""
        with self._lock:
            return sum(w.proc.is_alive() for w in self._workers)

    def __repr__(self):
        return f"ProcessCall({self.fn!r})"


def _close_all(workers: list, lock):
    with lock:
        todo, workers[:] = list(workers), []
    for w in todo:
        w.close()


__all__ = ["ProcessCall"]
