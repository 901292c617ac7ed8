"""The lab beside the sb3-cmzdril library: the trial grid (:mod:`.run`), the report (:mod:`.report`)
and their commands (:mod:`.cli`: ``cmzdril-lab benchmark``, ``cmzdril-lab report``).

It imports :mod:`sb3_cmzdril` and is never imported by it.
"""
from cmzdril_lab import report, run
from cmzdril_lab.report import write_report
from cmzdril_lab.run import benchmark, plan_grid, run_grid

__all__ = ["run", "report", "benchmark", "plan_grid", "run_grid", "write_report"]
