"""Precompute the batches' features and nearest rows (cpu backend) once: the A/B input."""
import pickle, sys, time
import numpy as np

AB = __import__('os').environ.get('AB_DIR', '/tmp/slam10ab')  # where the A/B's inputs and outputs go
from warpvx.apps import orbslam as o, orbslam_batch as ob
from warpvx.apps.orbslam_synth import render_sequence
B, UNIQUE, N = 16, int(sys.argv[1]), int(sys.argv[2])
left, right, K, gt = render_sequence(UNIQUE, (1241, 376), baseline=0.54, step=0.25, supersample=1)
cycle = list(range(UNIQUE)) + list(range(UNIQUE - 2, 0, -1))
frames = [left[cycle[i % len(cycle)]] for i in range(N)]
config = o.TrackerConfig()
feats_u = {}
t = time.time()
import warpvx
for i in range(UNIQUE):
    feats_u[i] = warpvx.orb(left[i], **config.orb_args(), backend="cpu")
print("orb", time.time() - t, flush=True)
before = np.zeros((0, 32), np.uint8)
batches = []
for b in range(N // B):
    idx = [cycle[i % len(cycle)] for i in range(b * B, b * B + B)]
    feats = [feats_u[i] for i in idx]
    before, nearest = ob.match_batch(feats, before, frames=B)
    batches.append((feats, nearest))
pickle.dump((K, batches, [cycle[i % len(cycle)] for i in range(N)]), open(AB + "/batches.pkl", "wb"))
print("done", time.time() - t)
