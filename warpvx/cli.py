"""The ``warpvx`` command: ``warpvx bench`` (CPU vs Warp vs OpenCV timings),
``warpvx sched-study`` (the scheduling study, :mod:`warpvx.sched.study`) and
``warpvx stabilize`` (the video stabilizer, :mod:`warpvx.apps.stabilize`).

Also run as ``python -m warpvx``.
"""

from __future__ import annotations

import argparse
import sys


def build_parser() -> argparse.ArgumentParser:
    from . import __version__
    from .bench import add_arguments

    parser = argparse.ArgumentParser(
        prog="warpvx",
        description="warpvx: embedded-vision primitives on NumPy/OpenCV and NVIDIA Warp.",
    )
    parser.add_argument("--version", action="version", version=f"warpvx {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    bench = sub.add_parser(
        "bench",
        help="time every primitive on each backend against OpenCV (and CV-CUDA, Kornia)",
        description="Time every registered primitive on each backend against OpenCV on all "
                    "cores (and CV-CUDA, Kornia when importable); print a table, write JSON "
                    "and a bar chart.",
    )
    add_arguments(bench)
    sub.add_parser(
        "sched-study",
        help="HEFT/XEFT scheduling study (arguments go to warpvx.sched.study; see its --help)",
        add_help=False,
    )
    from .apps.stabilize import add_arguments as add_stabilize_arguments

    add_stabilize_arguments(sub.add_parser(
        "stabilize",
        help="stabilize a shaky video (thesis §3.2) with the warpvx graph",
        description="Stabilize a video file or image folder IN into OUT; see apps/stabilize.py.",
    ))
    return parser


def main(argv=None) -> int:
    """Entry point of the ``warpvx`` console script; returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "sched-study":
        # Forward everything after the subcommand untouched (the study owns its options).
        try:
            from .sched.study import main as study_main
        except ImportError as exc:
            print(f"warpvx sched-study: not available ({exc})", file=sys.stderr)
            return 2
        status = study_main(argv[1:])
        return int(status or 0)
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command == "bench":
        from .bench import main_from_args

        return main_from_args(args)
    if args.command == "stabilize":
        from .apps.stabilize import run_cli

        return run_cli(args, "warpvx stabilize")
    parser.print_help()
    return 0 if not argv else 2


if __name__ == "__main__":
    sys.exit(main())
