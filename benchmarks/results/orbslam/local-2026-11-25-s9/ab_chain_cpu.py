"""Chain CPU per batch (thread time) in this process, PosePool(2, look_ahead=N): the chain's own
CPU cost of the speculation depth (waits excluded)."""
import pickle, sys, time
import numpy as np

AB = __import__('os').environ.get('AB_DIR', '/tmp/slam10ab')  # where the A/B's inputs and outputs go
from warpvx.apps import orbslam as o, orbslam_batch as ob
K, batches, idx = pickle.load(open(AB + "/batches.pkl", "rb"))
B = 16
config = o.TrackerConfig()
common = dict(K=K, config=config, baseline=None, frames=B)
la = None if sys.argv[1] == "auto" else int(sys.argv[1])
kw = {} if la is None and len(sys.argv) > 2 else ({"look_ahead": la} if la else {})
pool = ob.PosePool(2, **kw)
def run():
    tail, state, cpu, out = ob.NO_TAIL, o.TrackState(), 0.0, []
    aheads = []
    for feats, nearest in batches:
        tail, ahead = ob.pose_batch(None, feats, nearest, tail, pool=pool, **common)
        aheads.append((feats, ahead))
    for feats, ahead in aheads:
        c = time.thread_time()
        state, p, _ = ob.chain(state, feats, ahead, pool=pool, **common)
        cpu += time.thread_time() - c
        out.append(p)
    return 1e3 * cpu / len(batches), np.concatenate(out)
res = [run() for _ in range(4)]
print(sys.argv[1], "chain CPU ms/batch", [round(r[0], 2) for r in res], "cores", pool.started["_essential_job"], "dropped", pool.cancelled["_essential_job"], "spot", pool.started["on the spot"])
np.save(f"{AB}/cpu_{sys.argv[1]}.npy", res[-1][1])
pool.shutdown()
