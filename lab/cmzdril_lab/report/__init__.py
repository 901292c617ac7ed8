"""Reporting a grid of trials: run folders -> records -> tables, sections, figures, results.md.

:func:`write_report` is the entry point (``cmzdril-lab report``).
"""
from cmzdril_lab.report import report as _report
from cmzdril_lab.report.report import *  # noqa: F403  (the old module's names, listed once there)
from cmzdril_lab.report.report import render_markdown

__all__ = [*_report.__all__, "render_markdown"]
