"""How the report prints numbers and tables (markdown), shared by every report module."""
from __future__ import annotations

import math
from collections.abc import Iterable, Sequence


def fmt(value: float | None) -> str:
    """About three significant digits, as the paper prints (1690, 60.9, -52.6, 0.0123)."""
    if value is None or not math.isfinite(value):
        return "n/a"
    magnitude = abs(value)
    if magnitude >= 100:
        return f"{value:.0f}"
    if magnitude >= 10:
        return f"{value:.1f}"
    if magnitude >= 1:
        return f"{value:.2f}"
    return f"{value:.3g}"


def fmt_mean_std(mean: float, std: float) -> str:
    """``mean (std)``, the paper's notation."""
    return f"{fmt(mean)} ({fmt(std)})"


def fmt_ci(mean: float, low: float, high: float) -> str:
    """``mean [low, high]``; ``mean [n/a]`` when there is no interval (too few trials); ``n/a`` when
    there is no mean (a metric undefined for the runs, e.g. a percentage of a negative expert return)."""
    if not math.isfinite(mean):
        return fmt(mean)
    if not (math.isfinite(low) and math.isfinite(high)):
        return f"{fmt(mean)} [n/a]"
    return f"{fmt(mean)} [{fmt(low)}, {fmt(high)}]"


def md_table(header: Sequence[str], rows: Iterable[Sequence[str]]) -> str:
    """A GitHub-flavoured markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


__all__ = ["fmt", "fmt_mean_std", "fmt_ci", "md_table"]
