"""``warp-terrain gpu-check``: the prepared check of a machine's CPU and CUDA device
(``warp_terrain.bench.gpucheck``) under a hard time limit.

Prints the environment, then a PASS/FAIL/SKIP table on stdout (progress on stderr); ``--json
OUT`` also writes every figure there, atomically. Exit code 0 when nothing FAILs, 1 otherwise
(a check that breaks, misses its criteria, or the time limit), 2 for bad arguments. At the time
limit the report so far is printed and written and the process exits with 1 at once, whatever
the running check is doing.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import threading
import time
from pathlib import Path

from .progress import _add_quiet

GROUPS = ("compile", "repeat", "poison", "walks", "cuda_vs_cpu", "capture", "no_sync", "stream", "switches", "train", "process_split")  # bench.gpucheck.GROUPS
EXIT_FAIL = 1


def _seconds(value: str) -> float:
    try:
        s = float(value)
    except ValueError:
        s = math.nan
    if not math.isfinite(s) or s <= 0:
        raise argparse.ArgumentTypeError(f"invalid time limit {value!r}: expected a number of seconds > 0")
    return s


def _groups(value: str) -> list[str]:
    names = [s.strip() for s in value.split(",") if s.strip()]
    unknown = [n for n in names if n not in GROUPS]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"unknown check {', '.join(unknown) or value!r}: choose from {','.join(GROUPS)}")
    return names


def add_gpu_check(sub) -> None:
    p = sub.add_parser("gpu-check", help="check this machine's CPU and CUDA device: compile, consistency, throughput (PASS/FAIL table)",
                       description="Under a hard time limit: print the environment, compile every Warp kernel module on the CPU "
                                   "and CUDA, check consistency (two runs bit-identical, a poisoned memory pool, the column walk "
                                   "against the per-ray walk, CUDA against the CPU, the CPU process split), then time "
                                   "generate_batch (scans/s, pairs/s) and training steps of the default model (pairs/s). "
                                   "CUDA rows are SKIP without a CUDA device. Exit code 0 only when nothing FAILs.")
    p.add_argument("--quick", action="store_true", help="small batches (1, 8; training 8) and few repeats: the CI run on a CPU")
    p.add_argument("--json", default=None, metavar="OUT", help="also write the report with every figure to OUT (JSON, atomically)")
    p.add_argument("--time-limit", type=_seconds, default=420.0, metavar="SECONDS",
                   help="hard limit for the whole run, from the command's start (default 420)")
    p.add_argument("--only", type=_groups, default=None, metavar="NAMES", help=f"comma-separated subset of {','.join(GROUPS)} (default: all)")
    _add_quiet(p)
    p.set_defaults(func=cmd_gpu_check)


def _check_output(path: str) -> Path:
    """``--json OUT`` must name a file in an existing folder: said before anything runs."""
    out = Path(path)
    if out.is_dir():
        raise ValueError(f"--json {path!r}: is a folder; name a file")
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise ValueError(f"--json {path!r}: the folder {str(parent)!r} does not exist")
    if not os.access(parent, os.W_OK):
        raise ValueError(f"--json {path!r}: the folder {str(parent)!r} is not writable")
    return out


def cmd_gpu_check(args) -> int:
    started = time.monotonic()  # the time limit counts from here: imports and Warp's start-up included
    out = _check_output(args.json) if args.json else None
    from ..bench.gpucheck import GpuCheck, format_environment, format_report, write_report

    def progress(line: str) -> None:
        if not args.quiet:
            print(line, file=sys.stderr, flush=True)

    check = GpuCheck(quick=args.quick, time_limit_s=args.time_limit, only=args.only, progress=progress, started=started)
    done = threading.Lock()  # held by whoever writes the final report: the run's end or the watchdog

    def finish(report: dict) -> None:
        print(format_report(report), flush=True)
        if out is not None:
            write_report(report, out)
            print(f"report written to {out}", flush=True)

    def on_timeout(report: dict) -> None:
        if not done.acquire(blocking=False):
            return  # the run ended at the same moment: it writes the report
        progress(f"gpu-check: the {args.time_limit:g} s time limit was reached; stopping")
        try:
            finish(report)
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(EXIT_FAIL)  # a check stuck in a kernel or a child process cannot be interrupted otherwise

    print(format_environment(check.collect_environment(), args.quick, args.time_limit), flush=True)
    report = check.run(on_timeout=on_timeout)
    if not done.acquire(blocking=False):
        time.sleep(3600)  # the watchdog is writing the report and will end the process
    finish(report)
    return 0 if report["ok"] else EXIT_FAIL
