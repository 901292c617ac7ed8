"""results.md, its tables' CSVs and its figures, from one runs folder or two side by side.

:func:`write_report` reads a grid (``<RUNS_DIR>/<EnvName>/<method>/trial<t>/``, see
:mod:`~cmzdril_lab.report.records`) and, optionally, a reference grid (``reference_runs``: e.g.
the paper-faithful grid of an earlier version), and writes into the output folder:

* results.md — the headline (each grid's final evaluation with its confidence interval and its Table I,
  beside the paper's Table I), then per grid: the final evaluation
  (:mod:`~cmzdril_lab.report.final_eval`), Table I, the gap closed by CMZ-DRIL, the expert's scale
  and the reward signal (:mod:`~cmzdril_lab.report.tables`); the figures; the reference numbers
  (:mod:`~cmzdril_lab.report.paper`); the run folders behind every number; the commands.
* table1.csv and final_table.csv (``table1_reference.csv``, ``final_table_reference.csv`` for the
  reference grid): the tables at full precision, with their run folders.
* fig1_bc_dril_cmz.png, fig2_cmz_env_zero.png (the main grid's curves) and fig3_final_eval.png (the
  final evaluation; :mod:`~cmzdril_lab.report.figures`).

With ``readme`` the README's results block is replaced by a small headline: the main grid's final
evaluation as % of the expert, env by method (:mod:`~cmzdril_lab.report.readme`). Reference
numbers from elsewhere (the paper's Table I: :data:`PAPER_TABLE_I`) enter only through ``references``
and are printed labelled, apart from ours.
"""
from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

from cmzdril_lab.report.aggregate import CSV as ACROSS_CSV
from cmzdril_lab.report.aggregate import FIGURE as ACROSS_FIGURE
from cmzdril_lab.report.aggregate import write_aggregate
from cmzdril_lab.report.figures import (
    FIGURES,
    FINAL_FIGURE,
    FINAL_FIGURE_REFERENCE,
    SMOOTHING_SIGMA,
    plot_figure,
    plot_final,
)
from cmzdril_lab.report.final_eval import final_csv, final_table, mean_ci
from cmzdril_lab.report.formatting import fmt, fmt_ci, fmt_mean_std
from cmzdril_lab.report.paper import PAPER_TABLE_I, ReferenceTable, reference_markdown
from cmzdril_lab.report.readme import (
    README_BEGIN,
    README_END,
    link,
    readme_block,
    short_command,
    update_readme,
)
from cmzdril_lab.report.records import METHOD_LABELS, RunRecord, load_grid, load_runs
from cmzdril_lab.report.sections import (
    GridReport,
    analyse,
    differences_markdown,
    final_sections,
    headline_markdown,
    headline_text,
    readme_markdown,
    readme_text,
    sources_sections,
    status_lines,
    table_sections,
)
from cmzdril_lab.report.tables import (
    expert_returns,
    gap_closed,
    gap_trials,
    reward_signal,
    table_csv,
    table_one,
)
from sb3_cmzdril.errors import MissingFileError, UserError
from sb3_cmzdril.io import PathLike, atomic_write_text
from sb3_cmzdril.training.run_folder import TABLE_WINDOW

#: Output file name suffixes: the main grid's files, then the reference grid's.
SUFFIXES: tuple[str, str] = ("", "_reference")


def report_outputs() -> list[str]:
    """Every file name a report may write into its output folder (the CLI's --force check)."""
    names = ["results.md"]
    for suffix in SUFFIXES:
        names += [f"table1{suffix}.csv", f"final_table{suffix}.csv"]
    return names + [name for name, _, _ in FIGURES] + [FINAL_FIGURE, FINAL_FIGURE_REFERENCE, ACROSS_CSV, ACROSS_FIGURE]


def _source_line(rep: GridReport) -> str:
    records = rep.grid.records
    n_final = sum(bool(r.final) for r in records)
    curves = "Table I and Fig. 1/2" if rep.suffix == SUFFIXES[0] else "Table I"  # the curves: main grid only
    return (
        f"- **{rep.label}**: `{rep.root}`, {len(records)} runs: their `eval.csv` ({curves}), "
        f"`final_eval.csv` (the final evaluation; {n_final} of the {len(records)} runs have one), "
        f"`done.json` (the epoch of each "
        "lowest-u policy), `logs/progress_*.csv` (the reward signal) and the demo pools their `config.json` "
        "names (the expert's return in Table I)."
    )


