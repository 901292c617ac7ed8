"""BC, CMZ-DRIL, DRIL, no reward and the env's reward on one env outside the paper's grid, with an expert
nobody here wrote.

The env is gymnasium's LunarLanderContinuous (``LunarLander-v3`` with ``continuous=True``: 8
observations, 2 continuous engine actions); the expert is gymnasium's own heuristic controller
(``gymnasium.envs.box2d.lunar_lander.heuristic``, written by gymnasium's authors as the env's
demonstration policy), run deterministically. So neither the env nor the expert was chosen or tuned
by this project, and the claim "CMZ-DRIL improves on BC" is tested outside WaypointNav-v0,
HalfCheetah-v5 and Hopper-v5.

    python benchmarks/studies/outside_env.py    # 5 trials x (bc, cmz, zero, dril, env), 200k steps, 2 workers
    python benchmarks/studies/outside_env.py --trials 1 --timesteps 4096 --pool-episodes 10 -o /tmp/outside_env
                                                      # a smoke test (a few minutes)
    python benchmarks/studies/outside_env.py --report-only    # rewrite results.md/results.csv from the finished runs

It needs Box2D: ``pip install "gymnasium[box2d]"`` (on Python < 3.14 that is the ``box2d==2.3.10``
wheel and ``pygame-ce``, both with manylinux wheels; no swig).

How long: the smoke test above took 3.1 min of wall time with 1 worker and 4.5 min with 2, while
another benchmark's two trainings and test suites loaded the machine's 2 cores. One CMZ-DRIL or
no-reward run then stepped 108-436 env steps per wall second (SB3's time/fps, one torch thread), and
BC pretraining to convergence took 30-79 s. At that load the first three methods (10 PPO runs of 200k steps,
5 BC runs, 2 workers) needs about 40 min to 2.7 hours; on an idle machine a fraction of that (the raw
env stepped 4,000 steps per CPU second; HalfCheetah-v5 stepped 3,200 at the same time against 14,600
on an idle core, where PPO on it ran ~1,660 steps/s).
Each run's wall time is in the "Runs" table of results.md (from its done.json).

What it does, into OUTPUT (default results/outside_env), resumable at every step:

1. records the demo pool ``OUTPUT/LunarLander-v3/demos.npz`` with ``collect_demos`` (the expert is
   registered as the scripted expert ``lunar-heuristic``): ``--pool-episodes`` deterministic episodes,
   episode ``i`` reset with seed ``--pool-seed + i``; provenance in the NAME.json beside it. An
   existing pool is kept if it is the one asked for (same expert, episodes and seeds);
2. runs the package's trial grid (:func:`cmzdril_lab.run.grid.benchmark`) for ``bc``, ``cmz``,
   ``zero``, ``dril`` and ``env`` (the RL ceiling: PPO on the env's reward) x trials 0..T-1 with the
   hyperparameters of ``benchmarks/studies/outside_env.yml`` (CMZDRIL's constructor defaults, PPO's
   defaults): trial t trains on ``--n-demos`` pool episodes drawn with
   ``default_rng(t)``, every method of a trial from the same data, seeds and BC start. Finished runs
   are skipped, interrupted ones continue from their checkpoints. Each run ends with the final
   evaluation: every pool episode it did not train on, replayed from its reset seed (final_eval.csv);
3. writes ``OUTPUT/results.md`` and ``OUTPUT/results.csv`` with the report's own tables
   (:mod:`cmzdril_lab.report.final_eval`): per method, the mean over trials of the final
   evaluation (return, Fréchet distance, action MSE) with a 95% bootstrap confidence interval, also
   for the reward-free lowest-disagreement policy; trial by trial, each RL method against BC and
   against no reward; the share of episodes with return >= 200 (gymnasium's "solved"
   threshold for an episode); the paper's Table I window (the per-epoch evaluations); each run's
   numbers and wall time; and the expert's return on the same episodes and over the pool, for scale.
"""
from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from cmzdril_lab.records_store import materialize
from sb3_cmzdril.training.spec import METHODS  # the grid's methods, the env's reward included

ROOT = Path(__file__).resolve().parents[2]
ENV_ID = "LunarLander-v3"
EXPERT_NAME = "lunar-heuristic"
HYPERPARAMS = Path(__file__).resolve().with_name("outside_env.yml")
DEFAULT_OUTPUT = ROOT / "results" / "outside_env"
#: gymnasium's LunarLander documentation: "An episode is considered a solution if it scores at least 200 points."
SOLVED_RETURN = 200.0


