"""The lab's commands, ``benchmark`` (the trial grid), ``report`` (results.md, its tables and
figures) and ``pack``/``unpack`` (a study's compact records), and the console script ``cmzdril-lab``.

The library's own ``sb3-cmzdril`` finds both through the entry point group ``sb3_cmzdril.commands``
(this package's pyproject.toml), so ``sb3-cmzdril benchmark`` keeps working where the lab is installed.
"""
from __future__ import annotations

from sb3_cmzdril.cli.train import METHODS_HELP, add_run_options
from sb3_cmzdril.errors import OutputExistsError, UserError


def add_benchmark(sub) -> None:
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
    from sb3_cmzdril.training.spec import PAPER_METHODS

    p.add_argument(
        "--methods",
        default=",".join(PAPER_METHODS),
        help=f"comma-separated, from: {METHODS_HELP} (default: the paper's {','.join(PAPER_METHODS)})",
    )
    p.add_argument(
        "--sac-hyperparams",
        default=None,
        help="zoo-format YAML of the cmz-sac runs (default: the shipped hyperparams/cmzdril_sac.yml)",
    )
    p.add_argument(
        "--trials",
        default="5",
        help="a count T (trials 0..T-1; default 5, as the paper), or trial indices and ranges: 5-9, 0,3,7",
    )
    p.add_argument("--workers", type=int, default=1, help="runs at a time (default 1)")
    add_run_options(p, "progress display")
    p.add_argument("--demos-dir", default="experts", help="folder holding <EnvName>/demos.npz (default: experts)")
    p.add_argument("--backend", default="local", help="local (process pool, default) or ray")
    p.add_argument("--ray-address", default=None, help="Ray cluster address for ray.init (default: start a local Ray)")
    p.add_argument("-o", "--output", default="runs", help="runs folder (default: runs)")
    p.set_defaults(func=_run_benchmark)


def trial_indices(text: str) -> int | list[int]:
    """``--trials``: a count T (trials 0..T-1), or indices and ranges (``5-9``, ``0,3,7``, ``0-2,7``),
    so that a study's confirmation trials run apart from its tuning trials."""
    text = text.strip()
    if text.isdigit():
        return int(text)
    indices: list[int] = []
    for part in text.split(","):
        first, dash, last = (s.strip() for s in part.partition("-"))
        if not first.isdigit() or (dash and not last.isdigit()):
            raise UserError(f"--trials {text!r}: write a count (5), a range (5-9) or trial indices (0,3,7)")
        start, stop = int(first), int(last if dash else first)
        if stop < start:
            raise UserError(f"--trials {text!r}: the range {part.strip()} runs backwards")
        indices.extend(range(start, stop + 1))
    if len(set(indices)) != len(indices):
        raise UserError(f"--trials {text!r} names a trial twice")
    return indices


def _run_benchmark(args) -> int:
    from cmzdril_lab.run.grid import benchmark, summarize_outcomes
    from cmzdril_lab.run.worker import RunStatus
    from sb3_cmzdril.experts import command_line

    outcomes = benchmark(
        args.env,
        args.methods,
        trial_indices(args.trials),
        args.output,
        workers=args.workers,
        backend=args.backend,
        ray_address=args.ray_address,
        progress=not args.no_progress,
        command=command_line(),
        timesteps=args.timesteps,
        n_demos=args.n_demos,
        n_eval_episodes=args.eval_episodes,
        eval_every=args.eval_every,
        checkpoint_every=args.checkpoint_every,
        demos_dir=args.demos_dir,
        hyperparams=args.hyperparams,
        offpolicy_hyperparams=args.sac_hyperparams,
    )
    print(summarize_outcomes(outcomes))
    return 1 if any(o.status is RunStatus.FAILED for o in outcomes) else 0


