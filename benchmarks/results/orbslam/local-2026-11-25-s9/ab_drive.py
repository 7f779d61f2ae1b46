"""A/B driver: the batches of prep.py through a ChainProcess (send_batch / receive_batch, at most
DEPTH in flight, as the stream), rounds; prints per-batch chain wall/CPU/waits and FPS; saves poses."""
import json, pickle, sys, time
import numpy as np

AB = __import__('os').environ.get('AB_DIR', '/tmp/slam10ab')  # where the A/B's inputs and outputs go
from warpvx.apps import orbslam as o, orbslam_batch as ob
from warpvx.apps.orbslam_chain import ChainProcess, send_batch, receive_batch
K, batches, idx = pickle.load(open(AB + "/batches.pkl", "rb"))
workers, rounds, tag = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
B, DEPTH = 16, 3
config = o.TrackerConfig()
rows = []
with ChainProcess(workers) as proc:
    if len(sys.argv) > 4:
        proc.look_ahead = int(sys.argv[4])
    for r in range(rounds + 1):
        before = proc.counts()
        t = time.perf_counter()
        pending, poses, sent = [], [], 0
        for feats, nearest in batches:
            sent, ticket = send_batch(None, ob._pack_host(feats) if hasattr(ob, "_pack_host") else feats, nearest, sent,
                                      K=K, config=config, baseline=None, frames=B, proc=proc)
            pending.append(ticket)
            if len(pending) >= DEPTH:
                poses.append(receive_batch(pending.pop(0), proc=proc)[0])
        for tk in pending:
            poses.append(receive_batch(tk, proc=proc)[0])
        dt = time.perf_counter() - t
        now = proc.counts()
        n = len(batches)
        row = {"fps": n * B / dt,
               "wall": 1e3 * (now[3]["wall_s"] - before[3]["wall_s"]) / n,
               "cpu": 1e3 * (now[3]["cpu_s"] - before[3]["cpu_s"]) / n,
               "wait_kf": 1e3 * (now[0]["keyframe"] - before[0]["keyframe"]) / n,
               "wait_ahead": 1e3 * (now[0]["ahead"] - before[0]["ahead"]) / n,
               "spot": (now[1]["on the spot"] - before[1]["on the spot"]) / n,
               "cores": (now[1]["_essential_job"] - before[1]["_essential_job"]) / n}
        if r:  # (round 0: warm-up)
            rows.append(row)
        print(tag, r, {k: round(v, 2) for k, v in row.items()}, flush=True)
np.save(f"{AB}/poses_{tag}.npy", np.concatenate(poses))
med = {k: float(np.median([x[k] for x in rows])) for k in rows[0]}
print("MEDIAN", tag, {k: round(v, 2) for k, v in med.items()})
json.dump(med, open(f"{AB}/med_{tag}.json", "w"))
