"""One run of the ``train`` command: its methods (:mod:`.methods`), its settings resolved once
(:mod:`.spec`), its run folder (:mod:`.run_folder`) and the run itself, trained and evaluated (:mod:`.runs`)."""
from sb3_cmzdril.training.methods import METHOD_REGISTRY, METHODS, Method
from sb3_cmzdril.training.run_folder import RunFolder
from sb3_cmzdril.training.runs import run_experiment
from sb3_cmzdril.training.spec import ResolvedRun, RunSpec, plan_run, prepare_run, resolve_run

__all__ = ["METHODS", "METHOD_REGISTRY", "Method", "RunSpec", "ResolvedRun", "RunFolder", "plan_run", "prepare_run",
           "resolve_run", "run_experiment"]
