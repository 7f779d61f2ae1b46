"""The batched ORB-SLAM2 front end's tracking chain in a process of its own
(:class:`ChainProcess`): the sequential ``chain`` and the pose work that feeds it no longer
share the GIL of the process that runs the GPU role.

In process (:func:`~warpvx.apps.orbslam_batch.build_batch_graph` with a
:class:`~warpvx.apps.orbslam_pool.PosePool`), the chain ran in a graph worker thread beside
the GPU host thread, the executor's threads and the pool's hand-off threads: on the H100 host
it held the GIL for 18% of its wall time (63 ms per 16-frame batch for 35 ms of CPU). Here
the graph's two CPU nodes only hand batches over and take poses back::

    images, packed, nearest, sent[-1] -> pose_batch (CPU) -> sent, ticket: the batch's arrays
        into a shared block (:class:`~warpvx.apps.orbslam_pool.SharedBlock`), a message to the
        chain process (mono: the images stay behind; only stereo depths read them)
    ticket -> chain (CPU) -> poses [B, 4, 4], stats [B, 6]: waits for the batch's result
        (the GIL released)

and the chain process does the rest with its own state: a receiver thread copies each batch
out of the block and runs :func:`~warpvx.apps.orbslam_batch.pose_batch` at once, so the
batch's jobs start on the pose pool (:class:`~warpvx.apps.orbslam_pool.PosePool`, the chain
process's own: its keyframe speculation talks to it directly) while the previous batch is
tracked; its main thread runs :func:`~warpvx.apps.orbslam_batch.chain` batch after batch.
Same functions, same inputs, in the same order: the poses are the in-process ones, bit for bit.

The process is spawned once (with its pool) and serves any number of runs: a batch whose
``sent`` is 0 (the first of a stream, or a verification's primed one: see
:meth:`ChainProcess.dry_run`) starts a new run (fresh tracking state, the run's camera and
settings); a batch of no run fails. Every batch gets a result, in order, kept for
:data:`KEEP_RESULTS` batches: a ticket may be asked for again (the calibration times a node on
the same inputs several times). Shut it down with :meth:`ChainProcess.shutdown` (or a
``with`` block; also at the interpreter's exit): the pool's processes go with it, and its
shared blocks are unlinked. POSIX only (the blocks are POSIX shared memory).
"""

from __future__ import annotations

import collections
import contextlib
import os
import queue
import sys
import threading
import time
import traceback

import numpy as np

from ..errors import NodeExecutionError, WarpvxValueError
from ..keypoints import FIELDS
from .orbslam_pool import PosePool, Segments, SharedBlock, _caller_script_hidden, _resolve, check_look_ahead

#: Results a :class:`ChainProcess` keeps (by ticket) after they arrive.
KEEP_RESULTS = 64

#: Seconds :meth:`ChainProcess.shutdown` waits for the process to finish before it terminates it.
STOP_WAIT_S = 30.0


def _pack_host(feats) -> tuple:
    """Host features, a list of (Keypoints, uint8 [N_i, 32]) or
    :func:`~warpvx.apps.orbslam_batch.pack_feats`' value -> the packed form (each field and
    the descriptors joined, the counts): a few arrays for the shared block."""
    if not isinstance(feats, list):
        return feats
    return (tuple(np.concatenate([getattr(k, f) for k, _ in feats]) for f in FIELDS),
            np.concatenate([d for _, d in feats]), tuple(len(d) for _, d in feats))


# --------------------------------------------------------------------------- the chain process


