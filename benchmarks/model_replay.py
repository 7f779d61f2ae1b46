"""The contention model before and after a change, replayed offline on recorded H100 runs.

Each ``graph_bench.json`` holds, per graph, size and policy, the fit frames' timelines,
the plan and the measured makespans (``benchmarks/graph_bench.py``). For each of two
checkouts (``--before``: a copy of the older code; ``--after``: this one, by default)
:func:`graph_bench.replay` refits the model on each training policy's recorded frames
1-20 and predicts every policy's plan; the table gives the out-of-sample error of each
cell before and after, and the summary counts the cells within 20%. No GPU: the model's
fit and simulation only.

Usage::

    PYTHONPATH=. python benchmarks/model_replay.py --before <rev or folder> \\
        benchmarks/results/graph/h100-2026-11-24-s3/graph_bench.json other/graph_bench.json

``--after-gil`` (``--before-gil``) replays that side with busy neighbours weighed by the
recorded GIL shares, as ``graph_bench.py`` fits its model on CUDA; ``--before .
--after-gil`` compares the unweighted and the GIL-weighted model of one checkout.
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import shlex
import statistics
import subprocess
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

#: The training policies replayed in turn (each predicts the others out of sample).
TRAINS = ("baseline", "heft", "xeft")

_DUMP = ("import gzip, json, sys; sys.path.insert(0, 'benchmarks'); import graph_bench as gb; "
         "kw = {'gil': True} if sys.argv[1] == 'gil' else {}; "
         "op = lambda p: gzip.open(p, 'rt') if p.endswith('.gz') else open(p); "
         "print(json.dumps({p: {t: gb.replay(json.load(op(p)), t, **kw) for t in %r} "
         "for p in sys.argv[2:]}))" % (TRAINS,))


def load(path) -> dict:
    """A graph_bench.json, gzipped (``.json.gz``, as results are committed) or not."""
    path = Path(path)
    return json.loads(gzip.decompress(path.read_bytes()) if path.suffix == ".gz" else path.read_text())


def replay_rows(root: Path, paths, gil: bool = False) -> dict:
    """path -> training policy -> :func:`graph_bench.replay` rows, with the code of the
    checkout at ``root`` (a subprocess, so each side imports its own warpvx); ``gil``: busy
    neighbours weighed by the recorded GIL shares (``graph_bench.replay(..., gil=True)``)."""
    env = {**os.environ, "PYTHONPATH": str(root)}
    out = subprocess.run([sys.executable, "-c", _DUMP, "gil" if gil else "-", *map(str, paths)],
                         cwd=root, env=env,
                         check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def summary(rows, label: str, key: str = "error_pct") -> str:
    errs = [abs(r[key]) for r in rows if not r["trained_here"]]
    return (f"{label}: {sum(e <= 20 for e in errs)}/{len(errs)} within 20%, mean |error| "
            f"{statistics.mean(errs):.1f}%, median {statistics.median(errs):.1f}%, max {max(errs):.1f}%")


#: The after side's prediction told which of each plan's segments ran eagerly (a failed
#: capture: ``graph_bench.replay``'s ``error_eager_pct``), where its rows have it.
EAGER = "error_eager_pct"


def markdown(before: dict, after: dict) -> str:
    eager = all(EAGER in r for p in after.values() for t in TRAINS for r in p[t])
    head = "before | after" + (" | after, eager known" if eager else "")
    lines = []
    for path in after:
        lines += [f"## {os.path.relpath(path)}", "",
                  "| experiment | policy | measured ms | "
                  + " | ".join(f"trained on {t}: {head}" for t in TRAINS) + " |",
                  "| --- | --- | ---: | " + " | ".join(" | ".join(["---:"] * (2 + eager)) for _ in TRAINS) + " |"]
        for i, r in enumerate(after[path][TRAINS[0]]):
            cells = []
            for t in TRAINS:
                b, a = before[path][t][i], after[path][t][i]
                mark = " (trained)" if a["trained_here"] else ""
                cells += [f"{b['error_pct']:+.1f}%{mark}", f"{a['error_pct']:+.1f}%{mark}"]
                if eager:
                    cells.append(f"{a[EAGER]:+.1f}%{mark}" + (f" ({', '.join(a['eager'])})" if a["eager"] else ""))
            lines.append(f"| {r['tag']} | {r['policy']} | {r['measured_ms']:.3f} | " + " | ".join(cells) + " |")
        lines.append("")
        for t in TRAINS:
            lines += [f"- trained on {t}, out of sample, " + summary(before[path][t], "before"),
                      f"- trained on {t}, out of sample, " + summary(after[path][t], "after")]
            if eager:
                lines.append(f"- trained on {t}, out of sample, " + summary(after[path][t], "after, eager known", EAGER))
        lines.append("")
    for t in TRAINS:
        for label, got, key in (("before", before, "error_pct"), ("after", after, "error_pct"),
                                ("after, eager known", after, EAGER))[:2 + eager]:
            rows = [r for p in got.values() for r in p[t]]
            lines.append(f"- All runs, trained on {t}, out of sample, " + summary(rows, label, key))
    lines += ["", "## Against the first frames (the training rounds: the machine's later drift left out)",
              "", "Each policy's first recorded frames (measured in the same interleaved rounds as "
              "the training policy's, after them in the bench: out of sample for every other "
              "policy) against the prediction" + (" told its failed captures (eager known)" if eager
                                                  else "") + ", per run, trained on baseline.", "",
              "| run | before | after |", "| --- | --- | --- |"]
    for path in after:
        key = "pred_eager_ms" if eager else "pred_ms"
        cells = [summary(first_rows(got[path][TRAINS[0]], after[path][TRAINS[0]], key), label)
                 for got, label in ((before, "before"), (after, "after"))]
        lines.append(f"| {Path(path).parent.name}/{Path(path).name} | " + " | ".join(cells) + " |")
    lines += ["", "## The pick (target 2)", "",
              "The policy the model would pick (least predicted of the recorded plans) and its "
              "measured makespan over the fastest measured policy's (out-of-sample frames; a "
              "placement several policies ran: the mean of their runs).", "",
              "| run | experiment | fastest measured (pooled) | " + " | ".join(
                  f"trained on {t}: before | after" + (" | after, eager known" if eager else "")
                  for t in TRAINS) + " |",
              "| --- | --- | --- | " + " | ".join(" | ".join(["---"] * (2 + eager)) for _ in TRAINS) + " |"]
    for path in after:
        for tag in dict.fromkeys(r["tag"] for r in after[path][TRAINS[0]]):
            cells = []
            for t in TRAINS:
                sides = [(before, "pred_ms"), (after, "pred_ms")] + [(after, "pred_eager_ms")] * eager
                cells += [pick(got[path][t], tag, key) for got, key in sides]
            rows = [r for r in after[path][TRAINS[0]] if r["tag"] == tag]
            fastest = min(rows, key=lambda r: r["pooled_ms"])
            lines.append(f"| {Path(path).parent.name} | {tag} | {fastest['policy']} "
                         f"{fastest['pooled_ms']:.3f} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def first_rows(rows, ref, key="pred_ms") -> list:
    """``rows`` with ``error_pct`` of ``key`` against the policy's first frames
    (``measured_first_ms`` of ``ref``'s row of the same experiment and policy: the checkout
    that records it); rows without them left out."""
    first = {(m["tag"], m["policy"]): m.get("measured_first_ms") for m in ref}
    return [{**r, "error_pct": 100.0 * (r[key] / first[r["tag"], r["policy"]] - 1.0)}
            for r in rows if first.get((r["tag"], r["policy"]))]


def pick(rows, tag, key="pred_ms") -> str:
    """The least predicted (``key``) of ``tag``'s rows: its policy and its measured
    makespan over the fastest measured one's, flagged where it is more than 5% slower; a
    placement measured by several policies counts as the mean of their runs (``pooled_ms``:
    best on baseline's placement measured 13% apart from it is noise, not a pick)."""
    rows = [r for r in rows if r["tag"] == tag]
    chosen = min(rows, key=lambda r: r[key])
    over = 100.0 * (chosen["pooled_ms"] / min(r["pooled_ms"] for r in rows) - 1.0)
    return f"{chosen['policy']} {over:+.1f}%" + (" **>5%**" if over > 5 else "")


def regime(paths, gil: bool = False) -> str:
    """The training frames' regime against the interleaved rounds', with this checkout.

    Per experiment whose best ran baseline's placement (one placement, two series): the
    median makespan of baseline's training frames (run alone before the others, as the
    bench did until s5), of baseline's later interleaved frames and of best's first
    interleaved frames; and the out-of-sample error of every policy predicted by a model
    trained on baseline's training frames against one trained on best's first interleaved
    frames (the bench's training design since s6: training frames in the rounds)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import graph_bench as gb

    lines = ["| run | experiment | baseline training ms | baseline interleaved ms | same placement "
             "interleaved (best) ms | step | "
             + " | ".join(f"{p}: trained alone | in the rounds" for p in TRAINS) + " |",
             "| --- | --- | ---: | ---: | ---: | ---: | " + " | ".join("---: | ---:" for _ in TRAINS) + " |"]
    for path in paths:
        report = load(path)
        alone = {(r["tag"], r["policy"]): r for r in gb.replay(report, "baseline", gil=gil)}
        rounds = {(r["tag"], r["policy"]): r for r in gb.replay(report, "best", gil=gil)}
        for e in gb.experiments_of(report):
            pol = {p["policy"]: p for p in e["policies"]}
            if pol["best"]["placement"] != pol["baseline"]["placement"]:
                continue
            train = statistics.median(max(t[2] for t in f.values())
                                      for f in pol["baseline"]["fit_frames_data"])
            inter = pol["baseline"]["measured_out_ms"]
            cells = [f"{alone[e['tag'], p]['error_pct']:+.1f}% | {rounds[e['tag'], p]['error_pct']:+.1f}%"
                     for p in TRAINS]
            lines.append(f"| {Path(path).parent.name} | {e['tag']} | {train:.3f} | {inter:.3f} | "
                         f"{pol['best']['measured_in_ms']:.3f} | {_pct(inter, train)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def critical_path(timeline, unit, reads, placement) -> list:
    """The critical path of one frame's ``timeline`` (task -> (start, end) ms) over its
    units (``unit``: task -> the tuple of tasks it runs with: a GPU segment, else itself),
    walked back from the last to end: ``(unit, what it waited for last, wait ms, its ms)``
    in order, the wait kinds ``"start"``, ``"same <pe>"`` (its processor's previous unit)
    and ``"<pe> <- <pe>"`` (a hand-off between threads)."""
    from warpvx.graph.model import pe_of

    span = {u: (min(timeline[t][0] for t in u), max(timeline[t][1] for t in u))
            for u in set(unit.values())}
    proc = {u: placement[u[0]] for u in span}
    out, u = [], max(span, key=lambda v: span[v][1])
    while u is not None:
        s, f = span[u]
        cands = [(span[v][1], v, f"same {pe_of(proc[u])}") for v in span
                 if v != u and proc[v] == proc[u] and span[v][1] <= s + 1e-9]
        cands = [max(cands, key=lambda c: c[0])] if cands else []
        cands += [(span[v][1], v, f"{pe_of(proc[u])} <- {pe_of(proc[v])}")
                  for t in u for r in reads[t] if not r.delayed and r.producer is not None
                  for v in (unit[r.producer],) if v != u and proc[v] != proc[u]]
        if not cands:
            out.append((u, "start", s, f - s))
            break
        ready, v, kind = max(cands, key=lambda c: c[0])
        out.append((u, kind, s - ready, f - s))
        u = v
    return out[::-1]


def misses(paths, train: str = "baseline", gil: bool = False, graph: str = "two-cameras") -> str:
    """Where a model trained on ``train``'s frames 1-20 misses the other placements' frames
    1-20 (the same interleaved rounds: the machine's drift left out), with this checkout.

    Per policy whose placement differs from ``train``'s: predicted and measured (median)
    makespan, and the miss attributed along each measured frame's critical path
    (:func:`critical_path`), averaged over the frames: per unit on it (a CPU task, a
    replayed GPU segment or a task of an eager one: its capture failed,
    :func:`~warpvx.graph.model.eager_nodes`) its measured less its predicted time, per kind
    of wait its measured less its predicted wait. The largest terms, ms."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import graph_bench as gb
    from warpvx.graph.model import eager_nodes, gpu_segments, pe_of

    lines = ["| run | experiment | policy | predicted ms | measured ms (frames 1-20) | miss ms | "
             "largest terms on the critical path, measured - predicted (ms) |",
             "| --- | --- | --- | ---: | ---: | ---: | --- |"]
    for path in paths:
        report = load(path)
        for e, model, schedules in gb.replay_models(report, train, gil=gil):
            src = next(p for p in e["policies"] if p["policy"] == train)
            if e["graph"] != graph:
                continue
            for p in e["policies"]:
                if p["placement"] == src["placement"] or not p.get("fit_frames_data"):
                    continue
                frames = [gb.recorded_frame(r) for r in p["fit_frames_data"]]
                place = p["placement"]
                eager = eager_nodes(frames, model.reads, model.capturable, place)
                pred = model.predict(schedules[p["policy"]])
                gpu = sorted((t for t in place if place[t] == "gpu"), key=lambda t: pred.tasks[t].start)
                unit = {t: (t,) for t in place}
                unit.update((t, tuple(seg)) for seg in gpu_segments(
                    model.reads, model.capturable - eager, place, gpu) for t in seg)
                predicted = {t: (x.start, x.finish) for t, x in pred.tasks.items()}
                waits = {u: w for u, _, w, _ in critical_path(predicted, unit, model.reads, place)}
                terms = defaultdict(float)
                for f in frames:
                    measured = {t: (x.start, x.finish) for t, x in f.timeline.items()}
                    for u, kind, w, d in critical_path(measured, unit, model.reads, place):
                        what = ("cpu " if pe_of(place[u[0]]) == "cpu" else
                                "gpu eager " if u[0] in eager else "gpu segment ") + "+".join(u)
                        s0 = min(predicted[t][0] for t in u)
                        terms[what] += (d - (max(predicted[t][1] for t in u) - s0)) / len(frames)
                        terms[f"wait {kind}"] += (w - waits.get(u, 0.0)) / len(frames)
                meas = statistics.median(f.makespan for f in frames)
                top = sorted(terms.items(), key=lambda kv: -abs(kv[1]))[:6]
                lines.append(f"| {Path(path).parent.name} | {e['tag']} | {p['policy']} | "
                             f"{pred.makespan:.3f} | {meas:.3f} | {meas - pred.makespan:+.3f} | "
                             + "; ".join(f"{k} {v:+.2f}" for k, v in top) + " |")
    return "\n".join(lines)


def write_result(out: Path, script: str, argv, note: str, text: str) -> None:
    """Write ``text`` to ``out`` under its first line, the command that regenerates it
    (``script`` with ``argv``, or this process's arguments), and ``note`` if any."""
    command = f"PYTHONPATH=. python {script} " + shlex.join(argv if argv is not None else sys.argv[1:])
    note = f"{note}\n\n" if note else ""
    out.write_text(f"Regenerate: `{command}`\n\n{note}{text}\n")


def _pct(a, b) -> str:
    return f"{100.0 * (a - b) / b:+.1f}%"


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("results", nargs="+", type=Path, help="graph_bench.json files")
    p.add_argument("--before", required=True,
                   help="checkout of the older code: a folder, or a git revision of this one")
    p.add_argument("--after", type=Path, default=Path.cwd(), help="checkout of the newer code")
    p.add_argument("--before-gil", action="store_true",
                   help="the before side weighs busy neighbours by their GIL shares")
    p.add_argument("--after-gil", action="store_true",
                   help="the after side weighs busy neighbours by their GIL shares (as the "
                        "bench's model does on CUDA)")
    p.add_argument("--out", type=Path, default=None,
                   help="also write the table here (markdown, its first line the command)")
    p.add_argument("--misses", action="store_true",
                   help="also attribute the baseline-trained model's misses on the 16-node "
                        "graph's mixed placements along each frame's critical path")
    p.add_argument("--note", default="",
                   help="a paragraph written under the command (which runs designed the change)")
    args = p.parse_args(argv)
    paths = [r.resolve() for r in args.results]
    with tempfile.TemporaryDirectory() as tmp:
        before = Path(args.before)
        if not before.is_dir():  # a revision: its tree, as git archive gives it
            before = Path(tmp)
            tree = subprocess.run(["git", "archive", args.before], check=True, capture_output=True).stdout
            subprocess.run(["tar", "-x", "-C", tmp], input=tree, check=True)
        rows = replay_rows(before.resolve(), paths, args.before_gil)
    text = markdown(rows,
                    replay_rows(args.after.resolve(), paths, args.after_gil))
    text += ("\n\n## Training frames alone or in the rounds (this checkout"
             + (", GIL-weighted" if args.after_gil else "") + ")\n\n"
             + (regime.__doc__.split("\n\n")[1].replace("\n    ", " ").strip()) + "\n\n"
             + regime(paths, args.after_gil))
    if args.misses:
        text += ("\n\n## Where the model trained on baseline misses the mixed placements (this "
                 "checkout" + (", GIL-weighted" if args.after_gil else "") + ")\n\n"
                 + misses.__doc__.split("\n\n")[1].replace("\n    ", " ").strip() + "\n\n"
                 + misses(paths, gil=args.after_gil))
    print(text)
    if args.out:
        write_result(args.out, "benchmarks/model_replay.py", argv, args.note, text)


if __name__ == "__main__":
    main()
