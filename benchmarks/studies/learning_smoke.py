"""A real learning check: BC-only against CMZ-DRIL on a task with a scripted expert.

    python benchmarks/studies/learning_smoke.py [--env sb3_cmzdril:WaypointNav-v0] [--expert waypoint-reactive]
        [--n-demos 5] [--eval-episodes 20] [--timesteps 100000] [--seeds 0,1,2] [--methods bc,cmz]

For each seed: record ``--n-demos`` expert episodes for training (reset seeds 0..K-1) and
``--eval-episodes`` held-out ones (reset seeds 10000+), pretrain a CMZDRIL model by NLL (that
pretrained policy *is* the BC baseline: same data, same network seed), evaluate it, then (for the
other methods) train with PPO on the chosen reward for ``--timesteps`` steps and evaluate again. The
evaluation replays each held-out episode's reset seed and rolls the agent out deterministically
(true environment return, Fréchet distance to the expert's path, action MSE). The last lines print
each method's mean return over seeds.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from sb3_cmzdril import CMZDRIL
from sb3_cmzdril.experts import collect_demos
from sb3_cmzdril.metrics import evaluate_against_expert, trajectory_features

METHOD_NAMES = {"bc": "BC", "cmz": "CMZ-DRIL", "dril": "DRIL", "zero": "no reward", "env": "env reward"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="sb3_cmzdril:WaypointNav-v0")
    parser.add_argument("--expert", default="waypoint-reactive", help="scripted expert name or SB3 model path")
    parser.add_argument("--n-demos", type=int, default=5)
    parser.add_argument("--eval-episodes", type=int, default=20)
    parser.add_argument("--timesteps", type=int, default=100_000)
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--methods", default="bc,cmz", help=f"comma-separated, from {sorted(METHOD_NAMES)}")
    args = parser.parse_args()
    torch.set_num_threads(1)
    methods = args.methods.split(",")
    unknown = set(methods) - set(METHOD_NAMES)
    if unknown:
        parser.error(f"unknown methods {sorted(unknown)}")

    train_demos = collect_demos(args.expert, args.env, n_episodes=args.n_demos, seed=0)
    eval_demos = collect_demos(args.expert, args.env, n_episodes=args.eval_episodes, seed=10_000)
    expert_return = float(np.mean(eval_demos.episode_returns))
    trajectory_fn = trajectory_features(args.env)
    print(
        f"{args.env}: {args.n_demos} training demos ({len(train_demos)} steps), "
        f"{args.eval_episodes} evaluation episodes, "
        f"expert return on them {expert_return:.2f}"
    )

    results: dict[str, list[dict[str, float]]] = {m: [] for m in methods}
    for seed in (int(s) for s in args.seeds.split(",")):
        for method in methods:
            start = time.perf_counter()
            model = CMZDRIL(
                "MlpPolicy", args.env, demonstrations=train_demos, reward="cmz" if method == "bc" else method, seed=seed
            )
            if method == "bc":
                model.pretrain()
            else:
                model.learn(args.timesteps)
            ev = evaluate_against_expert(model, args.env, eval_demos, trajectory_fn=trajectory_fn)
            row = {"return": ev.mean_return, "frechet": ev.mean_frechet, "action_mse": ev.action_mse}
            results[method].append(row)
            print(
                f"seed {seed} {METHOD_NAMES[method]:10s} return {row['return']:8.2f}  Frechet {row['frechet']:.3f}  "
                f"action MSE {row['action_mse']:.4f}  ({time.perf_counter() - start:.0f}s)",
                flush=True,
            )

    print(f"\nmean over seeds {args.seeds} (expert {expert_return:.2f}):")
    for method in methods:
        rows = results[method]
        r = np.array([x["return"] for x in rows])
        f = np.array([x["frechet"] for x in rows])
        m = np.array([x["action_mse"] for x in rows])
        print(
            f"{METHOD_NAMES[method]:10s} return {r.mean():8.2f} (std {r.std():.2f})  "
            f"Frechet {f.mean():.3f}  action MSE {m.mean():.4f}"
        )


if __name__ == "__main__":
    main()
