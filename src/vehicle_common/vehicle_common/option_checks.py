"""Checks of numeric command-line options, each a one-line problem or None (issue #42: a
negative, zero or NaN value was accepted, or failed later with exit 1 or a traceback). The
callers print ``error: LINE`` and exit 2. No rclpy here."""

from __future__ import annotations

import math


def number_problem(
    option: str,
    value: float,
    *,
    minimum: float | None = None,
    above: float | None = None,
    why: str = "",
) -> str | None:
    """One line when ``value`` is not finite, below ``minimum`` or not above ``above``; None
    when it can be used. ``why`` is added to the line (what the limit is for)."""
    reason = f" ({why})" if why else ""
    if not math.isfinite(value):
        return f"{option} {value}: expected a finite number{reason}"
    if minimum is not None and value < minimum:
        return f"{option} {value:g}: must be >= {minimum:g}{reason}"
    if above is not None and value <= above:
        return f"{option} {value:g}: must be > {above:g}{reason}"
    return None


def first_problem(*problems: str | None) -> str | None:
    """The first of ``problems`` that is not None."""
    return next((p for p in problems if p), None)
