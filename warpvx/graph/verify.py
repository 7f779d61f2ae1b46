"""Graph verification (OpenVX ``vxVerifyGraph``): structure, then types and shapes by a dry run.

Structure: every node input is a graph input, a node output or a delay of one (else *missing
input*); data dependencies within a frame form no cycle (delays may close loops across
frames); every pin is feasible. Types and shapes: each node runs once, in dependency order, on
the CPU implementation (the GPU one, on Warp's CPU device, for GPU-only nodes) with sample
data at the graph's real sizes — the inputs' given values, or synthetic ones of their
declared shape and dtype. A primitive validates its arguments with warpvx's checker, whose
errors name the argument: that argument is the port in the :class:`~warpvx.errors.GraphError`.
The outputs become the samples of the next nodes (and what calibration times nodes on).
With delays, a second frame runs on the first one's values. User nodes run too, so they
should not have side effects that matter at verification.
"""

from __future__ import annotations

import zlib

import networkx as nx
import numpy as np

from ..arrays import contiguous
from ..errors import GraphError, WarpvxError
from ..runtime import Transfers
from .data import INPUT, DelayRef, describe, synth, zeros_like
from .nodes import port_of


def dependency_graph(graph) -> nx.DiGraph:
    """Nodes and their same-frame data edges (``u -> v`` with attribute ``data``: list)."""
    g = nx.DiGraph()
    g.add_nodes_from(graph.nodes)
    for node in graph.nodes.values():
        for port, ref in node.inputs.items():
            if isinstance(ref, DelayRef):
                continue
            if ref.producer is not None:
                u = ref.producer.name
                if g.has_edge(u, node.name):
                    g[u][node.name]["data"].append(ref)
                else:
                    g.add_edge(u, node.name, data=[ref])
    return g


def check_structure(graph) -> nx.DiGraph:
    """Missing inputs and cycles; returns the dependency graph."""
    for node in graph.nodes.values():
        for port, ref in node.inputs.items():
            data = ref.data if isinstance(ref, DelayRef) else ref
            if data.kind != INPUT and data.producer is None:
                raise node.error(port, f"reads {data.name!r}, which no node produces and which "
                                       f"is not a graph input (missing input)")
        if node.target is not None and node.target not in node.implementations:
            raise node.error("target", f"pinned to {node.target!r} but it has only "
                                       f"{sorted(node.implementations)} implementation(s)")
    for name, data in graph.outputs.items():
        if data.kind != INPUT and data.producer is None:
            raise GraphError(f"output {name!r}: {data.name!r} is never produced (missing input)")
    g = dependency_graph(graph)
    if not nx.is_directed_acyclic_graph(g):
        cycle = nx.find_cycle(g)
        steps = []
        for u, v in cycle:
            refs = g[u][v]["data"]
            port = next(p for p, r in graph.nodes[v].inputs.items() if r is refs[0])
            steps.append(f"node {v!r} port {port!r} reads {refs[0].name!r} from node {u!r}")
        first_v = cycle[0][1]
        first_port = next(p for p, r in graph.nodes[first_v].inputs.items()
                          if r is g[cycle[0][0]][first_v]["data"][0])
        raise GraphError(f"node {first_v!r} ({graph.nodes[first_v].kind}), port {first_port!r}: "
                         f"cycle: " + "; ".join(steps)
                         + " (use g.delay(data)[-1] to read the previous frame's value)")
    return g


def input_sample(data, given=None):
    """The sample of a graph input: ``given``, the written value, or synthetic data."""
    if given is not None:
        value = given
    elif data._has_value:
        value = data._value
    elif data.shape is not None and data.dtype is not None and all(s is not None for s in data.shape):
        value = synth(data.shape, data.dtype, seed=zlib.crc32(data.name.encode()))
    else:
        raise GraphError(f"input {data.name!r}: no value and no complete shape/dtype to verify "
                         f"with; give g.input(..., shape=, dtype=) or value=, or pass inputs")
    if hasattr(value, "numpy") and not isinstance(value, np.ndarray):
        value = value.numpy()
    check_input(data, value)
    return contiguous(value)


def check_input_names(graph, inputs: dict):
    """Every key of a frame's ``inputs`` names an input of ``graph`` (a misspelling raises
    GraphError naming it and listing the graph's inputs)."""
    unknown = [k for k in inputs if k not in graph.inputs]
    if unknown:
        raise GraphError(f"inputs: unknown input(s) {unknown}; the graph has {sorted(graph.inputs)}")


def check_input(data, value):
    """An input value agrees with the declared shape and dtype (None dims are free)."""
    if not isinstance(value, np.ndarray) and not (hasattr(value, "shape") and hasattr(value, "dtype")):
        if data.shape is not None or data.dtype is not None:
            raise GraphError(f"input {data.name!r}: expected an array of shape {data.shape} "
                             f"and dtype {data.dtype}, got {type(value).__name__}")
        return
    shape = tuple(value.shape)
    if data.shape is not None:
        ok = len(shape) == len(data.shape) and all(e is None or e == a for e, a in zip(data.shape, shape))
        if not ok:
            raise GraphError(f"input {data.name!r}: expected shape {data.shape}, got {shape}")
    if data.dtype is not None:
        dt = value.dtype if isinstance(value, np.ndarray) else _warp_np_dtype(value)
        if dt != data.dtype:
            raise GraphError(f"input {data.name!r}: expected dtype {data.dtype}, got {dt}")


