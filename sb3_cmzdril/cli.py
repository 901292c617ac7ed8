"""Command line: ``sb3-cmzdril <command> --help``.

Each command's parser is built by an ``_add_<command>`` function and runs a ``_run_<command>``
function that only translates arguments into calls of the library; the work lives in the modules.
"""
from __future__ import annotations

import argparse
import sys
from typing import List, Optional


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sb3-cmzdril",
        description="CMZ-DRIL imitation learning for stable-baselines3: experts, demos, training, benchmarks.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add in (_COMMANDS):
        add(sub)
    return parser


# -- train-expert / collect-demos (issue 3) ------------------------------------------------------
def _add_train_expert(sub) -> None:
    p = sub.add_parser(
        "train-expert",
        help="train an SB3 expert (SAC by default) with rl-zoo hyperparameters; resumable",
        description=(
            "Train an expert with rl-zoo-style hyperparameters (hyperparams/<algo>.yml of the repository "
            "unless --hyperparams is given). The best model by periodic deterministic evaluation is "
            "OUTPUT/model.zip; OUTPUT/metadata.json records how it was made. Checkpoints go to "
            "OUTPUT/checkpoints/; running the same command again resumes from the last one and trains "
            "until --timesteps in total. An existing expert is never replaced without --force."
        ),
    )
    p.add_argument("--env", required=True, help="environment id (anything gym.make accepts)")
    p.add_argument("--algo", default="sac", help="sac (default), td3, ddpg, ppo, a2c or dqn")
    p.add_argument("--timesteps", type=int, default=None, help="total training steps (default: n_timesteps from the YAML)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--hyperparams", default=None, help="zoo-format YAML (default: the repository's hyperparams/<algo>.yml)")
    p.add_argument("-o", "--output", default=None, help="output folder (default: experts/<EnvId>)")
    p.add_argument("--eval-freq", type=int, default=10_000, help="evaluate every N steps (default 10000)")
    p.add_argument("--eval-episodes", type=int, default=5, help="episodes per periodic evaluation (default 5)")
    p.add_argument("--final-eval-episodes", type=int, default=10, help="episodes of the final evaluation (default 10)")
    p.add_argument("--checkpoint-freq", type=int, default=20_000, help="checkpoint every N steps (default 20000)")
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar / progress lines")
    p.add_argument("-v", "--verbose", type=int, default=0, help="SB3 verbosity (0, 1 or 2)")
    p.add_argument("--force", action="store_true",
                   help="train even where OUTPUT holds an expert without checkpoints (replacing it), or a finished "
                        "one with fewer steps than --timesteps (continuing it)")
    p.set_defaults(func=_run_train_expert)


def _run_train_expert(args) -> int:
    from sb3_cmzdril.experts import command_line, train_expert

    path = train_expert(
        args.env,
        algo=args.algo,
        timesteps=args.timesteps,
        seed=args.seed,
        hyperparams_path=args.hyperparams,
        output_dir=args.output,
        eval_freq=args.eval_freq,
        n_eval_episodes=args.eval_episodes,
        checkpoint_freq=args.checkpoint_freq,
        progress_bar=not args.no_progress,
        final_eval_episodes=args.final_eval_episodes,
        n_threads=args.threads,
        command=command_line(),
        verbose=args.verbose,
        force=args.force,
    )
    print(path)
    return 0


def _add_collect_demos(sub) -> None:
    p = sub.add_parser(
        "collect-demos",
        help="record deterministic expert episodes into a demonstrations npz",
        description=(
            "Run an expert deterministically for K episodes (episode i reset with seed S+i) and save "
            "observations, actions, rewards and seeds. --expert is an SB3 model zip (any algorithm), a "
            "folder holding model.zip, or the name of a registered scripted expert."
        ),
    )
    p.add_argument("--expert", required=True, help="model zip, folder with model.zip, or scripted expert name")
    p.add_argument("--env", required=True, help="environment id")
    p.add_argument("--episodes", type=int, default=1, help="number of episodes (default 1)")
    p.add_argument("--seed", type=int, default=0, help="reset seed of the first episode (default 0)")
    p.add_argument("-o", "--output", required=True, help="output .npz file")
    p.add_argument("--force", action="store_true",
                   help="replace an existing OUTPUT, and the demos record of a metadata.json beside it that is not the expert's own")
    p.set_defaults(func=_run_collect_demos)


