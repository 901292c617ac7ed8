"""The ``train`` command: one run (an env, a method, a trial seed) into its run folder.

Its run options (:func:`add_run_options`) and method list (:data:`METHODS_HELP`) are public: the lab's
``benchmark`` command (``cmzdril_lab.cli``) offers the same options for a grid of runs."""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # the CLI imports its heavy modules only when a command runs
    from sb3_cmzdril.io import PathLike

#: The methods a run can use, as the help of ``--reward`` (and the lab's ``--methods``) lists them.
METHODS_HELP = (
    "bc (pretrained policy only), zero, env, dril or cmz (CMZDRIL, PPO), or cmz-sac (CMZ-DRIL's reward with the "
    "off-policy learner CMZDRILSAC) and its comparisons dril-sac, zero-sac and env-sac (the same learner with "
    "DRIL's reward, none, the env's)"
)


def add_run_options(p, what: str) -> None:
    """Options shared by train and benchmark: the data split, the evaluation and the checkpoints."""
    from sb3_cmzdril.training.spec import (
        DEFAULT_CHECKPOINT_EVERY,
        DEFAULT_EVAL_EPISODES,
        OFFPOLICY_EPOCH_STEPS,
    )

    p.add_argument(
        "--n-demos",
        type=int,
        default=None,
        help="training episodes per trial (default: n_demos of the YAML entry: 1 for MuJoCo, 5 for WaypointNav)",
    )
    p.add_argument(
        "--eval-episodes",
        type=int,
        default=DEFAULT_EVAL_EPISODES,
        help=f"held-out expert episodes per evaluation (default {DEFAULT_EVAL_EPISODES})",
    )
    p.add_argument(
        "--timesteps", type=int, default=None, help="total env steps per run (default: n_timesteps of the YAML)"
    )
    p.add_argument(
        "--eval-every",
        type=int,
        default=1,
        help=f"evaluate every k epochs (default 1: every epoch; an epoch is a PPO update, or "
        f"{OFFPOLICY_EPOCH_STEPS} steps of cmz-sac)",
    )
    p.add_argument(
        "--checkpoint-every",
        type=int,
        default=DEFAULT_CHECKPOINT_EVERY,
        help=f"checkpoint model.zip every k epochs (default {DEFAULT_CHECKPOINT_EVERY})",
    )
    p.add_argument(
        "--hyperparams",
        default=None,
        help="zoo-format YAML (default: the shipped hyperparams/cmzdril.yml; cmzdril_sac.yml for cmz-sac"
        + (")" if what == "progress bar" else ", whose runs read --sac-hyperparams)"),
    )
    p.add_argument("--no-progress", action="store_true", help=f"no {what}")


def add_train(sub) -> None:
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
    p.add_argument("--reward", required=True, metavar="METHOD", help=METHODS_HELP)
    p.add_argument("--demos", default=None, help="demo pool npz (default: experts/<EnvName>/demos.npz)")
    p.add_argument("--seed", type=int, default=0, help="trial seed: data split, networks and env (default 0)")
    add_run_options(p, "progress bar")
    p.add_argument("-o", "--output", default=None, help="run folder (default: runs/<EnvName>/<method>/trial<seed>)")
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    p.add_argument("-v", "--verbose", type=int, default=0, help="SB3 verbosity (0, 1 or 2)")
    p.set_defaults(func=_run_train)


def _run_train(args) -> int:
    import torch

    from sb3_cmzdril.experts import check_threads, command_line
    from sb3_cmzdril.training.runs import execute_run
    from sb3_cmzdril.training.spec import prepare_run

    threads = check_threads(args.threads)
    if threads is not None:
        torch.set_num_threads(threads)
    run = prepare_run(  # read and checked once; the run trains the model its checks built
        args.env,
        args.reward,
        args.seed,
        demos=args.demos,
        n_demos=args.n_demos,
        n_eval_episodes=args.eval_episodes,
        timesteps=args.timesteps,
        output_dir=args.output,
        hyperparams=args.hyperparams,
        eval_every=args.eval_every,
        checkpoint_every=args.checkpoint_every,
        command=command_line(),
        verbose=args.verbose,
    )
    spec = run.spec
    result = execute_run(run, progress_bar=not args.no_progress, verbose=args.verbose)
    if result["status"] == "skipped":
        print(f"{spec.output_dir} is already finished (done.json, {result.get('num_timesteps')} steps); nothing to do")
    window = result.get("final_window")
    if window:
        print(
            f"{result['status']}: {spec.label} -> {spec.output_dir}; "
            f"epochs {window['first_epoch']}-{window['last_epoch']}: "
            f"return {window['return']:.2f}, Fréchet {window['frechet']:.4g}, action MSE {window['action_mse']:.4g}"
        )
    else:
        print(f"{result['status']} at {result.get('num_timesteps')} steps: {spec.output_dir} (run again to continue)")
    for line in final_evaluation_lines(result.get("final_evaluation"), spec.output_dir, spec.method):
        print(line)
    return 0 if result["status"] in ("done", "skipped") else 1


def published_versions_note(demos: PathLike) -> str | None:
    """Deprecated after 0.2.0, goes in 0.4.0: a run logs this note itself
    (:func:`sb3_cmzdril.training.runs.published_versions_note` of its config.json)."""
    import warnings

    from sb3_cmzdril.io import file_sha256, versions
    from sb3_cmzdril.training.runs import published_versions_note as note

    warnings.warn("sb3_cmzdril.cli.train.published_versions_note moved to sb3_cmzdril.training.runs after 0.2.0 "
                  "(it takes a run's config.json); the old name goes in 0.4.0", FutureWarning, stacklevel=2)
    return note({"demos_sha256": file_sha256(demos), "versions": versions()})


def final_evaluation_lines(final: dict[str, Any] | None, output_dir: PathLike, method: str) -> list[str]:
    """One line per finally-evaluated policy: its held-out return and the file that holds it, so a user
    sees that the lowest-disagreement policy (chosen without the env reward) may be the better one, and
    which file is the method's result where that is not its last weights (cmz-sac's longest-episodes
    policy)."""
    from pathlib import Path

    from sb3_cmzdril.training.run_folder import AVERAGED_MODEL, LONGEST_MODEL, LOWEST_U_MODEL, MODEL_FILE
    from sb3_cmzdril.training.spec import result_policy

    files = {
        "final": ("final policy", MODEL_FILE),
        "lowest_u": ("lowest-u policy", LOWEST_U_MODEL),
        "longest": ("longest-episodes policy", LONGEST_MODEL),
        "averaged": ("averaged policy", AVERAGED_MODEL),
    }
    result = result_policy(method)
    if result != "final":
        files["final"] = ("last weights", MODEL_FILE)
        files[result] = (f"{files[result][0]}, the method's result", files[result][1])
    lines = []
    for policy, ev in (final or {}).items():
        if policy not in files or not isinstance(ev, dict) or "return_mean" not in ev:
            continue
        label, name = files[policy]
        epoch = f" (epoch {ev['epoch']})" if "epoch" in ev else ""
        lines.append(
            f"final evaluation, {label}{epoch}: return {ev['return_mean']:.2f} "
            f"(std {ev.get('return_std', float('nan')):.2f}) "
            f"over {ev.get('n_episodes', '?')} held-out episodes: {Path(output_dir) / name}"
        )
    return lines


__all__ = ["METHODS_HELP", "add_run_options", "add_train", "final_evaluation_lines", "published_versions_note"]