# -- the expert --------------------------------------------------------------------------------------
class LunarLanderHeuristic:
    """gymnasium's LunarLander heuristic behind SB3's ``predict`` (one observation or a batch).

    The controller is ``gymnasium.envs.box2d.lunar_lander.heuristic(env, s)``: it reads the env only
    to know whether the action space is continuous, and returns engine throttles clipped to [-1, 1].
    """

    def __init__(self, env: gym.Env) -> None:
        from gymnasium.envs.box2d.lunar_lander import heuristic

        if not getattr(env.unwrapped, "continuous", False):
            raise ValueError("the LunarLander heuristic expert needs the continuous env (env_kwargs continuous=True)")
        self._heuristic = heuristic
        self._env = env.unwrapped
        self.action_space = env.action_space

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        obs = np.asarray(observation)
        batch = obs.reshape(-1, *self._env.observation_space.shape)
        actions = np.stack([self._heuristic(self._env, o) for o in batch]).astype(self.action_space.dtype)
        return (actions[0] if obs.ndim == 1 else actions), None


def register_expert() -> None:
    """Make the expert the scripted expert ``lunar-heuristic`` of :func:`~sb3_cmzdril.experts.collect_demos`."""
    from sb3_cmzdril.experts import register_scripted_expert

    register_scripted_expert(EXPERT_NAME, LunarLanderHeuristic)


def env_kwargs() -> dict[str, Any]:
    """The env's kwargs from benchmarks/studies/outside_env.yml: the pool and the runs use the same ones."""
    from sb3_cmzdril.training.runs import load_run_hyperparams

    hp, _ = load_run_hyperparams(HYPERPARAMS, ENV_ID)
    return dict(hp.env_kwargs or {})


# -- 1. the demo pool ---------------------------------------------------------------------------------
def record_pool(output: Path, n_episodes: int, seed: int) -> Path:
    """The pool ``OUTPUT/LunarLander-v3/demos.npz``: recorded, or kept if it is the one asked for."""
    from sb3_cmzdril.experts import collect_demos, load_demonstrations
    from sb3_cmzdril.training.runs import default_demos_path

    path = default_demos_path(ENV_ID, output)
    if not path.is_file():
        register_expert()
        collect_demos(EXPERT_NAME, ENV_ID, n_episodes, seed=seed, output=path, env_kwargs=env_kwargs())
        return path
    pool = load_demonstrations(path)
    recorded = _pool_record(path)
    wanted = np.arange(seed, seed + n_episodes)
    if (recorded.get("expert") != f"scripted:{EXPERT_NAME}" or recorded.get("env_kwargs") != env_kwargs()
            or pool.n_episodes != n_episodes or not np.array_equal(pool.seeds, wanted)):
        raise SystemExit(
            f"{path} is not the pool asked for ({recorded.get('expert')}, env_kwargs {recorded.get('env_kwargs')}, "
            f"{pool.n_episodes} episodes, seeds {pool.seeds.min()}..{pool.seeds.max()}; asked: scripted:{EXPERT_NAME}, "
            f"{env_kwargs()}, --pool-episodes {n_episodes}, --pool-seed {seed}): its runs were made from it, so it is "
            "not replaced; use another -o, or the options it was made with"
        )
    print(f"demo pool {path}: {pool.n_episodes} episodes of {recorded.get('expert')}, kept", flush=True)
    return path


def _pool_record(pool_path: Path) -> dict[str, Any]:
    """The provenance collect_demos recorded for the pool ({} if none)."""
    from sb3_cmzdril.experts import pool_provenance

    return pool_provenance(pool_path)


def _box2d_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    for name in ("box2d", "box2d-py"):  # gymnasium[box2d]: box2d on Python < 3.14, box2d-py from 3.14
        try:
            return version(name)
        except PackageNotFoundError:
            continue
    return "not installed"


# -- 3. the results -----------------------------------------------------------------------------------
def finished_runs(output: Path) -> list:
    """The finished runs (done.json) of :data:`METHODS` on the env below ``output``, as the report reads them."""
    from cmzdril_lab.report.records import load_runs
    from sb3_cmzdril.experts import env_name

    if not (output / env_name(ENV_ID)).is_dir():
        return []
    return [r for r in load_runs(output) if r.env == env_name(ENV_ID) and r.method in METHODS and r.status == "done"]


