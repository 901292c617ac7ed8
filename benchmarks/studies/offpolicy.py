"""CMZDRILSAC (the off-policy learner) on a grid task, at a budget of CPU time per run.

    python benchmarks/studies/offpolicy.py NAME --env Walker2d-v5 --trials 0 1 --cpu-minutes 25 \
        [--set net_arch=[64,64] --set absorbing=auto ...]

Each trial trains :class:`sb3_cmzdril.sac.CMZDRILSAC` on the grid's training episode of that trial
(the split of ``sb3-cmzdril benchmark``: same pool, same held-out episodes) until the process has
spent ``--cpu-minutes`` of CPU time (pretraining included), then replays every held-out pool
episode with the final policy. Comparing methods at equal CPU time, not equal steps, is the point:
SAC takes about ten times PPO's CPU per step.

``--select longest`` keeps, reward-free, the policy whose deterministic episodes from 5 fixed starts
(seeds 100000 + 100 * trial + i, none of them a pool episode's) lasted longest at the start, every
``--eval-every`` steps and at the end, the latest on a tie
(:class:`sb3_cmzdril.selection.LongestEpisodesPolicy`). That kept policy is the run's "final"
policy in final_eval.csv; the last weights are evaluated on the same held-out episodes as "last".

Runs land in ``results/offpolicy/NAME/<Env>/cmz/trial<k>/`` in the grid's layout (config.json,
eval.csv every ``--eval-every`` steps on the trial's 5 evaluation episodes, SB3's training log in
logs/progress_0.csv, final_eval.csv,
done.json with ``cpu_time_s``), so ``benchmarks/studies/new_tasks.py`` pairs them trial by trial
with the grid's rows. A finished trial is skipped; an interrupted one starts again (runs are short,
and SAC's replay buffer is not checkpointed). ``--set`` values (parsed as YAML) go to the
constructor; ``net_arch`` goes into ``policy_kwargs``.
"""
from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import CSVOutputFormat, Logger
from stable_baselines3.common.monitor import Monitor
from tune import parse_sets  # the sibling script's (its folder is on sys.path when this one runs)

from sb3_cmzdril.experiments.run.run_folder import CONFIG_FILE, DONE_FILE, FINAL_EVAL_COLUMNS, FINAL_EVAL_CSV
from sb3_cmzdril.experiments.run.runs import final_eval_rows
from sb3_cmzdril.experiments.run.spec import plan_run, resolve_run
from sb3_cmzdril.experts import env_name
from sb3_cmzdril.io import atomic_write_text, write_json
from sb3_cmzdril.metrics import ExpertEvalCallback, evaluate_against_expert
from sb3_cmzdril.sac import CMZDRILSAC
from sb3_cmzdril.selection import LongestEpisodesPolicy

ROOT = Path(__file__).resolve().parents[2]
#: SB3's log_interval: a row of logs/progress_0.csv every this many episodes
LOG_EVERY_EPISODES = 10
#: episodes of each check of ``--select longest``, and the first reset seed of trial 0's checks
SELECT_EPISODES, SELECT_SEED = 5, 100_000


class CPUBudget(BaseCallback):
    """Stops training once the process has spent ``seconds`` of CPU time since ``start``."""

    def __init__(self, seconds: float, start: float) -> None:
        super().__init__()
        self.seconds, self.start = float(seconds), float(start)

    def _on_step(self) -> bool:
        return time.process_time() - self.start < self.seconds


