"""Where is the ensemble's disagreement u informative? A diagnostic for the paper grid's results.

    python benchmarks/studies/disagreement_coverage.py [--env HalfCheetah-v5,Hopper-v5,sb3_cmzdril:WaypointNav-v0]
        [--trials 0,1] [--hyperparams hyperparams/cmzdril.yml] [--demos-dir experts]

For each env and trial, with the benchmark's own data split (``split_episodes``) and hyperparameters,
this pretrains a CMZDRIL model exactly as a grid run starts (NLL pretraining of the policy, the
bootstrap ensemble) and measures the mean u

* on the training demonstration's observations,
* on the held-out expert episodes' observations (expert states the ensemble never saw),
* along rollouts from the held-out episodes' reset seeds of: the pretrained policy sampling its
  actions (what PPO's first rollout sees), the same policy acting deterministically (the BC
  baseline's evaluation), the ensemble's mean action (the members' average, another BC policy), and
  uniformly random actions (states far from the expert's),

with the true return of each rollout and the share of its steps where u is exactly 0: where every
member's action, clipped to the action bounds, lands on the same bound in every dimension. The
CMZ-DRIL reward can only guide the agent where u separates expert-like from other states: a rollout
whose u stays near u's ceiling gets a reward that is noise around 0, and one where the members all
extrapolate past a bound reads as the expert's own certainty.

    python benchmarks/studies/disagreement_coverage.py --env LunarLander-v3 --trials 0,1,2 \
        --hyperparams benchmarks/studies/outside_env.yml --demos-dir results/outside_env
"""
from __future__ import annotations

import argparse
from collections.abc import Callable

import gymnasium as gym
import numpy as np
import torch

from sb3_cmzdril import CMZDRIL
from sb3_cmzdril.demos import Demonstrations
from sb3_cmzdril.experiments.run.runs import (
    check_env_id,
    default_demos_path,
    load_run_hyperparams,
    split_episodes,
)

#: per set of states: mean u, true return, episode length, share of steps with u exactly 0
COLUMNS = ("u", "return", "length", "u = 0")


def rollout(env: gym.Env, act: Callable[[np.ndarray], np.ndarray], disagreement, seed: int) -> dict[str, float]:
    """One episode from ``seed``: its true return, length, mean u of the observations acted on and the
    share of them with u exactly 0."""
    obs, _ = env.reset(seed=seed)
    total, us, done = 0.0, [], False
    while not done:
        us.append(float(disagreement(obs[None])[0]))
        obs, reward, terminated, truncated, _ = env.step(act(obs))
        total += float(reward)
        done = terminated or truncated
    u = np.asarray(us)
    return {"return": total, "length": float(len(u)), "u": float(u.mean()), "u = 0": float(np.mean(u == 0.0))}


def measure(env_id: str, trial: int, hyperparams: str, demos_dir: str) -> dict[str, dict[str, float]]:
    hp, settings = load_run_hyperparams(hyperparams, env_id)
    pool = Demonstrations.load(default_demos_path(env_id, demos_dir))
    train_idx, eval_idx = split_episodes(pool.n_episodes, int(settings.get("n_demos", 1)), 5, trial)
    train, held_out = pool.select(train_idx), pool.select(eval_idx)
    env = gym.make(env_id, **(hp.env_kwargs or {}))
    kwargs = hp.model_kwargs()
    kwargs["device"] = "cpu"
    model = CMZDRIL(hp.policy or "MlpPolicy", env, demonstrations=train, reward="cmz", seed=trial, **kwargs)
    model.pretrain()
    ens = model.ensemble
    low, high = env.action_space.low, env.action_space.high
    policies = {
        "policy, sampled": lambda o: np.clip(model.predict(o, deterministic=False)[0], low, high),
        "policy, deterministic (BC)": lambda o: np.clip(model.predict(o, deterministic=True)[0], low, high),
        "ensemble mean action": lambda o: ens.predict(o[None])[0],
        "random actions": lambda o: env.action_space.sample(),
    }
    env.action_space.seed(trial)
    on_train, on_held_out = ens.disagreement(train.observations), ens.disagreement(held_out.observations)
    out: dict[str, dict[str, float]] = {
        "training demo": {"u": float(on_train.mean()), "u = 0": float(np.mean(on_train == 0.0))},
        "held-out expert episodes": {
            "u": float(on_held_out.mean()), "u = 0": float(np.mean(on_held_out == 0.0)),
            "return": float(np.mean(held_out.episode_returns)) if held_out.episode_returns is not None else np.nan,
        },
    }
    for name, act in policies.items():
        episodes = [rollout(env, act, ens.disagreement, int(seed)) for seed in held_out.seeds]
        out[name] = {k: float(np.mean([e[k] for e in episodes])) for k in COLUMNS}
    env.close()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="HalfCheetah-v5,Hopper-v5,sb3_cmzdril:WaypointNav-v0")
    parser.add_argument("--trials", default="0,1")
    parser.add_argument("--hyperparams", default="hyperparams/cmzdril.yml")
    parser.add_argument("--demos-dir", default="experts")
    args = parser.parse_args()
    torch.set_num_threads(1)
    for env_id in (check_env_id(e.strip()) for e in args.env.split(",")):
        results: list[dict[str, dict[str, float]]] = [
            measure(env_id, int(t), args.hyperparams, args.demos_dir) for t in args.trials.split(",")
        ]
        print(f"\n{env_id} (trials {args.trials}; mean over trials of each trial's mean over its 5 held-out seeds)")
        print(f"{'states':30s} {'mean u':>8s} {'return':>9s} {'length':>7s} {'u = 0':>6s}")
        for name in results[0]:
            row = {k: np.mean([r[name].get(k, np.nan) for r in results]) for k in COLUMNS}
            cells = [f"{row['u']:8.3f}"] + [("" if np.isnan(row[k]) else f"{row[k]:.1f}").rjust(w)
                                            for k, w in (("return", 9), ("length", 7))]
            cells.append(f"{row['u = 0']:6.0%}")
            print(f"{name:30s} " + " ".join(cells))


if __name__ == "__main__":
    main()
