"""results.md, its tables' CSVs and its figures, from one runs folder or two side by side.

:func:`write_report` reads a grid (``<RUNS_DIR>/<EnvName>/<method>/trial<t>/``, see
:mod:`~cmzdril_lab.report.records`) and, optionally, a reference grid (``reference_runs``: e.g.
the paper-faithful grid of an earlier version), and writes into the output folder:

* results.md — the answer first: the headline (the main grid's final evaluation as % of the expert, env
  by method, and its figure), the aggregate across tasks (:mod:`~cmzdril_lab.report.aggregate`); then
  per grid and task: the final evaluation (:mod:`~cmzdril_lab.report.final_eval`), Table I, the gap
  closed by CMZ-DRIL and the reward signal (:mod:`~cmzdril_lab.report.tables`) and the training
  curves; the reference numbers (:mod:`~cmzdril_lab.report.paper`); how to read every table; the run
  folders and commands behind every number. A hand-written discussion is linked, not copied, but for
  one section of it that the page must show on its own face (``discussion_section``, copied labelled by
  :mod:`~cmzdril_lab.report.excerpt`).
* table1.csv, final_table.csv, paired.csv and per_run.csv (``table1_reference.csv`` and so on for the
  reference grid): the tables at full precision, with their run folders; what the page shows in short.
* fig1_bc_dril_cmz.png, fig2_cmz_env_zero.png (the main grid's curves), fig3_final_eval.png (the
  final evaluation; :mod:`~cmzdril_lab.report.figures`) and fig4_across_tasks.png.

With ``readme`` the README's results block is replaced by the headline table and two sentences
(:mod:`~cmzdril_lab.report.readme`). Reference numbers from elsewhere (the paper's Table I:
:data:`PAPER_TABLE_I`) enter only through ``references`` and are printed labelled, apart from ours.
"""
from __future__ import annotations

import contextlib
import os
import shutil
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

from cmzdril_lab.report.aggregate import CSV as ACROSS_CSV
from cmzdril_lab.report.aggregate import FIGURE as ACROSS_FIGURE
from cmzdril_lab.report.aggregate import AcrossSection, write_aggregate
from cmzdril_lab.report.excerpt import excerpt
from cmzdril_lab.report.figures import (
    FIGURES,
    FINAL_FIGURE,
    FINAL_FIGURE_REFERENCE,
    SMOOTHING_SIGMA,
    plot_figure,
    plot_final,
)
from cmzdril_lab.report.final_eval import final_csv, final_table, mean_ci, paired_csv
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
    how_to_read,
    sources_sections,
    status_lines,
    table_sections,
)
from cmzdril_lab.report.tables import (
    expert_returns,
    gap_closed,
    gap_trials,
    per_run_csv,
    reward_signal,
    table_csv,
    table_one,
)
from sb3_cmzdril.errors import MissingFileError, UserError
from sb3_cmzdril.io import PathLike, atomic_write_text, deferred_signals, process_alive
from sb3_cmzdril.training.run_folder import TABLE_WINDOW

#: Output file name suffixes: the main grid's files, then the reference grid's.
SUFFIXES: tuple[str, str] = ("", "_reference")


def report_outputs() -> list[str]:
    """Every file name a report may write into its output folder (the CLI's --force check)."""
    names = ["results.md"]
    for suffix in SUFFIXES:
        names += [f"table1{suffix}.csv", f"final_table{suffix}.csv"]
    names += [name for name, _, _ in FIGURES] + [FINAL_FIGURE, FINAL_FIGURE_REFERENCE, ACROSS_CSV, ACROSS_FIGURE]
    for suffix in SUFFIXES:
        names += [f"paired{suffix}.csv", f"per_run{suffix}.csv"]
    return names


def _grid_name(rep: GridReport) -> str:
    runs = f"{len(rep.grid.records)} runs"
    return f"`{rep.root}` ({runs})" if rep.label == str(rep.root) else f"{rep.label} (`{rep.root}`, {runs})"


def _source_name(rep: GridReport) -> str:
    """The grid as the headline's note names it: its label, capitalised, or its folder."""
    return f"`{rep.root}`" if rep.label == str(rep.root) else rep.label[:1].upper() + rep.label[1:]


