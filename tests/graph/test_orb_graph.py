"""warpvx.orb_graph: the per-level ORB stage graph equals warpvx.orb; the DL node's GPU time."""


from types import SimpleNamespace

import cv2
import numpy as np
import pytest

import warpvx
from warpvx import sched
from warpvx.errors import WarpvxValueError
from warpvx.graph.orb_graph import KEYPOINT_FIELDS, dl_workload, orb_graph
from tests.images import bgr, gray
from tests.kernels.test_orb import assert_same_extraction

W, H = 160, 120
ORB_ARGS = dict(n_features=300, levels=4)
STAGES = ("FAST", "Grid", "Quadtree", "Angle", "Descriptor", "ScaleBack")


@pytest.fixture(scope="module")
def cams():
    """Two real gray views (a stereo-like pair: the second shifted by a few pixels)."""
    gray = cv2.cvtColor(bgr("astronaut"), cv2.COLOR_BGR2GRAY)
    left = cv2.resize(gray, (W + 8, H), interpolation=cv2.INTER_AREA)
    return [np.ascontiguousarray(left[:, :W]), np.ascontiguousarray(left[:, 8:])]


@pytest.fixture
def device_quadtree_only(monkeypatch):
    """Make the Warp quadtree's host fallback fail: a test passing with it ran the device
    quadtree."""
    from warpvx.kernels_warp import orb_stages

    def refuse(*args, **kwargs):
        raise AssertionError("the Warp Quadtree node fell back to the host quadtree")

    monkeypatch.setattr(orb_stages, "distribute_octtree", refuse)


def _assert_equal_to_orb(out, cam, img, backend="warp-cpu"):
    """The graph's camera ``cam`` against ``warpvx.orb`` on the CPU: every field and
    descriptor byte (on CUDA the angles within 2 ulp, see test_orb's assert_same_extraction)."""
    kps, desc = warpvx.orb(img, ORB_ARGS["n_features"], n_levels=ORB_ARGS["levels"],
                           backend="cpu")
    assert len(kps.x) > 50  # a real image: enough features for the comparison to mean something
    got = SimpleNamespace(**{f: out[f"cam{cam}.{f}"] for f in KEYPOINT_FIELDS})
    assert_same_extraction(got, out[f"cam{cam}.descriptors"], kps, desc, backend)


def pinned(on_gpu):
    """A policy: HEFT with every node that has both implementations pinned by
    ``on_gpu(name)`` (True: the GPU role, False: a CPU worker)."""
    def policy(dag):
        dag = dag.copy()
        for v, data in dag.nodes(data=True):
            cost = data["cost"]
            if "gpu" in cost and len(cost) > 1:
                data["cost"] = {p: c for p, c in cost.items() if (p == "gpu") == on_gpu(v)}
        return sched.heft(dag)
    return policy


# Placements: name -> (gpu_quadtree, on_gpu(node name)) for the nodes with both
# implementations. The mixed ones cross the host/device border between stages and between
# levels, in both directions.
PLACEMENTS = {
    "cpu": (True, lambda name: False),
    "all-warp": (True, lambda name: True),
    "cpu-exclusive-quadtree": (False, lambda name: True),
    "alternate-stages": (True, lambda name: name.startswith(("FAST", "Quadtree", "Descriptor",
                                                            "Handoff"))),
    # Levels 1 and 3 (and camera 1's hand-off) on the GPU role, levels 0 and 2 on the CPU.
    "alternate-levels": (True, lambda name: name[-1] in "13"),
}


@pytest.mark.parametrize("placement", list(PLACEMENTS))
def test_stage_graph_equals_orb(cams, warp_backend, device_quadtree_only, placement):
    gpu_quadtree, on_gpu = PLACEMENTS[placement]
    g = orb_graph(2, width=W, height=H, gpu_quadtree=gpu_quadtree, **ORB_ARGS)
    plan = g.schedule(pinned(on_gpu), n_cpus=2, gpu=warp_backend)
    for name, node in g.nodes.items():
        if len(node.implementations) == 2:
            assert (plan.placement[name] == "gpu") == on_gpu(name), name
    if not gpu_quadtree:
        assert all(plan.placement[f"Quadtree{c}.{lvl}"].startswith("cpu")
                   for c in (0, 1) for lvl in range(4))
    out = g.process({"cam0": cams[0], "cam1": cams[1]})
    for cam, img in enumerate(cams):
        _assert_equal_to_orb(out, cam, img, warp_backend)
    g.close()


@pytest.mark.parametrize("policy", ["baseline", "heft", "xeft", "best"])
def test_cpu_exclusive_quadtree_stays_on_the_cpu(policy):
    """gpu_quadtree=False (the thesis' setting): Quadtree nodes have only the sequential CPU
    implementation and every policy places them on CPU workers; the other stages keep both."""
    g = orb_graph(1, width=W, height=H, gpu_quadtree=False, **ORB_ARGS)
    both = orb_graph(1, width=W, height=H, **ORB_ARGS)
    for lvl in range(ORB_ARGS["levels"]):
        assert g.node(f"Quadtree0.{lvl}").implementations == frozenset({"cpu"})
        assert both.node(f"Quadtree0.{lvl}").implementations == frozenset({"cpu", "gpu"})
        for stage in STAGES:
            if stage != "Quadtree":
                assert g.node(f"{stage}0.{lvl}").implementations == frozenset({"cpu", "gpu"})
    plan = g.schedule(policy, n_cpus=2, gpu="warp-cpu")
    for lvl in range(ORB_ARGS["levels"]):
        assert plan.placement[f"Quadtree0.{lvl}"].startswith("cpu")
    if policy == "baseline":  # everything with a GPU implementation goes there
        assert plan.placement["FAST0.2"] == plan.placement["Descriptor0.0"] == "gpu"


