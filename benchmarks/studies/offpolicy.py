"""CMZDRILSAC (the off-policy learner) on a grid task, at a budget of CPU time per run.

    python benchmarks/studies/offpolicy.py NAME --env Walker2d-v5 --trials 0 1 --cpu-minutes 25 \
        [--set net_arch=[64,64] --set absorbing=auto ...]

Each trial trains :class:`sb3_cmzdril.cmzdril_sac.CMZDRILSAC` on the grid's training episode of that trial
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
with the grid's rows. ``--set`` values (parsed as YAML) go to the constructor; ``net_arch`` goes
into ``policy_kwargs``.

An env outside the grid takes the demo pool and YAML entry (``env_kwargs``, ``n_demos``) its grid
runs used, as ``plan_run`` takes them::

    python benchmarks/studies/offpolicy.py LL-sac-64-clip98-auto --env LunarLander-v3 --trials 0 \
        --demos results/outside_env/LunarLander-v3/demos.npz --hyperparams benchmarks/studies/outside_env.yml \
        --set 'net_arch=[64,64]' --set cmz_clip_quantile=0.98 --set absorbing=auto

A finished trial is skipped. Every ``--eval-every`` steps a run keeps a checkpoint in its folder's
``checkpoint/`` (the model, its replay buffer, the longest-episodes choice so far; removed when the
run is done), and the same command resumes an interrupted run from it, as a grid run resumes: the
CPU budget counts every segment, evaluations after the checkpoint are moved to eval.discarded.csv,
and the new segment reseeds with trial + its first step, so a resumed run is not step for step the
run it would have been. A run interrupted before its first checkpoint starts again.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import shlex
import shutil
import sys
from pathlib import Path
from typing import Any, cast

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import CSVOutputFormat, Logger
from stable_baselines3.common.monitor import Monitor
from tune import parse_sets  # the sibling script's (its folder is on sys.path when this one runs)

from cmzdril_lab.report.records import relative
from sb3_cmzdril.cmzdril_sac import CMZDRILSAC
from sb3_cmzdril.errors import UserError
from sb3_cmzdril.experts import env_name
from sb3_cmzdril.io import atomic_path, atomic_write_text, deferred_signals, read_json, write_json
from sb3_cmzdril.metrics import ExpertEvalCallback, evaluate_against_expert
from sb3_cmzdril.selection import LongestEpisodesPolicy
from sb3_cmzdril.training.run_folder import (
    CONFIG_FILE,
    DISCARDED_CSV,
    DONE_FILE,
    EVAL_CSV,
    FINAL_EVAL_COLUMNS,
    FINAL_EVAL_CSV,
    MODEL_FILE,
    STATE_FILE,
    RunState,
    discard_rows_after,
)
from sb3_cmzdril.training.runs import LONGEST_CHECK_EPISODES, LONGEST_CHECK_SEED, final_eval_rows
from sb3_cmzdril.training.spec import plan_run, resolve_run

ROOT = Path(__file__).resolve().parents[2]
#: SB3's log_interval: a row of logs/progress_0.csv every this many episodes
LOG_EVERY_EPISODES = 10
#: the run's checkpoint (every ``--eval-every`` steps), removed when the run is done: the model, its
#: replay buffer and the longest-episodes choice so far
CHECKPOINT_DIR, REPLAY_FILE, SELECTION_FILE = "checkpoint", "replay_buffer.pkl", "selection.pt"


class CPUBudget(BaseCallback):
    """Stops training once the run (every segment of it, see :class:`RunState`) has spent ``seconds`` of CPU time."""

    def __init__(self, seconds: float, state: RunState) -> None:
        super().__init__()
        self.seconds, self.state = float(seconds), state

    def _on_step(self) -> bool:
        return self.state.cpu_time() < self.seconds


class Checkpoint(BaseCallback):
    """Every ``every`` steps, after that step's evaluation and check: the model, its replay buffer,
    the longest-episodes choice so far and state.json, in ``folder``."""

    def __init__(self, folder: Path, every: int, state: RunState, selector: LongestEpisodesPolicy | None) -> None:
        super().__init__()
        self.folder, self.every, self.state, self.selector = folder, every, state, selector
        self._last = 0

    def _on_training_start(self) -> None:
        self._last = self.model.num_timesteps  # a resumed run starts from its checkpoint: nothing new to keep

    def _on_rollout_start(self) -> None:
        steps = self.model.num_timesteps
        if steps // self.every <= self._last // self.every:
            return
        self._last = steps
        self.folder.mkdir(exist_ok=True)
        # The checkpoint's files belong together: Ctrl-C or SIGTERM waits until all are written.
        with deferred_signals():
            with atomic_path(self.folder / MODEL_FILE, suffix=".zip") as tmp:
                self.model.save(tmp)
            with atomic_path(self.folder / REPLAY_FILE, suffix=".pkl") as tmp:
                cast(CMZDRILSAC, self.model).save_replay_buffer(tmp)
            if self.selector is not None:
                self.selector.save(self.folder / SELECTION_FILE)
            self.state.write(steps)

    def _on_step(self) -> bool:
        return True


def _start_afresh(folder: Path) -> None:
    """Remove what an attempt without a checkpoint left: its rows must not precede the new ones."""
    for stale in (EVAL_CSV, DISCARDED_CSV, STATE_FILE):
        (folder / stale).unlink(missing_ok=True)
    for log in (folder / "logs").glob("progress_*.csv"):
        log.unlink()


def run_trial(name: str, env_id: str, trial: int, cpu_minutes: float, eval_every: int, kwargs: dict[str, Any],
              out_root: Path, command: str, select: str = "last",
              max_timesteps: int | None = None, demos: Path | None = None,
              hyperparams: Path | None = None) -> dict[str, Any] | None:
    """Train (or resume) and evaluate one trial; its done.json summary (None: it was finished already).

    ``demos`` and ``hyperparams`` are the grid's (``plan_run``'s) pool and YAML: from the YAML entry
    the run takes the env's ``env_kwargs`` and ``n_demos``, nothing else (the constructor's
    arguments are ``kwargs``)."""
    folder = out_root / name / env_name(env_id) / "cmz" / f"trial{trial}"
    if (folder / DONE_FILE).is_file():
        print(f"{folder}: finished already, skipped")
        return None
    # The grid's split of this trial: the same training episode and held-out episodes as its runs.
    run = resolve_run(plan_run(env_id, "cmz", trial, timesteps=1, output_dir=folder, demos=demos,
                               hyperparams=hyperparams), check=False)
    env_kwargs = dict(run.hp.env_kwargs or {})
    kwargs = dict(kwargs)
    net_arch = kwargs.pop("net_arch", None)
    if net_arch is not None:
        kwargs["policy_kwargs"] = {**kwargs.get("policy_kwargs", {}), "net_arch": net_arch}
    config = {
        "env_id": env_id, "env_name": env_name(env_id), "method": "cmz", "reward": kwargs.get("reward", "cmz"),
        "algorithm": "CMZDRILSAC", "seed": trial, "demos": relative(Path(run.spec.demos).resolve(), ROOT),
        **({"env_kwargs": env_kwargs} if env_kwargs else {}),
        "train_episodes": list(run.train_idx), "eval_episodes": list(run.eval_idx), "n_demos": len(run.train_idx),
        "cpu_minutes": cpu_minutes, "eval_every_steps": eval_every, "model_kwargs": kwargs, "select": select,
        **({} if max_timesteps is None else {"max_timesteps": max_timesteps}),
    }
    checkpoint = folder / CHECKPOINT_DIR
    resuming = (checkpoint / MODEL_FILE).is_file()
    if resuming:
        stored = {k: v for k, v in read_json(folder / CONFIG_FILE).items() if k != "command"}
        if stored != json.loads(json.dumps(config)):  # as JSON stores it: tuples become lists
            raise UserError(f"{folder} holds a checkpoint of a run with other settings (its {CONFIG_FILE}); "
                            "give this one another NAME, or delete the folder to start it again")
    else:
        folder.mkdir(parents=True, exist_ok=True)
        _start_afresh(folder)
        write_json(folder / CONFIG_FILE, {**config, "command": command})
    env = Monitor(gym.make(env_id, **env_kwargs))
    if resuming:
        model = CMZDRILSAC.load(checkpoint / MODEL_FILE, env=env, device="cpu")
        model.load_replay_buffer(checkpoint / REPLAY_FILE)
        # As a resumed grid run does: a new seed per segment, and the evaluations after the
        # checkpoint belong to weights that are gone.
        model.set_random_seed(trial + model.num_timesteps)
        discard_rows_after(folder / EVAL_CSV, model.num_timesteps)
    else:
        env.reset(seed=trial)
        model = CMZDRILSAC("MlpPolicy", env, demonstrations=run.pool.select(run.train_idx), seed=trial,
                           device="cpu", **kwargs)
    start = int(model.num_timesteps)
    state = RunState(folder, dataclasses.replace(run.spec, command=command), start)
    eval_cb = ExpertEvalCallback(env_id, run.pool.select(run.eval_idx), eval_every=eval_every,
                                 csv_path=folder / EVAL_CSV, env_kwargs=env_kwargs)
    # What the agent does in training (episode length, u on its own states, the losses), as a grid run
    # keeps it: one CSV per segment, named by the step it starts from.
    (folder / "logs").mkdir(exist_ok=True)
    model.set_logger(Logger(None, [CSVOutputFormat(str(folder / "logs" / f"progress_{start}.csv"))]))
    callbacks: list[BaseCallback] = [eval_cb]
    selector = None
    if select == "longest":  # the starts the package's cmz-sac runs check too: their choices pair trial by trial
        selector = LongestEpisodesPolicy(env_id, check_every=eval_every, n_episodes=LONGEST_CHECK_EPISODES,
                                         seed=LONGEST_CHECK_SEED + 100 * trial, env_kwargs=env_kwargs)
        if resuming and not selector.load(checkpoint / SELECTION_FILE):
            raise UserError(f"{checkpoint} has no {SELECTION_FILE}: it is not a --select longest run's checkpoint")
        callbacks.append(selector)
    callbacks += [Checkpoint(checkpoint, eval_every, state, selector), CPUBudget(cpu_minutes * 60, state)]
    total = 10**9 if max_timesteps is None else max_timesteps
    model.learn(total - start, callback=callbacks, log_interval=LOG_EVERY_EPISODES, reset_num_timesteps=False)
    eval_cb.close()
    model.logger.close()
    held_out = run.held_out

    def held_out_evaluation() -> Any:
        return evaluate_against_expert(model, env_id, run.pool.select(held_out), env_kwargs=env_kwargs,
                                       start_mismatch="ignore")

    evaluations = {}
    if selector is not None:
        selector.close()
        evaluations["last"] = held_out_evaluation()
        selector.apply(model)
    ev = evaluations["final"] = held_out_evaluation()
    rows = [line for policy, e in evaluations.items() for line in final_eval_rows(policy, held_out, e)]
    atomic_write_text(folder / FINAL_EVAL_CSV, "\n".join([",".join(FINAL_EVAL_COLUMNS), *rows]) + "\n")
    state.write(model.num_timesteps)
    summary = {
        "status": "done", "env_id": env_id, "method": "cmz", "algorithm": "CMZDRILSAC", "seed": trial,
        "num_timesteps": int(model.num_timesteps), "cpu_time_s": state.cpu_time(), "wall_time_s": state.wall_time(),
        "segments": [segment["from_timesteps"] for segment in state.data["segments"]],
        "pretrain": model.pretrain_info,
        "final_evaluation": {"episodes": held_out, **{policy: e.summary() for policy, e in evaluations.items()}},
    }
    if selector is not None:
        summary["selection"] = {"rule": select, "kept_timesteps": selector.best_timesteps,
                                "kept_mean_length": selector.best_length, "env_steps": selector.env_steps,
                                "checks": [list(check) for check in selector.history]}
    write_json(folder / DONE_FILE, summary)
    shutil.rmtree(checkpoint, ignore_errors=True)  # the replay buffer alone is hundreds of MB
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
    parser.add_argument("--max-timesteps", type=int, default=None,
                        help="also stop at this many steps, if the CPU budget lasts that long (0: evaluate the "
                             "clone, the actor after pretraining, with no SAC step)")
    parser.add_argument("--demos", type=Path, default=None,
                        help="the demo pool (default: the grid's, experts/<EnvName>/demos.npz)")
    parser.add_argument("--hyperparams", type=Path, default=None,
                        help="zoo-format YAML whose entry for --env gives env_kwargs and n_demos (default: the "
                             "grid's hyperparams/cmzdril.yml), e.g. benchmarks/studies/outside_env.yml")
    parser.add_argument("-o", "--output", default=str(ROOT / "results" / "offpolicy"))
    args = parser.parse_args(argv)
    if args.max_timesteps is not None and args.max_timesteps < 0:
        parser.error(f"--max-timesteps must be 0 or more, got {args.max_timesteps}")
    th.set_num_threads(1)  # two runs side by side on two cores, as the grid runs
    command = "python benchmarks/studies/offpolicy.py " + shlex.join(sys.argv[1:] if argv is None else argv)
    kwargs = parse_sets(args.set)
    try:
        for trial in args.trials:
            run_trial(args.name, args.env, trial, args.cpu_minutes, args.eval_every, kwargs, Path(args.output),
                      command, args.select, args.max_timesteps, args.demos, args.hyperparams)
    except UserError as e:
        print(f"offpolicy.py: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
