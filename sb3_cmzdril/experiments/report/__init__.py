"""Reporting a grid of trials: run folders -> records -> tables, sections, figures, results.md.

:func:`write_report` is the entry point (``sb3-cmzdril report``). Before the split into ``run/`` and
``report/`` this package was the module ``sb3_cmzdril.experiments.report``; its names stay importable
from here.
"""
from sb3_cmzdril.experiments.report import report as _report
from sb3_cmzdril.experiments.report.report import *  # noqa: F403  (the old module's names, listed once there)
from sb3_cmzdril.experiments.report.report import render_markdown

__all__ = [*_report.__all__, "render_markdown"]
