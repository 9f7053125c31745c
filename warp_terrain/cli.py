"""The ``warp-terrain`` command line: one sub-command per everyday task.

Each sub-command is a ``cmd_<name>(args) -> int`` function registered in :func:`build_parser`
by an ``add_<name>(subparsers)`` function; to add one, write both and list the adder in
``SUBCOMMANDS``. Sub-commands only parse and call the library. Exit codes: 0 on success, 2 for
bad arguments (argparse's usage error, or ``error: <message>`` for a ``ValueError`` raised by
the library while checking them).
"""

from __future__ import annotations

import argparse
import json
import sys

from . import __version__

EXIT_USAGE = 2

BENCH_NAMES = ("noise", "rays", "stream")


# ------------------------------------------------------------------------------ argument types
def _device(value: str) -> str:
    if value == "cpu" or value == "cuda" or (value.startswith("cuda:") and value[5:].isdigit()):
        return value
    raise argparse.ArgumentTypeError(f"invalid device {value!r}: expected cpu, cuda or cuda:N")


def _only(value: str) -> list[str]:
    names = [s.strip() for s in value.split(",") if s.strip()]
    unknown = [n for n in names if n not in BENCH_NAMES]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"unknown benchmark {', '.join(unknown) or value!r}: choose from {','.join(BENCH_NAMES)}")
    return names


def _add_device(p: argparse.ArgumentParser) -> None:
    p.add_argument("--device", type=_device, default=None, metavar="{cpu,cuda}",
                   help="where the kernels run (default: CUDA if available, else CPU)")


# ------------------------------------------------------------------------------ bench
def add_bench(sub) -> None:
    p = sub.add_parser("bench", help="benchmark the simulator (terrain noise, ray casting, the data stream)",
                       description="Time fixed, seeded simulator workloads after a warm-up (compilation excluded).")
    p.add_argument("--json", action="store_true", help="print the results as JSON on stdout (progress goes to stderr)")
    _add_device(p)
    p.add_argument("--only", type=_only, default=None, metavar="NAMES",
                   help=f"comma-separated subset of {','.join(BENCH_NAMES)} (default: all)")
    p.add_argument("--quick", action="store_true", help="tiny workloads and fewer repeats: a smoke test, not a measurement")
    p.set_defaults(func=cmd_bench)


def cmd_bench(args) -> int:
    from .bench import format_table, run_benchmarks

    def progress(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    report = run_benchmarks(device=args.device, only=args.only, quick=args.quick, progress=progress)
    if args.json:
        json.dump(report, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print(format_table(report))
    return 0


# ------------------------------------------------------------------------------ preview
def add_preview(sub) -> None:
    p = sub.add_parser("preview", help="write a PNG figure of generated samples",
                       description="Render terrain, LIDAR returns, scan image, mask and ground truth of one sample "
                                   "per terrain setting (conf/terrain/*.yaml) into a PNG.")
    p.add_argument("--out", required=True, metavar="PATH.png", help="PNG file to write (its folder must exist)")
    p.add_argument("--terrain", default="octave5", metavar="NAME",
                   help="terrain setting (octave3, octave5, flat_cylinders, negative_obstacles), a comma-separated "
                        "list, 'all' (one row each) or a path to a terrain .yaml (default: octave5)")
    p.add_argument("--seed", type=int, default=0, help="sample seed (default: 0)")
    p.add_argument("--dpi", type=int, default=80, help="resolution of the PNG (default: 80)")
    _add_device(p)
    p.set_defaults(func=cmd_preview)


def cmd_preview(args) -> int:
    from .export.figures import write_preview

    out = write_preview(args.out, terrain=args.terrain, seed=args.seed, device=args.device, dpi=args.dpi)
    print(f"wrote {out}", file=sys.stderr)
    return 0


# ------------------------------------------------------------------------------ entry point
SUBCOMMANDS = (add_bench, add_preview)


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


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit code (0 ok, 2 bad arguments)."""
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
