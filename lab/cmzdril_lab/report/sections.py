"""The sections of results.md: the headline, each grid's per-task tables, how to read them, their sources.

:func:`analyse` computes every table of one grid (a :class:`GridReport`); :func:`headline_markdown`
gives the main grid's answer in one short table (% of the expert, env by method: also the README's);
the ``*_sections`` functions render the per-task tables and the sources, each with a sentence under it;
:func:`how_to_read` says how every number is made. :mod:`~cmzdril_lab.report` assembles them.
"""
from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from pathlib import Path

from cmzdril_lab.report.figures import SMOOTHING_SIGMA
from cmzdril_lab.report.final_eval import (
    CONFIDENCE,
    FinalRow,
    final_table,
    final_wide_markdown,
    find,
    method_text,
    trials_text,
    wins_markdown,
)
from cmzdril_lab.report.formatting import fmt, fmt_ci, fmt_mean_std, md_table
from cmzdril_lab.report.paper import PAPER_ENV_NAMES, ReferenceTable
from cmzdril_lab.report.readme import short_command
from cmzdril_lab.report.records import (
    METHOD_LABELS,
    METHOD_ORDER,
    Grid,
    RunRecord,
    env_key,
    label,
    relative,
    result_policy,
    setting_differences,
)
from cmzdril_lab.report.tables import (
    METRICS,
    SIGNAL_EPOCHS,
    TableRow,
    expert_returns,
    gap_closed,
    gap_trials,
    reward_signal,
    table_one,
)
from sb3_cmzdril.io import read_json_or_empty
from sb3_cmzdril.training.run_folder import ERROR_FILE, STATE_FILE, run_status


@dataclasses.dataclass
class GridReport:
    """A grid and every table computed from it."""

    grid: Grid
    suffix: str  #: "" for the main grid, "_reference" for the reference grid (output file names)
    rows: list[TableRow]  #: Table I
    final: list[FinalRow]
    experts: dict[str, tuple[float, float, int]]  #: the expert's return on the eval.csv episodes
    signal: dict[tuple[str, str], dict[str, tuple[float, float]]]

    @property
    def label(self) -> str:
        return self.grid.label

    @property
    def root(self) -> Path:
        return self.grid.root


def analyse(grid: Grid, window: int, suffix: str = "") -> GridReport:
    """Every table of one grid."""
    rows = table_one(grid.records, window)
    return GridReport(grid, suffix, rows, final_table(grid.records), expert_returns(grid.records, grid.root),
                      reward_signal(grid.records))


# -- the headline ---------------------------------------------------------------------------------------
def headline_markdown(rep: GridReport) -> str:
    """The headline, small enough for a README: one row per env, one column per method, each cell the
    final evaluation's % of the expert (mean over trials [CI]) of the method's result
    (:func:`result_policy`), then CMZ-DRIL's lowest-u policy; where cells differ in their trials, the
    trials too. A grid without a final evaluation gets Table I's mean (std) return of the training's
    last weights."""
    envs = sorted({r.env for r in rep.rows}, key=env_key)
    methods = [m for m in METHOD_ORDER if any(r.method == m for r in rep.rows)]
    columns: list[tuple[str, str]] = [(m, result_policy(m) if rep.final else "final") for m in methods]
    if rep.final and any(r.method == "cmz" and r.policy == "lowest_u" for r in rep.final):
        columns.append(("cmz", "lowest_u"))
    shown = [r for r in rep.final if (r.method, r.policy) in columns]
    varies = len({r.n_trials for r in shown} if rep.final else {r.n_trials for r in rep.rows}) > 1
    body = []
    for env in envs:
        cells = []
        for method, policy in columns:
            if rep.final:
                row = find(rep.final, env, method, policy)
                cells.append("—" if row is None else _trials(fmt_ci(*row.stat("pct_of_expert")), row.n_trials, varies))
            else:
                table_row = next((r for r in rep.rows if (r.env, r.method) == (env, method)), None)
                cells.append("—" if table_row is None else _trials(
                    fmt_mean_std(table_row.mean("return"), table_row.std("return")), table_row.n_trials, varies))
        body.append([env, *cells])
    header = [label(m, p) for m, p in columns]
    return md_table(["Env", *header], body)


