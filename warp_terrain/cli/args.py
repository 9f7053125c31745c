"""Argument types and option adders shared by the sub-commands.

A type raises ``argparse.ArgumentTypeError``, so argparse prints the usage and exits with 2.
"""

from __future__ import annotations

import argparse


# ------------------------------------------------------------------------------ types
def _device(value: str) -> str:
    if value == "cpu" or value == "cuda" or (value.startswith("cuda:") and value[5:].isdigit()):
        return value
    raise argparse.ArgumentTypeError(f"invalid device {value!r}: expected cpu, cuda or cuda:N")


def _int_at_least(minimum: int, what: str):
    """An argparse type: an integer >= ``minimum``, or an error naming ``what`` it is."""

    def parse(value: str) -> int:
        try:
            n = int(value)
        except ValueError:
            n = None
        if n is None or n < minimum:
            raise argparse.ArgumentTypeError(f"invalid {what} {value!r}: expected an integer >= {minimum}")
        return n

    return parse


_non_negative_int = _int_at_least(0, "count")
_positive_int = _int_at_least(1, "size")


def _noise_levels(value: str) -> list[float]:
    try:
        levels = [float(s) for s in value.split(",") if s.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid noise levels {value!r}: expected comma-separated numbers in [0, 1]") from None
    if not levels or any(not 0.0 <= x <= 1.0 for x in levels):
        raise argparse.ArgumentTypeError(f"invalid noise levels {value!r}: expected comma-separated numbers in [0, 1]")
    return levels


def _baseline_names(value: str) -> list[str]:
    from ..evaluation.baselines import BASELINES

    if value.strip() == "none":
        return []
    names = [s.strip() for s in value.split(",") if s.strip()]
    unknown = [n for n in names if n not in BASELINES]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"unknown baseline {', '.join(unknown) or value!r}: choose from {','.join(BASELINES)} or none")
    return names


# ------------------------------------------------------------------------------ options
def _add_device(p: argparse.ArgumentParser) -> None:
    p.add_argument("--device", type=_device, default=None, metavar="{cpu,cuda}",
                   help="where the kernels run (default: CUDA if available, else CPU)")


def _add_model(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", default=None, metavar="PATH",
                   help="a Reconstructor file or training checkpoint (default: the model shipped in the package)")


def _add_self_check(p: argparse.ArgumentParser) -> None:
    group = p.add_mutually_exclusive_group()
    group.add_argument("--self-check", dest="self_check", action="store_true", default=None,
                       help="check every map on its own scan (a fifth of its observed cells hidden) and keep only the share "
                            "of the model's correction they support, else the better classical fill (default: as the model file says)")
    group.add_argument("--no-self-check", dest="self_check", action="store_false", help="never check: the model's maps as they are")


def _add_tta(p: argparse.ArgumentParser) -> None:
    p.add_argument("--no-tta", dest="tta", action="store_false",
                   help="one prediction per map instead of the average over its 8 quarter turns and mirror images")
