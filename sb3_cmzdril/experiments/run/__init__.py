"""Running trials: a spec resolved once (:mod:`.spec`), its run folder (:mod:`.run_folder`), one run
trained and evaluated (:mod:`.runs`), and the grid of runs with its progress display (:mod:`.grid`)."""
from sb3_cmzdril.experiments.run.grid import benchmark, plan_grid, run_grid
from sb3_cmzdril.experiments.run.run_folder import RunFolder
from sb3_cmzdril.experiments.run.runs import run_experiment
from sb3_cmzdril.experiments.run.spec import METHODS, ResolvedRun, RunSpec, plan_run, resolve_run

__all__ = [
    "METHODS",
    "RunSpec",
    "ResolvedRun",
    "RunFolder",
    "plan_run",
    "resolve_run",
    "run_experiment",
    "plan_grid",
    "run_grid",
    "benchmark",
]