def _run_collect_demos(args) -> int:
    from sb3_cmzdril.experts import collect_demos

    collect_demos(args.expert, args.env, n_episodes=args.episodes, seed=args.seed, output=args.output, force=args.force)
    return 0


_COMMANDS: list = [_add_train_expert, _add_collect_demos]


# -- train / evaluate / benchmark / report (issue 5) ---------------------------------------------
_METHODS_HELP = "bc (pretrained policy only), zero, env, dril or cmz"


def _add_run_options(p, what: str) -> None:
    """Options shared by train and benchmark: the data split, the evaluation and the checkpoints."""
    from sb3_cmzdril.experiments.runs import DEFAULT_CHECKPOINT_EVERY, DEFAULT_EVAL_EPISODES

    p.add_argument("--n-demos", type=int, default=None,
                   help="training episodes per trial (default: n_demos of the YAML entry: 1 for MuJoCo, 5 for WaypointNav)")
    p.add_argument("--eval-episodes", type=int, default=DEFAULT_EVAL_EPISODES,
                   help=f"held-out expert episodes per evaluation (default {DEFAULT_EVAL_EPISODES})")
    p.add_argument("--timesteps", type=int, default=None, help="total PPO steps per run (default: n_timesteps of the YAML)")
    p.add_argument("--eval-every", type=int, default=1, help="evaluate every k PPO updates (default 1: every epoch)")
    p.add_argument("--checkpoint-every", type=int, default=DEFAULT_CHECKPOINT_EVERY,
                   help=f"checkpoint model.zip every k PPO updates (default {DEFAULT_CHECKPOINT_EVERY})")
    p.add_argument("--hyperparams", default=None, help="zoo-format YAML (default: the repository's hyperparams/cmzdril.yml)")
    p.add_argument("--no-progress", action="store_true", help=f"no {what}")


def _add_train(sub) -> None:
    p = sub.add_parser(
        "train",
        help="one run: an env, a method, a trial seed; writes eval.csv, config.json, model.zip, done.json; resumable",
        description=(
            "Train one imitator. The demo pool's episodes are split with --seed S (numpy default_rng(S) "
            "permutation: first --n-demos train, the next --eval-episodes are held out for evaluation); "
            "S also seeds the networks and the env. Writes OUTPUT/config.json (how to reproduce it), "
            "OUTPUT/eval.csv (return, Fréchet distance and action MSE against the held-out expert "
            "episodes, per epoch from epoch 0 = the BC-pretrained policy), OUTPUT/model.zip (checkpoint "
            "every --checkpoint-every updates) and OUTPUT/done.json at the end. Running the same command "
            "again skips a finished run and continues an interrupted one from its checkpoint."
        ),
    )
    p.add_argument("--env", required=True, help="environment id (anything gym.make accepts)")
    p.add_argument("--reward", required=True, metavar="METHOD", help=_METHODS_HELP)
    p.add_argument("--demos", default=None, help="demo pool npz (default: experts/<EnvName>/demos.npz)")
    p.add_argument("--seed", type=int, default=0, help="trial seed: data split, networks and env (default 0)")
    _add_run_options(p, "progress bar")
    p.add_argument("-o", "--output", default=None, help="run folder (default: runs/<EnvName>/<method>/trial<seed>)")
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    p.add_argument("-v", "--verbose", type=int, default=0, help="SB3 verbosity (0, 1 or 2)")
    p.set_defaults(func=_run_train)


