"""Per-thread summary of a py-spy raw profile (``py-spy record --threads -f raw``).

    python3 benchmarks/perf/pyspy_summary.py PROFILE.txt [--top 25] [--only SUBSTRING] [--skip SUBSTRING ...]

For each thread (most samples first): its share of the samples, the functions it was inside
(inclusive) and the frames it was in (self). With ``--gil`` profiles, a thread's samples are
those where it was the interpreter lock's last holder (that includes its GIL-releasing calls
while no other thread wanted the lock); with ``--idle``, all samples, waiting included: a
thread's ``--idle`` count over its ``--gil`` count says how much of its time it was not
holding the lock. ``--skip`` drops stacks through set-up (imports, JIT, verification).
"""

from __future__ import annotations

import argparse
import collections
import re

SETUP = ("Graph.verify", "_find_and_load", "render_sequence", "make_frames", "build_graph",
         "Module.load", "get_module_hash")


def summarise(path, only=None, skip=SETUP):
    """{thread: (samples, inclusive Counter, self Counter)} of a raw py-spy profile."""
    threads = collections.defaultdict(lambda: [0, collections.Counter(), collections.Counter()])
    with open(path) as f:
        for line in f:
            stack, n = line.rstrip().rsplit(" ", 1)
            if (only and only not in stack) or any(s in stack for s in skip):
                continue
            frames = stack.split(";")
            entry = threads[frames[0]]
            entry[0] += int(n)
            # a function counted once per stack (recursion), line numbers dropped
            for fn in {re.sub(r":\d+\)", ")", fr) for fr in frames[1:]}:
                entry[1][fn] += int(n)
            entry[2][frames[-1]] += int(n)
    return dict(threads)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("profile")
    p.add_argument("--top", type=int, default=25)
    p.add_argument("--threads", type=int, default=8)
    p.add_argument("--only", default=None, help="keep the stacks containing this")
    p.add_argument("--skip", nargs="*", default=list(SETUP), help="drop the stacks containing these")
    args = p.parse_args(argv)
    threads = summarise(args.profile, args.only, args.skip)
    total = sum(t[0] for t in threads.values()) or 1
    print(f"{total} samples")
    for name, (n, inclusive, own) in sorted(threads.items(), key=lambda kv: -kv[1][0])[:args.threads]:
        print(f"\n=== {name}: {n} samples ({100 * n / total:.1f}%)")
        for title, counter in (("inclusive", inclusive), ("self", own)):
            print(f"  {title}:")
            for fn, m in counter.most_common(args.top):
                print(f"    {m:7d} {100 * m / n:5.1f}%  {fn[:140]}")


if __name__ == "__main__":
    main()