def add_report(sub) -> None:
    p = sub.add_parser(
        "report",
        help="results.md (final evaluation, Table I), its CSVs and figures "
        "from a runs folder, optionally beside another",
        description=(
            "Read RUNS_DIR/<EnvName>/<method>/trial<t>/ (eval.csv, final_eval.csv, done.json, logs) and write "
            "OUTPUT/results.md: a headline (the final evaluation on every held-out pool episode, mean over trials "
            "with a 95% bootstrap CI, and Table I: mean (std) over trials of each run's metrics averaged over its "
            "last --window epochs, beside the paper's Table I), then per grid the final-evaluation tables (paired "
            "by trial against BC and no reward), Table I, the gap closed by CMZ-DRIL, the reward signal, the runs "
            "behind each number and the commands; OUTPUT/table1.csv, final_table.csv and the figures "
            "fig1_bc_dril_cmz.png, fig2_cmz_env_zero.png and fig3_final_eval.png. With --reference-runs a second "
            "grid (e.g. the paper-faithful one) is reported beside the first (its files end in _reference). "
            "A run is known by its config.json (env, method, trial seed), not its folder name: a copied folder "
            "counts once; whatever is left out (copies, folders without a readable config.json or of an unknown "
            "method, eval.csv rows holding NaN) is named with the reason, on the output and in results.md."
        ),
    )
    p.add_argument("runs_dir", metavar="RUNS_DIR", help="the benchmark's output folder")
    p.add_argument(
        "-o", "--output", default="docs", help="output folder (default: docs; its files are replaced only with --force)"
    )
    p.add_argument(
        "--reference-runs",
        metavar="DIR",
        help="a second runs folder (e.g. results/runs_paper_faithful) reported beside RUNS_DIR: its Table I "
        "(and final evaluation, where its runs have one) in the headline and its own sections",
    )
    p.add_argument(
        "--aggregate-runs",
        metavar="DIR",
        action="append",
        default=[],
        help="another runs folder (e.g. a benchmark of another env) whose final evaluations join RUNS_DIR's in "
        "the across-task aggregate (IQM, probability of improvement, performance profiles; rliable); repeatable",
    )
    p.add_argument("--label", help="how the report names RUNS_DIR's grid (default: the path as given)")
    p.add_argument("--reference-label", help="how the report names the --reference-runs grid (default: its path)")
    from sb3_cmzdril.training.run_folder import TABLE_WINDOW

    p.add_argument(
        "--window",
        type=int,
        default=TABLE_WINDOW,
        help=f"epochs averaged at the end of each run (default {TABLE_WINDOW}, as the paper)",
    )
    p.add_argument("--no-paper", action="store_true", help="leave out the paper's Table I reference numbers")
    p.add_argument(
        "--discussion",
        metavar="MARKDOWN",
        help="a hand-written markdown page (what the numbers mean) that results.md links to",
    )
    p.add_argument(
        "--discussion-section",
        metavar="TITLE",
        help="copy the --discussion page's '## ' section whose heading starts with TITLE into results.md, "
        "labelled as written by hand (what the page must say on its face: where a target was not reached)",
    )
    p.add_argument(
        "--readme", metavar="README", help="also replace the results block of this README with the headline table"
    )
    p.add_argument(
        "--no-figures", action="store_true", help="write the tables only (each figure takes a second or two)"
    )
    p.add_argument("--force", action="store_true", help="replace the report files already in OUTPUT")
    p.set_defaults(func=_run_report)


def _run_report(args) -> int:
    from pathlib import Path

    from cmzdril_lab.report.report import PAPER_TABLE_I, report_outputs, write_report
    from sb3_cmzdril.experts import command_line

    out = Path(args.output)
    existing = [name for name in report_outputs() if (out / name).exists()]
    if existing and not args.force:
        raise OutputExistsError(
            f"{out} already holds {', '.join(existing)}; pass --force to replace them, or choose another -o"
        )
    path = write_report(
        args.runs_dir,
        args.output,
        window=args.window,
        references=() if args.no_paper else (PAPER_TABLE_I,),
        command=command_line(),
        discussion=args.discussion,
        discussion_section=args.discussion_section,
        readme=args.readme,
        reference_runs=args.reference_runs,
        aggregate_runs=args.aggregate_runs,
        label=args.label,
        reference_label=args.reference_label,
        figures=not args.no_figures,
    )
    print(path)
    return 0


def add_pack(sub) -> None:
    p = sub.add_parser(
        "pack",
        help="write a study folder of run records into its compact archive (FOLDER.tar.xz), the form committed",
        description=(
            "Write each FOLDER's files into FOLDER.tar.xz beside it, sorted and without times or owners (the "
            "same files make the same bytes). Reports and studies read an archived folder by unpacking it "
            "beside the archive when it is missing or out of date; an unpacked folder holding runs that are "
            "not packed is never replaced."
        ),
    )
    p.add_argument("folders", nargs="+", metavar="FOLDER", help="a runs folder, e.g. results/runs")
    p.set_defaults(func=_run_pack)


def add_unpack(sub) -> None:
    p = sub.add_parser(
        "unpack",
        help="unpack a study's compact records (FOLDER.tar.xz) into FOLDER, e.g. to train on a pool it holds",
        description=(
            "Unpack FOLDER.tar.xz into FOLDER where FOLDER is missing or holds an older unpacking; reports and "
            "studies do this themselves. A folder holding runs that are not packed is never replaced."
        ),
    )
    p.add_argument("folders", nargs="+", metavar="FOLDER", help="an archived study folder, e.g. results/untuned")
    p.set_defaults(func=_run_unpack)


def _run_unpack(args) -> int:
    from cmzdril_lab.records_store import archive_of, unpack

    archives = [archive_of(folder) for folder in args.folders]
    missing = [str(archive) for archive in archives if not archive.is_file()]
    if missing:
        raise UserError(f"no archive {', '.join(missing)}")
    for archive, folder in zip(archives, args.folders, strict=True):
        unpack(archive, folder)
        print(folder)
    return 0


def _run_pack(args) -> int:
    from cmzdril_lab.records_store import pack

    for folder in args.folders:
        print(pack(folder))
    return 0


def main(argv: list[str] | None = None) -> int:
    """``cmzdril-lab``: the lab's commands with the library command line's error handling."""
    from sb3_cmzdril.cli import main as library_main

    return library_main(argv, prog="cmzdril-lab", commands=(add_benchmark, add_report, add_pack, add_unpack),
                        description="The sb3-cmzdril lab: the trial grid, its report and the compact run records.")


__all__ = ["add_benchmark", "add_pack", "add_report", "add_unpack", "main", "trial_indices"]
