"""Nodes bound to their implementation after verification: frames skip the public function's
validation where the replay is the same call, and keep it where it is not."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import warpvx
import warpvx.color
import warpvx.geometry
from warpvx.backend import resolve_backend
from warpvx.errors import GraphError
from warpvx.graph.bind import bind

GPUS = [False, "warp-cpu"]


def _counting(monkeypatch, module, name="check_image"):
    calls = []
    real = getattr(module, name)

    def counted(*a, **k):
        calls.append(a[1] if len(a) > 1 else None)
        return real(*a, **k)

    monkeypatch.setattr(module, name, counted)
    return calls


@pytest.mark.parametrize("gpu", GPUS)
def test_bound_frames_skip_validation_and_match_opencv(frames, monkeypatch, gpu):
    g = warpvx.Graph("bound")
    f = g.input("frame", shape=frames[0].shape, dtype=np.uint8)
    gray = g.color_convert(f, code="BGR2GRAY", target="gpu" if gpu else "cpu")
    g.output("gray", gray)
    g.schedule("heft", n_cpus=1, gpu=gpu)
    g.process({"frame": frames[0]})  # the executor (and its bound tasks) exist now
    calls = _counting(monkeypatch, warpvx.color)
    for fr in frames:
        out = g.process({"frame": fr})
        np.testing.assert_array_equal(out["gray"], cv2.cvtColor(fr, cv2.COLOR_BGR2GRAY))
    assert calls == []  # no per-frame validation of src
    g.close()


@pytest.mark.parametrize("gpu", GPUS)
def test_matrix_from_an_input_is_not_bound_and_follows_each_frame(frames, monkeypatch, gpu):
    # warp_perspective derives its coefficients from M: a node reading M as data is replayed
    # through the public function, so every frame's M is inverted anew.
    g = warpvx.Graph("warp")
    src = g.input("src", shape=frames[0].shape[:2], dtype=np.uint8)
    M = g.input("M", value=np.eye(3))
    h, w = frames[0].shape[:2]
    g.output("out", g.warp_perspective(src, M, dsize=(w, h), target="gpu" if gpu else "cpu"))
    g.schedule("heft", n_cpus=1, gpu=gpu)
    calls = _counting(monkeypatch, warpvx.geometry)
    img = cv2.cvtColor(frames[0], cv2.COLOR_BGR2GRAY)
    for dx in (0.0, 3.0, -5.0):
        m = np.float64([[1, 0, dx], [0, 1, 2.0], [0, 0, 1]])
        out = g.process({"src": img, "M": m})
        np.testing.assert_array_equal(out["out"], cv2.warpPerspective(img, m, (w, h)))
    assert len(calls) >= 3
    g.close()


def test_a_frame_of_another_shape_takes_the_public_path(frames):
    g = warpvx.Graph("free")
    f = g.input("frame", shape=(None, None, 3), dtype=np.uint8, value=frames[0])
    g.output("gray", g.color_convert(f, code="BGR2GRAY"))
    g.schedule("heft", n_cpus=1, gpu=False)
    small = np.ascontiguousarray(frames[1][:40, :50])
    for fr in (frames[0], small, frames[2]):
        np.testing.assert_array_equal(g.process({"frame": fr})["gray"],
                                      cv2.cvtColor(fr, cv2.COLOR_BGR2GRAY))
    g.close()


def test_bad_frame_input_is_still_a_graph_error(frames):
    g = warpvx.Graph("bad")
    f = g.input("frame", shape=frames[0].shape, dtype=np.uint8)
    g.output("gray", g.color_convert(f, code="BGR2GRAY"))
    g.process({"frame": frames[0]})
    with pytest.raises(GraphError, match="frame"):
        g.process({"frame": frames[0].astype(np.float32)})
    with pytest.raises(GraphError, match="frame"):
        g.process({"frame": frames[0][:, :, :2].copy()})
    g.close()


def test_which_nodes_bind(frames):
    g = warpvx.Graph("which")
    f = g.input("frame", shape=frames[0].shape, dtype=np.uint8)
    gray = g.color_convert(f, code="BGR2GRAY", name="gray")
    g.gaussian_blur(gray, ksize=(5, 5), sigma=1.2, name="blur")
    g.gaussian_pyramid(gray, levels=3, name="pyr")  # post-processes dispatch's result
    g.user(lambda x: x, [gray], name="user")
    g.verify()
    cpu = resolve_backend("cpu")
    public = {n: g.node(n).callable("cpu", cpu) for n in ("gray", "blur", "pyr", "user")}
    bound = {n: bind(g.node(n), "cpu", cpu) for n in public}
    # A user node runs its own function (wrapped to mark the thread as inside the node).
    assert bound["user"].__wrapped__ is g.node("user").fn
    # The pyramid is not bound: its bound callable is the public one (a fresh closure each time,
    # so compare by code).
    assert bound["pyr"].__code__ is public["pyr"].__code__
    assert bound["gray"].__code__ is not public["gray"].__code__
    assert bound["blur"].__code__ is not public["blur"].__code__
    img = frames[1]
    gray_img = bound["gray"](img)
    np.testing.assert_array_equal(gray_img, cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    np.testing.assert_array_equal(bound["blur"](gray_img), public["blur"](gray_img))
