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
With ``--runs FOLDER`` (repeatable) it also plays each trial's trained CMZ-DRIL policy from a benchmark
folder (``FOLDER/<EnvName>/cmz/trial<t>/model.zip``, which the repository does not keep: rerun the
folder's command first) deterministically from the same seeds, u being that run's own (its
``disagreement`` setting): what the agent learned to do with the reward.

    python benchmarks/studies/disagreement_coverage.py --env Pendulum-v1 --trials 0,1,2 \
        --hyperparams results/tuning/P-zoo-ppo/hyperparams.yml --demos-dir results/untuned \
        --runs results/tuning/P-zoo-ppo --runs results/tuning/P-zoo-ppo-unclipped
"""
from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

from sb3_cmzdril import CMZDRIL
from sb3_cmzdril.data.demos import Demonstrations
from sb3_cmzdril.data.spaces import Observations
from sb3_cmzdril.ensemble import BCEnsemble
from sb3_cmzdril.experts.envs import env_name
from sb3_cmzdril.training.runs import (
    check_env_id,
    default_demos_path,
    load_run_hyperparams,
    split_episodes,
)

#: per set of states: mean u, mean u on the members' unclipped actions (``disagreement="std_unclipped"``), true
#: return, episode length, share of steps with u exactly 0
COLUMNS = ("u", "u unclipped", "return", "length", "u = 0")


def unclipped(ensemble: BCEnsemble) -> Callable[[Observations], np.ndarray]:
    """``ensemble``'s u on its members' actions as they are, whatever form it was built with."""
    def score(obs: Observations) -> np.ndarray:
        form, ensemble.disagreement_form = ensemble.disagreement_form, "std_unclipped"
        try:
            return ensemble.disagreement(obs)
        finally:
            ensemble.disagreement_form = form
    return score


def rollout(env: gym.Env, act: Callable[[np.ndarray], np.ndarray], ensemble: BCEnsemble,
            seed: int) -> dict[str, float]:
    """One episode from ``seed``: its true return, length, the mean u of the observations acted on (the
    ensemble's own form, and unclipped) and the share of them with u exactly 0."""
    obs, _ = env.reset(seed=seed)
    total, observations, done = 0.0, [], False
    while not done:
        observations.append(obs)
        obs, reward, terminated, truncated, _ = env.step(act(obs))
        total += float(reward)
        done = terminated or truncated
    return {"return": total, "length": float(len(observations)), **u_columns(ensemble, np.stack(observations))}


def u_columns(ensemble: BCEnsemble, observations: Observations) -> dict[str, float]:
    """Mean u, mean unclipped u and the share of u exactly 0 on a batch of observations."""
    u = ensemble.disagreement(observations)
    return {"u": float(u.mean()), "u unclipped": float(unclipped(ensemble)(observations).mean()),
            "u = 0": float(np.mean(u == 0.0))}


def played(model: CMZDRIL, low: np.ndarray, high: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """``model``'s deterministic action, clipped to the bounds as the env clips it."""
    return lambda o: np.clip(model.predict(o, deterministic=True)[0], low, high)


def measure(env_id: str, trial: int, hyperparams: str, demos_dir: str,
            runs: tuple[str, ...] = ()) -> dict[str, dict[str, float]]:
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
    out: dict[str, dict[str, float]] = {
        "training demo": u_columns(ens, train.observations),
        "held-out expert episodes": {
            **u_columns(ens, held_out.observations),
            "return": float(np.mean(held_out.episode_returns)) if held_out.episode_returns is not None else np.nan,
        },
    }
    ensembles = dict.fromkeys(policies, ens)
    for folder in runs:
        trained = CMZDRIL.load(Path(folder) / env_name(env_id) / "cmz" / f"trial{trial}" / "model.zip", device="cpu")
        name = f"trained: {folder}"
        policies[name] = played(trained, low, high)
        ensembles[name] = trained.ensemble
    for name, act in policies.items():
        episodes = [rollout(env, act, ensembles[name], int(seed)) for seed in held_out.seeds]
        out[name] = {k: float(np.mean([e[k] for e in episodes])) for k in COLUMNS}
    env.close()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="HalfCheetah-v5,Hopper-v5,sb3_cmzdril:WaypointNav-v0")
    parser.add_argument("--trials", default="0,1")
    parser.add_argument("--hyperparams", default="hyperparams/cmzdril.yml")
    parser.add_argument("--demos-dir", default="experts")
    parser.add_argument("--runs", action="append", default=[], metavar="FOLDER",
                        help="a benchmark folder whose trained CMZ-DRIL policies to play too (repeatable)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    for env_id in (check_env_id(e.strip()) for e in args.env.split(",")):
        results: list[dict[str, dict[str, float]]] = [
            measure(env_id, int(t), args.hyperparams, args.demos_dir, tuple(args.runs)) for t in args.trials.split(",")
        ]
        print(f"\n{env_id} (trials {args.trials}; mean over trials of each trial's mean over its 5 held-out seeds)")
        width = max(30, *(len(name) for name in results[0]))
        print(f"{'states':{width}s} {'mean u':>8s} {'unclipped':>9s} {'return':>9s} {'length':>7s} {'u = 0':>6s}")
        for name in results[0]:
            row = {k: np.mean([r[name].get(k, np.nan) for r in results]) for k in COLUMNS}
            cells = [f"{row['u']:8.3f}", f"{row['u unclipped']:9.3f}"] + [
                ("" if np.isnan(row[k]) else f"{row[k]:.1f}").rjust(w) for k, w in (("return", 9), ("length", 7))]
            cells.append(f"{row['u = 0']:6.0%}")
            print(f"{name:{width}s} " + " ".join(cells))


if __name__ == "__main__":
    main()
