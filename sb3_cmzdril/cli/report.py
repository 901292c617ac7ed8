"""The ``report`` command: results.md, its tables and figures from one runs folder or two."""
from __future__ import annotations

from sb3_cmzdril.errors import OutputExistsError


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
    from sb3_cmzdril.experiments.run.run_folder import TABLE_WINDOW

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
        help="a hand-written markdown file (what the numbers mean), included as the Discussion section",
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

    from sb3_cmzdril.experiments.report.report import PAPER_TABLE_I, report_outputs, write_report
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
        readme=args.readme,
        reference_runs=args.reference_runs,
        aggregate_runs=args.aggregate_runs,
        label=args.label,
        reference_label=args.reference_label,
        figures=not args.no_figures,
    )
    print(path)
    return 0


__all__ = ["add_report"]
