"""The ``warpvx`` command: ``warpvx bench`` (CPU vs Warp vs OpenCV timings),
``warpvx sched-study`` (the scheduling study, :mod:`warpvx.sched.study`) and
``warpvx stabilize`` (the video stabilizer, :mod:`warpvx.apps.stabilize`).

Also run as ``python -m warpvx``.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import sys
from pathlib import Path

#: Where a command writes when no ``--out`` is given: a fresh folder under the current
#: directory (git-ignored), so a run never overwrites results committed in a repository.
RESULTS_ROOT = Path("warpvx-results")


# --- machinery shared by the subcommands ----------------------------------------------------


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Every option's help ends with its default, unless the text already states it."""

    def _get_help_string(self, action):
        text = action.help or ""
        if "default" in text.lower():
            return text
        return super()._get_help_string(action)


class ArgumentParser(argparse.ArgumentParser):
    """``argparse.ArgumentParser`` that shows defaults in ``--help`` (:class:`HelpFormatter`)
    and reports a bad argument on one line (exit status 2) instead of the usage text.
    Subparsers inherit both."""

    def __init__(self, *args, formatter_class=HelpFormatter, **kwargs):
        super().__init__(*args, formatter_class=formatter_class, **kwargs)

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def fresh_results_dir(command: str) -> Path:
    """Create and return ``./warpvx-results/<command>-<YYYYmmdd-HHMMSS>/`` (``-2``, ``-3``...
    appended when that exists). ``warpvx-results/`` gets a ``.gitignore`` of ``*``, so its
    contents stay untracked in whatever repository the command is run from."""
    RESULTS_ROOT.mkdir(parents=True, exist_ok=True)
    ignore = RESULTS_ROOT / ".gitignore"
    if not ignore.exists():
        ignore.write_text("*\n", encoding="utf-8")
    base = f"{command}-{_dt.datetime.now():%Y%m%d-%H%M%S}"
    n = 1
    while True:
        path = RESULTS_ROOT / (base if n == 1 else f"{base}-{n}")
        try:
            path.mkdir()
            return path
        except FileExistsError:
            n += 1


def positive_int(text: str) -> int:
    """``type=`` for an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {value}")
    return value


def comma_list(item=str, choices=None):
    """``type=`` for a comma-separated list: a list of ``item(part)``, each one of ``choices``
    when given (``item`` may raise ``argparse.ArgumentTypeError`` itself)."""

    def parse(text: str) -> list:
        parts = [p.strip() for p in text.split(",") if p.strip()]
        if not parts:
            raise argparse.ArgumentTypeError(f"expected a comma-separated list, got {text!r}")
        bad = [p for p in parts if choices is not None and p not in choices]
        if bad:
            raise argparse.ArgumentTypeError(
                f"unknown {', '.join(map(repr, bad))}; valid: {', '.join(choices)}")
        return [item(p) for p in parts]

    return parse


def value_range(cast=int, min_value=None):
    """``type=`` for ``LOW-HIGH`` (or one value, meaning LOW = HIGH): a ``(low, high)`` tuple of
    ``cast`` values with ``min_value <= low <= high``."""

    def parse(text: str) -> tuple:
        try:
            values = [cast(p) for p in text.replace(",", "-").split("-") if p.strip()]
        except ValueError:
            values = []
        if len(values) == 1:
            values *= 2
        if len(values) != 2 or values[0] > values[1]:
            raise argparse.ArgumentTypeError(f"expected LOW-HIGH with LOW <= HIGH, got {text!r}")
        if min_value is not None and values[0] < min_value:
            raise argparse.ArgumentTypeError(f"expected values >= {min_value}, got {text!r}")
        return tuple(values)

    return parse


# --- the command ----------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    from . import __version__
    from .bench import add_arguments

    parser = ArgumentParser(
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
    from .apps.stabilize_cli import add_arguments as add_stabilize_arguments

    add_stabilize_arguments(sub.add_parser(
        "stabilize",
        help="stabilize a shaky video (thesis §3.2) with the warpvx graph",
        description="Stabilize a video file or image folder IN into OUT; see apps/stabilize.py.",
    ))
    from .apps.orbslam_cli import add_arguments as add_orbslam_arguments

    add_orbslam_arguments(sub.add_parser(
        "orbslam",
        help="ORB-SLAM2 front end (thesis ch. 4): trajectory of a camera sequence",
        description="Track a KITTI/TUM folder, image folder or video; see apps/orbslam_frontend.py.",
    ))
    for command in ("ros-stabilize", "ros-orbslam"):
        sub.add_parser(command, add_help=False,
                       help="ROS 1 node (arguments: ROS remappings and _param:=value; see "
                            f"warpvx {command} --help and warpvx.ros.nodes)")
    return parser


def main(argv=None) -> int:
    """Entry point of the ``warpvx`` console script; returns the exit status (2 for bad
    arguments: argparse's own checks, or a warpvx error, reported on one line)."""
    from .errors import WarpvxError

    argv = list(sys.argv[1:] if argv is None else argv)
    command = argv[0] if argv else ""
    try:
        return _run(argv)
    except WarpvxError as exc:
        print(f"warpvx {command}: error: {exc}", file=sys.stderr)
        return 2


def _run(argv) -> int:
    if argv and argv[0] == "sched-study":
        # Forward everything after the subcommand untouched (the study owns its options).
        try:
            from .sched.study import main as study_main
        except ImportError as exc:
            print(f"warpvx sched-study: not available ({exc})", file=sys.stderr)
            return 2
        status = study_main(argv[1:])
        return int(status or 0)
    if argv and argv[0] in ("ros-stabilize", "ros-orbslam"):
        # ROS remappings (image:=/camera/image) are not argparse options: the node parses them.
        from .ros.nodes import main as node_main

        return node_main(argv[0], argv[1:])
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command == "bench":
        from .bench import main_from_args

        return main_from_args(args)
    if args.command == "stabilize":
        from .apps.stabilize_cli import run_cli

        return run_cli(args, "warpvx stabilize")
    if args.command == "orbslam":
        from .apps.orbslam_cli import run_cli as run_orbslam

        return run_orbslam(args, "warpvx orbslam")
    parser.print_help()
    return 0 if not argv else 2


if __name__ == "__main__":
    sys.exit(main())
