"""Where a CMZDRIL training loop spends its time: PPO's update with the NLL epoch, the rollouts, and
MuJoCo's own step inside them.

    python benchmarks/speed/profile_loop.py [--env Walker2d-v5] [--n-envs 8] [--steps 16384]

CMZDRIL (reward "cmz", package defaults, one demonstration of the env's shipped pool, one torch
thread, ``n_steps`` = 2048 / envs) is set up and pretrained first; then ``--steps`` more steps run
under cProfile. Prints each part's cumulative profiled seconds and its share of the loop. cProfile's
own overhead inflates the many small Python calls, so read the shares, not the seconds.
"""
from __future__ import annotations

import argparse
import cProfile
import pstats
from pathlib import Path

import torch
from stable_baselines3.common.env_util import make_vec_env

from sb3_cmzdril import CMZDRIL, Demonstrations

ROOT = Path(__file__).resolve().parents[2]
UPDATE_SIZE = 2048

#: (label, file suffix, function name) of the parts to report.
PARTS = (
    ("PPO update + NLL epoch (CMZDRIL.train)", "sb3_cmzdril/cmzdril/cmzdril.py", "train"),
    ("rollouts (collect_rollouts)", "common/on_policy_algorithm.py", "collect_rollouts"),
    ("  env steps (DummyVecEnv.step_wait)", "vec_env/dummy_vec_env.py", "step_wait"),
    ("    MuJoCo (mj_step)", "~", "<built-in method mujoco._functions.mj_step>"),
)


def cumulative_seconds(stats: pstats.Stats, suffix: str, name: str) -> float:
    """Cumulative seconds of the function ``name`` defined in a file ending with ``suffix``."""
    table = stats.stats  # type: ignore[attr-defined]  # pstats keeps its table in this attribute
    return sum(entry[3] for (path, _, func), entry in table.items() if func == name and path.endswith(suffix))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="Walker2d-v5")
    parser.add_argument("--n-envs", type=int, default=8)
    parser.add_argument("--steps", type=int, default=16384)
    args = parser.parse_args()
    if UPDATE_SIZE % args.n_envs:
        parser.error(f"--n-envs must divide {UPDATE_SIZE}")
    torch.set_num_threads(1)
    demos = Demonstrations.load(ROOT / "experts" / args.env / "demos.npz").select([0])
    env = make_vec_env(args.env, n_envs=args.n_envs, seed=0)
    model = CMZDRIL("MlpPolicy", env, demonstrations=demos, reward="cmz", seed=0, device="cpu",
                    n_steps=UPDATE_SIZE // args.n_envs)
    model.learn(UPDATE_SIZE)  # set-up and pretraining, outside the profile
    profile = cProfile.Profile()
    profile.enable()
    model.learn(args.steps, reset_num_timesteps=False)
    profile.disable()
    env.close()
    stats = pstats.Stats(profile)
    total = cumulative_seconds(stats, "sb3_cmzdril/common/imitation.py", "learn")
    print(f"{args.env}, {args.n_envs} envs, {args.steps} steps: {total:.1f} profiled seconds in learn()")
    for label, suffix, name in PARTS:
        seconds = cumulative_seconds(stats, suffix, name)
        print(f"{label:<42} {seconds:7.1f} s  {100 * seconds / total:5.1f}%")


if __name__ == "__main__":
    main()
