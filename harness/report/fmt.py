"""Numbers as a report prints them: signs, dashes for missing values, p-values."""

from __future__ import annotations

import math


def num(x: float, digits: int, sign: bool = False) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "—"
    return f"{x:+.{digits}f}" if sign else f"{x:.{digits}f}"


def text(x: object) -> str:
    """A cell's text: "—" for None, NaN and the empty string."""
    return "—" if x is None or x == "" or (isinstance(x, float) and math.isnan(x)) else str(x)


def p_text(p: float) -> str:
    return "—" if math.isnan(p) else f"{p:.2g}" if p >= 1e-4 else f"{p:.1e}"


def fixed(x: float | None, digits: int = 2) -> str:
    """``x`` with ``digits`` decimals, "—" for None and NaN."""
    return "—" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"
