"""The paper's experiment: running trials (:mod:`.run`) and reporting them (:mod:`.report`)."""
import sys

from sb3_cmzdril.experiments import report, run
from sb3_cmzdril.experiments.report import (
    figures,
    final_eval,
    formatting,
    paper,
    readme,
    records,
    sections,
    tables,
    write_report,
)
from sb3_cmzdril.experiments.run import (
    METHODS,
    RunSpec,
    benchmark,
    grid,
    plan_grid,
    plan_run,
    progress,
    run_experiment,
    run_folder,
    run_grid,
    runs,
    spec,
)

# Before the split every module sat here (sb3_cmzdril.experiments.runs, ...), and scripts import
# those paths. Registering the moved modules under their old names makes each old path the very same
# module object, not a copy: its classes stay one class, and monkeypatching either name patches both.
# (``sb3_cmzdril.experiments.report`` is the reporting package, which re-exports the old module's names.)
for _module in (grid, progress, run_folder, runs, spec,
                figures, final_eval, formatting, paper, readme, records, sections, tables):
    sys.modules[f"{__name__}.{_module.__name__.rsplit('.', 1)[-1]}"] = _module
del _module

__all__ = [
    "run",
    "report",
    "METHODS",
    "RunSpec",
    "plan_run",
    "run_experiment",
    "plan_grid",
    "run_grid",
    "benchmark",
    "write_report",
]
