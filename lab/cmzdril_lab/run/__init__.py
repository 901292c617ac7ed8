"""Running the trial grid: the runs of envs x methods x trials on local processes or Ray (:mod:`.grid`),
its progress display (:mod:`.progress`) and workers (:mod:`.worker`, :mod:`.remote`). One run is the
library's (:mod:`sb3_cmzdril.training`)."""
from cmzdril_lab.run.grid import benchmark, plan_grid, run_grid

__all__ = ["plan_grid", "run_grid", "benchmark"]