def solved_markdown(rows: Sequence) -> str:
    """Per method (final policies) and for the expert on the same episodes: the share of held-out
    episodes with return >= :data:`SOLVED_RETURN`, mean [CI] over trials."""
    from cmzdril_lab.report.final_eval import mean_ci
    from cmzdril_lab.report.formatting import fmt_ci, md_table

    def share(returns) -> float:
        return 100.0 * float(np.mean(np.asarray(returns) >= SOLVED_RETURN))

    body, expert = [], {}
    for row in rows:
        if row.policy != "final":
            continue
        shares = [share(r.final["final"]["return"]) for r in row.runs]
        body.append([row.label, str(row.n_trials), fmt_ci(*mean_ci(shares))])
        expert.update({r.trial: share(r.final["final"]["expert_return"]) for r in row.runs})
    if expert:
        body.append(["Expert (same episodes)", str(len(expert)), fmt_ci(*mean_ci(list(expert.values())))])
    return md_table(["Method", "Trials", f"Held-out episodes with return >= {SOLVED_RETURN:g} (%), mean [CI]"], body)


def runs_markdown(records: Sequence, output: Path) -> str:
    """One line per run: its steps, wall time and final evaluation (the numbers behind the tables)."""
    from cmzdril_lab.report.formatting import fmt, md_table

    body = []
    for r in records:
        means = {policy: fmt(float(np.mean(columns["return"]))) for policy, columns in r.final.items()}
        final = r.final["final"]
        body.append([r.relative(output), str(r.summary.get("num_timesteps", "n/a")),
                     fmt(r.summary.get("wall_time_s", float("nan")) / 60), str(final["episode"].size),
                     means["final"], means.get("lowest_u", "—"), fmt(float(np.mean(final["expert_return"])))])
    return md_table(["Run", "PPO steps", "Wall time (min)", "Held-out episodes", "Final return", "Lowest-u return",
                     "Expert return"], body)


def render_results(output: Path, pool_path: Path, command: str) -> tuple[str, str]:
    """(results.md, results.csv) from the finished runs below ``output`` and the demo pool."""
    from cmzdril_lab.report.final_eval import (
        final_csv,
        final_markdown,
        final_table,
        method_text,
        paired_markdown,
    )
    from cmzdril_lab.report.formatting import fmt, fmt_mean_std, md_table
    from cmzdril_lab.report.records import label, relative
    from cmzdril_lab.report.tables import table_one
    from sb3_cmzdril.experts import load_demonstrations

    records = finished_runs(output)
    rows = final_table(records)
    pool = load_demonstrations(pool_path)
    pool_returns = pool.episode_returns
    recorded = _pool_record(pool_path)
    first = records[0].config if records else {}
    steps = sorted({str(r.summary["num_timesteps"]) for r in records if r.method != "bc"})
    parts = [
        "# BC, CMZ-DRIL, DRIL, no reward and the env's reward outside the paper's grid: LunarLanderContinuous",
        "",
        f"Written by `{command}` at {time.strftime('%Y-%m-%d %H:%M')} from the finished runs below this folder "
        "(benchmarks/studies/outside_env.py; not edited by hand).",
        "",
        f"- Env: `{ENV_ID}` with `{env_kwargs()}` (gymnasium {gym.__version__}, Box2D {_box2d_version()}): "
        f"{pool.observations.shape[1]} "
        f"observations, {pool.actions.shape[1]} continuous actions.",
        "- Expert: gymnasium's own heuristic controller (`gymnasium.envs.box2d.lunar_lander.heuristic`, written by "
        f"gymnasium's authors), deterministic; registered here as the scripted expert `{EXPERT_NAME}`.",
        f"- Demo pool `{relative(pool_path, output)}`: {pool.n_episodes} episodes, reset seeds "
        f"{pool.seeds.min()}..{pool.seeds.max()}, {len(pool)} steps; expert return "
        f"{fmt(float(np.mean(pool_returns)))} ± {fmt(float(np.std(pool_returns)))} "
        f"(min {fmt(float(np.min(pool_returns)))}, max {fmt(float(np.max(pool_returns)))}), mean length "
        f"{fmt(float(np.mean(pool.episode_lengths)))}; recorded by `{recorded.get('command', 'n/a')}`.",
        f"- Each trial t trains on {first.get('n_demos', 'n/a')} pool episodes drawn with `default_rng(t)`; "
        "all methods of a trial share them, the seeds and the BC start. Hyperparameters: "
        "`benchmarks/studies/outside_env.yml` (CMZDRIL's constructor defaults and PPO's otherwise). BC is the "
        "early-stopped NLL-pretrained policy; CMZ-DRIL, DRIL, no reward (reward 0) and the env's reward "
        "(PPO + BC epochs, each with its reward) fine-tune it for "
        f"{', '.join(steps) or 'n/a'} PPO steps.",
        "",
        "## Final evaluation (every held-out pool episode)",
        "",
        method_text(),
        "",
        final_markdown(rows) if rows else "No finished runs yet.",
        "",
        "### Trial by trial",
        "",
        paired_markdown(rows) if rows else "No finished runs yet.",
        "",
        "### Solved episodes",
        "",
        f"gymnasium's LunarLander counts an episode with return >= {SOLVED_RETURN:g} as solved.",
        "",
        solved_markdown(rows) if rows else "No finished runs yet.",
        "",
        "## During training (the paper's Table I window)",
        "",
        f"Each run's per-epoch evaluations ({first.get('n_eval_episodes', 'n/a')} held-out episodes every "
        f"{first.get('eval_every', 'n/a')} PPO updates; BC: one) averaged over its last 100 epochs; mean (std) over "
        "trials.",
        "",
        md_table(["Method", "Trials", "Return"],
                 ([label(t.method), str(t.n_trials), fmt_mean_std(t.mean("return"), t.std("return"))]
                  for t in table_one(records))) if records else "No finished runs yet.",
        "",
        "## Runs",
        "",
        runs_markdown(records, output) if records else "No finished runs yet.",
    ]
    return "\n".join(parts) + "\n", final_csv(rows, output)