def _trials(cell: str, n: int, varies: bool) -> str:
    """A cell, with its number of trials where the table's cells differ in it."""
    return f"{cell}, n={n}" if varies else cell


def headline_text(rep: GridReport, window: int, source: str, details: str) -> str:
    """What :func:`headline_markdown`'s cells are, in two sentences: ``source`` names the runs, ``details``
    (a link) where the rest is."""
    if not rep.final:
        return (f"{source}: the env's true return of each run's per-epoch evaluation averaged over its last "
                f"{window} epochs, mean (population std) over trials; no run has a final evaluation yet. "
                f"Details in {details}.")
    chosen = [METHOD_LABELS[m] for m in METHOD_ORDER
              if result_policy(m) == "longest" and any(r.method == m for r in rep.final)]
    choices = []
    if len(chosen) == 1:
        choices.append(f"{chosen[0]} is its policy whose episodes lasted longest")
    elif chosen:
        choices.append(f"{', '.join(chosen[:-1])} and {chosen[-1]} are their policies whose episodes lasted longest")
    if any(r.method == "cmz" and r.policy == "lowest_u" for r in rep.final):
        choices.append("CMZ-DRIL (lowest u) is CMZ-DRIL's policy of lowest ensemble disagreement")
    which = f"; {' and '.join(choices)}, chosen without the env reward" if choices else ""
    return (f"{source}, final evaluation: each policy's return as % of the expert's on the same held-out episodes, "
            f"mean over {trials_text(rep.final)} trials [{100 * CONFIDENCE:g}% bootstrap CI]. A column is the "
            f"method's last weights{which}; details in {details}.")


def differences_markdown(a: GridReport, b: GridReport) -> str:
    """The settings whose values differ between the two grids' runs, from their config.json."""
    diffs = setting_differences(a.grid.records, b.grid.records)
    if not diffs:
        return f"The runs' config.json record the same settings in {a.label} and {b.label}."
    lines = [f"Settings that differ between the grids (from the runs' config.json: {a.label} vs {b.label}):", ""]
    for env, items in diffs.items():
        lines.append(f"- {env}: " + "; ".join(f"`{k}` {va} vs {vb}" for k, va, vb in items))
    return "\n".join(lines)


# -- one grid's sections ----------------------------------------------------------------------------------
def _eval_episodes(records: Sequence[RunRecord]) -> str:
    counts = sorted({int(r.columns["n_episodes"][-1]) for r in records})
    return " or ".join(map(str, counts))


def _paper_layout(rep: GridReport) -> str:
    """Return in the paper's layout (methods as rows, envs as columns) with the expert's return; where
    cells differ in their trials, the trials too."""
    envs = sorted({r.env for r in rep.rows}, key=env_key)
    methods = [m for m in METHOD_ORDER if any(r.method == m for r in rep.rows)]
    varies = len({r.n_trials for r in rep.rows}) > 1
    cells = {(r.env, r.method): _trials(fmt_mean_std(r.mean("return"), r.std("return")), r.n_trials, varies)
             for r in rep.rows}
    body = [[METHOD_LABELS[m], *(cells.get((e, m), "—") for e in envs)] for m in methods]
    if rep.experts:
        body.append(["Expert (held-out demos)", *(_trials(fmt_mean_std(*rep.experts[e][:2]), rep.experts[e][2], varies)
                                                  if e in rep.experts else "—" for e in envs)])
    return md_table(["Method", *envs], body)