def _run_train(args) -> int:
    import torch

    from sb3_cmzdril.experiments.runs import plan_run, run_experiment
    from sb3_cmzdril.experts import check_threads, command_line

    torch.set_num_threads(check_threads(args.threads))
    spec = plan_run(
        args.env, args.reward, args.seed, demos=args.demos, n_demos=args.n_demos, n_eval_episodes=args.eval_episodes,
        timesteps=args.timesteps, output_dir=args.output, hyperparams=args.hyperparams, eval_every=args.eval_every,
        checkpoint_every=args.checkpoint_every, command=command_line(),
    )
    result = run_experiment(spec, progress_bar=not args.no_progress, verbose=args.verbose)
    if result["status"] == "skipped":
        print(f"{spec.output_dir} is already finished (done.json, {result.get('num_timesteps')} steps); nothing to do")
    window = result.get("final_window")
    if window:
        print(
            f"{result['status']}: {spec.label} -> {spec.output_dir}; epochs {window['first_epoch']}-{window['last_epoch']}: "
            f"return {window['return']:.2f}, Fréchet {window['frechet']:.4g}, action MSE {window['action_mse']:.4g}"
        )
    else:
        print(f"{result['status']} at {result.get('num_timesteps')} steps: {spec.output_dir} (run again to continue)")
    return 0 if result["status"] in ("done", "skipped") else 1


def _add_evaluate(sub) -> None:
    p = sub.add_parser(
        "evaluate",
        help="replay expert episodes' starts with a model: return, Fréchet distance and action MSE per episode",
        description=(
            "Evaluate a model zip (a CMZDRIL run's model.zip, or any SB3 model such as an expert) against "
            "expert episodes: each episode's reset seed is replayed with the model's deterministic actions "
            "and compared with the expert's path (discrete Fréchet distance) and actions (MSE). "
            "The demo pool, env_kwargs and VecNormalize statistics are taken from the model's run folder "
            "(config.json, vecnormalize.pkl) when it has them."
        ),
    )
    p.add_argument("--model", required=True, help="model zip")
    p.add_argument("--env", required=True, help="environment id")
    p.add_argument("--demos", default=None,
                   help="demonstrations npz (default: the demo pool in config.json beside the model, else experts/<EnvName>/demos.npz)")
    p.add_argument("--episodes", default=None,
                   help="comma-separated episode indices of the demos file (default: for a run's model, the run's "
                        "held-out eval_episodes of its config.json; otherwise all)")
    p.add_argument("--env-kwargs", default=None,
                   help='e.g. "dict(max_steps=200)" (default: env_kwargs of config.json beside the model, if any)')
    p.add_argument("--vecnormalize", default=None,
                   help="VecNormalize statistics (default: vecnormalize.pkl beside the model, if any; required for a run "
                        "that normalised)")
    p.set_defaults(func=_run_evaluate)


