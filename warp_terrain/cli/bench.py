"""``warp-terrain bench``: time the simulator, training and inference (``warp_terrain.bench``)."""

from __future__ import annotations

import argparse
import json
import sys

from .args import _add_device
from .progress import _add_quiet, reporters

BENCH_NAMES = ("noise", "rays", "stream", "loader", "train", "infer")


def _only(value: str) -> list[str]:
    names = [s.strip() for s in value.split(",") if s.strip()]
    unknown = [n for n in names if n not in BENCH_NAMES]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"unknown benchmark {', '.join(unknown) or value!r}: choose from {','.join(BENCH_NAMES)}")
    return names


def add_bench(sub) -> None:
    p = sub.add_parser("bench", help="benchmark the simulator, training and inference (with anchors where installed)",
                       description="Time fixed, seeded workloads after a warm-up (compilation excluded): terrain noise, "
                                   "ray casting, the data stream and loader, training steps of the paper's model, and "
                                   "points -> map inference; with pyfastnoiselite and Open3D as anchors where installed "
                                   "(pip install -e .[bench]).")
    p.add_argument("--json", action="store_true", help="print the results as JSON on stdout (progress goes to stderr)")
    _add_device(p)
    p.add_argument("--only", type=_only, default=None, metavar="NAMES",
                   help=f"comma-separated subset of {','.join(BENCH_NAMES)} (default: all)")
    p.add_argument("--quick", action="store_true", help="tiny workloads and fewer repeats: a smoke test, not a measurement")
    _add_quiet(p)
    p.set_defaults(func=cmd_bench)


def cmd_bench(args) -> int:
    from ..bench import format_table, run_benchmarks

    progress, track = reporters(args.quiet, "workload")
    report = run_benchmarks(device=args.device, only=args.only, quick=args.quick, progress=progress, track=track)
    if args.json:
        json.dump(report, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print(format_table(report))
    return 0
