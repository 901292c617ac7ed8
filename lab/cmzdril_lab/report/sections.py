"""The sections of results.md, one grid at a time, and the headline that sets grids side by side.

:func:`analyse` computes every table of one grid (a :class:`GridReport`); the ``*_sections``
functions render them as markdown; :func:`headline_markdown` puts each grid's final evaluation and
Table I beside a reference table (the paper's). :mod:`~cmzdril_lab.report` assembles them.
"""
from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from pathlib import Path

from cmzdril_lab.report.final_eval import (
    CONFIDENCE,
    MIN_TRIALS_FOR_CI,
    FinalRow,
    expert_by_env,
    final_markdown,
    final_table,
    find,
    fmt_cell,
    method_text,
    paired_markdown,
    trials_text,
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
def _table_one_cell(rows: Sequence[TableRow], env: str, method: str) -> str:
    row = next((r for r in rows if (r.env, r.method) == (env, method)), None)
    return "—" if row is None else f"{fmt_mean_std(row.mean('return'), row.std('return'))}, n={row.n_trials}"


def headline_markdown(reports: Sequence[GridReport], reference: ReferenceTable | None) -> str:
    """Return per env and method: each grid's final evaluation (mean [CI], trials) and its % of expert
    where it has one, each grid's Table I (mean (std), trials), and the reference's numbers; then the
    expert's return."""
    columns = []
    for rep in reports:
        if rep.final:
            columns.append(f"{rep.label}: final evaluation, mean [{100 * CONFIDENCE:g}% CI]")
            columns.append(f"{rep.label}: final evaluation, % of expert [{100 * CONFIDENCE:g}% CI]")
        columns.append(f"{rep.label}: Table I, mean (std)")
    if reference is not None:
        columns.append(f"{reference.name[:1].upper() + reference.name[1:]}, mean (std)")
    envs = sorted({r.env for rep in reports for r in rep.rows}, key=env_key)
    body = []
    for env in envs:
        methods = [m for m in METHOD_ORDER if any(r.method == m and r.env == env for rep in reports for r in rep.rows)]
        lines = [(m, "final") for m in methods]
        lines += [(m, result_policy(m)) for m in methods if result_policy(m) != "final"
                  and any(find(rep.final, env, m, result_policy(m)) for rep in reports)]
        if any(find(rep.final, env, "cmz", "lowest_u") for rep in reports):
            lines.append(("cmz", "lowest_u"))
        for method, policy in lines:
            cells = []
            for rep in reports:
                if rep.final:
                    row = find(rep.final, env, method, policy)
                    cells += [fmt_cell(row), fmt_cell(row, "pct_of_expert")]
                cells.append(_table_one_cell(rep.rows, env, method) if policy == "final" else "—")
            if reference is not None:
                paper = reference.values.get(env, {}).get(method) if policy == "final" else None
                cells.append(fmt_mean_std(*paper) if paper else "—")
            body.append([env, label(method, policy), *cells])
        cells = []
        for rep in reports:
            if rep.final:
                final_expert = expert_by_env(rep.final).get(env)
                cells.append("—" if final_expert is None else f"{fmt_ci(*final_expert[:3])}, n={final_expert[3]}")
                cells.append("—")  # the expert's % of itself says nothing
            expert = rep.experts.get(env)
            cells.append("—" if expert is None else f"{fmt_mean_std(*expert[:2])}, n={expert[2]}")
        body.append([env, "Expert (held-out demos)", *cells, *(["—"] if reference is not None else [])])
    return md_table(["Env", "Method", *columns], body)


def readme_markdown(rep: GridReport) -> str:
    """The README's headline, small enough for a README: one row per env, one column per method, each
    cell the final evaluation's % of the expert (mean over trials [CI]) of the method's result
    (:func:`result_policy`), then CMZ-DRIL's lowest-u policy. A grid without a final evaluation
    gets Table I's mean (std) return of the training's last weights."""
    envs = sorted({r.env for r in rep.rows}, key=env_key)
    methods = [m for m in METHOD_ORDER if any(r.method == m for r in rep.rows)]
    columns: list[tuple[str, str]] = [(m, result_policy(m) if rep.final else "final") for m in methods]
    if rep.final and any(r.method == "cmz" and r.policy == "lowest_u" for r in rep.final):
        columns.append(("cmz", "lowest_u"))
    body = []
    for env in envs:
        cells = []
        for method, policy in columns:
            if rep.final:
                row = find(rep.final, env, method, policy)
                cells.append("—" if row is None else fmt_ci(*row.stat("pct_of_expert")))
            else:
                table_row = next((r for r in rep.rows if (r.env, r.method) == (env, method)), None)
                cells.append("—" if table_row is None
                             else fmt_mean_std(table_row.mean("return"), table_row.std("return")))
        body.append([env, *cells])
    header = [label(m, p) for m, p in columns]
    return md_table(["Env", *header], body)


def readme_text(rep: GridReport, window: int) -> str:
    """What :func:`readme_markdown`'s cells are, in words."""
    if not rep.final:
        return (f"The env's true return of each run's per-epoch evaluation averaged over its last {window} epochs, "
                "mean (population std) over trials.")
    return ("Final evaluation, % of the expert: 100 times a run's mean return over the expert's on the same "
            "held-out episodes (every pool episode the run did not train on), mean over "
            f"{trials_text(rep.final)} trials [{100 * CONFIDENCE:g}% bootstrap CI over trials]; the final policy of "
            f"each method{_result_clause(rep.final)}, and \"(lowest u)\": the CMZ-DRIL policy whose own training "
            "rollout had the lowest ensemble disagreement (chosen without the env reward).")


def _result_clause(rows: Sequence[FinalRow]) -> str:
    """How the methods among ``rows`` whose result is not their last weights choose it, in words."""
    chosen = [m for m in METHOD_ORDER if result_policy(m) == "longest" and any(r.method == m for r in rows)]
    if not chosen:
        return ""
    return (f" (for {', '.join(METHOD_LABELS[m] for m in chosen)}: its policy whose deterministic episodes from "
            "fixed starts lasted longest, or where the expert ends its episodes itself as long as its "
            "demonstrations, chosen without the env reward)")


def headline_text(reports: Sequence[GridReport], reference: ReferenceTable | None, window: int) -> str:
    """What the headline's columns are, in words."""
    parts = [f"The env's true return. Table I: each run's per-epoch evaluation (eval.csv) averaged over its last "
             f"{window} epochs, mean (population std) over trials, n = trials."]
    if any(rep.final for rep in reports):
        parts.append("Final evaluation: each run's policy on every pool episode not used for training "
                     f"(final_eval.csv), mean over trials [{100 * CONFIDENCE:g}% bootstrap CI over trials; n/a with "
                     f"fewer than {MIN_TRIALS_FOR_CI} trials]; \"(lowest u)\": the policy whose own training rollout "
                     "had the lowest ensemble disagreement (chosen without the env reward); % of expert: 100 times a "
                     "run's mean return over the expert's mean return on the same held-out episodes, mean over "
                     "trials [CI as above; n/a where the expert's mean return is not positive].")
    missing = [rep.label for rep in reports if not rep.final]
    if missing:
        parts.append(f"{', '.join(missing)}: no final evaluation (its runs have no final_eval.csv).")
    if reference is not None:
        parts.append(f"{reference.name[:1].upper() + reference.name[1:]}: copied from the paper (its own envs: "
                     + ", ".join(f"{PAPER_ENV_NAMES[e]} for {e}" for e in sorted(PAPER_ENV_NAMES, key=env_key))
                     + "), not produced by this code.")
    return " ".join(parts)


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
    """Return in the paper's layout (methods as rows, envs as columns) with the expert's return."""
    envs = sorted({r.env for r in rep.rows}, key=env_key)
    methods = [m for m in METHOD_ORDER if any(r.method == m for r in rep.rows)]
    cells = {(r.env, r.method): fmt_mean_std(r.mean("return"), r.std("return")) for r in rep.rows}
    body = [[METHOD_LABELS[m], *(cells.get((e, m), "—") for e in envs)] for m in methods]
    if rep.experts:
        body.append(["Expert (held-out demos)",
                     *(fmt_mean_std(*rep.experts[e][:2]) if e in rep.experts else "—" for e in envs)])
    return md_table(["Method", *envs], body)


def final_sections(rep: GridReport, h: str, figure: Path | None) -> list[str]:
    """The final evaluation of one grid: the table, the paired comparisons, the figure."""
    if not rep.final:
        return [f"{h} Final evaluation", "", "None: no run of this grid has a final_eval.csv (grids made before the "
                "final evaluation existed have none; a run writes it when it finishes).", ""]
    parts = [f"{h} Final evaluation (trials per cell: {trials_text(rep.final)})", "", method_text(), "",
             final_markdown(rep.final), ""]
    if all(r.method == "bc" for r in rep.final):
        parts += ["No RL run has a final evaluation yet: nothing to compare with BC.", ""]
    else:
        parts += ["Paired by trial (a trial's methods share the seed, the demo split and the held-out episodes): "
                  "in how many trials each policy's mean return is above BC's (and, for CMZ-DRIL, above no reward's "
                  "with the same learner and policy choice: CMZ-DRIL (SAC) against No reward (SAC)), and the mean "
                  "difference with its bootstrap CI. For the lowest-u "
                  "policies, the epoch each trial's choice came from (done.json).", "", paired_markdown(rep.final), ""]
    if figure is not None:
        parts += [f"![Final evaluation: {rep.label}]({figure.name})", ""]
    return parts


def _percent(share: float | None) -> str:
    return "n/a" if share is None else f"{100 * share:.0f}%"


def table_sections(rep: GridReport, h: str, window: int) -> list[str]:
    """Table I, the gap closed by CMZ-DRIL and the reward signal of one grid."""
    rows, experts = rep.rows, rep.experts
    gaps = gap_closed(rows)
    parts = [
        f"{h} Table I", "",
        f"Mean (std over trials) of each run's evaluation metric averaged over its last {window} epochs (all epochs "
        "if it has fewer; BC: its single evaluation of the pretrained policy, at epoch 0). An evaluation replays the "
        f"starts of the trial's held-out expert episodes ({_eval_episodes(rep.grid.records)} per trial) with the "
        "deterministic policy: return is the true env return, Fréchet the discrete Fréchet distance to the "
        "expert's path, action MSE the squared error of the policy's actions on the expert's observations. std is "
        "the population std (ddof=0).", "",
        md_table(["Env", "Method", "Trials", *(label for _, label, _ in METRICS)],
                 ([r.env, METHOD_LABELS[r.method], str(r.n_trials),
                   *(fmt_mean_std(r.mean(k), r.std(k)) for k, _, _ in METRICS)] for r in rows)), "",
        "Return only, in the paper's layout" + (
            ", with the expert's return on the same held-out episodes for scale (mean (std) over trials of each "
            "trial's mean; from the demo pool each run's config.json names):" if experts else ":"), "",
        _paper_layout(rep), "",
        f"{h} Gap closed by CMZ-DRIL", "",
        "(CMZ-DRIL - no reward) / (env. reward - no reward) of the Table I means, over the trials that all three "
        "methods have (Trials): 0 = no better than PPO+BC without "
        "reward, 1 = as good as training on the true reward (the paper: about 50% for the reward). For Fréchet "
        "distance and action MSE, where lower is better, the same ratio measures how far CMZ-DRIL moves from no "
        "reward toward env. reward.", "",
        md_table(["Env", "Trials", *(label for _, label, _ in METRICS)],
                 ([env, str(len(trials)),
                   *(_percent(gaps[env][k]) for k, _, _ in METRICS)]
                  for env, trials in gap_trials(rows).items())), "",
    ]
    if rep.signal:
        ordered = sorted(rep.signal.items(), key=lambda kv: (env_key(kv[0][0]), METHOD_ORDER.index(kv[0][1])))
        parts += [
            f"{h} The reward signal during training", "",
            f"From each run's SB3 progress log (`logs/progress_*.csv`): the rollout statistics averaged over its "
            f"first and last {SIGNAL_EPOCHS} PPO updates, then over trials. u is the ensemble disagreement of the "
            "states the agent visited (the same for every method: it is logged even where it is not the reward), "
            "shaped is the mean reward the wrapper gave (CMZ-DRIL: -alpha (u - ubar), which should stay near 0; "
            "DRIL: +1/-1; 0 for no reward), ubar the CMZ-DRIL EMA, length the training episodes' mean length.", "",
            md_table(["Env", "Method", "Trials", "u first → last", "shaped first → last", "ubar first → last",
                      "length first → last"],
                     ([env, METHOD_LABELS[method], str(int(cell["trials"][0])),
                       *(f"{fmt(cell[k][0])} → {fmt(cell[k][1])}" for k in ("u", "shaped", "ubar", "ep_len"))]
                      for (env, method), cell in ordered)), "",
        ]
    return parts


def _run_line(run: RunRecord, root: Path, table_value: float) -> str:
    text = (f"`{run.relative(root)}` ({run.status}, epochs {int(run.columns['epoch'][0])}-"
            f"{int(run.columns['epoch'][-1])}, Table I return {fmt(table_value)}")
    for policy, name in (("final", "final"), ("lowest_u", "lowest u")):
        if policy in run.final:
            values = run.final[policy]
            text += f", {name} {fmt(float(values['return'].mean()))} over {values['episode'].size} episodes"
    return text + ")"


def sources_sections(rep: GridReport, heading: str = "") -> list[str]:
    """The runs behind each number and the commands that made them, under ``heading`` if one is given."""
    parts = [heading, ""] if heading else []
    parts += ["Each (env, method) cell averages these runs; beside each run, the epochs it reached, its own return "
             "over the Table I window (eval.csv) and its final evaluation's mean return (final_eval.csv).", ""]
    for r in rep.rows:
        lines = (_run_line(run, rep.root, v) for run, v in zip(r.runs, r.per_run["return"], strict=True))
        parts.append(f"- {r.env} / {METHOD_LABELS[r.method]}: " + ", ".join(lines))
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