def _run_evaluate(args) -> int:
    from pathlib import Path

    from sb3_cmzdril.experiments.runs import CONFIG_FILE, default_demos_path, load_evaluation_model
    from sb3_cmzdril.experts import check_env_id, load_demonstrations
    from sb3_cmzdril.hyperparams import safe_eval
    from sb3_cmzdril.io import read_json
    from sb3_cmzdril.metrics import evaluate_against_expert

    check_env_id(args.env)
    model_path = Path(args.model)
    if not model_path.is_file():
        raise FileNotFoundError(f"model file not found: {model_path}")
    # A run folder's config.json knows how the model was trained and evaluated.
    config_path = model_path.parent / CONFIG_FILE
    run_config = read_json(config_path) if config_path.is_file() else {}
    if args.env_kwargs is not None:
        env_kwargs = safe_eval(args.env_kwargs)
        if not isinstance(env_kwargs, dict):
            raise ValueError(f"--env-kwargs must be a dict, got {args.env_kwargs!r}")
    else:
        env_kwargs = run_config.get("env_kwargs") or {}
    demos_path = Path(args.demos or run_config.get("demos") or default_demos_path(args.env))
    demos = load_demonstrations(demos_path)
    indices, which = _evaluation_episodes(args.episodes, demos.n_episodes, demos_path, run_config)
    vecnormalize, vecnormalize_note = _evaluation_statistics(args.vecnormalize, model_path, run_config)
    selected = demos.select(indices)
    model, transform = load_evaluation_model(model_path, args.env, env_kwargs, vecnormalize)
    print(f"episodes {','.join(map(str, indices))} of {demos_path}: {which}")
    if vecnormalize_note:
        print(vecnormalize_note)
    result = evaluate_against_expert(model, args.env, selected, obs_transform=transform, env_kwargs=env_kwargs or None)

    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"{model_path} on {args.env}: {selected.n_episodes} episodes of {demos_path}")
    for column in ("episode", "seed", "return", "expert return", "Fréchet", "action MSE", "length"):
        table.add_column(column, justify="right")
    for row, index in enumerate(indices):
        table.add_row(
            str(index), str(int(result.seeds[row])), f"{result.returns[row]:.2f}", f"{result.expert_returns[row]:.2f}",
            f"{result.frechet[row]:.4g}", f"{result.episode_action_mse[row]:.4g}", str(int(result.lengths[row])),
        )
    table.add_section()
    table.add_row(
        "mean", "", f"{result.mean_return:.2f} ± {result.std_return:.2f}", f"{float(result.expert_returns.mean()):.2f}",
        f"{result.mean_frechet:.4g}", f"{result.action_mse:.4g}", f"{result.mean_length:.1f}",
    )
    Console().print(table)
    return 0


def _evaluation_episodes(text: Optional[str], n_pool: int, demos_path, run_config: dict):
    """``(episode indices, how they were chosen)`` for ``evaluate``.

    Without ``--episodes``, a run's model is evaluated on the run's held-out episodes only: its
    training episodes would flatter it. They are indices into the run's pool, so they are used only
    on that very file (same path and sha256).
    """
    from pathlib import Path

    from sb3_cmzdril.experiments.runs import _sha256

    if text:
        try:
            indices = [int(i) for i in text.split(",") if i.strip()]
        except ValueError:
            raise ValueError(f"--episodes must be comma-separated integers, got {text!r}") from None
        bad = [i for i in indices if not 0 <= i < n_pool]
        if bad or not indices:
            raise ValueError(f"--episodes {text}: {demos_path} has {n_pool} episodes, numbered 0 to {n_pool - 1}")
        return indices, "as asked (--episodes)"
    held_out = run_config.get("eval_episodes")
    if held_out and run_config.get("demos") and Path(run_config["demos"]).resolve() == Path(demos_path).resolve():
        if run_config.get("demos_sha256") not in (None, _sha256(demos_path)):
            raise ValueError(
                f"{demos_path} changed since the run was trained (sha256 differs from its config.json): its held-out "
                "episodes cannot be told apart; pass --episodes"
            )
        return [int(i) for i in held_out], "the run's held-out episodes (eval_episodes of its config.json)"
    note = " (not the run's demo pool: no held-out split applies)" if held_out else ""
    return list(range(n_pool)), f"all {n_pool} episodes{note}"


def _evaluation_statistics(path: Optional[str], model_path, run_config: dict):
    """``(VecNormalize statistics file or None, a line saying which)`` for ``evaluate``.

    A policy trained on normalised observations and fed raw ones acts nonsensically, and its
    numbers would still print: a missing --vecnormalize file is an error, statistics beside the
    model are used (and said so), and a run whose config.json says it normalised needs them.
    """
    from pathlib import Path

    from sb3_cmzdril.experiments.runs import VECNORMALIZE_FILE

    if path is not None:
        if not Path(path).is_file():
            raise FileNotFoundError(f"VecNormalize statistics not found: {path}")
        return Path(path), f"observations normalised with {path} (--vecnormalize)"
    beside = Path(model_path).parent / VECNORMALIZE_FILE
    if beside.is_file():
        return beside, f"observations normalised with {beside}, found beside the model"
    if _normalises_observations((run_config.get("hyperparams_values") or {}).get("normalize")):
        raise FileNotFoundError(
            f"{model_path} was trained on VecNormalize'd observations (normalize in its config.json) but {beside} "
            "is missing; pass the statistics with --vecnormalize"
        )
    return None, None