@pytest.mark.parametrize("name", ["coffee", "brick"])
def test_all_warp_stages_equal_orb_at_full_settings(warp_backend, device_quadtree_only, name):
    """ORB-SLAM2's settings (8 levels, 2000 features) on a whole real photo, every node on the
    GPU role: the device quadtree runs its division rounds on every level."""
    img = gray(name)
    h, w = img.shape
    g = orb_graph(1, width=w, height=h)
    g.schedule("baseline", n_cpus=1, gpu=warp_backend)
    out = g.process({"cam0": img})
    kps, desc = warpvx.orb(img, 2000, backend="cpu")
    assert len(kps.x) > 1000
    got = SimpleNamespace(**{f: out[f"cam0.{f}"] for f in KEYPOINT_FIELDS})
    assert_same_extraction(got, out["cam0.descriptors"], kps, desc, warp_backend)
    g.close()


def test_warp_quadtree_past_capacity_takes_the_host_quadtree(cams, monkeypatch):
    """A point list larger than the one-level plan holds is distributed on the host, with the
    same result (as the fused extractor's overflow path)."""
    from warpvx.kernels_warp import orb_stages

    calls = []
    host = orb_stages.distribute_octtree
    monkeypatch.setattr(orb_stages, "distribute_octtree",
                        lambda *args: calls.append(args) or host(*args))

    class NoRoom(orb_stages.OrbPlan):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.cand_cap = 1

    monkeypatch.setattr(orb_stages, "OrbPlan", NoRoom)
    monkeypatch.setattr(orb_stages, "acquire", lambda key, make: make())  # no pooled plans
    monkeypatch.setattr(orb_stages, "release", lambda key, plan: None)
    g = orb_graph(2, width=W, height=H, **ORB_ARGS)
    g.schedule("baseline", n_cpus=1, gpu="warp-cpu")
    calls.clear()  # calibration may have run the stages (it does where CUDA is present)
    out = g.process({"cam0": cams[0], "cam1": cams[1]})
    assert len(calls) == 2 * ORB_ARGS["levels"]
    for cam, img in enumerate(cams):
        _assert_equal_to_orb(out, cam, img)
    g.close()


def test_stage_graph_shape_of_table51():
    g = orb_graph(8, levels=8, dl_node_ms=15, width=W * 2, height=H * 2)
    kinds = ("Scale", "FAST", "Grid", "Quadtree", "Angle", "Blur", "Descriptor", "ScaleBack")
    for cam in (0, 7):
        for lvl in range(8):
            for kind in kinds:
                if (kind, lvl) != ("Scale", 0):
                    g.node(f"{kind}{cam}.{lvl}")
    assert not g.node("Quadtree3.5").exclusive  # the device quadtree is its GPU implementation
    thesis = orb_graph(8, levels=8, width=W * 2, height=H * 2, gpu_quadtree=False)
    assert thesis.node("Quadtree3.5").exclusive  # the sequential quadtree only: CPU-exclusive
    assert g.node("DL").implementations == frozenset({"gpu"})
    # Calibration caches costs by the node's cache key and input sizes: a DL node of another
    # duration must not read this one's cost (Table 5.1's DL 20/25 ms columns once did).
    other = orb_graph(1, levels=2, dl_node_ms=25, width=W * 2, height=H * 2)
    assert other.node("DL").cache_key() != g.node("DL").cache_key()
    assert "dl" in g.outputs


def test_dl_node_time_is_what_was_asked():
    import warp as wp

    from warpvx.graph.orb_graph import busy_clock, dl_iterations

    asked_ms = 25.0
    src = wp.zeros(4, dtype=wp.uint8, device="cpu")
    # Measured with the device's busy clock (the thread's CPU time on Warp's CPU device, so a
    # shared 2-core host's other load does not count; a sleep would measure ~0). Up to three
    # fresh calibrate-then-measure attempts; a wrong calibration misses all three.
    clock = busy_clock("cpu")
    medians = []
    for _ in range(3):
        dl_iterations.cache_clear()
        fn = dl_workload(asked_ms)
        fn(src)  # calibrates on this device
        times = []
        for _ in range(5):
            t0 = clock()
            out = fn(src)
            wp.synchronize_device("cpu")
            times.append((clock() - t0) * 1e3)
        medians.append(float(np.median(times)))
        if abs(medians[-1] - asked_ms) <= 0.1 * asked_ms:
            break
    assert abs(medians[-1] - asked_ms) <= 0.1 * asked_ms, medians
    assert out.shape == (256,) and np.all(np.isfinite(out.numpy())) and out.numpy().any()


@pytest.mark.parametrize("kwargs, arg", [
    (dict(cameras=0), "cameras"), (dict(levels=0), "levels"), (dict(dl_node_ms=-1), "dl_node_ms"),
    (dict(levels=40, width=64, height=48), "levels"), (dict(scale_factor=1.0), "scale_factor"),
])
def test_bad_arguments_name_the_argument(kwargs, arg):
    with pytest.raises(WarpvxValueError, match=arg):
        orb_graph(**kwargs)
