"""Pose bit-identity: batched (chain process; look-ahead default and 16; a first run primed) vs
frame by frame, on a rendered 64-frame sequence and castle_simu; saves the batched poses (for main's)."""
import sys
import numpy as np

AB = __import__('os').environ.get('AB_DIR', '/tmp/slam10ab')  # where the A/B's inputs and outputs go
from warpvx.apps import orbslam as o, orbslam_batch as ob
from warpvx.apps.orbslam_sources import open_source
from warpvx.apps.orbslam_synth import render_sequence
tag = sys.argv[1]
left, _, K, _ = render_sequence(64, (640, 480), supersample=1)
seqs = {"rendered64": ([{"image": a} for a in left], o.Camera(K, (640, 480)))}
c = open_source("/work/shared/data/real/castle_simu")
seqs["castle_simu"] = (list(c), c.camera)
out = {}
for name, (frames, cam) in seqs.items():
    want = np.array([f.pose for f in o.track_frames(frames, cam)])
    for la in ([None, 16] if tag == "mine" else [None]):
        kw = {} if la is None else {"look_ahead": la}
        with ob.make_pool(2, chain_process=True, **kw) as proc:
            for run in ("first", "kept", "first_primed"):
                if run == "first_primed":
                    proc.graphs.clear()
                got = np.array([f.pose for f in ob.track_frames_batched(frames, cam, batch=16, pool=proc)])
                out[f"{name}_{la}_{run}"] = got
                print(tag, name, f"look_ahead={la}", run, "frames", len(got), "max|batched - frame by frame|",
                      float(np.abs(got - want).max()), dict(proc.started) if run == "first_primed" else "", flush=True)
np.savez(f"{AB}/ident_{tag}.npz", **out)
