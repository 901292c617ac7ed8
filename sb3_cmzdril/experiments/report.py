"""Table I and Figures 1-2 of the paper, computed from the runs' eval.csv files.

* :func:`load_runs` finds every ``<RUNS_DIR>/<EnvName>/<method>/trial<t>/eval.csv`` (env, method and
  trial come from the run's config.json when there is one, else from the path).
* :func:`table_one` — per env and method: mean (std over trials) of each run's evaluation return,
  Fréchet distance and action MSE averaged over its last 100 epochs (all of them if fewer; BC has
  one evaluation, at epoch 0). The std is the population std (numpy's ddof=0) over trials.
* :func:`gap_closed` — (cmz - zero) / (env - zero) per env and metric: how much of the gap between
  "no reward" and the true env reward CMZ-DRIL closes (the paper: about 50% for the reward).
* :func:`plot_figure` — one row per env, one column per metric (reward, Fréchet distance, action
  MSE) against the epoch; each trial's curve smoothed with a Gaussian filter (sigma 2 evaluations,
  ``scipy.ndimage.gaussian_filter1d``, as the paper), then the mean over trials with a ±1 std band.
  BC, evaluated once, is a horizontal line (mean over trials, ±1 std band).
* :func:`expert_returns` — per env, the true return of the expert's held-out episodes that each
  trial was evaluated against (from the demo pool named in the run's config.json): the scale.
* :func:`reward_signal` — per env and method, what the runs' SB3 progress logs say about the shaped
  reward: mean disagreement u over the first and last epochs, shaped reward and EMA, episode length.
* :func:`write_report` — results.md, table1.csv, fig1_bc_dril_cmz.png, fig2_cmz_env_zero.png.

Reference numbers from elsewhere (the paper's Table I: :data:`PAPER_TABLE_I`) enter only through
``references`` and are printed as separate, labelled tables: never mixed with measured numbers.
"""
from __future__ import annotations

import csv
import dataclasses
import hashlib
import io
import json
import math
import os
import re
import time
from pathlib import Path
from typing import Any, Dict, Iterable, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from sb3_cmzdril._atomic import PathLike, atomic_path, atomic_write_text
from sb3_cmzdril.demos import Demonstrations
from sb3_cmzdril.experiments.runs import (
    CONFIG_FILE,
    ERROR_FILE,
    EVAL_CSV,
    METHODS,
    STATE_FILE,
    TABLE_WINDOW,
    read_eval_csv,
    run_status,
    window_means,
)

#: How methods are named in tables and legends (the paper's names).
METHOD_LABELS: Dict[str, str] = {
    "bc": "BC",
    "dril": "DRIL",
    "cmz": "CMZ-DRIL",
    "zero": "No reward",
    "env": "Env. reward",
}
#: Row order of the tables: the paper's Table I first, then Fig. 2's extra methods.
METHOD_ORDER: Tuple[str, ...] = ("bc", "dril", "cmz", "zero", "env")
#: Column order of envs: the paper's (PyUXV, Half Cheetah, Hopper); others follow alphabetically.
ENV_ORDER: Tuple[str, ...] = ("WaypointNav-v0", "HalfCheetah-v5", "Hopper-v5")
#: Table metrics: (key in window_means, column header, eval.csv column).
METRICS: Tuple[Tuple[str, str, str], ...] = (
    ("return", "Return", "return_mean"),
    ("frechet", "Fréchet distance", "frechet_mean"),
    ("action_mse", "Action MSE", "action_mse"),
)
#: The paper's figures: which methods each compares.
FIGURES: Tuple[Tuple[str, str, Tuple[str, ...]], ...] = (
    ("fig1_bc_dril_cmz.png", "Fig. 1: CMZ-DRIL, BC and DRIL", ("bc", "dril", "cmz")),
    ("fig2_cmz_env_zero.png", "Fig. 2: CMZ-DRIL, env. reward and no reward", ("cmz", "env", "zero")),
)
SMOOTHING_SIGMA = 2.0
_COLORS = {"bc": "tab:gray", "dril": "tab:orange", "cmz": "tab:blue", "zero": "tab:red", "env": "tab:green"}


@dataclasses.dataclass(frozen=True)
class ReferenceTable:
    """Numbers reported elsewhere, keyed ``env -> method -> (mean, std)``, shown in their own table."""

    title: str
    note: str
    values: Mapping[str, Mapping[str, Tuple[float, float]]]


