"""What the scripts of benchmarks/perf/ share: argument types, the OpenCV thread setting, a
placement with one node moved."""

from __future__ import annotations

import argparse
from contextlib import contextmanager

import cv2


def positive(text: str) -> int:
    n = int(text)
    if n < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text}")
    return n


def non_negative(text: str) -> int:
    n = int(text)
    if n < 0:
        raise argparse.ArgumentTypeError(f"expected 0 or more, got {text}")
    return n


def positive_float(text: str) -> float:
    v = float(text)
    if not v > 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text}")
    return v


def frame_size(text: str) -> tuple:
    """``WxH`` of at least 32x32 (the two-camera graph's 4-level pyramids and 21x21 LK
    windows)."""
    try:
        w, h = (int(v) for v in text.split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WxH, e.g. 1280x720, got {text!r}") from None
    if w < 32 or h < 32:
        raise argparse.ArgumentTypeError(f"expected at least 32x32, got {text}")
    return w, h


def add_cv_threads(ap: argparse.ArgumentParser):
    ap.add_argument("--cv-threads", type=non_negative, default=1,
                    help="cv2.setNumThreads for the run (default 1, as graph_bench: one core per "
                         "CPU worker; 0: OpenCV's own pool left as it is)")


@contextmanager
def opencv_threads(n: int):
    """``cv2.setNumThreads(n)`` for the block (``n`` 0: left as it is), restored after."""
    before = cv2.getNumThreads()
    if n:
        cv2.setNumThreads(n)
    try:
        yield
    finally:
        cv2.setNumThreads(before)


def baseline_moving(dag, node: str, processor: str, name: str):
    """The baseline placement of ``dag`` (a one-frame task DAG) with ``node`` on
    ``processor`` (a CPU worker), called ``name``."""
    from warpvx.sched import policies
    from warpvx.sched.schedule import Schedule, ScheduledTask

    s = policies.baseline(dag)
    tasks = dict(s.tasks)
    st = tasks[node]
    tasks[node] = ScheduledTask(st.task, processor, st.start, st.finish)
    return Schedule(tasks, s.processors, name, s.priority, dict(s.info))