def final_sections(rep: GridReport, h: str, figure: Path | None) -> list[str]:
    """The final evaluation of one grid: the returns, the wins over the baselines, the figure (``figure``:
    where the headline does not show it already)."""
    if not rep.final:
        return ["No final evaluation: no run of this grid has a final_eval.csv (grids made before the final "
                "evaluation existed have none; a run writes it when it finishes).", ""]
    parts = [f"{h} Final evaluation (trials per cell: {trials_text(rep.final)})", "", final_wide_markdown(rep.final),
             "", f"Return on the held-out episodes, mean over trials [{100 * CONFIDENCE:g}% CI]. Every policy's % of "
             "the expert, Fréchet distance, action MSE and episodes at expert level, with the episodes per trial: "
             f"[final_table{rep.suffix}.csv](final_table{rep.suffix}.csv).", ""]
    if all(r.method == "bc" for r in rep.final):
        parts += ["No RL run has a final evaluation yet: nothing to compare with BC.", ""]
    else:
        parts += [wins_markdown(rep.final), "",
                  "Trials in which the policy's mean return is above the baseline's, on the same seed, demo split and "
                  "held-out episodes. Every policy's comparisons, the mean differences with their CIs and the epoch "
                  f"of each reward-free choice: [paired{rep.suffix}.csv](paired{rep.suffix}.csv).", ""]
    if figure is not None:
        parts += [f"![Final evaluation: {rep.label}]({figure.name})", ""]
    return parts


def _percent(share: float | None) -> str:
    return "n/a" if share is None else f"{100 * share:.0f}%"


def table_sections(rep: GridReport, h: str, window: int,
                   figures: Sequence[tuple[str, Path]] = ()) -> list[str]:
    """Table I (and ``figures``, its curves), the gap closed by CMZ-DRIL and the reward signal of one grid."""
    rows = rep.rows
    gaps = gap_closed(rows)
    counts = sorted({r.n_trials for r in rows})
    over = str(counts[0]) if len(counts) == 1 else f"{counts[0]}-{counts[-1]}"
    parts = [
        f"{h} Table I", "",
        _paper_layout(rep), "",
        f"Return of the per-epoch evaluations averaged over each run's last {window} epochs, mean (std) over "
        f"{over} trials" + (" (the expert: on the same held-out episodes)" if rep.experts else "")
        + f". Fréchet distance and action MSE: [table1{rep.suffix}.csv](table1{rep.suffix}.csv).", "",
        *(line for title, path in figures for line in (f"![{title}]({path.name})", "")),
        f"{h} Gap closed by CMZ-DRIL", "",
        md_table(["Env", "Trials", *(label for _, label, _ in METRICS)],
                 ([env, str(len(trials)),
                   *(_percent(gaps[env][k]) for k, _, _ in METRICS)]
                  for env, trials in gap_trials(rows).items())), "",
        "(CMZ-DRIL − no reward) / (env. reward − no reward) of the Table I means: 0% is no better than no reward, "
        "100% as good as the true reward.", "",
    ]
    if rep.signal:
        ordered = sorted(rep.signal.items(), key=lambda kv: (env_key(kv[0][0]), METHOD_ORDER.index(kv[0][1])))
        parts += [
            f"{h} The reward signal during training", "",
            md_table(["Env", "Method", "Trials", "u first → last", "shaped first → last", "ubar first → last",
                      "length first → last"],
                     ([env, METHOD_LABELS[method], str(int(cell["trials"][0])),
                       *(f"{fmt(cell[k][0])} → {fmt(cell[k][1])}" for k in ("u", "shaped", "ubar", "ep_len"))]
                      for (env, method), cell in ordered)), "",
            f"The first and last {SIGNAL_EPOCHS} PPO updates' ensemble disagreement u, shaped reward, its average "
            "ubar and episode length, mean over trials (`logs/progress_*.csv`).", "",
        ]
    return parts