def render_markdown(
    reports: Sequence[GridReport],
    figures: Sequence[tuple[str, Path]],
    final_figures: dict[str, Path],
    references: Sequence[ReferenceTable],
    report_command: str | None,
    window: int,
    discussion: str | None = None,
    across: AcrossSection | None = None,
    copied: str | None = None,
) -> str:
    """results.md: the headline, the across-task aggregate (``across``), a section copied from the discussion
    (``copied``), each grid's per-task sections and figures, the references, how to read them, the sources;
    ``discussion``: the link to a hand-written page."""
    two = len(reports) > 1
    main = reports[0]
    reference = references[0] if references else None
    intro = (f"Computed by `cmzdril_lab.report` on {time.strftime('%Y-%m-%d %H:%M %Z')} from the run records of "
             + " and ".join(_grid_name(rep) for rep in reports)
             + _typed_in(bool(references), bool(copied)))
    if discussion:
        intro += f" What the numbers mean, written by hand: [the discussion]({discussion})."
    parts = ["# Results", "", intro]
    for rep in reports:
        parts += status_lines(rep)
    parts += ["", "## Headline", "", headline_markdown(main), "",
              headline_text(main, window, _source_name(main), "[How to read](#how-to-read)"), ""]
    if main.suffix in final_figures:
        parts += [f"![Final evaluation: {main.label}]({final_figures[main.suffix].name})", ""]
    if across:
        parts += ["## Across tasks", "", across.body]
    if copied:
        parts += [copied]
    for i, rep in enumerate(reports):
        parts += [f"## Per task: {rep.label}" if two else "## Per task", ""]
        if i > 0:
            parts += [differences_markdown(main, rep), ""]
        parts += final_sections(rep, "###", final_figures.get(rep.suffix) if i > 0 else None)
        parts += table_sections(rep, "###", window, figures if i == 0 else ())
    parts += [reference_markdown(ref, "##") for ref in references]
    parts += how_to_read(reports, reference, window, across.notes if across else None, bool(figures))
    parts += ["## Where each number comes from", ""]
    for i, rep in enumerate(reports):
        parts += sources_sections(rep, f"### {rep.label}" if two else "", curves=i == 0 and bool(figures))
    parts += [
        "This report:",
        "",
        f"    {short_command(report_command or 'sb3-cmzdril report ' + str(main.root))}",
        "",
    ]
    return "\n".join(parts)


def _typed_in(references: bool, copied: bool) -> str:
    """The intro's clause on what the page holds that no record gave."""
    others = [name for name, present in (("the paper's", references), ("the section copied from the discussion",
                                                                        copied)) if present]
    if not others:
        return "; no number is typed in."
    return f"; no number is typed in, except {' and '.join(others)}, labelled as such."


def _check_inputs(window: int, discussion: PathLike | None, readme: PathLike | None,
                  discussion_section: str | None = None) -> None:
    """Fail on a bad input before anything is written."""
    if int(window) < 1:
        raise UserError(f"window must be >= 1, got {window}")
    if discussion is not None and not Path(discussion).is_file():
        raise MissingFileError(f"discussion file not found: {discussion}")
    if discussion_section is not None and discussion is None:
        raise UserError("a discussion section to copy needs the discussion page it is in (--discussion)")
    if readme is not None:
        readme_block(readme)


def _readme_text(reports: Sequence[GridReport], window: int, results: Path, readme: PathLike) -> str:
    """The README block: the main grid's headline table and two sentences (the rest is in results.md)."""
    rep = reports[0]
    unfinished = sum(r.status != "done" for r in rep.grid.records)
    source = f"{len(rep.grid.records)} runs in `{rep.root}`" + (f" ({unfinished} not finished)" if unfinished else "")
    details = f"[results.md]({link(results, Path(readme).parent)})"
    return headline_markdown(rep) + "\n\n" + headline_text(rep, window, f"From {source}", details)


#: The folder inside a report's output where its files are written before they replace the old ones.
STAGING_PREFIX = ".report-staging-"


@contextlib.contextmanager
def staged(out: Path) -> Iterator[Path]:
    """A fresh staging folder inside ``out`` (removed afterwards), and those that killed reports left."""
    for stale in out.glob(f"{STAGING_PREFIX}*"):
        pid = stale.name[len(STAGING_PREFIX):]
        if not pid.isdigit() or process_alive(int(pid)) is False:  # None: cannot tell, so it stays
            shutil.rmtree(stale, ignore_errors=True)
    stage = out / f"{STAGING_PREFIX}{os.getpid()}"
    shutil.rmtree(stage, ignore_errors=True)
    stage.mkdir()
    try:
        yield stage
    finally:
        shutil.rmtree(stage, ignore_errors=True)



