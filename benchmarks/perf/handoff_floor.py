"""The floor under the executor's alternating CPU/GPU chain: what one round (a CPU node, then a
GPU node, each reading the other's 16-byte value) costs in raw Warp and Python, without the
executor, on this machine.

    PYTHONPATH=. python3 benchmarks/perf/handoff_floor.py --out $OUT/floor

Rows, each the median over batches of ``--rounds`` rounds, us per round (the executor's
``overhead_bench`` reports per node: a round is two nodes):

- ``copies``: one thread: upload 16 bytes from pinned host memory, download them to pinned
  host memory, wait for the stream (``wp.synchronize_stream``): the device round trip;
- ``copies + event``: the same, waiting on an event recorded after the download
  (``wp.synchronize_event``), as a reader on another thread must;
- ``threads``: two Python threads handing a token back and forth (``threading.Event``), no
  device work: the wake-up cost of two hand-offs;
- ``threads + copies``: the GPU thread uploads, downloads and records an event; the CPU thread
  waits on the event, then hands back: the executor's round with nothing else.

Writes ``handoff_floor.md`` (the command on top).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import threading
import time
from pathlib import Path

import numpy as np


def _median_us(fn, rounds: int, batches: int) -> float:
    fn(rounds)  # warm-up
    times = []
    for _ in range(batches):
        t0 = time.perf_counter()
        fn(rounds)
        times.append((time.perf_counter() - t0) / rounds * 1e6)
    return statistics.median(times)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--device", default="cuda:0")
    ap.add_argument("--rounds", type=int, default=2000)
    ap.add_argument("--batches", type=int, default=7)
    args = ap.parse_args(argv)
    for name in ("rounds", "batches"):
        if getattr(args, name) < 1:
            ap.error(f"--{name}: at least 1, got {getattr(args, name)}")
    import warp as wp

    wp.config.quiet = True
    wp.init()
    dev = wp.get_device(args.device)
    pinned = dev.is_cuda
    host_in = wp.array(np.arange(4, dtype=np.float32), device="cpu", pinned=pinned)
    host_out = wp.zeros(4, dtype=wp.float32, device="cpu", pinned=pinned)
    on_dev = wp.zeros(4, dtype=wp.float32, device=dev)
    stream = wp.get_stream(dev) if dev.is_cuda else None
    event = wp.Event(dev) if dev.is_cuda else None

    def up_down():
        wp.copy(on_dev, host_in)
        wp.copy(host_out, on_dev)

    def gpu_work():  # what the GPU side of a round enqueues
        up_down()
        if event is not None:
            wp.record_event(event)

    def copies(n):
        for _ in range(n):
            up_down()
            if stream is not None:
                wp.synchronize_stream(stream)

    def copies_event(n):
        for _ in range(n):
            gpu_work()
            if event is not None:
                wp.synchronize_event(event)

    def handoffs(n, work=None):
        to_gpu, to_cpu = threading.Event(), threading.Event()

        def gpu_side():
            for _ in range(n):
                to_gpu.wait()
                to_gpu.clear()
                if work is not None:
                    work()
                to_cpu.set()

        t = threading.Thread(target=gpu_side)
        t.start()
        for _ in range(n):
            to_gpu.set()
            to_cpu.wait()
            to_cpu.clear()
            if event is not None and work is not None:
                wp.synchronize_event(event)
        t.join()

    rows = [("copies", _median_us(copies, args.rounds, args.batches)),
            ("copies + event", _median_us(copies_event, args.rounds, args.batches)),
            ("threads", _median_us(handoffs, args.rounds, args.batches)),
            ("threads + copies", _median_us(lambda n: handoffs(n, gpu_work), args.rounds,
                                            args.batches))]
    args.out.mkdir(parents=True, exist_ok=True)
    lines = [f"<!-- PYTHONPATH=. python3 benchmarks/perf/handoff_floor.py --out {args.out} -->",
             f"# One CPU->GPU->CPU round without the executor ({dev.name}, Warp {wp.config.version})",
             "", f"Median of {args.batches} batches of {args.rounds} rounds.", "",
             "| what | us per round | us per node (round / 2) |", "|---|---:|---:|"]
    lines += [f"| {name} | {us:.1f} | {us / 2:.1f} |" for name, us in rows]
    (args.out / "handoff_floor.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
