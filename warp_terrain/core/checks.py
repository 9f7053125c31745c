"""Argument checks that fail before any kernel runs, with a message naming the parameter."""

from __future__ import annotations

import math


def require(ok: bool, name: str, value, why: str) -> None:
    if not ok:
        raise ValueError(f"{name}={value!r}: {why}")


def check_finite(name: str, value) -> None:
    try:
        finite = math.isfinite(float(value))
    except (TypeError, ValueError):
        raise ValueError(f"{name}={value!r}: must be a number") from None
    if not finite:
        raise ValueError(f"{name}={value!r}: must be finite")
