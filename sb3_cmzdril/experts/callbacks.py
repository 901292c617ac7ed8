"""SB3 callbacks of expert training: progress display, periodic evaluation keeping the best model,
and resumable checkpoints. The experiment runs use :class:`ProgressCallback` too.

Their ``show``/``log`` flags print, as SB3's own callbacks do with ``verbose``.
"""
from __future__ import annotations

import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.evaluation import evaluate_policy

from sb3_cmzdril.experts.checkpoints import save_checkpoint
from sb3_cmzdril.io import atomic_path, write_json


class ProgressCallback(BaseCallback):
    """tqdm bar on a terminal; on a file (nohup, CI) a plain line every ``line_every`` steps."""

    def __init__(self, total: int, show: bool = True, line_every: int | None = None) -> None:
        super().__init__()
        self.total = int(total)
        self.show = show
        self.line_every = line_every or max(1000, self.total // 50)
        self.bar: Any = None  # a tqdm bar, where stderr is a terminal
        self._t0 = 0.0
        self._n0 = 0
        self._next_line = 0

    def _on_training_start(self) -> None:
        self._t0 = time.time()
        self._n0 = self.model.num_timesteps
        self._t_last, self._n_last = self._t0, self._n0
        self._next_line = (self._n0 // self.line_every + 1) * self.line_every
        if not self.show:
            return
        if sys.stderr.isatty():
            from tqdm import tqdm

            self.bar = tqdm(total=self.total, initial=self._n0, unit="step", dynamic_ncols=True, smoothing=0.05)

    def _on_step(self) -> bool:
        n = self.num_timesteps
        if self.bar is not None:
            self.bar.update(n - self.bar.n)
        elif self.show and n >= self._next_line:
            self._next_line = (n // self.line_every + 1) * self.line_every
            now = time.time()
            elapsed = now - self._t_last
            rate = (n - self._n_last) / elapsed if elapsed > 0 else float("nan")  # since the last line
            self._t_last, self._n_last = now, n
            eta = (self.total - n) / rate if rate > 0 else float("nan")
            print(
                f"[{time.strftime('%H:%M:%S')}] steps {n}/{self.total} ({100.0 * n / self.total:.0f}%), "
                f"{rate:.0f} steps/s, eta {eta / 60:.1f} min",
                flush=True,
            )
        return True

    def _on_training_end(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None


class ExpertEvalCallback(BaseCallback):
    """Evaluate deterministically every ``eval_freq`` total steps; keep the best as ``model.zip``.

    Like SB3's EvalCallback (deterministic ``evaluate_policy`` on a separate env, best model
    kept), but: the schedule is on the *total* step count so it survives resumes; the best score
    is restored from ``best.json`` so a resumed run never overwrites a better model; model.zip
    and the score are written atomically; the history goes into ``state``.
    """

    def __init__(self, eval_env, eval_freq: int, n_eval_episodes: int, model_path: Path, best_path: Path,
                 state: dict[str, Any], log: bool = True) -> None:
        super().__init__()
        self.eval_env = eval_env
        self.eval_freq = int(eval_freq)
        self.n_eval_episodes = int(n_eval_episodes)
        self.model_path = model_path
        self.best_path = best_path
        self.state = state
        self.log = log

    @property
    def best_mean_reward(self) -> float:
        best = self.state.get("best")
        return -math.inf if best is None else float(best["mean_reward"])

    def _on_step(self) -> bool:
        if self.eval_freq > 0 and self.num_timesteps % self.eval_freq < self.training_env.num_envs:
            if self.num_timesteps != self.state.get("last_eval_step"):
                self.evaluate()
        return True

    def evaluate(self) -> tuple[float, float]:
        """Evaluate now; the model becomes model.zip when it beats the best so far."""
        returns, lengths = evaluate_policy(
            self.model, self.eval_env, n_eval_episodes=self.n_eval_episodes, deterministic=True,
            return_episode_rewards=True, warn=False,
        )
        mean, std = float(np.mean(returns)), float(np.std(returns))
        step = int(self.model.num_timesteps)
        self.state["last_eval_step"] = step
        self.state.setdefault("evaluations", []).append(
            {"timesteps": step, "mean_reward": mean, "std_reward": std, "mean_ep_length": float(np.mean(lengths))}
        )
        new_best = mean > self.best_mean_reward
        if new_best:
            with atomic_path(self.model_path, suffix=".zip") as tmp:
                self.model.save(tmp)
            self.state["best"] = {"mean_reward": mean, "std_reward": std, "timesteps": step,
                                  "n_episodes": self.n_eval_episodes}
            write_json(self.best_path, self.state["best"])
        logger = getattr(self.model, "_logger", None)
        if logger is not None:
            logger.record("eval/mean_reward", mean)
            logger.record("eval/mean_ep_length", float(np.mean(lengths)))
        if self.log:
            print(
                f"[{time.strftime('%H:%M:%S')}] eval at {step} steps: {mean:.1f} +/- {std:.1f} "
                f"(length {np.mean(lengths):.0f})" + ("  new best -> model.zip" if new_best else
                                                     f"  (best {self.best_mean_reward:.1f})"),
                flush=True,
            )
        return mean, std


class ResumableCheckpointCallback(BaseCallback):
    """Every ``save_freq`` total steps: model + replay buffer + state.json, each atomic.

    state.json is written last and names the model/buffer files, so a crash at any moment leaves
    either the previous or the new checkpoint complete. Older checkpoint files are removed.
    """

    def __init__(self, save_freq: int, ckpt_dir: Path, state: dict[str, Any], t_start: float) -> None:
        super().__init__()
        self.save_freq = int(save_freq)
        self.ckpt_dir = ckpt_dir
        self.state = state
        self.t_start = t_start

    def _on_step(self) -> bool:
        if self.save_freq > 0 and self.num_timesteps % self.save_freq < self.training_env.num_envs:
            if self.num_timesteps != self.state.get("num_timesteps"):
                self.save()
        return True

    def save(self) -> None:
        """Write a checkpoint of the current step now."""
        save_checkpoint(self.model, self.ckpt_dir, self.state, self.t_start)
