"""The Ray side of :mod:`warpvx.apps.batch`: a pool of actors, each running one input at a time.

An actor is one worker process holding ``num_gpus`` of a GPU and ``num_cpus`` CPUs for its
whole life, so Warp's loaded kernels, the CUDA context and the graph calibration stay warm
from one input to the next (Ray runs GPU *tasks* in a fresh process each). A worker process
that dies is restarted by Ray and its input retried (``max_restarts`` / ``max_task_retries``);
when the retries are spent the input fails alone and a fresh actor takes the worker's place.
"""

from __future__ import annotations

import math
import os
from collections import deque

from ..errors import WarpvxValueError


def import_ray():
    """The ``ray`` module, or a warpvx error naming ``ray`` saying how to install it."""
    try:
        import ray
    except ImportError:
        raise WarpvxValueError("ray: Ray is not installed (pip install 'warpvx[cluster]'); "
                               "without --ray the batch runs in this process") from None
    return ray


class BatchWorker:
    """The actor: runs :func:`warpvx.apps.batch.run_item` for the inputs it is given."""

    def run(self, app, source, out_root, name, options) -> dict:
        from .batch import run_item

        return run_item(app, source, out_root, name, options)


def worker_count(resources, num_gpus, num_cpus, n_inputs, workers=None) -> int:
    """How many workers to start: ``workers`` (checked to fit) or as many as ``resources``
    (Ray's ``{"CPU": n, "GPU": m}``) hold, at most ``n_inputs``."""
    from ..check import check_float, check_int

    num_gpus = check_float(num_gpus, "num_gpus", min_value=0.0)
    num_cpus = check_float(num_cpus, "cpus_per_input", min_value=0.0, strict_min=True)
    if num_gpus > 1 and num_gpus != int(num_gpus):
        raise WarpvxValueError(f"num_gpus: expected a fraction <= 1 or a whole number, got {num_gpus:g}")
    cpus, gpus = resources.get("CPU", 0.0), resources.get("GPU", 0.0)
    fit = math.floor(cpus / num_cpus + 1e-9)
    if num_gpus > 0:
        fit = min(fit, math.floor(gpus / num_gpus + 1e-9))
    if fit < 1:
        raise WarpvxValueError(f"num_gpus, cpus_per_input: a worker asks for {num_gpus:g} GPU and "
                               f"{num_cpus:g} CPUs, the Ray cluster has {gpus:g} GPUs and {cpus:g} CPUs")
    if workers is None:
        return max(1, min(fit, n_inputs))
    workers = check_int(workers, "workers", min_value=1)
    if workers > fit:
        raise WarpvxValueError(f"workers: the Ray cluster holds at most {fit} workers of {num_gpus:g} "
                               f"GPU and {num_cpus:g} CPUs, got {workers}")
    return min(workers, n_inputs)


def run_on_ray(app, todo, out, options, report, *, address, num_gpus, num_cpus, workers, retries):
    """Run ``todo`` (``(index, source, name)`` triples) on Ray, calling ``report(index, row)``
    as each input finishes. ``address``: ``""`` for a local instance; joins the instance
    ``ray.init`` already made, and shuts down only one it started itself."""
    from ..check import check_int
    from .batch import summary_row

    ray = import_ray()
    retries = check_int(retries, "retries", min_value=0)
    started = not ray.is_initialized()
    if started:
        ray.init(address=address or None, include_dashboard=False, log_to_driver=False)
    try:
        n = worker_count(ray.cluster_resources(), num_gpus, num_cpus, len(todo), workers)
        actor = ray.remote(BatchWorker).options(num_gpus=num_gpus, num_cpus=num_cpus,
                                                max_restarts=retries, max_task_retries=retries)
        idle = [actor.remote() for _ in range(n)]
        pending, running = deque(todo), {}
        out = os.path.abspath(out)  # workers need not share the driver's working directory
        while pending or running:
            while pending and idle:
                worker, (i, source, name) = idle.pop(), pending.popleft()
                ref = worker.run.remote(app, os.path.abspath(source), out, name, options)
                running[ref] = (worker, i, source)
            [ref], _ = ray.wait(list(running), num_returns=1)
            worker, i, source = running.pop(ref)
            try:
                row = ray.get(ref)
            except ray.exceptions.RayError as exc:
                row = summary_row(source, None, "failed", error=f"worker died ({retries} retries spent): "
                                                         f"{type(exc).__name__}")
                ray.kill(worker, no_restart=True)
                worker = actor.remote()
            row["input"] = source
            idle.append(worker)
            report(i, row)
    finally:
        if started:
            ray.shutdown()


__all__ = ["import_ray", "BatchWorker", "worker_count", "run_on_ray"]