def _receive(inbox, jobs: queue.SimpleQueue, pool, stopping: threading.Event):
    """The chain process's receiver thread: each batch out of its block and through
    ``pose_batch`` (its jobs on ``pool`` now), queued for the main thread with the run's
    parameters; at a run's first batch the tail restarts and the run's settings apply."""
    from .orbslam_batch import NO_TAIL, pose_batch

    tail, params = NO_TAIL, None
    try:
        while (msg := inbox.recv()) is not None:
            if msg[0] == "counts":
                jobs.put(msg)  # (in order with the batches)
                continue
            if msg[0] == "unprime":
                tail, params = NO_TAIL, None  # (the primed run is not continued: see ChainProcess.send)
                continue
            _, ticket, run, payload = msg
            try:
                if run is not None:
                    params, settings = run
                    tail = NO_TAIL
                    sys.setswitchinterval(settings.pop("switch"))
                    for k, v in settings.items():
                        if pool is not None:
                            setattr(pool, k, v)
                if params is None:
                    raise NodeExecutionError("chain process: a batch outside a run (a run's first batch, "
                                             "sent 0, starts one)")
                images, packed, nearest = payload
                # Copies: the tracking state keeps the last frame's arrays past the block's reuse.
                packed, nearest = _resolve((packed, nearest), copy=True)
                tail, ahead = pose_batch(_resolve(images), packed, nearest, tail, pool=pool, **params)
                jobs.put(("batch", ticket, run is not None, params, packed, ahead))
            except Exception as exc:  # noqa: BLE001 - handed to the caller in order
                jobs.put(("failed", ticket, exc, traceback.format_exc()))
    except (EOFError, OSError):
        pass  # the parent is gone: stop
    finally:
        stopping.set()
        jobs.put(None)


def _send_error(outbox, ticket, exc, text):
    try:
        outbox.send(("error", ticket, exc, text))
    except Exception:  # noqa: BLE001 - an exception that does not pickle: its text
        outbox.send(("error", ticket, RuntimeError(f"{type(exc).__name__}: {exc}"), text))


def _serve(inbox, outbox, workers: int, quiet: bool, nice: int):
    """The chain process: its pose pool (``workers`` processes, 0: none; ``nice``: theirs), the receiver
    thread, and the chain over the queued batches in order, each result (or error) sent back."""
    import signal

    from . import orbslam as o
    from .orbslam_batch import chain

    # SIGTERM (the parent's last resort) unwinds through the finally: the pool goes too.
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(1))
    pool = PosePool(workers, quiet=quiet, bound=True, nice=nice) if workers else None
    timing = collections.Counter()
    try:
        jobs, stopping = queue.SimpleQueue(), threading.Event()
        threading.Thread(target=_receive, args=(inbox, jobs, pool, stopping), name="chain-receiver",
                         daemon=True).start()
        outbox.send(("ready",))
        state = None
        while (item := jobs.get()) is not None:
            if item[0] == "counts":
                counts = (pool.waited_s, pool.started, pool.cancelled) if pool is not None else ({},) * 3
                outbox.send(("counts", *(dict(c) for c in counts), dict(timing)))
            elif stopping.is_set():
                continue  # shutting down: the parent takes no more results
            elif item[0] == "failed":
                _send_error(outbox, *item[1:])
            else:
                _, ticket, first, params, packed, ahead = item
                if first:
                    state = o.TrackState()
                w, c = time.perf_counter(), time.thread_time()
                try:
                    state, poses, stats = chain(state, packed, ahead, pool=pool, **params)
                except Exception as exc:  # noqa: BLE001 - handed to the caller
                    _send_error(outbox, ticket, exc, traceback.format_exc())
                    continue
                finally:
                    timing["cpu_s"] += time.thread_time() - c
                    timing["wall_s"] += time.perf_counter() - w
                outbox.send(("done", ticket, poses, stats))
    except (EOFError, OSError, BrokenPipeError):
        pass  # the parent is gone
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)


# --------------------------------------------------------------------------- the parent's side


