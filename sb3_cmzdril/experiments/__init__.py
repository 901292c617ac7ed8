"""The paper's experiment: running trials (:mod:`.run`) and reporting them (:mod:`.report`)."""
from sb3_cmzdril.experiments import report, run
from sb3_cmzdril.experiments.report import write_report
from sb3_cmzdril.experiments.run import METHODS, RunSpec, benchmark, plan_grid, plan_run, run_experiment, run_grid

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
