"""ExpertEvalCallback: the evaluation against expert episodes every k PPO updates, logged and in a CSV."""
from __future__ import annotations

import csv
import math
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.type_aliases import TrainFreq, TrainFrequencyUnit

from sb3_cmzdril.data.demos import Demonstrations, as_demonstrations
from sb3_cmzdril.errors import UserError
from sb3_cmzdril.metrics.evaluation import (
    ExpertEvaluation,
    _checked,
    _make_env,
    _require_seeds,
    evaluate_against_expert,
)
from sb3_cmzdril.metrics.trajectories import TrajectoryFn, trajectory_features


class ExpertEvalCallback(BaseCallback):
    """Evaluate against held-out expert episodes every ``eval_every`` policy updates.

    *Epoch* = number of completed rollout+update cycles (PPO updates). For on-policy algorithms it
    is computed from ``num_timesteps // (n_steps * n_envs)``, and for off-policy ones that train every
    ``train_freq`` steps (SAC, TD3...) from ``num_timesteps // (train_freq * n_envs)``, so it
    continues across resumed runs (``learn(..., reset_num_timesteps=False)``); with ``steps_per_epoch``
    an epoch is that many env steps for any algorithm. Epoch 0 (the policy
    before the first update, e.g. the BC-pretrained one) is evaluated at the first rollout, then
    every ``eval_every`` epochs, and the last epoch at the end of training if it was not already.

    Each evaluation records SB3's EvalCallback keys ``eval/mean_reward``, ``eval/std_reward`` and
    ``eval/mean_ep_length`` (the true return; the same keys as the expert training's evaluation), plus
    ``eval/frechet``, ``eval/action_mse`` and ``eval/epoch``, with the model's logger (dumped with the logs of the
    rollout that follows; the final one is dumped at once) and appends a row with :attr:`CSV_COLUMNS` to
    ``csv_path``, flushed row by row. An existing CSV keeps its rows: the run appends to it, and a
    resumed run does not re-evaluate an (epoch, timesteps) already there.

    :param eval_env: env id (made with ``env_kwargs``) or a gymnasium Env, without reward wrappers.
    :param demos: held-out expert episodes with recorded reset seeds (or a path to them).
    :param eval_every: evaluate every this many PPO updates.
    :param csv_path: where to append the evaluation rows; None for no file.
    :param trajectory_fn: see :func:`evaluate_against_expert`.
    :param steps_per_epoch: env steps per epoch (None: the algorithm's update cycle, above). An
        off-policy learner that updates every step evaluates every ``eval_every * steps_per_epoch``
        steps with it, not every ``eval_every`` steps.
    """

    CSV_COLUMNS: tuple[str, ...] = (
        "epoch",
        "timesteps",
        "return_mean",
        "return_std",
        "frechet_mean",
        "frechet_std",
        "action_mse",
        "length_mean",
        "n_episodes",
    )

    def __init__(
        self,
        eval_env: str | gym.Env,
        demos: Demonstrations | str | Path,
        eval_every: int = 1,
        csv_path: str | Path | None = None,
        trajectory_fn: TrajectoryFn | None = None,
        env_kwargs: Mapping[str, Any] | None = None,
        verbose: int = 0,
        steps_per_epoch: int | None = None,
    ) -> None:
        super().__init__(verbose)
        counts = {"eval_every": eval_every, "steps_per_epoch": 1 if steps_per_epoch is None else steps_per_epoch}
        for name, value in counts.items():
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise UserError(f"{name} must be a positive integer, got {value!r}")
        self.steps_per_epoch = None if steps_per_epoch is None else int(steps_per_epoch)
        self.demos = as_demonstrations(demos)
        _require_seeds(self.demos)  # fail at construction, not after the first rollout
        self.eval_every = int(eval_every)
        self.csv_path = Path(csv_path) if csv_path is not None else None
        self.trajectory_fn = trajectory_fn
        self._env_arg = eval_env
        self._env_kwargs = dict(env_kwargs or {})
        self.eval_env: gym.Env | None = None
        self._owns_env = False
        self._env_id: str | None = None
        #: one summary dict per evaluation of this callback (epoch, timesteps and the CSV columns)
        self.history: list[dict[str, float]] = []
        self.last_evaluation: ExpertEvaluation | None = None
        self._done: set = set()  # (epoch, timesteps) already evaluated
        self._rollouts_completed = 0  # epochs of a run that trains every k episodes: from this learn() on

    # -- setup ----------------------------------------------------------------------------------
    def _init_callback(self) -> None:
        if self.eval_env is None:
            self.eval_env, self._owns_env, self._env_id = _make_env(self._env_arg, self._env_kwargs or None)
            self.demos = _checked(self.demos, self.eval_env)
        if self.csv_path is not None:
            self._prepare_csv()

    def _prepare_csv(self) -> None:
        path = self.csv_path
        assert path is not None
        path.parent.mkdir(parents=True, exist_ok=True)
        if not path.exists():
            with open(path, "w", newline="") as f:
                csv.writer(f, lineterminator="\n").writerow(self.CSV_COLUMNS)
            return
        text = path.read_text()
        if not text.strip():
            path.write_text(",".join(self.CSV_COLUMNS) + "\n")
            return
        rows = list(csv.reader(text.splitlines()))
        if tuple(rows[0]) != self.CSV_COLUMNS:
            raise UserError(
                f"{path} exists with columns {rows[0]}, not {list(self.CSV_COLUMNS)}: pass another csv_path"
            )
        if not text.endswith("\n"):  # a run killed mid-row: start ours on a fresh line
            with open(path, "a", newline="") as f:
                f.write("\n")
        logged = set()
        for row in rows[1:]:
            try:
                logged.add((int(row[0]), int(row[1])))
            except (ValueError, IndexError):
                continue
        if self.model.num_timesteps > 0:
            # Resumed run: the previous run's final evaluation already covers where we restart.
            self._done |= logged
        elif logged:
            warnings.warn(
                f"{path} already has {len(logged)} rows from an earlier run; appending to them",
                UserWarning,
                stacklevel=2,
            )

    # -- hooks ----------------------------------------------------------------------------------
    def _epoch(self) -> int:
        if self.steps_per_epoch is not None:
            return int(self.model.num_timesteps // self.steps_per_epoch)
        n_steps = getattr(self.model, "n_steps", None)
        if isinstance(n_steps, (int, np.integer)) and n_steps > 0:
            # A rollout is exactly n_steps * n_envs steps and each completed one is followed by an update.
            return int(self.model.num_timesteps // (n_steps * self.model.n_envs))
        train_freq = getattr(self.model, "train_freq", None)
        if isinstance(train_freq, TrainFreq) and train_freq.unit == TrainFrequencyUnit.STEP:
            # Each off-policy rollout collects train_freq steps per env, then trains.
            return int(self.model.num_timesteps // (train_freq.frequency * self.model.n_envs))
        return self._rollouts_completed

    def _on_rollout_start(self) -> None:
        epoch = self._epoch()
        # An epoch of steps_per_epoch spans many rollouts of an off-policy learner: its first one evaluates.
        if epoch % self.eval_every == 0 and all(epoch != done for done, _ in self._done):
            self._evaluate(epoch, dump=False)

    def _on_rollout_end(self) -> None:
        self._rollouts_completed += 1

    def _on_step(self) -> bool:
        return True

    def _on_training_end(self) -> None:
        epoch = self._epoch()
        if self.steps_per_epoch is not None and self.model.num_timesteps % self.steps_per_epoch:
            # Training ended inside an epoch: its row is that epoch's end, not a second row of the last
            # one begun (whose evaluation at its first step is already there).
            epoch += 1
        self._evaluate(epoch, dump=True)

    # -- work -----------------------------------------------------------------------------------
    def _evaluate(self, epoch: int, dump: bool) -> None:
        timesteps = int(self.model.num_timesteps)
        if (epoch, timesteps) in self._done:
            return
        self._done.add((epoch, timesteps))
        assert self.eval_env is not None
        trajectory_fn = self.trajectory_fn if self.trajectory_fn is not None else trajectory_features(self._env_id)
        result = evaluate_against_expert(self.model, self.eval_env, self.demos, trajectory_fn=trajectory_fn)
        self.last_evaluation = result
        row: dict[str, float] = {"epoch": epoch, "timesteps": timesteps, **result.summary()}
        self.history.append(row)

        self.logger.record("eval/mean_reward", result.mean_return)
        self.logger.record("eval/std_reward", result.std_return)
        self.logger.record("eval/frechet", result.mean_frechet)
        self.logger.record("eval/action_mse", result.action_mse)
        self.logger.record("eval/mean_ep_length", result.mean_length)
        self.logger.record("eval/epoch", epoch)
        if dump:
            self.logger.dump(timesteps)
        if self.csv_path is not None:
            with open(self.csv_path, "a", newline="") as f:
                csv.writer(f, lineterminator="\n").writerow([_csv_value(row[c]) for c in self.CSV_COLUMNS])
                f.flush()
        if self.verbose >= 1:
            print(
                f"[expert eval] epoch {epoch} ({timesteps} steps): return {result.mean_return:.1f} "
                f"± {result.std_return:.1f}, Fréchet {result.mean_frechet:.4g}, action MSE {result.action_mse:.4g}"
            )

    def close(self) -> None:
        """Close the eval env if this callback made it."""
        if self.eval_env is not None and self._owns_env:
            self.eval_env.close()
        self.eval_env = None


def _csv_value(value: float) -> str:
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    value = float(value)
    return repr(value) if math.isfinite(value) else str(value)