def write_report(
    runs_dir: PathLike,
    output_dir: PathLike = "docs",
    *,
    window: int = TABLE_WINDOW,
    references: Sequence[ReferenceTable] = (PAPER_TABLE_I,),
    command: str | None = None,
    sigma: float = SMOOTHING_SIGMA,
    discussion: PathLike | None = None,
    discussion_section: str | None = None,
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
    :param discussion: a markdown page written by a person (what the numbers mean): results.md links to
        it (relatively, so it should lie in the same documentation tree), it does not copy it.
    :param discussion_section: but for this one of its ``## `` sections (the first words of the heading),
        copied after the across-task aggregate, labelled as written by hand (where a target was not
        reached, say: the page must say so itself).
    :param readme: a README holding the :data:`README_BEGIN`/:data:`README_END` block: it is replaced
        by the headline table (the main grid's final evaluation as % of the expert, env by method) and two
        sentences saying what its cells are and linking results.md.
    :param reference_runs: a second runs folder (e.g. the paper-faithful grid) reported beside the first.
    :param label: how tables name the grid of ``runs_dir`` (default: the path as given);
        ``reference_label`` the same for ``reference_runs``.
    :param figures: False writes the tables only (quicker: each figure takes a second or two).
    :param aggregate_runs: more runs folders (e.g. a benchmark of another env) whose final evaluations
        join the main grid's in the across-task aggregate (:mod:`~cmzdril_lab.report.aggregate`,
        rliable), written when the main grid has final evaluations.
    """
    _check_inputs(window, discussion, readme, discussion_section)
    out = Path(output_dir)
    copied = excerpt(discussion, discussion_section, out) if discussion is not None and discussion_section else None
    grids = [load_grid(runs_dir, label)]
    if reference_runs is not None:
        grids.append(load_grid(reference_runs, reference_label))
        if grids[0].label == grids[1].label:
            raise UserError(f"both grids are labelled {grids[0].label!r}: give them different labels")
    reports = [analyse(grid, int(window), suffix) for grid, suffix in zip(grids, SUFFIXES[: len(grids)], strict=True)]
    out.mkdir(parents=True, exist_ok=True)
    with staged(out) as stage:
        written = {"results.md"}
        final_figures: dict[str, Path] = {}
        for rep, figure_name in zip(reports, (FINAL_FIGURE, FINAL_FIGURE_REFERENCE)[: len(reports)], strict=True):
            atomic_write_text(stage / f"table1{rep.suffix}.csv", table_csv(rep.rows, rep.root))
            atomic_write_text(stage / f"per_run{rep.suffix}.csv", per_run_csv(rep.rows, rep.root))
            written.update({f"table1{rep.suffix}.csv", f"per_run{rep.suffix}.csv"})
            if rep.final:
                atomic_write_text(stage / f"final_table{rep.suffix}.csv", final_csv(rep.final, rep.root))
                atomic_write_text(stage / f"paired{rep.suffix}.csv", paired_csv(rep.final))
                written.update({f"final_table{rep.suffix}.csv", f"paired{rep.suffix}.csv"})
                if figures:
                    figure = plot_final(rep.final, stage / figure_name, f"Final evaluation: {rep.label}")
                    if figure is not None:  # rep.final has rows, so there is one
                        final_figures[rep.suffix] = figure
                        written.add(figure_name)
        curves = []
        for filename, title, methods in FIGURES if figures else ():
            path = plot_figure(reports[0].grid.records, methods, stage / filename, title, sigma)
            if path is not None:
                curves.append((title, path))
                written.add(filename)
        across = None
        if reports[0].final:
            pooled = list(reports[0].final) + [row for d in aggregate_runs for row in final_table(load_runs(d))]
            across = write_aggregate(pooled, stage, figures)
            if across is not None:
                written.update({ACROSS_CSV, ACROSS_FIGURE} if figures else {ACROSS_CSV})
        notes = link(discussion, out) if discussion is not None else None
        text = render_markdown(reports, curves, final_figures, references, command, int(window), notes, across,
                               copied)
        atomic_write_text(stage / "results.md", text)
        # The new report replaces the old one at once: an interruption leaves one or the other, never a mix.
        with deferred_signals():
            for name in sorted(written):
                os.replace(stage / name, out / name)
            for name in set(report_outputs()) - written:
                (out / name).unlink(missing_ok=True)  # an earlier report's file this one would contradict
    if readme is not None:
        update_readme(
            readme,
            _readme_text(reports, int(window), out / "results.md", readme),
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
    "per_run_csv",
    "paired_csv",
    "plot_figure",
    "plot_final",
    "report_outputs",
    "write_report",
    "fmt",
    "fmt_ci",
    "fmt_mean_std",
]
