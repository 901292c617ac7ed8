"""Experts: training SB3 experts, scripted experts, and recording demonstrations from them.

One module a job:

- :mod:`~sb3_cmzdril.experts.scripted`: the scripted-expert registry (``collect-demos --expert NAME``)
- :mod:`~sb3_cmzdril.experts.envs`: env ids and seeds as the commands take them, the training VecEnv
- :mod:`~sb3_cmzdril.experts.loading`: SB3 model zips of any algorithm; ``--expert`` to a policy
- :mod:`~sb3_cmzdril.experts.adapters`: published agents on an env version whose observation is laid out
  otherwise (the RL Zoo's Ant-v3 agents on Ant-v5)
- :mod:`~sb3_cmzdril.experts.training`: ``train_expert`` (resumable, best model by evaluation)
- :mod:`~sb3_cmzdril.experts.checkpoints`: its resumable state on disk
- :mod:`~sb3_cmzdril.experts.callbacks`: its SB3 callbacks (progress, evaluation, checkpoints)
- :mod:`~sb3_cmzdril.experts.collect`: ``collect_demos``, episodes and the pool's provenance
- :mod:`sb3_cmzdril.shipped`: the shipped demo pools and experts, from a checkout or an installed wheel

The names below are the package's API; import them from ``sb3_cmzdril.experts``.
"""
from sb3_cmzdril.experts.checkpoints import BEST_FILE, STATE_FILE, save_checkpoint
from sb3_cmzdril.experts.collect import (
    collect_demos,
    load_demonstrations,
    pool_provenance,
    provenance_path,
    run_episode,
)
from sb3_cmzdril.experts.envs import check_env_id, check_seed, env_name
from sb3_cmzdril.experts.loading import algorithm_classes, load_expert_model, resolve_expert
from sb3_cmzdril.experts.scripted import SCRIPTED_EXPERTS, ScriptedExpertFactory, register_scripted_expert
from sb3_cmzdril.experts.training import check_threads, train_expert
from sb3_cmzdril.io import LOCK_FILE, command_line
from sb3_cmzdril.shipped import shipped_demos, shipped_envs, shipped_expert

__all__ = [
    "BEST_FILE",
    "LOCK_FILE",
    "SCRIPTED_EXPERTS",
    "STATE_FILE",
    "ScriptedExpertFactory",
    "algorithm_classes",
    "check_env_id",
    "check_seed",
    "check_threads",
    "collect_demos",
    "command_line",
    "env_name",
    "load_demonstrations",
    "load_expert_model",
    "pool_provenance",
    "provenance_path",
    "register_scripted_expert",
    "resolve_expert",
    "run_episode",
    "save_checkpoint",
    "shipped_demos",
    "shipped_envs",
    "shipped_expert",
    "train_expert",
]