class ChainProcess:
    """The chain process of the batched front end (see the module's docstring) with its pose
    pool of ``workers`` processes (0: the pose work in the chain process's receiver thread),
    spawned on construction (the pool started before it returns). Pass it as
    :func:`~warpvx.apps.orbslam_batch.track_frames_batched`'s ``pool`` for any number of runs;
    close it with :meth:`shutdown` (or a ``with`` block).

    ``ahead``, ``share``, ``direct``, ``look_ahead``: the pool's settings (:class:`~warpvx.apps.orbslam_pool.PosePool`),
    applied at each run's start; ``quiet`` False: multiprocessing's stock ``Pool``; ``nice``:
    the pose processes' niceness increment (see :func:`~warpvx.apps.orbslam_pool.make_pool`).
    :meth:`counts` (and ``waited_s``, ``started``, ``cancelled``) reports the pool's counters
    and the chain's wall and thread CPU time. ``graphs`` as
    :class:`~warpvx.apps.orbslam_pool.PosePool`'s."""

    def __init__(self, workers: int, quiet: bool = True, ahead: bool = True, share: bool = True, nice: int = 0,
                 direct: bool = True, look_ahead: int | None = None):
        from multiprocessing import get_context, util

        if os.name != "posix":
            raise WarpvxValueError("chain_process: needs POSIX shared memory (run the chain in process)")
        ctx = get_context("spawn")
        self.workers, self.ahead, self.share, self.direct = workers, ahead, share, direct
        self.look_ahead = check_look_ahead(look_ahead)
        self.graphs = {}
        child_in, self._to_child = ctx.Pipe(duplex=False)
        self._from_child, child_out = ctx.Pipe(duplex=False)
        self._process = ctx.Process(target=_serve, args=(child_in, child_out, workers, quiet, nice),
                                    name="orbslam-chain")
        with _caller_script_hidden():
            self._process.start()
        # Only the child holds its ends: its exit is an EOF here, the parent's one there.
        child_in.close()
        child_out.close()
        self._segments, self._blocks = Segments(), {}
        self._results, self._next, self._counts = collections.OrderedDict(), 0, collections.deque()
        # (send posts under the send lock: the tickets reach the process in order)
        self._send_lock, self._read_lock = threading.RLock(), threading.Lock()
        self._local = threading.local()  # .dry, .prime: see dry_run
        # Dry tickets -> frames (answered here, kept as results are); the primed batch: see dry_run.
        self._dry, self._primed = collections.OrderedDict(), None
        #: Primed batches (see dry_run): "sent", "taken" by the stream's first, "dropped" (not taken).
        self.primes = collections.Counter()
        self._stop = util.Finalize(self, _stop, args=(self._to_child, self._from_child, self._process,
                                                      self._segments), exitpriority=10)
        try:
            if self._read()[0] != "ready":
                raise NodeExecutionError("chain process: unexpected first message")
        except BaseException:
            self.shutdown()
            raise

    @contextlib.contextmanager
    def dry_run(self, prime: bool = False):
        """In the block, batches that this thread sends (:func:`send_batch`) get poses and
        stats of the right shape and dtype, zeros, at once (answered here: the process neither
        reads them nor tracks them, and a run's state stays as it was).
        :func:`~warpvx.apps.orbslam_batch.track_frames_batched` verifies its graph so (the
        verification runs two batches; each was the whole pose work and chain of a batch,
        on the H100 ~2 x 70 ms per call): the stream then runs that work on the same first
        batch, its errors raised from there. Other threads' batches are real.

        ``prime``: the block's first batch of a run (``sent`` 0: the verification's first, the
        stream's first batch) also goes to the process for real, so that its pose work and
        chain run while the verification goes on and the stream starts; the stream's first
        batch, if equal to it (every array, bit for bit), takes its ticket instead of sending
        it again. One primed batch at a time, and none while real batches are in flight (a
        process tracks one run at a time: a prime starts one). A batch of no run sent after
        the prime (the calibration's samples) waits for the primed batch's work, so that it is
        not timed beside it, and ends the primed run."""
        before = self.dry, getattr(self._local, "prime", False)
        self._local.dry, self._local.prime = True, prime
        try:
            yield
        finally:
            self._local.dry, self._local.prime = before

    @property
    def dry(self) -> bool:
        """Whether this thread is in :meth:`dry_run`."""
        return getattr(self._local, "dry", False)

    # -- the graph's nodes call these

    @property
    def priming(self) -> bool:
        """Whether this thread is in a priming :meth:`dry_run`."""
        return self.dry and self._local.prime

    def prime(self, payload, run) -> bool:
        """Send a run's first batch (as :meth:`send`) for the stream's first to take (see
        :meth:`dry_run`); False, sending nothing, while real batches are in flight or a
        primed one waits."""
        with self._send_lock:
            if self._blocks or self._primed is not None:
                return False
            self._primed = (self._send(payload, run), payload, run)
        self.primes["sent"] += 1
        return True

    def send_dry(self, frames: int) -> int:
        """A ticket for ``frames`` zero poses and stats (see :meth:`dry_run`)."""
        with self._send_lock:
            ticket, self._next = self._next, self._next + 1
            self._dry[ticket] = frames
            while len(self._dry) > KEEP_RESULTS:
                self._dry.popitem(last=False)
        return ticket

    def send(self, payload, run) -> int:
        """Hand a batch (``payload``: (images or None, packed features, nearest), arrays) to
        the process; ``run``: None, or the first batch's (params, settings). Returns its ticket
        (the primed one's when this is the primed batch, see :meth:`dry_run`)."""
        with self._send_lock:
            primed, self._primed = self._primed, None
        if primed is not None:
            taken = run is not None and _same_value((payload, run), primed[1:])
            self.primes["taken" if taken else "dropped"] += 1
            if taken:
                return primed[0]
            if run is None:
                # Not the stream's batch after the primed one (the calibration's samples): the
                # primed run ends there, as if it had not started, once its work is done (a
                # calibration must not time the process while it works the prime).
                try:
                    self.result(primed[0])
                except Exception:  # noqa: BLE001 - a dropped prime's error is nobody's
                    pass
                self._post(("unprime",))
        with self._send_lock:
            return self._send(payload, run)

    def _send(self, payload, run) -> int:
        """Post a batch (the caller holds the send lock): its ticket."""
        ticket, self._next = self._next, self._next + 1
        block = SharedBlock([payload], self._segments)
        self._blocks[ticket] = block
        self._post(("batch", ticket, run, block.refer(payload)))
        return ticket

    def result(self, ticket: int):
        """The batch's (poses float64 [B, 4, 4], stats float64 [B, 6]), waited for; the chain
        process's error raised again here."""
        frames = self._dry.get(ticket)
        if frames is not None:
            from .orbslam import STATS

            return np.zeros((frames, 4, 4)), np.zeros((frames, len(STATS)))
        with self._read_lock:
            while ticket not in self._results:
                if ticket not in self._blocks:  # (a real batch's block goes when its result comes)
                    raise WarpvxValueError(f"ticket: batch {ticket}'s result is no longer kept")
                self._file(self._read())
            msg = self._results[ticket]
        if msg[0] == "error":
            exc, text = msg[2], msg[3]
            if hasattr(exc, "add_note"):
                exc.add_note(f"(in the chain process)\n{text}")
            raise exc
        return msg[2], msg[3]

    def counts(self) -> tuple:
        """(waited_s, started, cancelled, chain time): the pool's counters (see
        :class:`~warpvx.apps.orbslam_pool.PosePool`) and {"wall_s", "cpu_s"} summed over
        the chain's batches. Between runs (results still to come are kept)."""
        self._post(("counts",))
        with self._read_lock:
            while not self._counts:
                self._file(self._read())
            msg = self._counts.popleft()
        return tuple(collections.Counter(c) for c in msg[1:4]) + ({"wall_s": 0.0, "cpu_s": 0.0, **msg[4]},)

    @property
    def waited_s(self):
        return self.counts()[0]

    @property
    def started(self):
        return self.counts()[1]

    @property
    def cancelled(self):
        return self.counts()[2]

    def _file(self, msg):
        """File a message from the process: a result (its block goes back: the process copied
        what it keeps) or a counts reply (the caller holds the read lock)."""
        if msg[0] == "counts":
            self._counts.append(msg)
            return
        if msg[0] not in ("done", "error"):
            raise NodeExecutionError(f"chain process: unexpected message {msg[0]!r}")
        ticket = msg[1]
        block = self._blocks.pop(ticket, None)
        if block is not None:
            block.release()
        self._results[ticket] = msg
        while len(self._results) > KEEP_RESULTS:
            self._results.popitem(last=False)

    def _post(self, msg):
        with self._send_lock:
            if not self._process.is_alive():
                raise NodeExecutionError(f"chain process: exited (code {self._process.exitcode})")
            self._to_child.send(msg)

    def _read(self):
        """The next message from the process (blocked without the GIL); its exit is an error."""
        from multiprocessing.connection import wait

        wait([self._from_child, self._process.sentinel])
        try:
            return self._from_child.recv()
        except (EOFError, OSError):
            raise NodeExecutionError(f"chain process: exited (code {self._process.exitcode})") from None

    def shutdown(self, cancel_futures: bool = False):
        """Stop the process (batches still queued there are dropped; ``cancel_futures`` is
        :class:`~warpvx.apps.orbslam_pool.PosePool`'s, kept for its callers: either way) and
        unlink the shared blocks."""
        self.graphs.clear()
        self._primed = None
        self._stop()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.shutdown()


