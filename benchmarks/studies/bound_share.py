"""How often does each pool's expert hold its actions on a bound, and what does ``disagreement="auto"`` take?

    python benchmarks/studies/bound_share.py [--env HalfCheetah-v5,Hopper-v5,Walker2d-v5,Swimmer-v5,
        sb3_cmzdril:WaypointNav-v0] [--trials 0-9] [--hyperparams hyperparams/cmzdril.yml] [--demos-dir experts]

For each env: the share of the pool's action entries that sit exactly on a bound of the env's action
space, the lowest and highest share of any one episode, and for each trial the share in its training
demonstrations (the benchmark's own split, ``split_episodes``, with the YAML entry's ``n_demos``) with
the form ``"auto"`` takes from them (``"std_unclipped"`` from ``AUTO_UNCLIPPED_SHARE`` up). The
other pools:

    python benchmarks/studies/bound_share.py --env LunarLander-v3 \\
        --hyperparams benchmarks/studies/outside_env.yml --demos-dir results/outside_env
    python benchmarks/studies/bound_share.py --env BipedalWalker-v3,Pendulum-v1 --demos-dir results/untuned
    python benchmarks/studies/bound_share.py --env Walker2d-v5 --demos-dir results/pools/tqc

The repository's output of the four: results/tuning/bound_share.txt.
"""
from __future__ import annotations

import argparse

import gymnasium as gym

from cmzdril_lab.cli import trial_indices
from sb3_cmzdril.data.demos import Demonstrations
from sb3_cmzdril.ensemble import AUTO_UNCLIPPED_SHARE, auto_disagreement_form, share_on_bound
from sb3_cmzdril.training.runs import check_env_id, default_demos_path, load_run_hyperparams, split_episodes

MUJOCO_AND_GRID = "HalfCheetah-v5,Hopper-v5,Walker2d-v5,Swimmer-v5,sb3_cmzdril:WaypointNav-v0"


def describe(env_id: str, trials: list[int], hyperparams: str, demos_dir: str) -> str:
    """The lines for one env's pool."""
    hp, settings = load_run_hyperparams(hyperparams, env_id)
    pool = Demonstrations.load(default_demos_path(env_id, demos_dir))
    env = gym.make(env_id, **(hp.env_kwargs or {}))
    space = env.action_space
    env.close()
    episodes = [share_on_bound(pool.episode(i)["actions"], space) for i in range(pool.n_episodes)]
    lines = [f"{env_id} ({default_demos_path(env_id, demos_dir)}, {pool.n_episodes} episodes, actions {space}): "
             f"{share_on_bound(pool.actions, space):.2%} of the action entries on a bound; one episode "
             f"{min(episodes):.2%} to {max(episodes):.2%}"]
    n_demos = int(settings.get("n_demos", 1))
    for trial in trials:
        train_idx, _ = split_episodes(pool.n_episodes, n_demos, 5, trial)
        actions = pool.select(train_idx).actions
        lines.append(f"  trial {trial}: {n_demos} training episode(s) {list(train_idx)}, "
                     f"{share_on_bound(actions, space):.2%} on a bound, "
                     f"disagreement='auto' takes {auto_disagreement_form(actions, space)!r}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default=MUJOCO_AND_GRID, help="comma-separated env ids")
    parser.add_argument("--trials", default="0-9", help="trials whose training split to read (default 0-9)")
    parser.add_argument("--hyperparams", default="hyperparams/cmzdril.yml", help="for n_demos and env_kwargs")
    parser.add_argument("--demos-dir", default="experts", help="folder of <EnvName>/demos.npz pools")
    args = parser.parse_args(argv)
    envs = [check_env_id(e) for e in args.env.split(",")]
    chosen = trial_indices(args.trials)
    trials = list(range(chosen)) if isinstance(chosen, int) else chosen
    print(f"disagreement='auto' takes 'std_unclipped' from {AUTO_UNCLIPPED_SHARE:.0%} of the entries on a bound up")
    for env_id in envs:
        print(describe(env_id, trials, args.hyperparams, args.demos_dir))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
