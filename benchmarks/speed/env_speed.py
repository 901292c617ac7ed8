"""Single-env steps/s of WaypointNav-v0 against HalfCheetah-v5, random actions, resets included.

    python benchmarks/speed/env_speed.py                 # 20,000 steps each
    python benchmarks/speed/env_speed.py --steps 50000 --repeats 3

Both envs come from ``gym.make`` with their registered wrappers, step the same number of times with
actions sampled beforehand (so sampling is not timed), and reset when an episode ends. The two alternate for
``--repeats`` rounds and the best run of each is kept, because the machine is shared. The last line is the ratio.
"""
from __future__ import annotations

import argparse
import sys
import time
from typing import Any

import gymnasium as gym

import sb3_cmzdril  # noqa: F401  (registers WaypointNav-v0)


def steps_per_second(env_id: str, n_steps: int, seed: int = 0, env_kwargs: dict[str, Any] | None = None) -> float:
    """Random-action steps/s of one ``gym.make(env_id)``, resets counted in the time."""
    env = gym.make(env_id, **(env_kwargs or {}))
    env.action_space.seed(seed)
    actions = [env.action_space.sample() for _ in range(n_steps)]
    env.reset(seed=seed)
    step, reset = env.step, env.reset
    t0 = time.perf_counter()
    for a in actions:
        _, _, terminated, truncated, _ = step(a)
        if terminated or truncated:
            reset()
    elapsed = time.perf_counter() - t0
    env.close()
    return n_steps / elapsed


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--n-beams", type=int, default=None)
    parser.add_argument("--n-obstacles", type=int, default=None)
    args = parser.parse_args(argv)
    kwargs = {k: v for k, v in (("n_beams", args.n_beams), ("n_obstacles", args.n_obstacles)) if v is not None}

    envs = (("WaypointNav-v0", "sb3_cmzdril:WaypointNav-v0", kwargs), ("HalfCheetah-v5", "HalfCheetah-v5", {}))
    runs: dict[str, list[float]] = {name: [] for name, _, _ in envs}
    for i in range(args.repeats):
        # Alternate the two so that a burst of load from other processes hits both alike.
        for name, env_id, kw in envs:
            runs[name].append(steps_per_second(env_id, args.steps, seed=i, env_kwargs=kw))
    results = {name: max(r) for name, r in runs.items()}
    for name, r in runs.items():
        print(f"{name:16s} {results[name]:10,.0f} steps/s  (best of {args.repeats} x {args.steps:,} steps; "
              f"runs: {', '.join(f'{x:,.0f}' for x in r)})")
    ratio = results["WaypointNav-v0"] / results["HalfCheetah-v5"]
    print(f"ratio WaypointNav-v0 / HalfCheetah-v5 = {ratio:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
