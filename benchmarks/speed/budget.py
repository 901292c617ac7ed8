"""What a 1M- or 3M-step CMZ-DRIL run costs on one core: steps per CPU second, 1 env against 8;
and what the off-policy learner ``cmz-sac`` reaches in 20 CPU-minutes.

    python benchmarks/speed/budget.py [--env Walker2d-v5] [--steps 40960] [--n-envs 1 8] [-o FILE]
    python benchmarks/speed/budget.py --method cmz-sac [--env Walker2d-v5] [--steps 4000] [-o FILE]

For each number of envs, CMZDRIL (reward "cmz", the package defaults, one demonstration of the
env's shipped pool) trains ``--steps`` steps in this process with one torch thread; the envs share
one DummyVecEnv, so every policy forward and every ensemble scoring is one batch over the envs.
``n_steps`` is 2048 / n_envs, so that a PPO update sees the same 2,048 transitions whatever the
number of envs. The training loop (rollouts, scoring, PPO updates, the BC epoch after each) is timed
in process CPU seconds (``time.process_time``), which time spent waiting for the core does not
inflate as it does wall time; wall seconds are printed beside them. Load still slows each step
(shared caches and cores): with both cores busy, one env measured 337 steps per CPU second against
626 with one other process, so run it on an otherwise idle machine. The one-time pretraining (BC to
convergence, ensemble fit) is timed apart. The projection to 1M and 3M steps is loop time per step
times the steps plus the pretraining: arithmetic on the measurement, labelled as such.

``--method cmz-sac`` times CMZDRILSAC instead, with the env's entry of the shipped
hyperparams/cmzdril_sac.yml (one env: SAC takes one gradient step per env step), and projects the
steps that fit in 20 CPU-minutes of the loop after its pretraining.

Writes a markdown table to ``-o`` (default: print only).
"""
from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path

import torch
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env

from cmzdril_lab.report.formatting import md_table
from sb3_cmzdril import CMZDRIL, Demonstrations
from sb3_cmzdril.cmzdril_sac import CMZDRILSAC
from sb3_cmzdril.io import atomic_write_text, command_line
from sb3_cmzdril.training.spec import load_run_hyperparams

ROOT = Path(__file__).resolve().parents[2]
UPDATE_SIZE = 2048


class LoopClock(BaseCallback):
    """CPU and wall seconds of the training loop only (after set-up, before tear-down)."""

    def _on_training_start(self) -> None:
        self.cpu0, self.wall0, self.steps0 = time.process_time(), time.perf_counter(), self.model.num_timesteps

    def _on_step(self) -> bool:
        return True

    def _on_training_end(self) -> None:
        self.cpu = time.process_time() - self.cpu0
        self.wall = time.perf_counter() - self.wall0
        self.steps = self.model.num_timesteps - self.steps0