def render_markdown(
    reports: Sequence[GridReport],
    figures: Sequence[tuple[str, Path]],
    final_figures: dict[str, Path],
    references: Sequence[ReferenceTable],
    report_command: str | None,
    window: int,
    discussion: str | None = None,
    across: str | None = None,
) -> str:
    """results.md: the headline, the across-task aggregate (``across``), each grid's sections, the
    figures, the references, the sources."""
    two = len(reports) > 1
    h = "###" if two else "##"
    reference = references[0] if references else None
    parts = [
        "# Results",
        "",
        f"Computed by `cmzdril_lab.report` on {time.strftime('%Y-%m-%d %H:%M %Z')} from these files. "
        "Every number in the tables is computed from them, none is typed in, except the paper's numbers, which "
        "are copied from the paper and labelled as such. The Discussion, if any, is written by hand.",
        "",
        *(_source_line(rep) for rep in reports),
    ]
    for rep in reports:
        parts += status_lines(rep)
    parts += [
        "",
        "## Headline",
        "",
        headline_text(reports, reference, window),
        "",
        headline_markdown(reports, reference),
        "",
    ]
    if across:
        parts += ["## Across tasks", "", across, ""]
    if two:
        parts += [differences_markdown(reports[0], reports[1]), ""]
    for i, rep in enumerate(reports):
        if two:
            parts += [f"## {rep.label}", ""]
        parts += final_sections(rep, h, final_figures.get(rep.suffix))
        parts += table_sections(rep, h, window)
        if i == 0 and figures:
            parts += [f"{h} Figures", ""]
            for title, path in figures:
                parts += [
                    f"**{title}.** One row per env, one column per metric against the epoch; each trial's "
                    f"curve is smoothed with a Gaussian filter (sigma {SMOOTHING_SIGMA:g} evaluations), then "
                    "the line is the mean over trials and the band ±1 std. BC (evaluated once) is the dashed "
                    "horizontal line with its ±1 std band.",
                    "",
                    f"![{title}]({path.name})",
                    "",
                ]
    if references:
        parts += ["## Reference numbers", "", *(reference_markdown(ref) for ref in references)]
    if discussion:
        parts += ["## Discussion", "", discussion.strip(), ""]
    parts += ["## Where each number comes from", ""]
    for rep in reports:
        parts += sources_sections(rep, f"### {rep.label}" if two else "")
    parts += [
        "This report:",
        "",
        f"    {short_command(report_command or 'sb3-cmzdril report ' + str(reports[0].root))}",
        "",
    ]
    return "\n".join(parts)


def _check_inputs(window: int, discussion: PathLike | None, readme: PathLike | None) -> None:
    """Fail on a bad input before anything is written."""
    if int(window) < 1:
        raise UserError(f"window must be >= 1, got {window}")
    if discussion is not None and not Path(discussion).is_file():
        raise MissingFileError(f"discussion file not found: {discussion}")
    if readme is not None:
        readme_block(readme)


def _readme_text(
    reports: Sequence[GridReport],
    window: int,
    command: str | None,
    results: Path,
    readme: PathLike,
) -> str:
    """The README block: the main grid's headline in small (the full one is in results.md)."""
    rep = reports[0]
    unfinished = sum(r.status != "done" for r in rep.grid.records)
    source = f"{len(rep.grid.records)} runs in `{rep.root}`" + (f" ({unfinished} not finished)" if unfinished else "")
    return (
        readme_markdown(rep)
        + "\n\n"
        + readme_text(rep, window)
        + f" From {source}; written by `{short_command(command)}`; details in "
        f"[results.md]({link(results, Path(readme).parent)})."
    )


