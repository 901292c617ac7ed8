"""What the tests share besides fixtures (those are in conftest.py): the one tiny model setting and
the hyperparameter files made from it, scripted experts and their demonstrations, and hand-written
run folders. Test modules import from here, never from one another."""
from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import yaml
from stable_baselines3.common.callbacks import BaseCallback

from sb3_cmzdril.cmzdril import CMZDRIL
from sb3_cmzdril.data.demos import Demonstrations

#: The one tiny setting: a CMZDRIL (PPO) model whose learn() calls take a fraction of a second.
#: Everything that trains a model in the tests starts from it, in Python or as a YAML file.
TINY: dict[str, Any] = dict(
    n_steps=64,
    batch_size=32,
    n_epochs=2,
    policy_kwargs=dict(net_arch=[16, 16]),
    ensemble_hidden=(16, 16),
    ensemble_epochs=5,
    bc_pretrain_epochs=5,
    seed=0,
)
#: CMZDRIL's five rule settings given outright, its defaults before 0.3.0 (the paper's): a test of one rule
#: gives the others these, so that only its own decides
PAPER: dict[str, Any] = dict(CMZDRIL.defaults_before["0.3.0"])
#: The same network and batch for a SAC expert (its own keys: a replay buffer and its warm-up). Its
#: policy_kwargs is a dict of its own: SB3's off-policy algorithms write ``use_sde`` into theirs.
TINY_SAC: dict[str, Any] = dict(
    learning_starts=50,
    buffer_size=2000,
    batch_size=TINY["batch_size"],
    policy_kwargs=dict(net_arch=list(TINY["policy_kwargs"]["net_arch"])),
)

#: The env of the tests that run whole experiments, cut to 50-step episodes in their YAML files.
ENV = "Pendulum-v1"
#: Episodes in those tests' demo pools.
POOL_EPISODES = 6
#: 50-step episodes: what the experiment tests' hyperparameter files give ``env_kwargs``.
SHORT_EPISODES = dict(max_episode_steps=50)


def zoo_hyperparams(settings: Mapping[str, Any], **extra: Any) -> dict[str, Any]:
    """``settings`` and ``extra`` as one section of an rl-zoo hyperparameter file: dicts written as
    the zoo's ``"dict(...)"`` strings, tuples as lists, and no seed (a run's seed is its trial's)."""

    def written(value: Any) -> Any:
        if isinstance(value, dict):
            return "dict(" + ", ".join(f"{k}={v!r}" for k, v in value.items()) + ")"
        return list(value) if isinstance(value, tuple) else value

    first = {"n_timesteps": extra.pop("n_timesteps")} if "n_timesteps" in extra else {}
    merged = {**first, "policy": "MlpPolicy", **settings, **extra}
    return {key: written(value) for key, value in merged.items() if key != "seed"}


def zoo_yaml(section: str, settings: Mapping[str, Any], **extra: Any) -> str:
    """A hyperparameter file with one section (an env id, or ``default``): see :func:`zoo_hyperparams`."""
    return yaml.safe_dump({section: zoo_hyperparams(settings, **extra)}, sort_keys=False)


#: The experiment tests' CMZDRIL file: 256 steps of :data:`TINY` on 50-step episodes, one demo.
TINY_PPO_YAML = zoo_yaml("default", TINY, n_timesteps=256, env_kwargs=SHORT_EPISODES, n_demos=1)
#: The command-line tests' SAC expert file: 200 steps of :data:`TINY_SAC` on 50-step episodes.
TINY_SAC_YAML = zoo_yaml(ENV, TINY_SAC, n_timesteps=200, env_kwargs=SHORT_EPISODES)


def pendulum_expert(obs: np.ndarray) -> np.ndarray:
    """A PD controller on the pole angle: deterministic, a function of the observation only."""
    obs = np.atleast_2d(obs)
    theta = np.arctan2(obs[:, 1], obs[:, 0])
    return np.clip(-8.0 * theta - 1.5 * obs[:, 2], -2.0, 2.0).astype(np.float32)[:, None]


def cartpole_expert(obs: np.ndarray) -> np.ndarray:
    """Push toward the side the pole falls to (keeps CartPole up for hundreds of steps)."""
    obs = np.atleast_2d(obs)
    return (obs[:, 2] + 0.5 * obs[:, 3] > 0).astype(np.int64)


