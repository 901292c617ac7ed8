"""The reactive expert on WaypointNav-v0: success, collisions, return and length over seeded episodes.

    python benchmarks/studies/waypoint_expert.py                       # seeds 0..199
    python benchmarks/studies/waypoint_expert.py --episodes 50 --n-beams 16
    python benchmarks/studies/waypoint_expert.py --figure docs/figures/waypoint_expert_paths.png

Episode ``i`` is reset with seed ``i``. The figure shows the expert's paths on the first four seeds.
"""
from __future__ import annotations

import argparse
import sys
import time
from typing import Any

import gymnasium as gym
import numpy as np

import sb3_cmzdril  # noqa: F401  (registers the env and the expert)
from sb3_cmzdril.experts import SCRIPTED_EXPERTS

ENV_ID = "sb3_cmzdril:WaypointNav-v0"


def run_episodes(n_episodes: int, env_kwargs: dict[str, Any] | None = None, first_seed: int = 0
                 ) -> list[dict[str, Any]]:
    """Run the registered expert on seeds ``first_seed ..``; one dict of outcomes per episode."""
    env = gym.make(ENV_ID, **(env_kwargs or {}))
    expert = SCRIPTED_EXPERTS["waypoint-reactive"](env)
    results = []
    for seed in range(first_seed, first_seed + n_episodes):
        obs, info = env.reset(seed=seed)
        ret, length, done = 0.0, 0, False
        while not done:
            action, _ = expert.predict(obs)
            obs, reward, terminated, truncated, info = env.step(action)
            ret += float(reward)
            length += 1
            done = terminated or truncated
        results.append({"seed": seed, "return": ret, "length": length, "success": bool(info["is_success"]),
                        "collision": bool(info["collision"]) and not info["out_of_bounds"],
                        "out_of_bounds": bool(info["out_of_bounds"]), "truncated": bool(truncated),
                        "path": env.unwrapped.trajectory, "field": env.unwrapped.field})
    env.close()
    return results


def save_figure(path: str, results: list[dict[str, Any]], columns: int = 2) -> None:
    """A grid of fields with the expert's path on each (the first ``len(results)`` seeds)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sb3_cmzdril.envs.plotting import plot_trajectories

    rows = (len(results) + columns - 1) // columns
    fig, axes = plt.subplots(rows, columns, figsize=(4.2 * columns, 4.2 * rows), squeeze=False)
    for ax, r in zip(list(axes.flat)[: len(results)], results, strict=True):
        outcome = "goal" if r["success"] else ("collision" if r["collision"] or r["out_of_bounds"] else "time-out")
        plot_trajectories(r["field"], {"expert": r["path"]}, ax=ax,
                          title=f"seed {r['seed']}: {r['length']} steps, {outcome}, return {r['return']:.1f}")
    for ax in list(axes.flat)[len(results):]:
        ax.axis("off")
    fig.suptitle("WaypointNav-v0: reactive expert paths")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=200, help="episodes, seeds first-seed.. (default 200)")
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--n-beams", type=int, default=None)
    parser.add_argument("--n-obstacles", type=int, default=None)
    parser.add_argument("--figure", default=None, help="also write a 2x2 grid of expert paths (PNG)")
    parser.add_argument("--figure-seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    args = parser.parse_args(argv)
    kwargs = {k: v for k, v in (("n_beams", args.n_beams), ("n_obstacles", args.n_obstacles)) if v is not None}

    t0 = time.perf_counter()
    res = run_episodes(args.episodes, kwargs, args.first_seed)
    wall = time.perf_counter() - t0
    success = np.mean([r["success"] for r in res])
    returns = np.array([r["return"] for r in res])
    lengths = np.array([r["length"] for r in res])
    failures = [(r["seed"], "collision" if r["collision"] else "out_of_bounds" if r["out_of_bounds"] else "truncated")
                for r in res if not r["success"]]
    print(f"WaypointNav-v0 {kwargs or 'defaults'}, reactive expert, seeds {args.first_seed}.."
          f"{args.first_seed + args.episodes - 1} ({wall:.1f} s)")
    print(f"success rate   {100 * success:.1f}% ({int(round(success * len(res)))}/{len(res)})")
    print(
        f"collisions     {sum(r['collision'] for r in res)} (obstacle), {sum(r['out_of_bounds'] for r in res)} (wall)"
    )
    print(f"truncated      {sum(r['truncated'] for r in res)}")
    print(f"mean return    {returns.mean():.2f} (std {returns.std():.2f})")
    print(f"mean length    {lengths.mean():.1f} (std {lengths.std():.1f}, min {lengths.min()}, max {lengths.max()})")
    if failures:
        print("failures       " + ", ".join(f"seed {s}: {why}" for s, why in failures))

    if args.figure:
        by_seed = {r["seed"]: r for r in res}
        chosen = [by_seed.get(s) or run_episodes(1, kwargs, s)[0] for s in args.figure_seeds]
        save_figure(args.figure, chosen)
        print(f"figure         {args.figure}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
