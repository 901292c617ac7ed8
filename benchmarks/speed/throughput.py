"""Training throughput: CMZ-DRIL against plain SB3 PPO with identical settings on HalfCheetah-v5.

    python benchmarks/speed/throughput.py [--steps 20480] [--repeats 3] [--per-step-scoring]

Both run in this one process, interleaved (PPO, CMZ-DRIL, PPO, ...), each for the same number of
steps with PPO's default settings and one env; the median of the repeats is reported. CMZ-DRIL uses
its defaults (policy inputs standardised with the demo's statistics, BC pretraining early-stopped on
held-out demo steps, each rollout scored from the rollout buffer in one ensemble forward), or with
``--per-step-scoring`` one forward per env step inside the reward wrapper. It uses
reward "cmz", one 1,000-step demonstration (the shipped expert's first episode when
experts/HalfCheetah-v5/demos.npz exists, else 1,000 steps of a fixed linear feedback policy: the
speed does not depend on the demo's quality) and one BC epoch after every PPO update.

"steps/s" is measured from the start to the end of the training loop (SB3's on_training_start ->
on_training_end), i.e. rollouts + PPO updates (+ BC epochs); CMZ-DRIL's one-time pretraining (BC
pretraining to convergence and ensemble fitting, before the loop) is printed separately, with the
epochs the early stopping ran. The last line is the ratio
CMZ-DRIL / PPO of the medians.
"""
from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback

from sb3_cmzdril import CMZDRIL, Demonstrations

ENV_ID = "HalfCheetah-v5"
SHIPPED_DEMOS = Path(__file__).resolve().parents[2] / "experts" / ENV_ID / "demos.npz"


class LoopTimer(BaseCallback):
    """Wall time of the training loop only (after set-up, before tear-down)."""

    def _on_training_start(self) -> None:
        self.start = time.perf_counter()
        self.start_steps = self.model.num_timesteps

    def _on_step(self) -> bool:
        return True

    def _on_training_end(self) -> None:
        self.seconds = time.perf_counter() - self.start
        self.steps = self.model.num_timesteps - self.start_steps


def one_demo(seed: int = 0) -> tuple[Demonstrations, str]:
    if SHIPPED_DEMOS.is_file():
        return Demonstrations.load(SHIPPED_DEMOS).select([0]), f"shipped expert episode ({SHIPPED_DEMOS})"
    env = gym.make(ENV_ID)
    rng = np.random.default_rng(seed)
    gain = rng.normal(scale=0.3, size=(env.action_space.shape[0], env.observation_space.shape[0]))
    obs, _ = env.reset(seed=seed)
    observations, actions = [], []
    for _ in range(1000):
        act = np.clip(gain @ obs, -1, 1).astype(np.float32)
        observations.append(obs)
        actions.append(act)
        obs, _, terminated, truncated, _ = env.step(act)
        if terminated or truncated:
            obs, _ = env.reset()
    return Demonstrations(
        np.array(observations), np.array(actions), [1000]
    ), "1,000 steps of a fixed linear feedback policy"


def run(kind: str, steps: int, demos: Demonstrations, seed: int, batch_scoring: bool = True) -> dict:
    timer = LoopTimer()
    start = time.perf_counter()
    if kind == "ppo":
        model = PPO("MlpPolicy", ENV_ID, seed=seed, device="cpu")
    else:
        model = CMZDRIL(
            "MlpPolicy",
            ENV_ID,
            demonstrations=demos,
            reward="cmz",
            seed=seed,
            device="cpu",
            batch_scoring=batch_scoring,
        )
    model.learn(steps, callback=timer)
    total = time.perf_counter() - start
    result = {
        "loop_sps": timer.steps / timer.seconds,
        "total_sps": timer.steps / total,
        "setup_s": total - timer.seconds,
    }
    if kind != "ppo":
        info = model.pretrain_info
        result.update(bc_s=info["bc_seconds"], bc_epochs=info["bc_epochs"], ensemble_s=info["ensemble_seconds"])
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=20480, help="environment steps per run (default 10 PPO updates)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1, help="torch threads (1 was fastest on our machines)")
    parser.add_argument(
        "--per-step-scoring", action="store_true", help="CMZ-DRIL scores every env step (batch_scoring=False)"
    )
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    demos, source = one_demo()
    scoring = "per step" if args.per_step_scoring else "batched per rollout"
    print(
        f"{ENV_ID}, {args.steps} steps per run, {args.repeats} repeats, "
        f"torch threads {args.threads}, CMZ-DRIL scoring {scoring}"
    )
    print(f"demonstration: {source}, {len(demos)} steps")
    results: dict = {"ppo": [], "cmzdril": []}
    for repeat in range(args.repeats):
        for kind in ("ppo", "cmzdril"):
            r = run(kind, args.steps, demos, seed=repeat, batch_scoring=not args.per_step_scoring)
            results[kind].append(r)
            print(
                f"  repeat {repeat}: {kind:8s} loop {r['loop_sps']:7.0f} steps/s, "
                f"end to end {r['total_sps']:7.0f} steps/s, set-up {r['setup_s']:.1f}s"
            )
    med = {k: statistics.median(r["loop_sps"] for r in v) for k, v in results.items()}
    med_total = {k: statistics.median(r["total_sps"] for r in v) for k, v in results.items()}
    print(f"PPO      median training-loop throughput: {med['ppo']:.0f} steps/s (end to end {med_total['ppo']:.0f})")
    print(
        f"CMZ-DRIL median training-loop throughput: {med['cmzdril']:.0f} steps/s "
        f"(end to end {med_total['cmzdril']:.0f}, incl. pretraining)"
    )
    pre = results["cmzdril"]
    print(
        f"CMZ-DRIL pretraining (median): BC {statistics.median(r['bc_s'] for r in pre):.1f}s "
        f"({statistics.median(r['bc_epochs'] for r in pre):.0f} epochs to the early stop), "
        f"ensemble {statistics.median(r['ensemble_s'] for r in pre):.1f}s"
    )
    print(f"end-to-end ratio CMZ-DRIL/PPO: {med_total['cmzdril'] / med_total['ppo']:.3f}")
    print(f"ratio CMZ-DRIL/PPO: {med['cmzdril'] / med['ppo']:.3f}")


if __name__ == "__main__":
    main()