def how_to_read(reports: Sequence[GridReport], reference: ReferenceTable | None, window: int,
                across: str | None, curves: bool) -> list[str]:
    """How every number of the page is made, one paragraph a table."""
    episodes = {rep.label: _eval_episodes(rep.grid.records) for rep in reports}
    per_trial = (next(iter(episodes.values())) if len(set(episodes.values())) == 1
                 else "; ".join(f"{name}: {n}" for name, n in episodes.items()))
    parts = ["## How to read", ""]
    if any(rep.final for rep in reports):
        parts += [
            f"- **Final evaluation** (the headline, its figure and the per-task tables): {_lower(method_text())}",
            "- **Paired by trial**: a trial's methods share the seed, the demo split and the held-out episodes. The "
            "table counts in how many trials each policy's mean return is above BC's (and, for CMZ-DRIL, above no "
            "reward's with the same learner and policy choice: CMZ-DRIL (SAC) against No reward (SAC)); the CSV adds "
            "the mean difference with its bootstrap CI and, for the reward-free choices, the epoch each trial's "
            "choice came from (done.json).",
        ]
    parts += [
        f"- **Table I**: mean (std over trials) of each run's evaluation metric averaged over its last {window} epochs "
        "(all epochs if it has fewer; BC: its single evaluation of the pretrained policy, at epoch 0). An evaluation "
        f"replays the starts of the trial's held-out expert episodes ({per_trial} per trial) with the deterministic "
        "policy: return is the true env return, Fréchet the discrete Fréchet distance to the expert's path, action "
        "MSE the squared error of the policy's actions on the expert's observations. std is the population std "
        "(ddof=0). The expert's return: mean (std) over trials of each trial's mean on the same held-out episodes, "
        "from the demo pool each run's config.json names.",
        "- **Gap closed by CMZ-DRIL**: (CMZ-DRIL - no reward) / (env. reward - no reward) of the Table I means, "
        "over the trials that all three methods have (Trials): 0 = no better than PPO+BC without reward, 1 = as "
        "good as training on the true reward (the paper: about 50% for the reward). For Fréchet distance and action "
        "MSE, where lower is better, the same ratio measures how far CMZ-DRIL moves from no reward toward env. "
        "reward. n/a where the env. reward does no better than no reward: there is no gap to close.",
        f"- **The reward signal**: from each run's SB3 progress log (`logs/progress_*.csv`): the rollout statistics "
        f"averaged over its first and last {SIGNAL_EPOCHS} PPO updates, then over trials. u is the ensemble "
        "disagreement of the states the agent visited (the same for every method: it is logged even where it is not "
        "the reward), shaped is the mean reward the wrapper gave (CMZ-DRIL: -alpha (u - ubar), which should stay "
        "near 0; DRIL: +1/-1; 0 for no reward), ubar the CMZ-DRIL EMA, length the training episodes' mean length.",
    ]
    if across:
        parts.append(f"- **Across tasks**: {_lower(across)}")
    if curves:
        parts.append("- **Fig. 1 and 2**: one row per env, one column per metric against the epoch; each trial's "
                     f"curve is smoothed with a Gaussian filter (sigma {SMOOTHING_SIGMA:g} evaluations), then the line "
                     "is the mean over trials and the band ±1 std. BC (evaluated once) is the dashed horizontal line "
                     "with its ±1 std band.")
    if reference is not None:
        parts.append(f"- **{reference.name[:1].upper() + reference.name[1:]}**: copied from the paper (its own envs: "
                     + ", ".join(f"{PAPER_ENV_NAMES[e]} for {e}" for e in sorted(PAPER_ENV_NAMES, key=env_key))
                     + "), not produced by this code.")
    return [*parts, ""]


def _lower(text: str) -> str:
    return text[:1].lower() + text[1:]


def source_line(rep: GridReport, curves: bool) -> str:
    """The files of one grid that the page reads, and what each gives."""
    records = rep.grid.records
    n_final = sum(bool(r.final) for r in records)
    return (
        f"`{rep.root}`, {len(records)} runs: their `eval.csv` ({'Table I and Fig. 1/2' if curves else 'Table I'}), "
        f"`final_eval.csv` (the final evaluation; {n_final} of the {len(records)} runs have one), `done.json` (the "
        "epoch of each lowest-u policy), `logs/progress_*.csv` (the reward signal) and the demo pools their "
        "`config.json` names (the expert's return in Table I)."
    )


def _spans(values: Sequence[int]) -> str:
    """0, 1, 2, 3, 5 as "0-3, 5"."""
    spans: list[list[int]] = []
    for v in sorted(values):
        if spans and v == spans[-1][1] + 1:
            spans[-1][1] = v
        else:
            spans.append([v, v])
    return ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in spans)