def measure(env_id: str, n_envs: int, steps: int, demos: Demonstrations, seed: int = 0) -> dict[str, float]:
    env = make_vec_env(env_id, n_envs=n_envs, seed=seed)
    cpu0 = time.process_time()
    model = CMZDRIL("MlpPolicy", env, demonstrations=demos, reward="cmz", seed=seed, device="cpu",
                    n_steps=UPDATE_SIZE // n_envs)
    clock = LoopClock()
    model.learn(steps, callback=clock)
    total_cpu = time.process_time() - cpu0
    env.close()
    return {"n_envs": n_envs, "steps": clock.steps, "loop_cpu_s": clock.cpu, "loop_wall_s": clock.wall,
            "setup_cpu_s": total_cpu - clock.cpu}


def measure_sac(env_id: str, steps: int, demos: Demonstrations, seed: int = 0) -> dict[str, float]:
    """CMZDRILSAC with the shipped settings for ``env_id``: ``steps`` timed after 1,000 untimed
    ones (the first updates start at ``learning_starts``)."""
    hp, _ = load_run_hyperparams(ROOT / "hyperparams" / "cmzdril_sac.yml", env_id, method="cmz-sac")
    env = make_vec_env(env_id, n_envs=1, seed=seed)
    cpu0 = time.process_time()
    model = CMZDRILSAC(hp.policy or "MlpPolicy", env, demonstrations=demos, seed=seed, device="cpu",
                       **hp.model_kwargs())
    model.learn(1000)
    clock = LoopClock()
    model.learn(steps, callback=clock, reset_num_timesteps=False)
    total_cpu = time.process_time() - cpu0
    env.close()
    return {"n_envs": 1, "steps": clock.steps, "loop_cpu_s": clock.cpu, "loop_wall_s": clock.wall,
            "setup_cpu_s": total_cpu - clock.cpu, "shipped_steps": float(hp.n_timesteps or 0)}


def _table(header: list[str], rows: list[dict[str, float]],
           cells: Callable[[dict[str, float], float], list[str]]) -> str:
    """A markdown table of measurements: ``cells(row, CPU seconds per step)`` gives each row's cells."""
    return md_table(header, [cells(r, r["loop_cpu_s"] / r["steps"]) for r in rows])


def sac_table(env_id: str, rows: list[dict[str, float]]) -> str:
    def cells(r: dict[str, float], per_step: float) -> list[str]:
        shipped_minutes = (r["shipped_steps"] * per_step + r["setup_cpu_s"]) / 60
        return [f"{r['shipped_steps']:.0f} steps shipped", f"{1 / per_step:.0f}", f"{1000 * per_step:.1f}",
                f"{r['setup_cpu_s']:.0f}", f"{shipped_minutes:.1f}", f"{(1200 - r['setup_cpu_s']) / per_step:,.0f}"]

    return _table([f"{env_id}, `cmz-sac`", "steps per CPU second (loop)", "CPU ms per step",
                   "pretraining and first 1,000 steps, CPU s", "CPU minutes for the shipped budget",
                   "steps in 20 CPU-minutes"], rows, cells)


def table(env_id: str, rows: list[dict[str, float]]) -> str:
    def cells(r: dict[str, float], per_step: float) -> list[str]:
        return [f"{r['n_envs']:.0f}", f"{1 / per_step:.0f}", f"{r['steps'] / r['loop_wall_s']:.0f}",
                f"{r['setup_cpu_s']:.0f}", f"{(1e6 * per_step + r['setup_cpu_s']) / 60:.1f}",
                f"{(3e6 * per_step + r['setup_cpu_s']) / 60:.1f}"]

    return _table([f"{env_id}: envs per process", "steps per CPU second (loop)", "wall steps/s (loop)",
                   "pretraining, CPU s", "projected CPU minutes for 1M steps", "for 3M steps"], rows, cells)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="Walker2d-v5")
    parser.add_argument("--method", choices=("cmz", "cmz-sac"), default="cmz")
    parser.add_argument("--steps", type=int, help="timed training steps per measurement (default: 40960, "
                        "20 PPO updates; 4000 for cmz-sac)")
    parser.add_argument("--n-envs", type=int, nargs="+", default=[1, 8], help="envs per process (cmz only)")
    parser.add_argument("-o", "--output", type=Path, help="markdown file for the table")
    args = parser.parse_args()
    if any(UPDATE_SIZE % n for n in args.n_envs):
        parser.error(f"every --n-envs must divide {UPDATE_SIZE}")
    torch.set_num_threads(1)
    demos = Demonstrations.load(ROOT / "experts" / args.env / "demos.npz").select([0])
    if args.method == "cmz-sac":
        steps = args.steps or 4000
        text = (
            f"Measured by `{command_line()}` on {time.strftime('%Y-%m-%d')} (1 torch thread, CPU time of this "
            f"process; CMZDRILSAC with hyperparams/cmzdril_sac.yml's settings, {steps} timed steps).\n\n"
            + sac_table(args.env, [measure_sac(args.env, steps, demos)]) + "\n"
        )
    else:
        steps = args.steps or 40960
        rows = []
        for n in args.n_envs:
            rows.append(measure(args.env, n, steps, demos))
            print(table(args.env, rows[-1:]).splitlines()[-1], flush=True)
        text = (
            f"Measured by `{command_line()}` on {time.strftime('%Y-%m-%d')} (1 torch thread, CPU time of this "
            f"process; CMZDRIL defaults, reward cmz, {steps} steps, n_steps = {UPDATE_SIZE} / envs).\n\n"
            + table(args.env, rows) + "\n"
        )
    print(text)
    if args.output is not None:
        atomic_write_text(args.output, text)


if __name__ == "__main__":
    main()