def _warp_np_dtype(a):
    from ..arrays import numpy_dtype

    return numpy_dtype(a)


def dry_run(graph, order, given=None, gpu=None):
    """Run every node on samples; set each data object's ``sample`` and the delays' inits.

    A node runs its CPU implementation when it has one, except a node pinned to the GPU when
    ``gpu`` (a resolved GPU backend) is given: it runs there (a batch of images on Warp's CPU
    device can take seconds where the GPU takes milliseconds). Otherwise GPU-only nodes run on
    Warp's CPU device.

    With delays, two frames run: the first reads the delays' initial values (checking that
    they fit), the second reads the first frame's values, so the samples calibration times
    nodes on are those of a running video (LK tracking real points, not zeros). ``given``
    is one dict of input values, or a list of two: the inputs of both frames, so that the
    second frame differs from the first (LK then tracks real motion, as in a video, instead
    of converging at once on a still image).
    """
    frames = _given_frames(given)
    for frame in frames:
        check_input_names(graph, frame)
    for name, data in graph.inputs.items():
        data.sample = input_sample(data, frames[0].get(name))
    for node in graph.nodes.values():
        for d in node.outputs.values():
            d.sample = None
    from ..backend import resolve_backend

    cpu = resolve_backend("cpu")
    _dry_frame(graph, order, cpu, previous=None, gpu=gpu)
    for delay in graph.delays:
        if delay.init is not None:
            delay.set_initial(delay.init)
        else:
            delay.set_initial(zeros_like(delay.data.sample))
    if graph.delays:
        previous = {d.data.name: d.data.sample for d in graph.delays}
        for d in graph.delays:
            d.sample_previous = previous[d.data.name]
        if len(frames) > 1:
            for name, data in graph.inputs.items():
                if name in frames[1]:
                    data.sample = input_sample(data, frames[1][name])
        _dry_frame(graph, order, cpu, previous=previous, gpu=gpu)


def _given_frames(given) -> list:
    if given is None:
        return [{}]
    if isinstance(given, dict):
        return [given]
    if isinstance(given, (list, tuple)) and 1 <= len(given) <= 2 and all(isinstance(g, dict) for g in given):
        return list(given)
    raise GraphError(f"inputs: expected a dict name -> value, or a list of two such dicts (two "
                     f"consecutive frames), got {type(given).__name__}")


def _dry_frame(graph, order, cpu, previous, gpu=None):
    for name in order:
        node = graph.nodes[name]
        values = []
        for port, ref in node.inputs.items():
            if isinstance(ref, DelayRef):
                delay = ref.delay
                if previous is not None:
                    values.append(previous[ref.data.name])
                elif delay.init is not None:
                    values.append(delay.init)
                elif ref.data.sample is not None:
                    values.append(zeros_like(ref.data.sample))
                else:
                    raise node.error(port, f"reads {ref.name!r} before {ref.data.name!r} is "
                                           f"produced in the frame; give g.delay(..., init=) "
                                           f"its initial value")
            else:
                values.append(ref.sample)
        result = _run_once(node, values, cpu, gpu)
        outs = _split(node, result)
        for data, value in zip(node.outputs.values(), outs):
            data.sample = value


def _run_once(node, values, cpu, gpu=None):
    try:
        on_gpu = gpu is not None and node.target == "gpu" and "gpu" in node.implementations
        if "cpu" in node.implementations and not on_gpu:
            return node.callable("cpu", cpu)(*values)
        from ..backend import init_warp, resolve_backend

        be = gpu if on_gpu else resolve_backend("warp-cpu")
        io = Transfers(be.device)
        with init_warp().ScopedDevice(be.device):
            outs = node.callable("gpu", be)(*io.upload(list(values)))
        return io.download(outs)
    except GraphError:
        raise
    except WarpvxError as exc:
        ports = list(node.inputs) + list(getattr(node, "arguments", {}))
        port = port_of(str(exc), ports)
        raise node.error(port, f"{exc} (inputs: "
                               f"{', '.join(f'{p}={describe(v)}' for p, v in zip(node.inputs, values))})") from exc
    except Exception as exc:  # noqa: BLE001 - user code: report it as a verification error
        raise node.error(None, f"raised {type(exc).__name__} during verification: {exc}") from exc


def _split(node, result) -> tuple:
    ports = node.output_ports
    if len(ports) == 1:
        return (result,)
    if not isinstance(result, (tuple, list)) or len(result) != len(ports):
        got = f"{len(result)} values" if isinstance(result, (tuple, list)) else type(result).__name__
        raise node.error(ports[0], f"expected {len(ports)} outputs {tuple(ports)}, got {got}")
    return tuple(result)


def verify(graph, inputs: dict | None = None, gpu=None) -> list:
    """Verify ``graph``; returns the nodes in execution (topological) order. ``gpu``: see
    :func:`dry_run`."""
    g = check_structure(graph)
    order = list(nx.lexicographical_topological_sort(g, key=lambda n: graph._node_index[n]))
    dry_run(graph, order, inputs, gpu)
    return order


__all__ = ["verify", "check_structure", "dependency_graph", "dry_run", "check_input",
           "check_input_names", "contiguous"]