def run_trial(name: str, env_id: str, trial: int, cpu_minutes: float, eval_every: int, kwargs: dict[str, Any],
              out_root: Path, command: str, select: str = "last") -> dict[str, Any] | None:
    """Train and evaluate one trial; its done.json summary (None: it was finished already)."""
    folder = out_root / name / env_name(env_id) / "cmz" / f"trial{trial}"
    if (folder / DONE_FILE).is_file():
        print(f"{folder}: finished already, skipped")
        return None
    # The grid's split of this trial: the same training episode and held-out episodes as its runs.
    run = resolve_run(plan_run(env_id, "cmz", trial, timesteps=1, output_dir=folder), check=False)
    folder.mkdir(parents=True, exist_ok=True)
    # An interrupted attempt starts again from scratch: its evaluation rows must not precede the new ones.
    (folder / "eval.csv").unlink(missing_ok=True)
    kwargs = dict(kwargs)
    net_arch = kwargs.pop("net_arch", None)
    if net_arch is not None:
        kwargs["policy_kwargs"] = {**kwargs.get("policy_kwargs", {}), "net_arch": net_arch}
    write_json(folder / CONFIG_FILE, {
        "env_id": env_id, "env_name": env_name(env_id), "method": "cmz", "reward": kwargs.get("reward", "cmz"),
        "algorithm": "CMZDRILSAC", "seed": trial, "demos": str(Path(run.spec.demos).relative_to(ROOT)),
        "train_episodes": list(run.train_idx), "eval_episodes": list(run.eval_idx), "n_demos": len(run.train_idx),
        "cpu_minutes": cpu_minutes, "eval_every_steps": eval_every, "model_kwargs": kwargs, "select": select,
        "command": command,
    })
    start_cpu, start_wall = time.process_time(), time.perf_counter()
    env = Monitor(gym.make(env_id))
    env.reset(seed=trial)
    model = CMZDRILSAC("MlpPolicy", env, demonstrations=run.pool.select(run.train_idx), seed=trial, device="cpu",
                       **kwargs)
    eval_cb = ExpertEvalCallback(env_id, run.pool.select(run.eval_idx), eval_every=eval_every,
                                 csv_path=folder / "eval.csv")
    # What the agent does in training (episode length, u on its own states, the losses), as a grid run keeps it.
    (folder / "logs").mkdir(exist_ok=True)
    model.set_logger(Logger(None, [CSVOutputFormat(str(folder / "logs" / "progress_0.csv"))]))  # the grid's name
    callbacks: list[BaseCallback] = [eval_cb]
    selector = None
    if select == "longest":
        selector = LongestEpisodesPolicy(env_id, check_every=eval_every, n_episodes=SELECT_EPISODES,
                                         seed=SELECT_SEED + 100 * trial)
        callbacks.append(selector)
    model.learn(10**9, callback=[*callbacks, CPUBudget(cpu_minutes * 60, start_cpu)], log_interval=LOG_EVERY_EPISODES)
    eval_cb.close()
    model.logger.close()
    held_out = run.held_out

    def held_out_evaluation() -> Any:
        return evaluate_against_expert(model, env_id, run.pool.select(held_out), start_mismatch="ignore")

    evaluations = {}
    if selector is not None:
        selector.close()
        evaluations["last"] = held_out_evaluation()
        selector.apply(model)
    ev = evaluations["final"] = held_out_evaluation()
    rows = [line for policy, e in evaluations.items() for line in final_eval_rows(policy, held_out, e)]
    atomic_write_text(folder / FINAL_EVAL_CSV, "\n".join([",".join(FINAL_EVAL_COLUMNS), *rows]) + "\n")
    summary = {
        "status": "done", "env_id": env_id, "method": "cmz", "algorithm": "CMZDRILSAC", "seed": trial,
        "num_timesteps": int(model.num_timesteps), "cpu_time_s": time.process_time() - start_cpu,
        "wall_time_s": time.perf_counter() - start_wall, "pretrain": model.pretrain_info,
        "final_evaluation": {"episodes": held_out, **{policy: e.summary() for policy, e in evaluations.items()}},
    }
    if selector is not None:
        summary["selection"] = {"rule": select, "kept_timesteps": selector.best_timesteps,
                                "kept_mean_length": selector.best_length, "env_steps": selector.env_steps,
                                "checks": [list(check) for check in selector.history]}
    write_json(folder / DONE_FILE, summary)
    expert = float(np.mean(ev.expert_returns))
    print(f"{folder}: {model.num_timesteps} steps in {summary['cpu_time_s'] / 60:.1f} CPU-min; final return "
          f"{ev.summary()['return_mean']:.0f} ({100 * ev.summary()['return_mean'] / expert:.1f}% of the expert)")
    return summary


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("name", help="variant name: runs go to results/offpolicy/NAME")
    parser.add_argument("--env", default="Walker2d-v5")
    parser.add_argument("--trials", type=int, nargs="+", default=[0])
    parser.add_argument("--cpu-minutes", type=float, default=25.0, help="CPU time per run, pretraining included")
    parser.add_argument("--eval-every", type=int, default=10240, help="steps between evaluations in eval.csv")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="CMZDRILSAC constructor argument (repeatable); net_arch goes to policy_kwargs")
    parser.add_argument("--select", choices=("last", "longest"), default="last",
                        help="the run's final policy: the last weights, or the reward-free longest-episodes choice")
    parser.add_argument("-o", "--output", default=str(ROOT / "results" / "offpolicy"))
    args = parser.parse_args(argv)
    th.set_num_threads(1)  # two runs side by side on two cores, as the grid runs
    command = "python benchmarks/studies/offpolicy.py " + shlex.join(sys.argv[1:] if argv is None else argv)
    kwargs = parse_sets(args.set)
    for trial in args.trials:
        run_trial(args.name, args.env, trial, args.cpu_minutes, args.eval_every, kwargs, Path(args.output), command,
                  args.select)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