def write_report(
    runs_dir: PathLike,
    output_dir: PathLike = "docs",
    *,
    window: int = TABLE_WINDOW,
    references: Sequence[ReferenceTable] = (PAPER_TABLE_I,),
    command: str | None = None,
    sigma: float = SMOOTHING_SIGMA,
    discussion: PathLike | None = None,
    readme: PathLike | None = None,
    reference_runs: PathLike | None = None,
    label: str | None = None,
    reference_label: str | None = None,
    figures: bool = True,
    aggregate_runs: Sequence[PathLike] = (),
) -> Path:
    """Write results.md, the tables' CSVs and the figures into ``output_dir``; returns results.md's path.

    :param references: tables of numbers from elsewhere (default: the paper's Table I), each shown
        separately and labelled; the first also stands in the headline; pass ``()`` for none.
    :param command: the report command line to record (the CLI passes its own).
    :param discussion: a markdown file written by a person (what the numbers mean), included as the
        report's "Discussion" section.
    :param readme: a README holding the :data:`README_BEGIN`/:data:`README_END` block: it is replaced
        by a small headline (the main grid's final evaluation as % of the expert, env by method) and a
        line naming this report.
    :param reference_runs: a second runs folder (e.g. the paper-faithful grid) reported beside the first.
    :param label: how tables name the grid of ``runs_dir`` (default: the path as given);
        ``reference_label`` the same for ``reference_runs``.
    :param figures: False writes the tables only (quicker: each figure takes a second or two).
    :param aggregate_runs: more runs folders (e.g. a benchmark of another env) whose final evaluations
        join the main grid's in the across-task aggregate (:mod:`~cmzdril_lab.report.aggregate`,
        rliable), written when the main grid has final evaluations.
    """
    _check_inputs(window, discussion, readme)
    grids = [load_grid(runs_dir, label)]
    if reference_runs is not None:
        grids.append(load_grid(reference_runs, reference_label))
        if grids[0].label == grids[1].label:
            raise UserError(f"both grids are labelled {grids[0].label!r}: give them different labels")
    reports = [analyse(grid, int(window), suffix) for grid, suffix in zip(grids, SUFFIXES[: len(grids)], strict=True)]
    out = Path(output_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = {"results.md"}
    final_figures: dict[str, Path] = {}
    for rep, figure_name in zip(reports, (FINAL_FIGURE, FINAL_FIGURE_REFERENCE)[: len(reports)], strict=True):
        atomic_write_text(out / f"table1{rep.suffix}.csv", table_csv(rep.rows, rep.root))
        written.add(f"table1{rep.suffix}.csv")
        if rep.final:
            atomic_write_text(out / f"final_table{rep.suffix}.csv", final_csv(rep.final, rep.root))
            written.add(f"final_table{rep.suffix}.csv")
            if figures:
                figure = plot_final(rep.final, out / figure_name, f"Final evaluation: {rep.label}")
                if figure is not None:  # rep.final has rows, so there is one
                    final_figures[rep.suffix] = figure
                    written.add(figure_name)
    curves = []
    for filename, title, methods in FIGURES if figures else ():
        path = plot_figure(reports[0].grid.records, methods, out / filename, title, sigma)
        if path is not None:
            curves.append((title, path))
            written.add(filename)
    across = None
    if reports[0].final:
        pooled = list(reports[0].final) + [row for d in aggregate_runs for row in final_table(load_runs(d))]
        across = write_aggregate(pooled, out, figures)
        if across is not None:
            written.update({ACROSS_CSV, ACROSS_FIGURE} if figures else {ACROSS_CSV})
    notes = Path(discussion).read_text(encoding="utf-8") if discussion is not None else None
    text = render_markdown(reports, curves, final_figures, references, command, int(window), notes, across)
    atomic_write_text(out / "results.md", text)
    for name in set(report_outputs()) - written:
        (out / name).unlink(missing_ok=True)  # an earlier report's file this one would contradict
    if readme is not None:
        update_readme(
            readme,
            _readme_text(reports, int(window), command, out / "results.md", readme),
        )
    return out / "results.md"


__all__ = [
    "METHOD_LABELS",
    "PAPER_TABLE_I",
    "README_BEGIN",
    "README_END",
    "FIGURES",
    "ReferenceTable",
    "RunRecord",
    "GridReport",
    "load_runs",
    "table_one",
    "gap_closed",
    "gap_trials",
    "expert_returns",
    "reward_signal",
    "final_table",
    "mean_ci",
    "headline_markdown",
    "update_readme",
    "table_csv",
    "plot_figure",
    "plot_final",
    "report_outputs",
    "write_report",
    "fmt",
    "fmt_ci",
    "fmt_mean_std",
]