def _runs_lines(rows: Sequence[TableRow], root: Path) -> list[str]:
    """The runs of a grid, a line per set of envs with the same methods and trials (the methods with the
    same trials together), then any run whose folder is not ``<env>/<method>/trial<t>``."""
    by_env: dict[str, dict[str, list[str]]] = {}
    elsewhere = []
    for r in sorted(rows, key=lambda r: (env_key(r.env), METHOD_ORDER.index(r.method))):
        by_env.setdefault(r.env, {}).setdefault(_spans([run.trial for run in r.runs]), []).append(f"`{r.method}`")
        elsewhere += [f"`{run.relative(root)}`" for run in r.runs
                      if Path(run.relative(root)).as_posix() != f"{r.env}/{r.method}/trial{run.trial}"]
    envs: dict[str, list[str]] = {}
    for env, by_trials in by_env.items():
        text = "; ".join(f"{', '.join(methods)} trials {trials}" for trials, methods in by_trials.items())
        envs.setdefault(text, []).append(env)
    lines = [f"- {', '.join(names)}: {text}" for text, names in envs.items()]
    return lines + ([f"- in other folders: {', '.join(elsewhere)}"] if elsewhere else [])


def sources_sections(rep: GridReport, heading: str = "", curves: bool = False) -> list[str]:
    """The runs behind each number and the commands that made them, under ``heading`` if one is given."""
    parts = [heading, ""] if heading else []
    parts += [f"From {source_line(rep, curves)} Each (env, method) averages the runs "
              f"`<env>/<method>/trial<t>` below `{rep.root}`; each run's status, epochs, Table I return and final "
              f"returns are in [per_run{rep.suffix}.csv](per_run{rep.suffix}.csv).", ""]
    parts += _runs_lines(rep.rows, rep.root)
    created, resumed = _commands(rep.grid.records, rep.root)
    parts += ["", "Runs created by:", ""] + ([f"    {short_command(c)}" for c in created] or ["    (not recorded)"])
    if resumed:
        parts += ["", "Also run (resumes, other invocations):", ""] + [f"    {short_command(c)}" for c in resumed]
    return parts + [""]


def _commands(records: Sequence[RunRecord], root: Path) -> tuple[list[str], list[str]]:
    """(commands that created the runs, other commands that resumed them), each listed once."""
    created = list(dict.fromkeys(str(r.config["command"]) for r in records if r.config.get("command")))
    resumed: list[str] = []

    def add(command: str | None) -> None:
        if command and command not in created and command not in resumed:
            resumed.append(str(command))

    for r in records:
        for segment in read_json_or_empty(r.path / STATE_FILE).get("segments", [])[1:]:
            add(segment.get("command"))
    log = root / "benchmark.jsonl"
    if log.is_file():
        for line in log.read_text(encoding="utf-8").splitlines():
            try:
                add(json.loads(line).get("command"))
            except (ValueError, AttributeError):
                continue
    return created, resumed


def status_lines(rep: GridReport) -> list[str]:
    """Unfinished runs, runs that failed before any evaluation and whatever the report left out, with
    the reason (none of them may vanish silently)."""
    records, root = rep.grid.records, rep.root
    unfinished = [r for r in records if r.status != "done"]
    listed = {r.path for r in records} | {s.path for s in rep.grid.skipped}
    failed = sorted(p.parent for p in root.rglob(ERROR_FILE)
                    if p.parent not in listed and run_status(p.parent) == "failed")
    parts = []
    if unfinished:
        parts += ["", f"**{rep.label}: {len(unfinished)} run(s) are not finished** (their numbers use the epochs they "
                  "reached; they have no final evaluation yet): "
                  + ", ".join(f"`{r.relative(root)}` ({r.status})" for r in unfinished)]
    if failed:
        parts += ["", f"**{rep.label}: {len(failed)} run(s) failed without any evaluation** (see their error.txt): "
                  + ", ".join(f"`{relative(p, root)}`" for p in failed)]
    if rep.grid.skipped:
        parts += ["", f"**{rep.label}: left out** (a run counts by its config.json, once per trial): "
                  + "; ".join(f"`{relative(s.path, root)}` ({s.reason})" for s in rep.grid.skipped)]
    return parts