#: The paper's Table I: mean (std) reward over the last 100 training epochs, 5 trials, one demo
#: episode for the MuJoCo envs (v1, mujoco-py) and five for PyUXV. Our envs stand in for theirs.
PAPER_TABLE_I = ReferenceTable(
    title="The paper's Table I (reported numbers, copied from the paper, not produced by this code)",
    note=(
        "Mean (std) reward over the last 100 training epochs. The paper's envs: PyUXV (our stand-in: "
        "WaypointNav-v0), MuJoCo Half Cheetah and Hopper version 1 (we run -v5); DRIL was not tested on PyUXV."
    ),
    values={
        "WaypointNav-v0": {"bc": (-52.6, 45.0), "cmz": (-34.8, 29.4)},
        "HalfCheetah-v5": {"bc": (708.0, 162.0), "dril": (277.0, 60.9), "cmz": (1690.0, 360.0)},
        "Hopper-v5": {"bc": (704.0, 248.0), "dril": (244.0, 23.0), "cmz": (1140.0, 514.0)},
    },
)


# -- loading ------------------------------------------------------------------------------------------
@dataclasses.dataclass
class RunRecord:
    """One run's evaluation history and where it came from."""

    env: str  #: env name without module prefix
    method: str
    trial: int
    path: Path  #: the run folder
    columns: Dict[str, np.ndarray]  #: eval.csv as columns, sorted by epoch
    status: str  #: done / partial / failed / new (see runs.run_status)
    config: Dict[str, Any]

    def relative(self, root: Path) -> str:
        return _relative(self.path, root)


def _relative(path: Path, root: Path) -> str:
    try:
        return str(path.relative_to(root))
    except ValueError:
        return str(path)


_TRIAL = re.compile(r"^trial(\d+)$")


def _read_json_or_empty(path: Path) -> Dict[str, Any]:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}


def load_runs(runs_dir: PathLike) -> List[RunRecord]:
    """Every run below ``runs_dir`` with at least one evaluation row, sorted by env, method, trial."""
    root = Path(runs_dir)
    if not root.is_dir():
        raise FileNotFoundError(f"runs folder not found: {root}")
    records = []
    for csv_path in sorted(root.rglob(EVAL_CSV)):
        folder = csv_path.parent
        config = _read_json_or_empty(folder / CONFIG_FILE)
        match = _TRIAL.match(folder.name)
        env = config.get("env_name") or folder.parent.parent.name
        method = config.get("method") or folder.parent.name
        trial = config.get("seed", int(match.group(1)) if match else None)
        if method not in METHODS or trial is None:
            continue  # not a run of the grid's layout
        columns = read_eval_csv(csv_path)
        if columns["epoch"].size == 0:
            continue
        records.append(RunRecord(env, method, int(trial), folder, columns, run_status(folder), config))
    return sorted(records, key=lambda r: (_env_key(r.env), METHOD_ORDER.index(r.method), r.trial))


def _env_key(env: str) -> Tuple[int, str]:
    return (ENV_ORDER.index(env), env) if env in ENV_ORDER else (len(ENV_ORDER), env)


def _group(records: Iterable[RunRecord]) -> Dict[Tuple[str, str], List[RunRecord]]:
    groups: Dict[Tuple[str, str], List[RunRecord]] = {}
    for r in records:
        groups.setdefault((r.env, r.method), []).append(r)
    return groups


# -- Table I ---------------------------------------------------------------------------------------------
@dataclasses.dataclass
class TableRow:
    """One (env, method) cell group of Table I."""

    env: str
    method: str
    runs: List[RunRecord]
    per_run: Dict[str, List[float]]  #: metric -> each run's window mean, in run order
    window: int

    @property
    def n_trials(self) -> int:
        return len(self.runs)

    def mean(self, metric: str) -> float:
        return float(np.mean(self.per_run[metric]))

    def std(self, metric: str) -> float:
        return float(np.std(self.per_run[metric]))  # population std over trials (ddof=0)


def table_one(records: Sequence[RunRecord], window: int = TABLE_WINDOW) -> List[TableRow]:
    """Table I rows, one per (env, method) present, in the report's order."""
    rows = []
    for (env, method), runs in _group(records).items():
        means = [window_means(r.columns, window) for r in runs]
        per_run = {key: [m[key] for m in means] for key, _, _ in METRICS}
        rows.append(TableRow(env, method, runs, per_run, window))
    return rows


