"""Binding a primitive node to its implementation once, after verification.

A primitive's public function validates its arguments, derives what the implementation takes
(mode codes, inverted matrices, sizes) and calls :func:`warpvx.registry.dispatch`. In a
verified graph the constants never change and every frame's inputs have been checked by the
graph (graph inputs against their declared shape and dtype, intermediates produced by the
nodes themselves), so a frame need not run that again: :func:`bind` runs the public function
once per node and processing element with a recording ``dispatch``, and each frame then calls
``dispatch`` directly with the recorded arguments and the frame's input values in place of
the samples.

A node is bound only where that replay is provably the same call: every input is an array
passed to ``dispatch`` unchanged (found by identity), the public function returns
``dispatch``'s result unchanged, and a second recording with different input contents of
the same shapes derives the same other arguments (nothing is computed from input values). A
frame whose inputs differ in shape or dtype from verification's samples, and every other
node, calls the public function as before.
"""

from __future__ import annotations

import types

import numpy as np

from .data import DelayRef
from .nodes import PrimitiveNode


class _Recorder:
    """A stand-in for ``dispatch`` that records its call and returns a marker object."""

    def __init__(self):
        self.calls = []
        self.marker = object()

    def __call__(self, name, backend, *args, **kwargs):
        self.calls.append((name, (backend,) + args, kwargs))
        return self.marker


def _record(node, values, backend):
    """``(name, args, kwargs)`` of the one ``dispatch`` call the public function makes for
    ``values``, or None when it makes none or several, fails, or does not return
    ``dispatch``'s result unchanged."""
    fn = node.function
    rec = _Recorder()
    clone = types.FunctionType(fn.__code__, {**fn.__globals__, "dispatch": rec}, fn.__name__,
                               fn.__defaults__, fn.__closure__)
    clone.__kwdefaults__ = fn.__kwdefaults__
    kw = dict(node.arguments)
    kw.update(zip(node.input_ports, values))
    try:
        result = clone(**kw, backend=backend)
    except Exception:  # noqa: BLE001 - e.g. post-processing of the marker: not bindable
        return None
    if result is not rec.marker or len(rec.calls) != 1:
        return None
    return rec.calls[0]


def _same(a, b) -> bool:
    """Deep equality of recorded arguments (arrays by value, host or device)."""
    if isinstance(a, (tuple, list)) and type(a) is type(b):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    arr_a, arr_b = (hasattr(x, "numpy") and not isinstance(x, np.generic) for x in (a, b))
    if isinstance(a, np.ndarray) or arr_a or isinstance(b, np.ndarray) or arr_b:
        ha = a.numpy() if arr_a and not isinstance(a, np.ndarray) else a
        hb = b.numpy() if arr_b and not isinstance(b, np.ndarray) else b
        return isinstance(ha, np.ndarray) and isinstance(hb, np.ndarray) and \
            ha.shape == hb.shape and ha.dtype == hb.dtype and np.array_equal(ha, hb)
    try:
        return bool(a == b) and type(a) is type(b)
    except Exception:  # noqa: BLE001 - incomparable objects: treat as different
        return a is b


def _other_contents(a: np.ndarray) -> np.ndarray:
    """An array of ``a``'s shape and dtype whose every element differs from ``a``'s."""
    if a.dtype == np.bool_:
        return ~a
    with np.errstate(over="ignore", invalid="ignore"):
        return (a + np.ones((), a.dtype)).astype(a.dtype)  # integers wrap around


def _replay(node, pe, backend):
    """``(name, args, kwargs, slots, kw_slots)`` for replaying ``node``'s dispatch, or None."""
    samples = []
    for port in node.input_ports:
        ref = node.inputs[port]
        sample = ref.data.sample if isinstance(ref, DelayRef) else ref.sample
        if not isinstance(sample, np.ndarray) or sample.size == 0:
            return None
        samples.append(sample)
    other = [_other_contents(s) for s in samples]
    if pe == "gpu":
        from ..runtime import Transfers

        io = Transfers(backend.device)
        samples, other = io.upload(samples), io.upload(other)
    first = _record(node, samples, backend)
    second = _record(node, other, backend)
    if first is None or second is None or first[0] != second[0]:
        return None
    name, args, kwargs = first
    index = {id(s): j for j, s in enumerate(samples)}
    slots = [(i, index[id(a)]) for i, a in enumerate(args) if id(a) in index]
    kw_slots = [(k, index[id(v)]) for k, v in kwargs.items() if id(v) in index]
    if sorted(j for _, j in slots + kw_slots) != list(range(len(samples))):
        return None  # an input was transformed (or passed twice): not a plain replay
    moved = {i for i, _ in slots} | {k for k, _ in kw_slots}
    args2, kwargs2 = second[1], second[2]
    if len(args2) != len(args) or set(kwargs2) != set(kwargs):
        return None
    if not all(_same(a, b) for i, (a, b) in enumerate(zip(args, args2)) if i not in moved):
        return None
    if not all(_same(v, kwargs2[k]) for k, v in kwargs.items() if k not in moved):
        return None
    # The recorded samples must not stay alive in the replay: placeholders instead.
    args = tuple(None if i in moved else a for i, a in enumerate(args))
    kwargs = {k: (None if k in moved else v) for k, v in kwargs.items()}
    expected = tuple((tuple(s.shape), s.dtype) for s in samples)
    return name, args, kwargs, slots, kw_slots, expected


def bind(node, pe: str, backend):
    """``fn(*input_values, out=None)`` running ``node`` on ``pe`` with ``backend``: a direct
    ``dispatch`` replay where the node can be bound (see the module docstring), else the
    node's own callable (the public function, validation included)."""
    public = node.callable(pe, backend)
    if not isinstance(node, PrimitiveNode):
        return public
    replay = _replay(node, pe, backend)
    if replay is None:
        return public
    from ..registry import dispatch

    name, base_args, base_kwargs, slots, kw_slots, expected = replay
    takes_out = "out" in base_kwargs

    def run(*values, out=None):
        for v, (shape, dtype) in zip(values, expected):
            if getattr(v, "shape", None) != shape or getattr(v, "dtype", None) != dtype:
                return public(*values, out=out)
        if out is not None and not takes_out:
            return public(*values, out=out)
        args = list(base_args)
        for i, j in slots:
            args[i] = values[j]
        kwargs = dict(base_kwargs)
        for k, j in kw_slots:
            kwargs[k] = values[j]
        if out is not None:
            kwargs["out"] = out
        return dispatch(name, *args, **kwargs)

    return run