def record(
    env_id: str, policy: Callable[[np.ndarray], np.ndarray], n_episodes: int, max_steps: int, seed: int = 0
) -> Demonstrations:
    """``n_episodes`` of ``policy`` on ``env_id`` (at most ``max_steps`` each), env seeds ``seed, seed + 1, ...``."""
    env = gym.make(env_id)
    episodes = []
    for i in range(n_episodes):
        obs, _ = env.reset(seed=seed + i)
        o, a, r = [], [], []
        for _ in range(max_steps):
            act = policy(obs)[0]
            o.append(obs)
            a.append(act)
            obs, rew, terminated, truncated, _ = env.step(act)
            r.append(rew)
            if terminated or truncated:
                break
        episodes.append({"observations": np.array(o), "actions": np.array(a), "rewards": np.array(r), "seed": seed + i})
    env.close()
    return Demonstrations.from_episodes(episodes)


class Interrupt(BaseCallback):
    """Dies like a killed process would, once training has passed ``at`` steps."""

    def __init__(self, at: int) -> None:
        super().__init__()
        self.at = at

    def _on_rollout_start(self) -> None:
        if self.model.num_timesteps >= self.at:
            raise KeyboardInterrupt("simulated interruption")

    def _on_step(self) -> bool:
        return True


EVAL_HEADER = "epoch,timesteps,return_mean,return_std,frechet_mean,frechet_std,action_mse,length_mean,n_episodes"


def write_run(root: Path, method: str, trial: int, returns: Sequence[float], frechet: Sequence[float] | None = None,
              mse: Sequence[float] | None = None, *, env: str = "HalfCheetah-v5",
              final: dict[str, list[float]] | None = None, done: bool = True, lowest_epoch: int | None = None,
              hyperparams: dict | None = None, expert: float = 1000.0) -> Path:
    """A run folder with hand-written records (the report must not care who wrote them).

    ``returns`` etc. are eval.csv's per-epoch values; ``final`` maps a policy to the returns of its
    held-out episodes (Fréchet 10 + trial + episode, action MSE 0.01 (1 + trial), expert return
    ``expert`` + 10 trial + episode); ``done=False`` leaves the run unfinished (a checkpoint, no done.json).
    """
    out = root / env / method / f"trial{trial}"
    out.mkdir(parents=True)
    frechet = frechet or [1.0] * len(returns)
    mse = mse or [0.1] * len(returns)
    lines = [EVAL_HEADER] + [f"{e},{e * 2048},{r},0,{f},0,{m},1000,5"
                             for e, (r, f, m) in enumerate(zip(returns, frechet, mse, strict=True))]
    (out / "eval.csv").write_text("\n".join(lines) + "\n")
    config = {"env_name": env, "method": method, "seed": trial, "command": f"pytest {root.name}",
              "hyperparams_values": hyperparams or {"bc_pretrain_epochs": 1000}}
    (out / "config.json").write_text(json.dumps(config))
    if final:
        rows = ["policy,episode,seed,return,length,frechet,action_mse,expert_return"]
        for policy, values in final.items():
            rows += [f"{policy},{i},{i},{v!r},1000,{10 + trial + i},{0.01 * (1 + trial)!r},{expert + 10 * trial + i!r}"
                     for i, v in enumerate(values)]
        (out / "final_eval.csv").write_text("\n".join(rows) + "\n")
    if done:
        summary = {"status": "done", "final_evaluation": {"lowest_u": {"epoch": lowest_epoch}} if lowest_epoch else {}}
        (out / "done.json").write_text(json.dumps(summary))
    else:
        (out / "model.zip").write_bytes(b"checkpoint")
    return out


def with_entry(yaml_text: str, entry: str) -> str:
    """``yaml_text`` with one more setting ``entry`` (``"  key: value\\n"``) under its env key: a line of the
    same key at the same indentation is replaced (hyperparameter files refuse a key written twice)."""
    key = entry.split(":", 1)[0] + ":"
    lines = yaml_text.splitlines(keepends=True)
    kept = [line for line in lines if not line.startswith(key)]
    return "".join(kept) + entry


#: The off-policy epoch of the tests' runs (steps; conftest's ``short_offpolicy_epochs``): the shipped
#: 2,048 would make every tiny run one epoch.
SHORT_OFFPOLICY_EPOCH = 64


def write_tiny_yaml(path: Path, settings: Mapping[str, Any], n_timesteps: int = 256, **extra: Any) -> Path:
    """A hyperparameter file at ``path`` whose ``default`` entry is ``settings`` on the tests' short
    Pendulum-v1 episodes, one demo; ``path``."""
    path.write_text(zoo_yaml("default", settings, n_timesteps=n_timesteps, env_kwargs=SHORT_EPISODES, n_demos=1,
                             **extra))
    return path
