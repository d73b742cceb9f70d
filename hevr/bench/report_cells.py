"""How one cell of a benchmark report reads: figures, ratios, ours beside the paper's, a cell looked up.

The report's sections (:mod:`hevr.bench.report`, :mod:`hevr.bench.report_goals`,
:mod:`hevr.bench.report_tables`, :mod:`hevr.bench.report_limits`) format every number through these,
so that one figure reads the same in every table.
"""

from __future__ import annotations

from typing import Any

DASH = "–"


def number(x: float | None) -> str:
    """A figure with as many digits as its size deserves (three significant, thousands grouped); a dash for none."""
    if x is None:
        return DASH
    return f"{x:,.0f}" if x >= 100 else f"{x:,.1f}" if x >= 10 else f"{x:.2f}" if x >= 0.1 else f"{x:.3f}"


def compare(ours: float | None, theirs: float | None) -> str:
    """'ours / paper (paper ÷ ours ×)' — the ratio is how many times faster we are."""
    if ours is None:
        return DASH if theirs is None else f"{DASH} / {number(theirs)}"
    if theirs is None:
        return number(ours)
    return f"{number(ours)} / {number(theirs)} (**{times(theirs / ours)}**)"


def times(r: float) -> str:
    """A ratio, ``47×`` or ``1.25×``."""
    return f"{r:,.0f}×" if r >= 10 else f"{r:.2f}×"


def megabytes(b: int | None) -> str:
    """Bytes as MB (10⁶ bytes); a dash for none."""
    return DASH if b is None else f"{b / 1e6:,.0f}" if b >= 1e7 else f"{b / 1e6:,.2f}"


def lookup(cells: dict[str, Any], key: str, field: str | None = None) -> Any:
    """The cell ``key`` (or its ``field``); None where it was not run, was refused, or lacks the field."""
    c = cells.get(key)
    if c is None or (isinstance(c, dict) and "refused" in c):
        return None
    return c if field is None else c.get(field)


def plain_column(cells: dict, keys: list[str], theirs: float | None) -> str:
    """The plain column: the fastest ``render_plain`` among the cells (same render, any key)."""
    ps = [p for p in (lookup(cells, k, "plain_s") for k in keys) if p is not None]
    return compare(min(ps) if ps else None, theirs)
