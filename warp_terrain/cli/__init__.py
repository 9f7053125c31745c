"""The ``warp-terrain`` command line: one sub-command per everyday task.

Each sub-command is an ``add_<name>(subparsers)`` that declares its options and a
``cmd_<name>(args) -> int`` that calls the library, in one module per command group: ``data``
(generate, preview), ``figures`` (figures, export-usd), ``evaluate``, ``model`` (reconstruct,
export-onnx, package-model), ``bench``, ``gpucheck`` (gpu-check) and ``view``; shared argument types live in ``args``. To add one,
write both functions and list the adder in ``SUBCOMMANDS``. A ``cmd_<name>`` imports what it
needs when it runs, so ``warp-terrain --help`` starts fast. ``warp-terrain train OVERRIDES``
hands the rest of the command line to Hydra (``cli.train``).

Exit codes: 0 on success, 2 for bad arguments (argparse's usage error, or ``error: <message>``
for a ``ValueError`` raised by the library while checking them).
"""

from __future__ import annotations

import argparse
import re
import sys

from ..core.version import __version__
from .bench import add_bench
from .data import add_generate, add_preview
from .evaluate import add_evaluate
from .figures import add_export_usd, add_figures
from .gpucheck import add_gpu_check
from .model import add_export_onnx, add_package_model, add_reconstruct
from .view import add_view

EXIT_USAGE = 2


# ------------------------------------------------------------------------------ train
def add_train(sub) -> None:
    sub.add_parser("train", help="train a model: Hydra overrides as for python train.py (warp-terrain train --help)",
                   description="Hydra overrides follow, e.g. warp-terrain train terrain=octave3 train.steps=500; "
                               "the same as python train.py in a source checkout.", add_help=False)


def run_train(args: list[str]) -> int:
    """``warp-terrain train OVERRIDES``: Hydra parses the rest of the command line."""
    from .train import main as train_main

    saved = sys.argv
    sys.argv = ["warp-terrain train", *args]
    try:
        train_main()
    finally:
        sys.argv = saved
    return 0


# ------------------------------------------------------------------------------ entry point
SUBCOMMANDS = (add_train, add_bench, add_preview, add_figures, add_export_usd, add_generate, add_evaluate, add_reconstruct, add_export_onnx,
               add_package_model, add_view, add_gpu_check)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="warp-terrain",
        description="Simulated LIDAR terrains and their elevation maps: everyday commands.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for add in SUBCOMMANDS:
        add(sub)
    return parser


#: Options whose value may start with a minus sign (a list of numbers): ``--transform -5,0,...``.
NUMERIC_LIST_OPTIONS = ("--transform",)


def join_numeric_values(argv: list[str]) -> list[str]:
    """``--transform -5,0,1`` as ``--transform=-5,0,1``: argparse would take ``-5,0,1`` for an option."""
    out = []
    i = 0
    while i < len(argv):
        if argv[i] in NUMERIC_LIST_OPTIONS and i + 1 < len(argv) and re.fullmatch(r"-[\d.][\d.,eE+-]*", argv[i + 1]):
            out.append(f"{argv[i]}={argv[i + 1]}")
            i += 2
        else:
            out.append(argv[i])
            i += 1
    return out


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit code (0 ok, 2 bad arguments)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] == "train":
        return run_train(argv[1:])
    argv = join_numeric_values(argv)
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:  # argparse: --help/--version (0) or a usage error (2), already printed
        return e.code if isinstance(e.code, int) else EXIT_USAGE
    try:
        return int(args.func(args) or 0)
    except ValueError as e:
        message = " ".join(str(e).split()) or type(e).__name__
        print(f"error: {message}", file=sys.stderr)
        return EXIT_USAGE


if __name__ == "__main__":
    sys.exit(main())