def _normalises_observations(normalize) -> bool:
    """Whether a zoo ``normalize`` entry (True, a dict, or its string form) normalises observations."""
    from sb3_cmzdril.hyperparams import safe_eval

    if isinstance(normalize, str):
        normalize = safe_eval(normalize)
    if isinstance(normalize, dict):
        return bool(normalize.get("norm_obs", True))
    return bool(normalize)


def _add_benchmark(sub) -> None:
    p = sub.add_parser(
        "benchmark",
        help="the paper's trial grid (envs x methods x trials) on local processes or Ray; resumable",
        description=(
            "Run every method on every env for --trials trials. Trial t splits the env's demo pool "
            "(DEMOS_DIR/<EnvName>/demos.npz) with numpy default_rng(t) into --n-demos training and "
            "--eval-episodes evaluation episodes and uses t as network/env seed: all methods of a trial "
            "share data and seeds. Runs go to OUTPUT/<EnvName>/<method>/trial<t>/ (see `train`), --workers "
            "at a time, one torch thread each. Running the command again skips finished runs and continues "
            "interrupted ones from their checkpoints; a failed run leaves error.txt and the others go on."
        ),
    )
    p.add_argument("--env", required=True, help="environment id(s), comma-separated")
    from sb3_cmzdril.experiments.runs import METHODS

    p.add_argument("--methods", default=",".join(METHODS), help=f"comma-separated, from: {_METHODS_HELP} (default: all)")
    p.add_argument("--trials", type=int, default=5, help="trials 0..T-1 (default 5, as the paper)")
    p.add_argument("--workers", type=int, default=1, help="runs at a time (default 1)")
    _add_run_options(p, "progress display")
    p.add_argument("--demos-dir", default="experts", help="folder holding <EnvName>/demos.npz (default: experts)")
    p.add_argument("--backend", default="local", help="local (process pool, default) or ray")
    p.add_argument("--ray-address", default=None, help="Ray cluster address for ray.init (default: start a local Ray)")
    p.add_argument("-o", "--output", default="runs", help="runs folder (default: runs)")
    p.set_defaults(func=_run_benchmark)


def _run_benchmark(args) -> int:
    from sb3_cmzdril.experiments.grid import benchmark, summarize_outcomes
    from sb3_cmzdril.experts import command_line

    outcomes = benchmark(
        args.env, args.methods, args.trials, args.output, workers=args.workers, backend=args.backend,
        ray_address=args.ray_address, progress=not args.no_progress, command=command_line(),
        timesteps=args.timesteps, n_demos=args.n_demos, n_eval_episodes=args.eval_episodes,
        eval_every=args.eval_every, checkpoint_every=args.checkpoint_every, demos_dir=args.demos_dir,
        hyperparams=args.hyperparams,
    )
    print(summarize_outcomes(outcomes))
    return 1 if any(o["status"] == "failed" for o in outcomes) else 0