def _same_value(a, b) -> bool:
    """Whether ``a`` and ``b`` (nested tuples, lists and dicts of arrays and plain values) are
    equal, arrays bit for bit (shape and dtype too: -0.0 is not 0.0, a NaN is itself)."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.shape == b.shape
                and a.dtype == b.dtype and a.tobytes() == b.tobytes())
    if isinstance(a, (tuple, list)) or isinstance(b, (tuple, list)):
        return type(a) is type(b) and len(a) == len(b) and all(_same_value(x, y) for x, y in zip(a, b))
    if isinstance(a, dict) or isinstance(b, dict):
        return (type(a) is type(b) and a.keys() == b.keys()
                and all(_same_value(a[k], b[k]) for k in a))
    return type(a) is type(b) and a == b


def _stop(to_child, from_child, process, segments):
    """:meth:`ChainProcess.shutdown`: an end message (the receiver thread stops and the main
    thread drops what is queued, then shuts its pool down), a wait, SIGTERM and SIGKILL as
    the last resorts; the shared blocks unlinked, the pipes closed."""
    try:
        to_child.send(None)
    except (OSError, ValueError):
        pass  # already gone
    to_child.close()
    process.join(STOP_WAIT_S)
    for end in (process.terminate, process.kill):
        if process.exitcode is None:
            end()
            process.join(5.0)
    from_child.close()
    segments.close()


# --------------------------------------------------------------------------- the graph's nodes


def send_batch(images, feats, nearest, sent, *, K, config, baseline, frames, proc: ChainProcess):
    """The graph's ``pose_batch`` node with a chain process: the batch to ``proc`` ->
    (``sent`` + 1, its ticket). ``sent`` 0: the first batch of a run (its parameters go with
    it). ``images`` travel only for a stereo camera. In ``proc``'s
    :meth:`~ChainProcess.dry_run`, a dry ticket (a priming one's first batch also sent)."""
    run = None
    if sent == 0:
        params = dict(K=K, config=config, baseline=baseline, frames=frames)
        run = (params, {"switch": sys.getswitchinterval(), "ahead": proc.ahead, "share": proc.share,
                        "direct": proc.direct, "look_ahead": check_look_ahead(proc.look_ahead)})
    if proc.dry and not (run is not None and proc.priming):
        return sent + 1, proc.send_dry(frames)
    payload = (None if baseline is None else np.asarray(images), _pack_host(feats), tuple(nearest))
    if proc.dry:
        proc.prime(payload, run)  # (or not: a run on this process goes on)
        return sent + 1, proc.send_dry(frames)
    return sent + 1, proc.send(payload, run)


def receive_batch(ticket, *, proc: ChainProcess):
    """The graph's ``chain`` node with a chain process: the batch's (poses, stats)."""
    return proc.result(ticket)


__all__ = ["ChainProcess", "send_batch", "receive_batch", "KEEP_RESULTS"]