def write_results(output: Path, pool_path: Path, command: str) -> Path:
    """results.md and results.csv in ``output``; returns results.md's path."""
    from sb3_cmzdril.io import atomic_write_text

    markdown, table = render_results(output, pool_path, command)
    atomic_write_text(output / "results.csv", table)
    atomic_write_text(output / "results.md", markdown)
    return output / "results.md"


# -- the command ----------------------------------------------------------------------------------------
def main(argv: Sequence[str] | None = None) -> int:
    from cmzdril_lab.run.grid import parse_list
    from sb3_cmzdril.experts import command_line

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--trials", type=int, default=5, help="trials 0..T-1 (default 5)")
    parser.add_argument("--timesteps", type=int, default=None,
                        help="PPO steps of the RL methods (default: n_timesteps of benchmarks/studies/outside_env.yml)")
    parser.add_argument("--n-demos", type=int, default=None,
                        help="training episodes per trial (default: n_demos of benchmarks/studies/outside_env.yml)")
    parser.add_argument("--workers", type=int, default=2, help="runs at a time, one CPU each (default 2)")
    parser.add_argument("--methods", default=",".join(METHODS), help=f"comma-separated, from {', '.join(METHODS)}")
    parser.add_argument("--pool-episodes", type=int, default=50,
                        help="expert episodes in the demo pool: training episodes plus the held-out rest (default 50)")
    parser.add_argument("--pool-seed", type=int, default=1000,
                        help="reset seed of the pool's first episode (default 1000: apart from the training envs' "
                             "seeds, the trial indices)")
    parser.add_argument("--eval-episodes", type=int, default=5,
                        help="held-out episodes of each per-epoch evaluation (default 5, as the paper)")
    parser.add_argument("--eval-every", type=int, default=5,
                        help="PPO updates between per-epoch evaluations (default 5)")
    parser.add_argument("-o", "--output", type=Path, default=DEFAULT_OUTPUT,
                        help="output folder (default results/outside_env)")
    parser.add_argument("--report-only", action="store_true", help="only rewrite results.md/results.csv")
    args = parser.parse_args(argv)
    unknown = sorted(set(parse_list(args.methods)) - set(METHODS))
    if unknown:
        parser.error(f"--methods: {unknown} are not among {', '.join(METHODS)}")
    command = command_line(["python", "benchmarks/studies/outside_env.py", *sys.argv[1:]])
    output = materialize(args.output).resolve()  # results/outside_env is kept as outside_env.tar.xz
    output.mkdir(parents=True, exist_ok=True)

    pool_path = record_pool(output, args.pool_episodes, args.pool_seed)
    status = 0
    if not args.report_only:
        from cmzdril_lab.run.grid import benchmark, summarize_outcomes

        outcomes = benchmark(
            ENV_ID, args.methods, args.trials, output, workers=args.workers, command=command,
            timesteps=args.timesteps, n_demos=args.n_demos, n_eval_episodes=args.eval_episodes,
            eval_every=args.eval_every, demos_dir=output, hyperparams=HYPERPARAMS,
        )
        print(summarize_outcomes(outcomes), flush=True)
        status = 1 if any(o.status == "failed" for o in outcomes) else 0
    path = write_results(output, pool_path, command)
    print(path.read_text(encoding="utf-8"), flush=True)
    print(f"wrote {path} and {output / 'results.csv'}", flush=True)
    return status


if __name__ == "__main__":
    sys.exit(main())