def gap_closed(rows: Sequence[TableRow]) -> Dict[str, Dict[str, Optional[float]]]:
    """env -> metric -> (cmz - zero) / (env - zero), None where a method is missing or env == zero."""
    by = {(r.env, r.method): r for r in rows}
    result: Dict[str, Dict[str, Optional[float]]] = {}
    for env in dict.fromkeys(r.env for r in rows):
        cmz, zero, true = by.get((env, "cmz")), by.get((env, "zero")), by.get((env, "env"))
        result[env] = {}
        for key, _, _ in METRICS:
            if cmz is None or zero is None or true is None or true.mean(key) == zero.mean(key):
                result[env][key] = None
            else:
                result[env][key] = (cmz.mean(key) - zero.mean(key)) / (true.mean(key) - zero.mean(key))
    return result


def fmt(value: Optional[float]) -> str:
    """About three significant digits, as the paper prints (1690, 60.9, -52.6, 0.0123)."""
    if value is None or not math.isfinite(value):
        return "n/a"
    magnitude = abs(value)
    if magnitude >= 100:
        return f"{value:.0f}"
    if magnitude >= 10:
        return f"{value:.1f}"
    if magnitude >= 1:
        return f"{value:.2f}"
    return f"{value:.3g}"


def fmt_mean_std(mean: float, std: float) -> str:
    return f"{fmt(mean)} ({fmt(std)})"