def _add_report(sub) -> None:
    p = sub.add_parser(
        "report",
        help="results.md (final evaluation, Table I), its CSVs and figures from a runs folder, optionally beside another",
        description=(
            "Read RUNS_DIR/<EnvName>/<method>/trial<t>/ (eval.csv, final_eval.csv, done.json, logs) and write "
            "OUTPUT/results.md: a headline (the final evaluation on every held-out pool episode, mean over trials "
            "with a 95% bootstrap CI, and Table I: mean (std) over trials of each run's metrics averaged over its "
            "last --window epochs, beside the paper's Table I), then per grid the final-evaluation tables (paired "
            "by trial against BC and no reward), Table I, the gap closed by CMZ-DRIL, the reward signal, the runs "
            "behind each number and the commands; OUTPUT/table1.csv, final_table.csv and the figures "
            "fig1_bc_dril_cmz.png, fig2_cmz_env_zero.png and fig3_final_eval.png. With --reference-runs a second "
            "grid (e.g. the paper-faithful one) is reported beside the first (its files end in _reference)."
        ),
    )
    p.add_argument("runs_dir", metavar="RUNS_DIR", help="the benchmark's output folder")
    p.add_argument("-o", "--output", default="docs", help="output folder (default: docs; its files are replaced only with --force)")
    p.add_argument("--reference-runs", metavar="DIR",
                   help="a second runs folder (e.g. docs/runs_paper_faithful) reported beside RUNS_DIR: its Table I "
                        "(and final evaluation, where its runs have one) in the headline and its own sections")
    p.add_argument("--label", help="how the report names RUNS_DIR's grid (default: the path as given)")
    p.add_argument("--reference-label", help="how the report names the --reference-runs grid (default: its path)")
    from sb3_cmzdril.experiments.runs import TABLE_WINDOW

    p.add_argument("--window", type=int, default=TABLE_WINDOW,
                   help=f"epochs averaged at the end of each run (default {TABLE_WINDOW}, as the paper)")
    p.add_argument("--no-paper", action="store_true", help="leave out the paper's Table I reference numbers")
    p.add_argument("--discussion", metavar="MARKDOWN",
                   help="a hand-written markdown file (what the numbers mean), included as the Discussion section")
    p.add_argument("--readme", metavar="README",
                   help="also replace the results block of this README with the headline table")
    p.add_argument("--no-figures", action="store_true", help="write the tables only (each figure takes a second or two)")
    p.add_argument("--force", action="store_true", help="replace the report files already in OUTPUT")
    p.set_defaults(func=_run_report)


def _run_report(args) -> int:
    from pathlib import Path

    from sb3_cmzdril.experiments.report import PAPER_TABLE_I, report_outputs, write_report
    from sb3_cmzdril.experts import command_line

    out = Path(args.output)
    existing = [name for name in report_outputs() if (out / name).exists()]
    if existing and not args.force:
        raise FileExistsError(f"{out} already holds {', '.join(existing)}; pass --force to replace them, or choose another -o")
    path = write_report(
        args.runs_dir, args.output, window=args.window, references=() if args.no_paper else (PAPER_TABLE_I,),
        command=command_line(), discussion=args.discussion, readme=args.readme,
        reference_runs=args.reference_runs, label=args.label, reference_label=args.reference_label,
        figures=not args.no_figures,
    )
    print(path)
    return 0


_COMMANDS += [_add_train, _add_evaluate, _add_benchmark, _add_report]


#: Exceptions that mean "the input is wrong" (a bad value, a missing or existing file, an optional
#: package not installed): one line and exit code 2. Anything else is a bug and keeps its traceback.
USER_ERRORS = (ValueError, OSError, KeyError, ImportError)
#: Commands that continue from their checkpoints when run again.
RESUMABLE = ("train-expert", "train", "benchmark")


def _one_line(error: BaseException) -> str:
    # str(KeyError("x")) is "'x'", quoted; its argument is the message.
    text = str(error.args[0]) if isinstance(error, KeyError) and error.args else str(error)
    return "; ".join(line.strip() for line in text.splitlines() if line.strip()) or type(error).__name__


def main(argv: Optional[List[str]] = None) -> int:
    """Run one command; every user error ends here as one line on stderr and exit code 2, an
    interruption (Ctrl-C) as one line and exit code 130."""
    from sb3_cmzdril._mujoco_log import route_mujoco_warnings
    from sb3_cmzdril.console import show_library_messages

    parser = build_parser()
    args = parser.parse_args(argv)
    route_mujoco_warnings()
    try:
        with show_library_messages():  # the library logs its notes for a person; the CLI shows them
            return int(args.func(args) or 0)
    except KeyboardInterrupt:
        again = "resume" if args.command in RESUMABLE else "start again"
        print(f"sb3-cmzdril {args.command}: interrupted; rerun the same command to {again}", file=sys.stderr)
        return 130
    except USER_ERRORS as e:
        print(f"sb3-cmzdril {args.command}: error: {_one_line(e)}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
