"""Progress on stderr for the commands that run for minutes (``evaluate``, ``generate``, ``bench``).

The library's loops take ``progress(line)`` (one line per step) and ``track(items, what)`` (an
iterable wrapper that yields ``items`` in order); here they become a tqdm bar on stderr with
its ETA, and lines written above the bar (``tqdm.write``), so stdout keeps only the command's
result (the JSON of ``--json``). ``--quiet`` silences both; errors still reach stderr.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Iterable, Sequence


def _add_quiet(p: argparse.ArgumentParser) -> None:
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar or progress lines on stderr (errors still)")


def reporters(quiet: bool, unit: str) -> tuple[Callable[[str], None], Callable[[Sequence, str], Iterable]]:
    """``(progress, track)`` for a command: lines and a tqdm bar counting ``unit`` on stderr,
    or nothing when ``quiet``."""
    from tqdm import tqdm

    def progress(line: str) -> None:
        if not quiet:
            tqdm.write(line, file=sys.stderr)

    def track(items: Sequence, what: str) -> Iterable:
        return tqdm(items, desc=what, unit=unit, file=sys.stderr, dynamic_ncols=True, disable=quiet)

    return progress, track