def table_csv(rows: Sequence[TableRow], runs_dir: Path) -> str:
    """Table I as CSV, full precision, with each number's run folders (relative to ``runs_dir``)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    header = ["env", "method", "n_trials", "window_epochs"]
    for key, _, _ in METRICS:
        header += [f"{key}_mean", f"{key}_std"]
    writer.writerow(header + ["run_dirs"])
    for r in rows:
        values: List[Any] = [r.env, r.method, r.n_trials, r.window]
        for key, _, _ in METRICS:
            values += [repr(r.mean(key)), repr(r.std(key))]
        writer.writerow(values + [";".join(run.relative(runs_dir) for run in r.runs)])
    return out.getvalue()


# -- the expert's scale and the reward signal ---------------------------------------------------------
#: Columns of SB3's progress CSV that :func:`reward_signal` summarises.
SIGNAL_COLUMNS: Tuple[Tuple[str, str], ...] = (
    ("u", "rollout/disagreement_mean"),
    ("shaped", "rollout/shaped_reward_mean"),
    ("ubar", "rollout/ubar_mean"),
    ("ep_len", "rollout/ep_len_mean"),
)
#: Epochs averaged at the start and at the end of a run in :func:`reward_signal`.
SIGNAL_EPOCHS = 10


def _demo_pool_candidates(record: RunRecord, runs_dir: Path) -> List[Path]:
    """Where a run's demo pool may be: the path it recorded, else experts/<EnvName>/demos.npz beside
    the working directory or the repository holding ``runs_dir`` (a fresh clone moves the path)."""
    tail = Path("experts") / record.env / "demos.npz"
    found = [Path(record.config["demos"])] if record.config.get("demos") else []
    return found + [Path.cwd() / tail] + [parent / tail for parent in runs_dir.resolve().parents]


def expert_returns(records: Sequence[RunRecord], runs_dir: PathLike) -> Dict[str, Tuple[float, float, int]]:
    """env -> (mean, std over trials, trials) of the mean true return of each trial's held-out expert
    episodes: the episodes its evaluations replay. Trials whose pool cannot be found, whose pool's
    sha256 differs from the one recorded, or whose pool has no rewards are left out."""
    root = Path(runs_dir)
    per_env: Dict[str, Dict[int, float]] = {}
    pools: Dict[Path, Tuple[str, Any]] = {}
    for r in records:
        episodes = r.config.get("eval_episodes")
        if not episodes or r.trial in per_env.get(r.env, {}):
            continue
        for candidate in _demo_pool_candidates(r, root):
            if not candidate.is_file():
                continue
            if candidate not in pools:
                digest = hashlib.sha256(candidate.read_bytes()).hexdigest()
                pools[candidate] = (digest, Demonstrations.load(candidate))
            digest, pool = pools[candidate]
            if r.config.get("demos_sha256") not in (None, digest) or pool.episode_returns is None:
                continue
            per_env.setdefault(r.env, {})[r.trial] = float(np.mean(pool.episode_returns[list(episodes)]))
            break
    return {env: (float(np.mean(list(v.values()))), float(np.std(list(v.values()))), len(v)) for env, v in per_env.items()}


def _progress_log(record: RunRecord) -> Dict[str, np.ndarray]:
    """The run's SB3 progress CSVs (one per segment, ``progress_<start step>.csv``) joined in step
    order; a resumed segment replaces the rows its predecessor logged after the checkpoint it
    resumed from. {} without logs."""
    segments = []
    for path in (record.path / "logs").glob("progress_*.csv"):
        start = path.stem.split("_")[-1]
        if start.isdigit():
            segments.append((int(start), path))
    rows: List[Dict[str, str]] = []
    for start, path in sorted(segments):
        rows = [row for row in rows if float(row["time/total_timesteps"]) <= start]
        with open(path, newline="", encoding="utf-8") as f:
            rows += [row for row in csv.DictReader(f) if row.get("time/total_timesteps")]
    columns: Dict[str, np.ndarray] = {}
    for key, column in SIGNAL_COLUMNS:
        values = [float(row[column]) if row.get(column) else np.nan for row in rows]
        columns[key] = np.asarray(values, dtype=np.float64)
    return columns


def reward_signal(records: Sequence[RunRecord], epochs: int = SIGNAL_EPOCHS) -> Dict[Tuple[str, str], Dict[str, Tuple[float, float]]]:
    """(env, method) -> {"u": (first, last), "shaped": (first, last), "ubar": ..., "ep_len": ...}: the
    mean over trials of each run's rollout statistics averaged over its first and last ``epochs``
    PPO updates. Runs without progress logs are left out; so is BC (it has no rollouts)."""
    result: Dict[Tuple[str, str], Dict[str, Tuple[float, float]]] = {}
    for (env, method), runs in _group(r for r in records if r.method != "bc").items():
        logs = [log for log in map(_progress_log, runs) if log and log["u"].size]
        if not logs:
            continue
        cell: Dict[str, Tuple[float, float]] = {}
        for key, _ in SIGNAL_COLUMNS:
            first = [np.nanmean(log[key][:epochs]) for log in logs if np.isfinite(log[key][:epochs]).any()]
            last = [np.nanmean(log[key][-epochs:]) for log in logs if np.isfinite(log[key][-epochs:]).any()]
            cell[key] = (float(np.mean(first)) if first else math.nan, float(np.mean(last)) if last else math.nan)
        cell["trials"] = (float(len(logs)), float(len(logs)))
        result[(env, method)] = cell
    return result


# -- figures ------------------------------------------------------------------------------------------------
def _smoothed_band(runs: Sequence[RunRecord], column: str, sigma: float) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(epochs, mean, std) over trials of each trial's smoothed curve; epochs not reached by every
    trial use the trials that reached them (an unfinished trial shortens nothing)."""
    from scipy.ndimage import gaussian_filter1d

    epochs = np.unique(np.concatenate([r.columns["epoch"] for r in runs]))
    grid = np.full((len(runs), len(epochs)), np.nan)
    for i, r in enumerate(runs):
        values = r.columns[column]
        smooth = gaussian_filter1d(values, sigma, mode="nearest") if sigma > 0 and len(values) > 1 else values
        grid[i, np.searchsorted(epochs, r.columns["epoch"])] = smooth
    return epochs, np.nanmean(grid, axis=0), np.nanstd(grid, axis=0)  # every column has a trial


