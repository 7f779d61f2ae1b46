"""Does the graph model's out-of-sample error come from the host's speed drifting, and does a
probe taken just before a run fix it? Offline, on recorded graph-bench runs (no GPU).

Since session 7 ``graph_bench.py`` times a fixed single-threaded OpenCV call before every
interleaved round (``round_log``: ``reference_ms``, the median of 3 calls of its
``denoise`` on a 640x360 image), with the machine's busy and steal time and the cores our
process kept busy over the round. Three checks:

1. *Tracking*: per experiment and policy, each round's median makespan against the
   reference before it (and the other host signals), over the settle, training and later
   rounds: the correlation of their logs and the slope of log makespan on log reference
   (an elasticity: 1 where the makespan moves as the reference does, the CPU share of the
   frame where only the CPU tasks do); the reference's own lag-1 autocorrelation (a speed
   that persists from one round to the next is one a probe can carry forward); and the
   heavy OpenCV nodes' in-frame time (the reference's own call, ``denoise``, among them)
   later over training against the reference later over training.
2. *Scaled replay*: the contention model refit as the bench fits it (GIL-weighted,
   :func:`graph_bench.replay_models`) predicts every policy's recorded plan with its CPU
   tasks' work (``cpu``), or its CPU tasks' and the GPU host thread's eager calls' work and a
   captured segment's fixed cost per replay (``cpu+host``), times ``r = probe now / probe during training`` (training: the median of
   the training rounds' references). The probe now: the reference before each round
   (``round``: each out-of-sample frame predicted with its round's ``r``, the cell the
   median of those predictions), the one before the policy's first scored round
   (``first``: what a user has before running), the median of the round's and the two
   before it (``rolling``, against the median of the settle and training rounds: a more
   robust statistic), and the median over all later rounds (``oracle``: not available
   before the run; the most a level shift of the probe could tell).

Usage::

    PYTHONPATH=. python benchmarks/host_speed_replay.py --out benchmarks/results/graph/model-replay-host-speed.md \\
        benchmarks/results/graph/h100-2026-11-24-s7/graph_bench.json.gz ...
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import statistics
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import graph_bench as gb  # noqa: E402
from model_replay import load, write_result  # noqa: E402 - a graph_bench.json(.gz); a result file

#: The policies of the first rounds and of the later ones (graph_bench.SCHEDULERS, POLICIES).
SCHEDULERS = gb.SCHEDULERS
POLICIES = gb.POLICIES
#: Host signals of a round (graph_bench.ROUND_FIELDS' keys) checked against the makespans.
SIGNALS = ("reference_ms", "busy_pct", "steal_pct", "process_cores")
#: Which parts of a prediction the probe ratio scales: kinds of processing element whose
#: task work (calibrated alone time times the in-frame law, copies left out) is scaled;
#: ``"gpu"`` also scales a captured segment's fixed cost per replay (its launch: host work).
PARTS = {"cpu": ("cpu",), "cpu+host": ("cpu", "gpu")}
#: Probe statistics (see the module docstring), in table order.
PROBES = ("round", "first", "rolling", "oracle")
#: The heavy single-threaded OpenCV nodes of the CV graph (``denoise``: the reference's call).
HEAVY = ("denoiseL", "denoiseR", "edgesL", "edgesR")
#: Rounds the rolling probe takes the median of (the round's and those before it).
ROLLING = 3
WITHIN = 20.0


def round_table(e) -> list:
    """The rounds of one experiment in the order they ran: ``(phase, log entry, policy ->
    median makespan ms)`` over the settle, training and later rounds."""
    rl = e["round_log"]
    out = []
    for phase, log, names in (("settle", e["settle"]["log"], SCHEDULERS),
                              ("training", rl["training"], SCHEDULERS),
                              ("later", rl["later"], POLICIES)):
        out += [(phase, r, dict(zip(names, r["medians"]))) for r in log]
    return out


def _corr(x, y) -> float:
    if len(x) < 3 or np.std(x) == 0 or np.std(y) == 0:
        return float("nan")
    return float(np.corrcoef(x, y)[0, 1])


def _slope(x, y) -> float:
    return float(np.polyfit(x, y, 1)[0]) if len(x) >= 3 and np.std(x) > 0 else float("nan")


def tracking(e) -> dict:
    """Check 1 for one experiment: per policy, the correlation of log round median with
    each :data:`SIGNALS` (log of the reference, the others as they are) and the slope of log
    median on log reference; the reference's range and lag-1 autocorrelation; per-series
    normalised points (log median over the policy's median, log reference over the
    experiment's median) for pooling."""
    rows = round_table(e)
    ref = np.array([r["reference_ms"] for _, r, _ in rows])
    out = {"ref_min": float(ref.min()), "ref_max": float(ref.max()),
           "lag1": _corr(ref[:-1], ref[1:]), "policies": {}, "points": {}}
    mid_ref = float(np.median(ref))
    # The round index: each round's medians over their policies' own medians, averaged
    # (what moved every policy alike: the machine at that time).
    own = {pol: statistics.median(m[pol] for _, _, m in rows if pol in m) for pol in POLICIES}
    index = [statistics.mean(v / own[pol] for pol, v in m.items()) for _, _, m in rows]
    out["index"] = _corr(np.log(ref), np.log(index))
    out["index_range"] = (min(index), max(index))
    for pol in POLICIES:
        sel = [(r, m[pol]) for _, r, m in rows if pol in m]
        y = np.log([m for _, m in sel])
        got = {}
        for s in SIGNALS:
            v = np.array([r.get(s, np.nan) for r, _ in sel], dtype=float)
            ok = ~np.isnan(v)
            x = np.log(v[ok]) if s == "reference_ms" else v[ok]
            got[s] = _corr(x, y[ok])
        x = np.log([r["reference_ms"] for r, _ in sel])
        got["slope"] = _slope(x, y)
        got["rounds"] = len(sel)
        out["policies"][pol] = got
        busy, cores = (np.array([r.get(k, np.nan) for r, _ in sel], dtype=float)
                       for k in ("busy_pct", "process_cores"))
        out["points"][pol] = list(zip(x - math.log(mid_ref), y - float(np.median(y)),
                                      busy - np.nanmedian(busy), cores - np.nanmedian(cores)))
    out["steal_max"] = max(r.get("steal_pct", 0.0) for _, r, _ in rows)
    return out


def reference_step(e) -> float:
    """The reference's median over the later rounds over its median over the training rounds."""
    rl = e["round_log"]
    return (statistics.median(r["reference_ms"] for r in rl["later"])
            / statistics.median(r["reference_ms"] for r in rl["training"]))


def step(e) -> tuple:
    """The training policy's median makespan over its later (out-of-sample) frames over
    its training frames, and :func:`reference_step`."""
    p = next(p for p in e["policies"] if p["policy"] == e["train"])
    fit_n = e["fit_frames"]
    return (statistics.median(p["makespans"][fit_n:]) / statistics.median(p["makespans"][:fit_n]),
            reference_step(e))


def heavy_drift(e) -> list:
    """Per scheduler policy: each heavy OpenCV node on a CPU worker, its worker and its
    median in-frame time in the later (out-of-sample) frames over the training frames;
    beside :func:`reference_step`."""
    ref = reference_step(e)
    out = []
    for p in e["policies"]:
        if p["policy"] == "best":
            continue
        nodes = []
        for n in HEAVY:
            a, b = p.get("fit_nodes", {}).get(n), p.get("nodes", {}).get(n)
            if a and b and a["pe"].startswith("cpu") and b["pe"] == a["pe"]:
                nodes.append((n, a["pe"], b["measured_ms"] / a["measured_ms"]))
        if nodes:
            out.append((p["policy"], nodes, ref))
    return out


def scaled(model, r: float, pes) -> object:
    """``model`` with the task work of ``pes`` (its in-frame law: ratio and fixed cost per
    task) times ``r``, and with ``"gpu"`` a captured segment's fixed cost per replay;
    copies, waits and the replays' device time as they are."""
    slow = {k: dataclasses.replace(s, ratio=s.ratio * r, overhead=s.overhead * r)
            if k in pes else s for k, s in model.slowdown.items()}
    fixed = model.segment_fixed * (r if "gpu" in pes else 1.0)
    return dataclasses.replace(model, slowdown=slow, segment_fixed=fixed)


def probe_ratios(e, policy: str, fit_rounds: int, block: int, n_out: int) -> dict:
    """Per :data:`PROBES` statistic: the probe ratio of each of ``policy``'s ``n_out``
    out-of-sample frames (now over training)."""
    rows = round_table(e)
    refs = [r["reference_ms"] for _, r, _ in rows]
    first_later = next(i for i, (ph, _, _) in enumerate(rows) if ph == "later")
    train = statistics.median(r["reference_ms"] for ph, r, _ in rows if ph == "training")
    train_all = statistics.median(r["reference_ms"] for ph, r, _ in rows if ph != "later")
    oracle = statistics.median(refs[first_later:])
    # The later round each out-of-sample frame ran in: baseline, heft and xeft count their
    # training rounds among their frames, best joined at the later rounds.
    skip = 0 if policy == "best" else fit_rounds
    start = fit_rounds * block
    rnd = [first_later + (start + j) // block - skip for j in range(n_out)]
    first = refs[rnd[0]]
    return {"round": [refs[k] / train for k in rnd],
            "first": [first / train] * n_out,
            "rolling": [statistics.median(refs[max(0, k - ROLLING + 1):k + 1]) / train_all for k in rnd],
            "oracle": [oracle / train] * n_out}


def predictor(model, schedules):
    """``pred(policy, r, parts)``: the predicted makespan (ms) of ``policy``'s schedule with
    :data:`PARTS` ``parts`` :func:`scaled` by ``r`` (memoised: frames share rounds)."""
    cache = {}

    def pred(policy, r, parts):
        key = (policy, round(r, 9), parts)
        if key not in cache:
            m = model if r == 1.0 else scaled(model, r, PARTS[parts])
            cache[key] = m.makespan(schedules[policy])
        return cache[key]

    return pred


def replay_scaled(report, train: str = "baseline") -> list:
    """Check 2 for one graph_bench.json: rows per experiment and policy with the plain
    out-of-sample prediction and, per :data:`PARTS` and :data:`PROBES`, the scaled one
    (ms) against the measured median of its out-of-sample frames, plus the per-round errors
    (each later round's median against the prediction for that round)."""
    block = report.get("block", 10)
    rows = []
    for e, model, schedules in gb.replay_models(report, train, gil=True):
        fit_n = e["fit_frames"]
        fit_rounds = -(-fit_n // block)
        pred = predictor(model, schedules)
        later = [(r["reference_ms"], m) for ph, r, m in round_table(e) if ph == "later"]
        train_ref = statistics.median(r["reference_ms"] for r in e["round_log"]["training"])
        for p in e["policies"]:
            pol = p["policy"]
            out = p["makespans"][fit_n:]
            ratios = probe_ratios(e, pol, fit_rounds, block, len(out))
            plain = pred(pol, 1.0, "cpu")
            row = {"run": report["_name"], "tag": e["tag"], "graph": e["graph"], "policy": pol,
                   "trained_here": pol == train, "measured_ms": statistics.median(out),
                   "measured_first_ms": statistics.median(p["makespans"][:fit_n]),
                   "plain_ms": plain, "scaled_ms": {}, "round_err": {}}
            for parts in PARTS:
                for probe in PROBES:
                    row["scaled_ms"][parts, probe] = statistics.median(
                        pred(pol, r, parts) for r in ratios[probe])
            # Per later round scored: its median against the plain and the round-scaled
            # prediction (does the probe track the rounds?).
            skip = fit_rounds if pol == "best" else 0  # best's first rounds: its fit frames
            for ref, meds in later[skip:]:
                row["round_err"].setdefault("plain", []).append(gb._err(plain, meds[pol]))
                for parts in PARTS:
                    row["round_err"].setdefault(parts, []).append(
                        gb._err(pred(pol, ref / train_ref, parts), meds[pol]))
            rows.append(row)
    return rows


def _experiments(reports: dict):
    """``(run name, experiment)`` of every report, in order."""
    for name, report in reports.items():
        for e in report["experiments"]:
            yield name, e


def _summary(errs) -> str:
    a = [abs(v) for v in errs]
    return (f"{sum(v <= WITHIN for v in a)}/{len(a)} within {WITHIN:g}%, mean |error| "
            f"{statistics.mean(a):.1f}%, median {statistics.median(a):.1f}%, max {max(a):.1f}%")


def _f(v, spec="+.2f") -> str:
    return "-" if v is None or v != v else format(v, spec)


def markdown(reports: dict, rows: list) -> str:
    lines = ["## 1. Does the makespan track the host signals, round by round?", "",
             "Per run and experiment, over its settle, training and later rounds (best: later "
             "rounds only): the reference's range and lag-1 autocorrelation; per policy the "
             "correlation of log round median with log reference (r) and the slope of log "
             "median on log reference (b: 1 where the makespan moves with the reference); "
             "the correlation with the machine's busy % and our busy cores; the round index "
             "(each round's medians over their policies' own medians, averaged: what moved "
             "every policy alike), its range and its correlation with log reference.", "",
             "| run | experiment | reference ms | lag-1 | round index | index r | " + " | ".join(
                 f"{p}: r / b / busy r / cores r" for p in POLICIES) + " |",
             "| --- | --- | --- | ---: | --- | ---: | " + " | ".join("---" for _ in POLICIES) + " |"]
    pooled, steal = {}, []
    for name, e in _experiments(reports):
        t = tracking(e)
        steal.append(t["steal_max"])
        cells = []
        for pol in POLICIES:
            g = t["policies"][pol]
            cells.append(f"{_f(g['reference_ms'])} / {_f(g['slope'])} / {_f(g['busy_pct'])} / "
                         f"{_f(g['process_cores'])}")
            pooled.setdefault((e["graph"], pol), []).extend(t["points"][pol])
        lines.append(f"| {name} | {e['tag']} | {t['ref_min']:.1f}-{t['ref_max']:.1f} | "
                     f"{_f(t['lag1'])} | {t['index_range'][0]:.2f}-{t['index_range'][1]:.2f} | "
                     f"{_f(t['index'])} | " + " | ".join(cells) + " |")
    lines += ["", f"Steal time: at most {max(steal):.2f}% of the machine in any round.", "",
              "Pooled per graph and policy (each series' log median, log reference, busy % "
              "and busy cores taken about its own median):", "",
              "| graph | policy | rounds | r | b | busy r | cores r |",
              "| --- | --- | ---: | ---: | ---: | ---: | ---: |"]
    for (graph, pol), pts in pooled.items():
        x, y, busy, cores = np.array(pts).T
        ok = ~np.isnan(busy) & ~np.isnan(cores)
        lines.append(f"| {graph} | {pol} | {len(pts)} | {_f(_corr(x, y))} | {_f(_slope(x, y))} | "
                     f"{_f(_corr(busy[ok], y[ok]))} | {_f(_corr(cores[ok], y[ok]))} |")
    lines += ["", "The training policy's step (its later frames' median makespan over its "
              "training frames': the drift the model meets) beside the reference's (later "
              "rounds' median over the training rounds'):", "",
              "| run | experiment | training policy later / training | reference later / training |",
              "| --- | --- | ---: | ---: |"]
    steps = []
    for name, e in _experiments(reports):
        steps.append(step(e))
        lines.append(f"| {name} | {e['tag']} | {steps[-1][0]:.2f} | {steps[-1][1]:.2f} |")
    x, y = np.log(np.array(steps)).T[::-1]
    lines += ["", f"Over the {len(steps)} experiments: correlation of the log steps "
              f"{_f(_corr(x, y))}, slope {_f(_slope(x, y))}."]
    lines += ["", "The heavy OpenCV nodes on a CPU worker (the reference is the same OpenCV "
              "call as `denoise`, on a quarter of the 1280x720 image): their median in-frame "
              "time in the out-of-sample frames over the training frames (node@worker ratio), "
              "beside the reference's later over training median.", "",
              "| run | experiment | policy | node@worker later / training | reference later / training |",
              "| --- | --- | --- | --- | ---: |"]
    pts = []
    for name, e in _experiments(reports):
        for pol, nodes, ref in heavy_drift(e):
            pts += [(math.log(ref), math.log(v)) for _, _, v in nodes]
            lines.append(f"| {name} | {e['tag']} | {pol} | " + ", ".join(
                f"{n}@{pe} {v:.2f}" for n, pe, v in nodes) + f" | {ref:.2f} |")
    x, y = np.array(pts).T
    lines += ["", f"Over the {len(pts)} node series: correlation of the log ratios "
              f"{_f(_corr(x, y))}, slope {_f(_slope(x, y))}."]
    lines += ["", "## 2. The prediction scaled by the probe ratio, out of sample", "",
              "Trained on baseline (the bench's model, GIL-weighted); error of each cell's "
              "prediction against the median of its frames 21-100 (best: its frames 21-80, "
              "as the bench scores it). plain: the model as it is; then per part scaled "
              "(`cpu`: CPU tasks; `cpu+host`: CPU tasks, the GPU host thread's eager "
              "calls and a captured segment's fixed cost per replay) and per probe statistic.", "",
              "| run | experiment | policy | measured ms | plain | " + " | ".join(
                  f"{parts}: {probe}" for parts in PARTS for probe in PROBES) + " |",
              "| --- | --- | --- | ---: | ---: | " + " | ".join(
                  "---:" for _ in PARTS for _ in PROBES) + " |"]
    for r in rows:
        mark = " (trained)" if r["trained_here"] else ""
        cells = [f"{gb._err(r['scaled_ms'][k], r['measured_ms']):+.1f}%"
                 for k in ((parts, probe) for parts in PARTS for probe in PROBES)]
        lines.append(f"| {r['run']} | {r['tag']} | {r['policy']}{mark} | {r['measured_ms']:.3f} | "
                     f"{gb._err(r['plain_ms'], r['measured_ms']):+.1f}% | " + " | ".join(cells) + " |")
    lines += ["", "Summary: every cell (the training policy's frames 21-100 included, as the "
              "bench's out-of-sample column counts them), then the other policies only.", "",
              "| prediction | all cells | other policies |", "| --- | --- | --- |"]
    others = [r for r in rows if not r["trained_here"]]
    variants = [("plain", lambda r: r["plain_ms"])] + [
        (f"{parts}, {probe}", lambda r, k=(parts, probe): r["scaled_ms"][k])
        for parts in PARTS for probe in PROBES]
    for label, get in variants:
        lines.append(f"| {label} | " + " | ".join(
            _summary([gb._err(get(r), r["measured_ms"]) for r in sel]) for sel in (rows, others)) + " |")
    lines += ["", "Per graph and size, every cell: within 20% plain -> each variant.", "",
              "| experiment | cells | plain | " + " | ".join(label for label, _ in variants[1:]) + " |",
              "| --- | ---: | ---: | " + " | ".join("---:" for _ in variants[1:]) + " |"]
    for tag in dict.fromkeys(r["tag"] for r in rows):
        sel = [r for r in rows if r["tag"] == tag]
        lines.append(f"| {tag} | {len(sel)} | " + " | ".join(
            str(sum(abs(gb._err(get(r), r["measured_ms"])) <= WITHIN for r in sel))
            for _, get in variants) + " |")
    lines += ["", "Per round: each later round's median makespan against the plain prediction "
              "and the one scaled by that round's own probe ratio; the spread (standard "
              "deviation) of the per-round errors within a cell, median over the cells, and "
              "the median |error| over all rounds (a probe that tracks the rounds shrinks both).", "",
              "| graph | rounds | plain: spread / median abs | " + " | ".join(
                  f"{parts}, round: spread / median abs" for parts in PARTS) + " |",
              "| --- | ---: | --- | " + " | ".join("---" for _ in PARTS) + " |"]
    for graph in dict.fromkeys(r["graph"] for r in rows):
        sel = [r for r in rows if r["graph"] == graph]
        cells = []
        for key in ("plain",) + tuple(PARTS):
            spread = statistics.median(statistics.pstdev(r["round_err"][key]) for r in sel)
            med = statistics.median(abs(v) for r in sel for v in r["round_err"][key])
            cells.append(f"{spread:.1f}% / {med:.1f}%")
        lines.append(f"| {graph} | {sum(len(r['round_err']['plain']) for r in sel)} | " + " | ".join(cells) + " |")
    lines += ["", "## 3. How much of each miss is the drift at all?", "",
              "Each cell's plain prediction against its policy's first 20 frames (baseline, "
              "heft, xeft: the training rounds, the very rounds the model learnt from, so no "
              "drift between them; best: its first two later rounds) and the policy's own "
              "step (frames 21-100 over its first 20 frames' median). A probe that took the "
              "drift out perfectly would leave the first column's error.", "",
              "| run | experiment | policy | plain vs frames 21-100 | plain vs first 20 frames | own step |",
              "| --- | --- | --- | ---: | ---: | ---: |"]
    for r in rows:
        lines.append(f"| {r['run']} | {r['tag']} | {r['policy']}{' (trained)' if r['trained_here'] else ''} | "
                     f"{gb._err(r['plain_ms'], r['measured_ms']):+.1f}% | "
                     f"{gb._err(r['plain_ms'], r['measured_first_ms']):+.1f}% | "
                     f"{r['measured_ms'] / r['measured_first_ms']:.2f} |")
    first = [r for r in others if r["policy"] != "best"]
    lines += ["", "heft and xeft (their first frames in the training rounds), against frames "
              "21-100: " + _summary([gb._err(r["plain_ms"], r["measured_ms"]) for r in first])
              + "; against their first 20 frames: "
              + _summary([gb._err(r["plain_ms"], r["measured_first_ms"]) for r in first]) + "."]
    return "\n".join(lines)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("results", nargs="+", type=Path,
                   help="graph_bench.json(.gz) files with a per-round reference (session 7 on)")
    p.add_argument("--out", type=Path, default=None,
                   help="also write the tables here (markdown, its first line the command)")
    p.add_argument("--note", default="", help="a paragraph written under the command")
    args = p.parse_args(argv)
    reports = {}
    for path in args.results:
        report = load(path)
        if not all("round_log" in e for e in report.get("experiments", ())):
            raise SystemExit(f"{path}: no per-round reference (round_log): a run before session 7")
        report["_name"] = f"{path.parent.name.replace('h100-2026-11-24-', '')}/{path.name.split('.')[0]}"
        reports[report["_name"]] = report
    rows = [r for report in reports.values() for r in replay_scaled(report)]
    text = markdown(reports, rows)
    print(text)
    if args.out:
        write_result(args.out, "benchmarks/host_speed_replay.py", argv, args.note, text)


if __name__ == "__main__":
    main()