def plot_figure(
    records: Sequence[RunRecord],
    methods: Sequence[str],
    path: PathLike,
    title: str = "",
    sigma: float = SMOOTHING_SIGMA,
) -> Optional[Path]:
    """The paper's Fig. 1/2 layout for ``methods``; None (nothing written) when none of them ran."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    groups = _group(r for r in records if r.method in methods)
    if not groups:
        return None
    envs = sorted({env for env, _ in groups}, key=_env_key)
    fig = Figure(figsize=(13, 3.2 * len(envs) + 0.8), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(envs), len(METRICS), squeeze=False)
    for row, env in enumerate(envs):
        for col, (_, label, column) in enumerate(METRICS):
            ax = axes[row, col]
            xmax = max((r.columns["epoch"][-1] for (e, m), runs in groups.items() if e == env and m != "bc" for r in runs), default=1)
            for method in methods:
                runs = groups.get((env, method))
                if not runs:
                    continue
                name = f"{METHOD_LABELS[method]} (n={len(runs)})"
                color = _COLORS[method]
                if method == "bc":
                    # BC is evaluated once (epoch 0): a horizontal line over the training epochs.
                    values = np.array([r.columns[column][0] for r in runs])
                    mean, std = float(values.mean()), float(values.std())
                    ax.axhline(mean, color=color, linestyle="--", label=name)
                    ax.axhspan(mean - std, mean + std, color=color, alpha=0.12, linewidth=0)
                    continue
                epochs, mean, std = _smoothed_band(runs, column, sigma)
                ax.plot(epochs, mean, color=color, label=name)
                ax.fill_between(epochs, mean - std, mean + std, color=color, alpha=0.2, linewidth=0)
            ax.set_xlim(0, max(1, xmax))
            ax.set_xlabel("epoch (PPO update)")
            ax.set_title(f"{env}: {label}", fontsize=10)
            ax.grid(alpha=0.3)
            if col == 0:
                ax.legend(fontsize=8, loc="best")
    fig.suptitle(
        (title + "\n" if title else "")
        + f"mean over trials, band ±1 std; curves Gaussian-smoothed (sigma {sigma:g} evaluations)",
        fontsize=11,
    )
    path = Path(path)
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    return path


# -- results.md ---------------------------------------------------------------------------------------------
def _md_table(header: Sequence[str], rows: Iterable[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def _paper_layout(values: Mapping[Tuple[str, str], str], envs: Sequence[str], methods: Sequence[str]) -> str:
    """Methods as rows and envs as columns, the way the paper prints Table I."""
    return _md_table(["Method", *envs], ([METHOD_LABELS[m], *(values.get((e, m), "—") for e in envs)] for m in methods))


def reference_markdown(reference: ReferenceTable) -> str:
    """A reference table in the paper's layout, with its title and note."""
    envs = sorted(reference.values, key=_env_key)
    methods = [m for m in METHOD_ORDER if any(m in reference.values[e] for e in envs)]
    cells = {(e, m): fmt_mean_std(*v) for e in envs for m, v in reference.values[e].items()}
    return f"### {reference.title}\n\n{reference.note}\n\n{_paper_layout(cells, envs, methods)}\n"


#: What the paper calls the envs we stand in for (column headers of the side-by-side table).
PAPER_ENV_NAMES: Dict[str, str] = {"WaypointNav-v0": "PyUXV", "HalfCheetah-v5": "Half Cheetah v1", "Hopper-v5": "Hopper v1"}
#: Markers of the README block that ``write_report(readme=...)`` replaces.
README_BEGIN = "<!-- results table: written by `sb3-cmzdril report --readme`, do not edit by hand -->"
README_END = "<!-- end of results table -->"


def side_by_side_markdown(
    rows: Sequence[TableRow],
    experts: Mapping[str, Tuple[float, float, int]],
    reference: ReferenceTable,
) -> str:
    """Return (mean (std) over trials, last-100-epoch window) beside the reference's numbers, env by
    env; the last row is the expert's return on the held-out episodes."""
    envs = sorted({r.env for r in rows}, key=_env_key)
    methods = [m for m in METHOD_ORDER if any(r.method == m for r in rows)]
    ours = {(r.env, r.method): f"{fmt_mean_std(r.mean('return'), r.std('return'))} [{r.n_trials}]" for r in rows}
    header = ["Method"]
    for env in envs:
        header += [f"{env} (ours)", f"{PAPER_ENV_NAMES.get(env, env)} (paper)"]
    lines = []
    for method in methods:
        line = [METHOD_LABELS[method]]
        for env in envs:
            paper = reference.values.get(env, {}).get(method)
            line += [ours.get((env, method), "—"), fmt_mean_std(*paper) if paper else "—"]
        lines.append(line)
    line = ["Expert (held-out demos)"]
    for env in envs:
        line += [fmt_mean_std(*experts[env][:2]) if env in experts else "—", "—"]
    lines.append(line)
    return _md_table(header, lines)


def _readme_block(path: PathLike) -> Tuple[str, int, int]:
    """(README text, end of the begin marker, start of the end marker); errors name what is missing."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"README not found: {path}")
    text = path.read_text(encoding="utf-8")
    start, end = text.find(README_BEGIN), text.find(README_END)
    if start < 0 or end < start:
        raise ValueError(f"{path} has no results block: add the lines {README_BEGIN!r} and {README_END!r} where it goes")
    return text, start + len(README_BEGIN), end


def _link(target: Path, start: Path) -> str:
    """``target`` relative to ``start`` with forward slashes, for a markdown link."""
    return Path(os.path.relpath(target.resolve(), start.resolve())).as_posix()


def _short_command(command: Optional[str]) -> str:
    """The command with its program's folder dropped (a README should not show this machine's paths)."""
    if not command:
        return "sb3-cmzdril report"
    program, _, rest = command.partition(" ")
    return f"{Path(program).name} {rest}".strip()


def update_readme(path: PathLike, block: str) -> None:
    """Replace the text between :data:`README_BEGIN` and :data:`README_END` in ``path`` (atomically)."""
    text, start, end = _readme_block(path)
    atomic_write_text(path, text[:start] + "\n" + block.strip() + "\n" + text[end:])


def _eval_episodes(records: Sequence[RunRecord]) -> str:
    counts = sorted({int(r.columns["n_episodes"][-1]) for r in records})
    return " or ".join(map(str, counts))


def _commands(records: Sequence[RunRecord], root: Path) -> Tuple[List[str], List[str]]:
    """(commands that created the runs, other commands that resumed them), each listed once."""
    created = list(dict.fromkeys(str(r.config["command"]) for r in records if r.config.get("command")))
    resumed: List[str] = []
    for r in records:
        for segment in _read_json_or_empty(r.path / STATE_FILE).get("segments", [])[1:]:
            command = segment.get("command")
            if command and command not in created and command not in resumed:
                resumed.append(str(command))
    log = root / "benchmark.jsonl"
    if log.is_file():
        for line in log.read_text(encoding="utf-8").splitlines():
            try:
                command = json.loads(line).get("command")
            except ValueError:
                continue
            if command and command not in created and command not in resumed:
                resumed.append(str(command))
    return created, resumed


def render_markdown(
    rows: Sequence[TableRow],
    records: Sequence[RunRecord],
    runs_dir: Path,
    figures: Sequence[Tuple[str, Path]],
    references: Sequence[ReferenceTable],
    report_command: Optional[str],
    window: int,
    experts: Optional[Mapping[str, Tuple[float, float, int]]] = None,
    signal: Optional[Mapping[Tuple[str, str], Mapping[str, Tuple[float, float]]]] = None,
    discussion: Optional[str] = None,
) -> str:
    envs = sorted({r.env for r in rows}, key=_env_key)
    methods = [m for m in METHOD_ORDER if any(r.method == m for r in rows)]
    unfinished = [r for r in records if r.status != "done"]
    listed = {r.path for r in records}
    # Runs that failed before their first evaluation have no numbers, but must not vanish silently.
    failed_empty = sorted(p.parent for p in runs_dir.rglob(ERROR_FILE) if p.parent not in listed and run_status(p.parent) == "failed")
    parts = [
        "# Results",
        "",
        f"Computed by `sb3_cmzdril.experiments.report` from the `eval.csv` files under `{runs_dir}` "
        f"({len(records)} runs), their `logs/progress_*.csv` (the reward-signal table) and the demo pools "
        f"their `config.json` names (the expert's return) on {time.strftime('%Y-%m-%d %H:%M %Z')}. Every "
        "number in the tables is computed from those files, none is typed in, except the paper's numbers, "
        "which are copied from the paper and labelled as such. The Discussion, if any, is written by hand.",
    ]
    if unfinished:
        parts += ["", f"**{len(unfinished)} run(s) are not finished** (their numbers use the epochs they reached): "
                  + ", ".join(f"`{r.relative(runs_dir)}` ({r.status})" for r in unfinished)]
    if failed_empty:
        parts += ["", f"**{len(failed_empty)} run(s) failed without any evaluation** (see their error.txt): "
                  + ", ".join(f"`{_relative(p, runs_dir)}`" for p in failed_empty)]
    parts += [
        "",
        "## Table I",
        "",
        f"Mean (std over trials) of each run's evaluation metric averaged over its last {window} epochs "
        "(all epochs if it has fewer; BC: its single evaluation of the pretrained policy, at epoch 0). "
        f"An evaluation replays the starts of the trial's held-out expert episodes ({_eval_episodes(records)} "
        "per trial) with the deterministic policy: return is the true env return, Fréchet the discrete "
        "Fréchet distance to the expert's path, action MSE the squared error of the policy's actions "
        "on the expert's observations. std is the population std (ddof=0).",
        "",
        _md_table(
            ["Env", "Method", "Trials", *(label for _, label, _ in METRICS)],
            ([r.env, METHOD_LABELS[r.method], str(r.n_trials), *(fmt_mean_std(r.mean(k), r.std(k)) for k, _, _ in METRICS)] for r in rows),
        ),
        "",
        "Return only, in the paper's layout"
        + (", with the expert's return on the same held-out episodes for scale (mean (std) over trials of "
           "each trial's mean; from the demo pool each run's config.json names):" if experts else ":"),
        "",
        _paper_layout({(r.env, r.method): fmt_mean_std(r.mean("return"), r.std("return")) for r in rows}, envs, methods),
    ]
    if experts:
        parts[-1] += "\n| Expert (held-out demos) | " + " | ".join(
            fmt_mean_std(*experts[e][:2]) if e in experts else "—" for e in envs) + " |"
    parts += [
        "",
        "## Gap closed by CMZ-DRIL",
        "",
        "(CMZ-DRIL - no reward) / (env. reward - no reward) of the Table I means: 0 = no better than PPO+BC "
        "without reward, 1 = as good as training on the true reward (the paper: about 50% for the reward). "
        "For Fréchet distance and action MSE, where lower is better, the same ratio measures how far "
        "CMZ-DRIL moves from no reward toward env. reward.",
        "",
    ]
    gaps = gap_closed(rows)
    parts += [
        _md_table(["Env", *(label for _, label, _ in METRICS)],
                  ([env, *(("n/a" if g[k] is None else f"{100 * g[k]:.0f}%") for k, _, _ in METRICS)] for env, g in gaps.items())),
        "",
    ]
    if signal:
        parts += [
            "## The reward signal during training",
            "",
            f"From each run's SB3 progress log (`logs/progress_*.csv`): the rollout statistics averaged over "
            f"its first and last {SIGNAL_EPOCHS} PPO updates, then over trials. u is the ensemble disagreement "
            "of the states the agent visited (the same for every method: it is logged even where it is not the "
            "reward), shaped is the mean reward the wrapper gave (CMZ-DRIL: -alpha (u - ubar), which should "
            "stay near 0; DRIL: +1/-1; 0 for no reward), ubar the CMZ-DRIL EMA, length the training episodes' "
            "mean length.",
            "",
            _md_table(
                ["Env", "Method", "Trials", "u first → last", "shaped first → last", "ubar first → last", "length first → last"],
                ([env, METHOD_LABELS[method], str(int(cell["trials"][0])),
                  *(f"{fmt(cell[k][0])} → {fmt(cell[k][1])}" for k in ("u", "shaped", "ubar", "ep_len"))]
                 for (env, method), cell in sorted(signal.items(), key=lambda kv: (_env_key(kv[0][0]), METHOD_ORDER.index(kv[0][1]))))
            ),
            "",
        ]
    if figures:
        parts += ["## Figures", ""]
        for title, path in figures:
            parts += [f"**{title}.** One row per env, one column per metric against the epoch; each trial's "
                      f"curve is smoothed with a Gaussian filter (sigma {SMOOTHING_SIGMA:g} evaluations), then "
                      "the line is the mean over trials and the band ±1 std. BC (evaluated once) is the dashed "
                      "horizontal line with its ±1 std band.", "", f"![{title}]({path.name})", ""]
    if references:
        parts += ["## Reference numbers", ""]
        parts += [reference_markdown(ref) for ref in references]
        name = references[0].title.split(" (")[0]
        parts += [f"### Ours beside {name[:1].lower() + name[1:]}", "",
                  "Return, mean (std) over trials [trials]; ours on -v5 and WaypointNav-v0, the paper's on its "
                  "own envs, experts and step budgets.", "",
                  side_by_side_markdown(rows, experts or {}, references[0]), ""]
    if discussion:
        parts += ["## Discussion", "", discussion.strip(), ""]
    parts += ["## Where each number comes from", "",
              "Each (env, method) cell of Table I averages these runs; beside each run, the epochs it reached "
              "and its own return over the Table I window.", ""]
    for r in rows:
        parts.append(f"- {r.env} / {METHOD_LABELS[r.method]}: " + ", ".join(
            f"`{run.relative(runs_dir)}` ({run.status}, epochs {int(run.columns['epoch'][0])}-{int(run.columns['epoch'][-1])}, "
            f"return {fmt(value)})"
            for run, value in zip(r.runs, r.per_run["return"])))
    created, resumed = _commands(records, runs_dir)
    parts += ["", "## Commands", "", "Runs created by:", ""]
    parts += [f"    {_short_command(c)}" for c in created] or ["    (not recorded)"]
    if resumed:
        parts += ["", "Also run (resumes, other invocations):", ""] + [f"    {_short_command(c)}" for c in resumed]
    parts += ["", "This report:", "", f"    {_short_command(report_command or 'sb3-cmzdril report ' + str(runs_dir))}", ""]
    return "\n".join(parts)


def write_report(
    runs_dir: PathLike,
    output_dir: PathLike = "docs",
    *,
    window: int = TABLE_WINDOW,
    references: Sequence[ReferenceTable] = (PAPER_TABLE_I,),
    command: Optional[str] = None,
    sigma: float = SMOOTHING_SIGMA,
    discussion: Optional[PathLike] = None,
    readme: Optional[PathLike] = None,
) -> Path:
    """Write results.md, table1.csv and the figures into ``output_dir``; returns results.md's path.

    :param references: extra tables of numbers from elsewhere (default: the paper's Table I), each
        shown separately and labelled; pass ``()`` for none.
    :param command: the report command line to record (the CLI passes its own).
    :param discussion: a markdown file written by a person (what the numbers mean), included as the
        report's "Discussion" section.
    :param readme: a README holding the :data:`README_BEGIN`/:data:`README_END` block: it is replaced
        by the side-by-side table (ours beside the first reference's numbers) and a line naming this report.
    """
    root = Path(runs_dir)
    records = load_runs(root)
    if not records:
        raise ValueError(f"no runs with evaluations under {root} (expected <EnvName>/<method>/trial<t>/{EVAL_CSV})")
    if int(window) < 1:
        raise ValueError(f"window must be >= 1, got {window}")
    out = Path(output_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows = table_one(records, int(window))
    atomic_write_text(out / "table1.csv", table_csv(rows, root))
    figures = []
    for filename, title, methods in FIGURES:
        path = plot_figure(records, methods, out / filename, title, sigma)
        if path is not None:
            figures.append((title, path))
    if discussion is not None and not Path(discussion).is_file():
        raise FileNotFoundError(f"discussion file not found: {discussion}")
    if readme is not None:
        if not references:
            raise ValueError("readme needs a reference table to set ours beside (do not combine with no references)")
        _readme_block(readme)  # fail before writing anything
    notes = Path(discussion).read_text(encoding="utf-8") if discussion is not None else None
    experts = expert_returns(records, root)
    text = render_markdown(rows, records, root, figures, references, command, int(window),
                           experts=experts, signal=reward_signal(records), discussion=notes)
    atomic_write_text(out / "results.md", text)
    if readme is not None:
        unfinished = sum(r.status != "done" for r in records)
        update_readme(readme, side_by_side_markdown(rows, experts, references[0]) + (
            f"\n\nReturn, mean (std) over trials [trials], from {len(records)} runs"
            + (f" ({unfinished} not finished)" if unfinished else "")
            + f"; written by `{_short_command(command)}`; details in [results.md]({_link(out / 'results.md', Path(readme).parent)})."))
    return out / "results.md"


__all__ = [
    "METHOD_LABELS",
    "PAPER_TABLE_I",
    "ReferenceTable",
    "RunRecord",
    "TableRow",
    "load_runs",
    "table_one",
    "gap_closed",
    "expert_returns",
    "side_by_side_markdown",
    "update_readme",
    "reward_signal",
    "table_csv",
    "plot_figure",
    "write_report",
    "fmt",
]
