"""The report on hand-written run folders: the headline first, Table I, the final evaluation with its
bootstrap CIs, two grids side by side, partial grids, the README block, the discussion link and the figures.

Every run folder here is written by the test (eval.csv, final_eval.csv, config.json, done.json), so
each number the report prints can be computed by hand; the grid that writes real runs is tested in
test_experiments.py.
"""
from __future__ import annotations

import csv
import math
import shutil
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import bootstrap

from cmzdril_lab import report
from cmzdril_lab.report.figures import plot_final
from cmzdril_lab.report.final_eval import (
    expert_level_share,
    expert_percent,
    final_table,
    mean_ci,
    paired_markdown,
)
from cmzdril_lab.report.records import NOT_SET, load_runs, read_final_eval, setting_differences
from helpers import write_run
from sb3_cmzdril.cli import main

ENV = "HalfCheetah-v5"
PNG = b"\x89PNG\r\n\x1a\n"


def by_hand_ci(values: Sequence[float]):
    """The interval the report must print, computed here with scipy directly (same settings)."""
    result = bootstrap((np.asarray(values, dtype=float),), np.mean, confidence_level=0.95, n_resamples=9999,
                       method="percentile", random_state=0)
    return result.confidence_interval.low, result.confidence_interval.high


def _rows(path: Path) -> list:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _paired(docs: Path) -> dict:
    """paired.csv by (method, policy, baseline)."""
    return {(r["method"], r["policy"], r["baseline"]): r for r in _rows(docs / "paired.csv")}


def _ci(row: dict, column: str) -> tuple[float, float, float]:
    return tuple(float(row[f"{column}_{k}"]) for k in ("mean", "ci_low", "ci_high"))


# Four trials; each final policy's held-out returns. CMZ-DRIL beats BC in trials 0, 2, 3 (3 of 4)
# and no reward in trials 0, 2, 3 (3 of 4).
FINAL = {
    "bc": [[100, 200, 300], [150, 150, 150], [400, 0, 200], [50, 70, 90]],  # means 200, 150, 200, 70
    "cmz": [[300, 300, 300], [100, 120, 110], [500, 600, 700], [90, 80, 100]],  # 300, 110, 600, 90
    "zero": [[250, 250, 250], [130, 130, 130], [500, 500, 500], [60, 60, 60]],
}
LOWEST = {"cmz": [[210, 220, 230], [160, 160, 160], [300, 300, 300], [100, 100, 100]],  # 220, 160, 300, 100
          "zero": [[200, 200, 200], [100, 100, 100], [250, 250, 250], [80, 80, 80]]}


@pytest.fixture
def main_grid(tmp_path) -> Path:
    """The new-defaults grid: bc, cmz, zero x 4 trials with final evaluations (lowest u for cmz, zero)."""
    root = tmp_path / "runs"
    for method, finals in FINAL.items():
        for trial, values in enumerate(finals):
            final = {"final": values, **({"lowest_u": LOWEST[method][trial]} if method in LOWEST else {})}
            returns = [float(np.mean(values))] if method == "bc" else [0.0, 100.0 + trial, 200.0 + trial]
            write_run(root, method, trial, returns, final=final, lowest_epoch=None if method == "bc" else 10 + trial)
    return root


@pytest.mark.slow
def test_final_table_means_and_cis_equal_hand_computed(main_grid, tmp_path):
    path = report.write_report(main_grid, tmp_path / "docs", references=())
    text = path.read_text()
    table = {(r["method"], r["policy"]): r for r in _rows(tmp_path / "docs" / "final_table.csv")}
    assert set(table) == {("bc", "final"), ("cmz", "final"), ("zero", "final"),
                          ("cmz", "lowest_u"), ("zero", "lowest_u")}
    for (method, policy), episodes in [*(((m, "final"), v) for m, v in FINAL.items()),
                                       *(((m, "lowest_u"), v) for m, v in LOWEST.items())]:
        per_trial = [sum(e) / len(e) for e in episodes]
        mean = sum(per_trial) / len(per_trial)
        low, high = by_hand_ci(per_trial)
        row = table[(method, policy)]
        assert (row["n_trials"], row["episodes_per_run"]) == ("4", "3;3;3;3")
        assert [float(v) for v in row["return_per_run"].split(";")] == pytest.approx(per_trial, rel=1e-12)
        assert float(row["return_mean"]) == pytest.approx(mean, rel=1e-12)
        assert (float(row["return_ci_low"]), float(row["return_ci_high"])) == (pytest.approx(low), pytest.approx(high))
        assert low < mean < high
        # Fréchet: 10 + trial + episode, so each trial's mean is 11 + trial; action MSE 0.01 (1 + trial)
        assert float(row["frechet_mean"]) == pytest.approx(np.mean([11 + t for t in range(4)]))
        assert float(row["action_mse_mean"]) == pytest.approx(np.mean([0.01 * (1 + t) for t in range(4)]))
        name = report.METHOD_LABELS[method] + (" (lowest u)" if policy == "lowest_u" else "")
        assert f"| {name} | {report.fmt_ci(mean, low, high)} |" in text  # one env: one column, 4 trials each
    # Paired by trial: the page counts the trials above the baseline, paired.csv has the differences.
    assert "| CMZ-DRIL | BC | 3 of 4 |" in text and "| CMZ-DRIL | No reward | 3 of 4 |" in text
    assert "| CMZ-DRIL (lowest u) | BC | 4 of 4 |" in text  # 220, 160, 300, 100 vs 200, 150, 200, 70
    assert "| CMZ-DRIL (lowest u) | No reward (lowest u) | 4 of 4 |" in text  # vs 200, 100, 250, 80
    pairs = _paired(tmp_path / "docs")
    assert _ci(pairs[("cmz", "final", "bc")], "return_diff") == pytest.approx(mean_ci([100, -40, 400, 20]))
    assert _ci(pairs[("cmz", "final", "zero")], "return_diff") == pytest.approx(mean_ci([50, -20, 100, 30]))
    assert (pairs[("cmz", "final", "bc")]["above"], pairs[("cmz", "final", "bc")]["trials"]) == ("3", "0;1;2;3")
    assert pairs[("cmz", "lowest_u", "bc")]["selected_epochs"] == "10;11;12;13"  # the epoch of each choice
    assert pairs[("zero", "lowest_u", "bc")]["above"] == "2"  # 200, 100, 250, 80: only in the CSV
    assert "| No reward (lowest u) | BC |" not in text
    assert (tmp_path / "docs" / "fig3_final_eval.png").read_bytes()[:8] == PNG
    assert "](fig3_final_eval.png)" in text


@pytest.mark.slow
def test_expert_level_share_counts_episodes_at_half_the_expert_return(main_grid, tmp_path):
    # The fixture's expert returns are 1000 + 10 trial + episode: only CMZ-DRIL's trial 2 (500, 600, 700
    # against 1020, 1021, 1022) has episodes at half of it or more, two of three.
    report.write_report(main_grid, tmp_path / "docs", references=())
    table = {(r["method"], r["policy"]): r for r in _rows(tmp_path / "docs" / "final_table.csv")}
    assert float(table[("cmz", "final")]["expert_level_mean"]) == pytest.approx((0 + 0 + 2 / 3 + 0) / 4)
    for key in [("bc", "final"), ("zero", "final"), ("cmz", "lowest_u")]:
        assert float(table[key]["expert_level_mean"]) == 0.0
    assert "Episodes at expert level" in (tmp_path / "docs" / "results.md").read_text()
    share = {"return": np.array([50.0, 49.9, 120.0]), "expert_return": np.array([100.0, 100.0, 100.0])}
    assert expert_level_share(share) == pytest.approx(2 / 3)  # exactly half counts
    assert math.isnan(expert_level_share({"return": np.array([-10.0]), "expert_return": np.array([-20.0])}))


def _pct(returns: Sequence[float], trial: int, expert: float = 1000.0) -> float:
    """% of expert of one fixture run by hand: its 3 episodes' expert returns average expert + 10 trial + 1."""
    return 100 * float(np.mean(returns)) / (expert + 10 * trial + 1)


def test_percent_of_expert_equals_hand_computed(main_grid, tmp_path):
    text = report.write_report(main_grid, tmp_path / "docs", references=(), figures=False).read_text()
    table = {(r["method"], r["policy"]): r for r in _rows(tmp_path / "docs" / "final_table.csv")}
    # CMZ-DRIL: 300, 110, 600, 90 against 1001, 1011, 1021, 1031
    cmz = [100 * 300 / 1001, 100 * 110 / 1011, 100 * 600 / 1021, 100 * 90 / 1031]
    assert cmz == pytest.approx([_pct(v, t) for t, v in enumerate(FINAL["cmz"])], rel=1e-12)
    row = table[("cmz", "final")]
    assert float(row["pct_of_expert_mean"]) == pytest.approx(np.mean(cmz), rel=1e-12)
    low, high = by_hand_ci(cmz)
    assert (float(row["pct_of_expert_ci_low"]), float(row["pct_of_expert_ci_high"])) == (pytest.approx(low),
                                                                                         pytest.approx(high))
    ret = report.fmt_ci(*mean_ci([300, 110, 600, 90]))
    lowest = [_pct(v, t) for t, v in enumerate(LOWEST["cmz"])]
    bc = [_pct(v, t) for t, v in enumerate(FINAL["bc"])]
    zero = [_pct(v, t) for t, v in enumerate(FINAL["zero"])]
    # The headline: % of the expert, env by method, the final policies then CMZ-DRIL's lowest u.
    assert (f"| {ENV} | {report.fmt_ci(*mean_ci(bc))} | {report.fmt_ci(np.mean(cmz), low, high)} "
            f"| {report.fmt_ci(*mean_ci(zero))} | {report.fmt_ci(*mean_ci(lowest))} |") in text
    assert f"| CMZ-DRIL | {ret} |" in text  # the final evaluation's return
    assert float(table[("cmz", "lowest_u")]["pct_of_expert_mean"]) == pytest.approx(np.mean(lowest), rel=1e-12)
    # Paired: trial by trial against BC's 200, 150, 200, 70 on the same episodes
    row = _paired(tmp_path / "docs")[("cmz", "final", "bc")]
    assert _ci(row, "pct_of_expert_diff") == pytest.approx(mean_ci([c - b for c, b in zip(cmz, bc, strict=True)]))
    assert row["above"] == "3" and "| CMZ-DRIL | BC | 3 of 4 |" in text
    assert expert_percent({"return": np.array([0.0, 300.0]), "expert_return": np.array([100.0, 300.0])}) == 75.0


def test_percent_of_expert_is_na_without_positive_expert_returns(tmp_path):
    # Expert returns -1000 + 10 trial + episode: all negative, so neither a percentage nor a share
    root = tmp_path / "runs"
    for trial in range(3):
        write_run(root, "bc", trial, [1.0], final={"final": [-900.0, -800.0]}, expert=-1000.0)
        write_run(root, "cmz", trial, [1.0, 2.0], final={"final": [-700.0, -600.0]}, expert=-1000.0)
    text = report.write_report(root, tmp_path / "docs", references=(), figures=False).read_text()
    table = {r["method"]: r for r in _rows(tmp_path / "docs" / "final_table.csv")}
    assert all(math.isnan(float(table[m]["pct_of_expert_mean"])) for m in ("bc", "cmz"))
    ret = report.fmt_ci(-650.0, -650.0, -650.0)
    expert = report.fmt_ci(*mean_ci([-999.5 + 10 * t for t in range(3)]))
    assert f"| {ENV} | n/a | n/a |" in text  # the headline: no % of the expert for BC and CMZ-DRIL
    assert f"| CMZ-DRIL | {ret} |" in text and f"| Expert (held-out demos) | {expert} |" in text  # the returns
    assert math.isnan(float(table["cmz"]["expert_level_mean"]))  # nor a share of episodes at expert level
    assert "| CMZ-DRIL | BC | 3 of 3 |" in text  # paired: the return counts, the % of the expert does not
    row = _paired(tmp_path / "docs")[("cmz", "final", "bc")]
    assert _ci(row, "return_diff") == (200.0, 200.0, 200.0) and math.isnan(float(row["pct_of_expert_diff_mean"]))
    assert math.isnan(expert_percent({"return": np.array([]), "expert_return": np.array([])}))


def test_an_expert_that_fails_now_and_then_keeps_a_percentage_but_not_an_expert_level_share():
    # Expert returns 300 and -100 on the two held-out episodes (a fall): the mean, 100, still sets the scale.
    columns = {"return": np.array([150.0, -50.0]), "expert_return": np.array([300.0, -100.0])}
    assert expert_percent(columns) == 50.0
    assert math.isnan(expert_level_share(columns))  # half of a negative return is no bar to clear
    assert math.isnan(expert_percent({"return": np.array([5.0, 5.0]), "expert_return": np.array([10.0, -10.0])}))


def test_mean_ci_needs_three_finite_values():
    assert mean_ci([1.0, 3.0])[0] == 2.0 and all(math.isnan(v) for v in mean_ci([1.0, 3.0])[1:])
    assert all(math.isnan(v) for v in mean_ci([1.0, 2.0, float("nan")])[1:])
    assert mean_ci([2.0, 2.0, 2.0]) == (2.0, 2.0, 2.0)  # percentile interval of equal values: no width
    assert mean_ci([1.0, 5.0, 9.0])[1:] == pytest.approx(by_hand_ci([1.0, 5.0, 9.0]))


def test_partial_grid_reports_trials_per_cell(tmp_path):
    root = tmp_path / "runs"
    write_run(root, "bc", 0, [50.0], final={"final": [40.0, 60.0]})
    write_run(root, "bc", 1, [70.0], final={"final": [80.0, 100.0]})
    write_run(root, "cmz", 0, [10.0, 20.0], final={"final": [30.0, 50.0], "lowest_u": [45.0, 55.0]}, lowest_epoch=3)
    write_run(root, "cmz", 1, [10.0, 30.0], done=False)  # still training: Table I only
    text = report.write_report(root, tmp_path / "docs", references=(), figures=False).read_text()
    assert "| BC | 70.0 [n/a], n=2 |" in text  # (50 + 90) / 2, no CI from 2 trials; cells differ in trials
    assert "| CMZ-DRIL | 40.0 [n/a], n=1 |" in text
    assert "| CMZ-DRIL | BC | 0 of 1 |" in text  # 40 - 50 on trial 0
    assert _ci(_paired(tmp_path / "docs")[("cmz", "final", "bc")], "return_diff")[0] == -10.0
    assert "| CMZ-DRIL | 17.5 (2.50) |" in text  # Table I: (15 + 20) / 2
    assert "1 run(s) are not finished" in text and "`HalfCheetah-v5/cmz/trial1` (partial)" in text
    assert "Final evaluation (trials per cell: 1-2)" in text
    assert "![" not in text and not list((tmp_path / "docs").glob("*.png"))  # figures=False: tables only


@pytest.mark.slow
def test_grid_without_final_evaluation(tmp_path):
    root = tmp_path / "runs"
    for trial in (0, 1):
        write_run(root, "bc", trial, [50.0 + trial])
        write_run(root, "cmz", trial, [100.0, 200.0 + trial])
    out = tmp_path / "docs"
    out.mkdir()
    (out / "fig3_final_eval.png").write_bytes(b"from an earlier report")
    text = report.write_report(root, out, references=()).read_text()
    assert "No final evaluation: no run of this grid has a final_eval.csv" in text
    # The headline falls back on Table I: BC 50 and 51, CMZ-DRIL 150 and 150.5
    cells = f"{report.fmt_mean_std(50.5, 0.5)} | {report.fmt_mean_std(150.25, 0.25)}"
    assert f"| {ENV} | {cells} |" in text and "no run has a final evaluation yet" in text
    assert not (out / "final_table.csv").exists() and not (out / "paired.csv").exists()
    assert not (out / "fig3_final_eval.png").exists()  # a stale figure would contradict the report


def test_read_final_eval_names_a_malformed_file(tmp_path):
    (tmp_path / "final_eval.csv").write_text("policy,episode,return\nfinal,0,1.0\n")
    with pytest.raises(ValueError, match="final_eval.csv: missing column"):
        read_final_eval(tmp_path / "final_eval.csv")
    (tmp_path / "final_eval.csv").write_bytes(b"\xff\xfe\x00binary")
    with pytest.raises(ValueError, match="final_eval.csv is not a final_eval.csv: not UTF-8 text"):
        read_final_eval(tmp_path / "final_eval.csv")
    assert read_final_eval(tmp_path / "nothing.csv") == {}


# -- what a report counts, and what it says it left out -------------------------------------------------
def test_a_copied_run_folder_is_the_same_trial_counted_once(main_grid, tmp_path, capsys):
    assert main(["report", str(main_grid), "-o", str(tmp_path / "before"), "--no-figures"]) == 0
    capsys.readouterr()
    shutil.copytree(main_grid / ENV / "cmz" / "trial0", main_grid / ENV / "cmz" / "trial0.bak")
    # An unfinished second folder of BC trial 1 elsewhere: the finished one counts, wherever it lies.
    write_run(main_grid / "elsewhere", "bc", 1, [999.0], done=False)
    assert main(["report", str(main_grid), "-o", str(tmp_path / "after"), "--no-figures"]) == 0
    out = capsys.readouterr().out
    for name in ("table1.csv", "final_table.csv", "paired.csv", "per_run.csv"):
        assert (tmp_path / "after" / name).read_text() == (tmp_path / "before" / name).read_text(), name
    copy = (f"`{ENV}/cmz/trial0.bak` (another folder of {ENV} CMZ-DRIL trial 0 (config.json), counted once, "
            f"from {ENV}/cmz/trial0)")
    other = (f"`elsewhere/{ENV}/bc/trial1` (another folder of {ENV} BC trial 1 (config.json), counted once, "
             f"from {ENV}/bc/trial1)")
    text = (tmp_path / "after" / "results.md").read_text()
    assert f"**{main_grid}: left out** (a run counts by its config.json, once per trial): " in text
    assert copy in text and other in text
    assert f"{main_grid}: left out {ENV}/cmz/trial0.bak: another folder of {ENV} CMZ-DRIL trial 0" in out


def test_runs_the_report_cannot_place_are_named_with_the_reason(main_grid, tmp_path, capsys):
    write_run(main_grid, "gail", 0, [5.0])  # a method the report does not know
    nameless = write_run(main_grid, "cmz", 9, [5.0])
    (nameless / "config.json").unlink()  # which run is it? the folder's name does not say
    broken = write_run(main_grid, "cmz", 8, [5.0])
    (broken / "config.json").write_text("[1, 2]")
    assert main(["report", str(main_grid), "-o", str(tmp_path / "docs"), "--no-figures"]) == 0
    out = capsys.readouterr().out
    text = (tmp_path / "docs" / "results.md").read_text()
    for line in (f"`{ENV}/gail/trial0` (method 'gail' in config.json is none of bc, zero, env, dril, cmz, cmz-sac, "
                 "dril-sac, zero-sac, env-sac)",
                 f"`{ENV}/cmz/trial9` (no config.json, so not known which run it is)",
                 f"`{ENV}/cmz/trial8` (config.json is not what sb3-cmzdril wrote: it holds a JSON array, "
                 "not an object)"):
        assert line in text
        path, reason = line[1:-1].split("` (")
        assert f"left out {path}: {reason}" in out
    cmz = next(r for r in _rows(tmp_path / "docs" / "table1.csv") if r["method"] == "cmz")
    assert cmz["n_trials"] == "4"  # still the four trials of the fixture
    assert f"- {ENV}: `bc`, `cmz`, `zero` trials 0-3" in text  # where each number comes from


def test_a_nan_row_is_left_out_not_the_method(tmp_path):
    root = tmp_path / "runs"
    for trial in (0, 1):
        write_run(root, "cmz", trial, [100.0, float("nan") if trial else 150.0, 200.0])
    text = report.write_report(root, tmp_path / "docs", references=(), figures=False).read_text()
    # Table I: trial 0 (100 + 150 + 200) / 3 = 150, trial 1 (100 + 200) / 2 = 150
    assert "| CMZ-DRIL | 150 (0) |" in text
    assert (f"`{ENV}/cmz/trial1/eval.csv` (1 row(s) with NaN or infinite values left out; its other rows count)"
            in text)


@pytest.mark.parametrize("content", [b"\x89PNG\r\n\x1a\n\xff\xfe binary", b"time,loss\n1,2\n"],
                         ids=["binary", "other-csv"])
def test_a_garbage_eval_csv_is_one_line_naming_it(main_grid, tmp_path, capsys, content):
    bad = main_grid / ENV / "cmz" / "trial2" / "eval.csv"
    bad.write_bytes(content)
    assert main(["report", str(main_grid), "-o", str(tmp_path / "docs"), "--no-figures"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"sb3-cmzdril report: error: {bad} is not an eval.csv: ") and err.count("\n") == 1
    assert not (tmp_path / "docs").exists()


def _reference_grid(root: Path) -> Path:
    """The paper-faithful grid: other settings, no final_eval.csv, bc with 1 trial, cmz with 2."""
    old = {"bc_pretrain_epochs": 100}
    write_run(root, "bc", 0, [30.0], hyperparams=old)
    write_run(root, "cmz", 0, [0.0, 40.0], hyperparams=old)
    write_run(root, "cmz", 1, [0.0, 60.0], hyperparams=old)
    return root


@pytest.mark.slow
def test_two_grids_side_by_side_with_the_paper(main_grid, tmp_path, capsys):
    ref = _reference_grid(tmp_path / "paper_faithful")
    out = tmp_path / "docs"
    assert main(["report", str(main_grid), "--reference-runs", str(ref), "-o", str(out),
                 "--label", "new", "--reference-label", "old"]) == 0
    text = (out / "results.md").read_text()
    headline, rest = text.split("## Per task: new\n")
    body, old = rest.split("## Per task: old\n")
    # The headline: the main grid's % of the expert alone, then its figure; nothing of the other grid yet.
    cmz_pct = report.fmt_ci(*mean_ci([_pct(v, t) for t, v in enumerate(FINAL["cmz"])]))
    lowest_pct = report.fmt_ci(*mean_ci([_pct(v, t) for t, v in enumerate(LOWEST["cmz"])]))
    row = next(line for line in headline.splitlines() if line.startswith(f"| {ENV} |"))
    assert row.split(" | ")[2] == cmz_pct and row.endswith(f" | {lowest_pct} |")
    assert "](fig3_final_eval.png)" in headline and "25.0" not in headline and "1690" not in headline
    # Per task, the new grid: the final evaluation's returns and Table I; the old grid: Table I only.
    assert f"| CMZ-DRIL | {report.fmt_ci(*mean_ci([300, 110, 600, 90]))} |" in body
    assert f"| CMZ-DRIL (lowest u) | {report.fmt_ci(*mean_ci([220, 160, 300, 100]))} |" in body
    expert = report.fmt_ci(*mean_ci([1001 + 10 * t for t in range(4)]))
    assert f"| Expert (held-out demos) | {expert} |" in body
    window = [(0.0 + 100 + t + 200 + t) / 3 for t in range(4)]  # Table I: 3 epochs, all in the window
    assert f"| CMZ-DRIL | {report.fmt_mean_std(np.mean(window), np.std(window))} |" in body
    assert f"| BC | {report.fmt_mean_std(155.0, np.std([200, 150, 200, 70]))} |" in body
    assert "No final evaluation: no run of this grid has a final_eval.csv" in old
    assert f"- {ENV}: `bc_pretrain_epochs` 1000 vs 100" in old
    # old: cmz the mean of 20 and 30 (2 epochs each) over 2 trials, bc 1 trial: the cells name their trials
    assert "| CMZ-DRIL | 25.0 (5.00), n=2 |" in old and "| BC | 30.0 (0), n=1 |" in old
    assert "## The paper's Table I" in old and "| 1690 (360) |" in old and "| 708 (162) |" in old
    assert f"`{ref}`" in text and "## How to read" in old and "## Where each number comes from" in old
    assert {p.name for p in out.iterdir()} == {"results.md", "table1.csv", "table1_reference.csv", "final_table.csv",
                                              "paired.csv", "per_run.csv", "per_run_reference.csv",
                                              "fig1_bc_dril_cmz.png", "fig2_cmz_env_zero.png", "fig3_final_eval.png",
                                              "across_tasks.csv", "fig4_across_tasks.png"}
    assert _rows(out / "table1_reference.csv")[1]["run_dirs"] == f"{ENV}/cmz/trial0;{ENV}/cmz/trial1"
    runs = _rows(out / "per_run_reference.csv")
    assert [(r["method"], r["trial"], r["run_dir"], r["status"]) for r in runs] == [
        ("bc", "0", f"{ENV}/bc/trial0", "done"), ("cmz", "0", f"{ENV}/cmz/trial0", "done"),
        ("cmz", "1", f"{ENV}/cmz/trial1", "done")]
    assert [float(r["table1_return"]) for r in runs] == [30.0, 20.0, 30.0] and runs[0]["final_return"] == ""
    # Existing report files are kept unless --force; two grids need two names.
    assert main(["report", str(main_grid), "-o", str(out)]) == 2
    assert "final_table.csv" in capsys.readouterr().err
    assert main(["report", str(main_grid), "--reference-runs", str(ref), "-o", str(tmp_path / "x"),
                 "--label", "same", "--reference-label", "same"]) == 2
    assert "both grids are labelled 'same'" in capsys.readouterr().err


def test_the_page_opens_with_the_answer_and_keeps_the_detail_short(main_grid, tmp_path):
    text = report.write_report(main_grid, tmp_path / "docs", figures=False).read_text()
    lines = text.splitlines()
    # The first table on the page is the headline: env by method, short heads, a short note under it.
    first = next(i for i, line in enumerate(lines) if line.startswith("|"))
    assert lines[first - 2] == "## Headline"
    assert lines[first] == "| Env | BC | CMZ-DRIL | No reward | CMZ-DRIL (lowest u) |"
    note = lines[first + 4]  # header, rule, one env, blank
    assert lines[first + 3] == "" and note.count(". ") <= 1 and len(note) < 600
    # Every table's heads are short; the long explanations are under "How to read", after the tables.
    heads = [c.strip() for line in lines if line.startswith("| ") and lines[lines.index(line) + 1].startswith("|--")
             for c in line.strip("|").split("|")]
    assert max(map(len, heads)) <= 30, max(heads, key=len)
    order = [lines.index(h) for h in ("## Headline", "## Across tasks", "## Per task", "## How to read",
                                      "## Where each number comes from")]
    assert order == sorted(order)
    assert "9999 resamples" in "\n".join(lines[order[3]:order[4]])  # the bootstrap's details: How to read
    rows = _rows(tmp_path / "docs" / "per_run.csv")  # the runs, one a row, instead of a listing on the page
    assert len(rows) == 12 and {r["status"] for r in rows} == {"done"}
    cmz0 = next(r for r in rows if (r["method"], r["trial"]) == ("cmz", "0"))
    assert (float(cmz0["final_return"]), cmz0["final_episodes"], float(cmz0["lowest_u_return"])) == (300.0, "3", 220.0)
    assert f"`{ENV}/cmz/trial0`" not in text  # no per-run listing on the page


def test_the_final_evaluation_figure_reads_at_page_width(tmp_path):
    # Five envs: two panels a row (three rows, the legend in the sixth panel), not five in one row.
    envs = ("Hopper-v5", "Walker2d-v5", "Swimmer-v5", "Ant-v5", "HalfCheetah-v5")
    for env in envs:
        for trial in range(3):
            write_run(tmp_path / "runs", "bc", trial, [1.0], env=env, final={"final": [100.0, 120.0]})
            write_run(tmp_path / "runs", "cmz", trial, [1.0, 2.0], env=env, final={"final": [300.0, 320.0]})
    path = plot_final(final_table(load_runs(tmp_path / "runs")), tmp_path / "fig.png", "t")
    header = path.read_bytes()
    assert header[:8] == PNG
    width, height = int.from_bytes(header[16:20], "big"), int.from_bytes(header[20:24], "big")
    assert width < 1.6 * 110 * 6 * 2 and height > width  # about 11 inches wide at 110 dpi, taller than wide


def test_setting_differences_name_missing_settings(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    write_run(a, "bc", 0, [1.0], hyperparams={"standardize_observations": "auto", "n_steps": 2048, "norm": 1})
    write_run(b, "bc", 0, [1.0], hyperparams={"n_steps": 2048})
    write_run(b, "bc", 0, [1.0], env="Hopper-v5", hyperparams={"n_steps": 1})  # only in b: not compared
    write_run(a, "cmz-sac", 0, [1.0], hyperparams={"buffer_size": 10})  # a method only a has: not compared
    # a setting one grid leaves out counts at the learner's default (here 'auto': no difference); a key
    # that is no constructor argument and that one grid lacks is named as not set
    assert setting_differences(load_runs(a), load_runs(b)) == {ENV: [("norm", "1", NOT_SET)]}
    c = tmp_path / "c"
    write_run(c, "bc", 0, [1.0], hyperparams={"n_steps": 2048, "norm": 1})
    assert setting_differences(load_runs(a), load_runs(c)) == {}


def test_readme_block_shows_the_headline(main_grid, tmp_path, capsys):
    ref = _reference_grid(tmp_path / "paper_faithful")
    readme = tmp_path / "README.md"
    readme.write_text(f"# X\n\n{report.README_BEGIN}\nold table\n{report.README_END}\n\nafter\n")
    assert main(["report", str(main_grid), "--reference-runs", str(ref), "-o", str(tmp_path / "docs"),
                 "--label", "new", "--reference-label", "old", "--readme", str(readme), "--no-figures"]) == 0
    text = readme.read_text()
    assert "old table" not in text and text.startswith("# X\n\n") and text.endswith(f"{report.README_END}\n\nafter\n")
    block = text[text.index(report.README_BEGIN):text.index(report.README_END)]
    # Small: one row per env, one column per method (final policies, then CMZ-DRIL's lowest u), each cell
    # the final evaluation's % of the expert; nothing of the reference grid or the paper.
    assert "| Env | BC | CMZ-DRIL | No reward | CMZ-DRIL (lowest u) |" in block
    expert = [1001 + 10 * t for t in range(4)]  # 1000 + 10 trial + mean of episodes 0-2
    cmz = report.fmt_ci(*mean_ci([100 * r / e for r, e in zip([300, 110, 600, 90], expert, strict=True)]))
    (row,) = [line for line in block.splitlines() if line.startswith(f"| {ENV} |")]
    assert row.split(" | ")[2] == cmz
    assert "1690" not in block and "old:" not in block
    assert f"From 12 runs in `{main_grid}`, final evaluation:" in block
    assert "details in [results.md](docs/results.md)" in block
    assert len(block.splitlines()) <= 12
    note = block.splitlines()[-1]  # under the table: at most two sentences
    assert block.splitlines()[-2] == "" and note.count(". ") <= 1 and note.endswith(".")
    readme.write_text("no block here\n")
    assert main(["report", str(main_grid), "-o", str(tmp_path / "again"), "--readme", str(readme)]) == 2
    assert "has no results block" in capsys.readouterr().err
    assert not (tmp_path / "again" / "results.md").exists()


def test_final_table_orders_final_then_lowest_u(main_grid):
    rows = final_table(load_runs(main_grid))
    assert [(r.method, r.policy) for r in rows] == [("bc", "final"), ("cmz", "final"), ("zero", "final"),
                                                    ("cmz", "lowest_u"), ("zero", "lowest_u")]


def test_the_off_policy_method_is_paired_with_its_own_learner_without_reward(tmp_path):
    # Held-out returns per trial: cmz-sac's result (its longest-episodes choice) beats zero-sac's in
    # trials 0 and 2 (by 30, -10, 50); each last-weights row is paired with the other's last weights.
    returns = {"bc": ([10, 10, 10], None), "cmz-sac": ([100, 90, 120], [80, 70, 60]),
               "zero-sac": ([70, 100, 70], [90, 90, 90])}
    for method, (longest, last) in returns.items():
        for trial in range(3):
            final = {"final": [float(last[trial])] * 2, "longest": [float(longest[trial])] * 2} if last else \
                {"final": [float(longest[trial])] * 2}
            write_run(tmp_path, method, trial, [1.0], final=final)
    table = paired_markdown(final_table(load_runs(tmp_path)))
    assert f"| CMZ-DRIL (SAC) | 3 of 3 | {report.fmt_ci(*mean_ci([90.0, 80.0, 110.0]))} |" in table
    assert f"| 2 of 3 | {report.fmt_ci(*mean_ci([30.0, -10.0, 50.0]))} | ?, ?, ? |" in table  # longest vs longest
    assert f"| 0 of 3 | {report.fmt_ci(*mean_ci([-10.0, -20.0, -30.0]))} | — |" in table  # last weights vs last
    assert sum("| No reward (SAC)" in line and "| — | — |" in line for line in table.splitlines()) == 2


# -- Table I, gap closed, reward signal, discussion (moved from test_experiments.py) -------------------
def test_report_gap_closed_and_window_on_synthetic_runs(tmp_path):
    runs_dir = tmp_path / "runs"
    n = 150  # more than the 100-epoch window: the first 50 epochs must not count
    for trial, shift in ((0, 0.0), (1, 20.0)):
        write_run(runs_dir, "zero", trial, [-1e6] * 50 + [100 + shift] * 100, [5.0] * n, [0.5] * n)
        write_run(runs_dir, "env", trial, [-1e6] * 50 + [300 + shift] * 100, [1.0] * n, [0.3] * n)
        write_run(runs_dir, "cmz", trial, [-1e6] * 50 + [200 + shift] * 100, [4.0] * n, [0.4] * n)
        write_run(runs_dir, "bc", trial, [50 + shift], [6.0], [0.6])
    path = report.write_report(runs_dir, tmp_path / "docs", references=(), figures=False)
    text = path.read_text()
    assert "| CMZ-DRIL | 210 (10.0) |" in text and "| BC | 60.0 (10.0) |" in text  # Table I's return
    table = {r["method"]: r for r in _rows(tmp_path / "docs" / "table1.csv")}  # and its other metrics
    cmz = [float(table["cmz"][k]) for k in ("frechet_mean", "frechet_std", "action_mse_mean")]
    bc = [float(table["bc"][k]) for k in ("return_mean", "frechet_mean", "action_mse_mean")]
    assert cmz == pytest.approx([4.0, 0.0, 0.4]) and bc == pytest.approx([60.0, 6.0, 0.6])
    assert "| HalfCheetah-v5 | 2 | 50% | 25% | 50% |" in text  # (210-110)/(310-110), (4-5)/(1-5), (0.4-0.5)/(0.3-0.5)
    assert "paper's Table I" not in text
    gaps = report.gap_closed(report.table_one(report.load_runs(runs_dir)))
    assert gaps["HalfCheetah-v5"]["return"] == pytest.approx(0.5)


def test_report_gap_closed_pairs_trials_of_a_partial_grid(tmp_path):
    # env reward has only trial 1 so far: the gap must use trial 1 of every method, not the means of
    # two cmz and zero trials against one env-reward trial
    runs_dir = tmp_path / "runs"
    for trial, shift in ((0, 0.0), (1, 1000.0)):
        write_run(runs_dir, "zero", trial, [100 + shift] * 3)
        write_run(runs_dir, "cmz", trial, [200 + shift] * 3)
    write_run(runs_dir, "env", 1, [1300.0] * 3)
    rows = report.table_one(report.load_runs(runs_dir))
    assert report.gap_trials(rows) == {"HalfCheetah-v5": [1]}
    assert report.gap_closed(rows)["HalfCheetah-v5"]["return"] == pytest.approx(0.5)  # (1200-1100)/(1300-1100)
    write_run(tmp_path / "none", "cmz", 0, [1.0] * 3)
    write_run(tmp_path / "none", "zero", 0, [1.0] * 3)
    write_run(tmp_path / "none", "env", 1, [2.0] * 3)
    lonely = report.table_one(report.load_runs(tmp_path / "none"))
    assert report.gap_closed(lonely)["HalfCheetah-v5"]["return"] is None
    text = report.write_report(tmp_path / "none", tmp_path / "docs", references=(), figures=False).read_text()
    assert "| HalfCheetah-v5 | 0 | n/a | n/a | n/a |" in text


def test_report_gap_closed_is_none_where_the_env_reward_does_no_better_than_no_reward(tmp_path):
    runs_dir = tmp_path / "runs"
    # return: the env reward beats no reward (a gap); Fréchet: the env reward is further than no reward
    # (lower is better: no gap); action MSE: both alike (no gap)
    write_run(runs_dir, "zero", 0, [100.0] * 3, [5.0] * 3, [0.5] * 3)
    write_run(runs_dir, "env", 0, [300.0] * 3, [5.1] * 3, [0.5] * 3)
    write_run(runs_dir, "cmz", 0, [200.0] * 3, [4.0] * 3, [0.4] * 3)
    gaps = report.gap_closed(report.table_one(report.load_runs(runs_dir)))["HalfCheetah-v5"]
    assert gaps == {"return": pytest.approx(0.5), "frechet": None, "action_mse": None}
    text = report.write_report(runs_dir, tmp_path / "docs", references=(), figures=False).read_text()
    assert "| HalfCheetah-v5 | 1 | 50% | n/a | n/a |" in text


def _progress_csv(run_dir: Path, start: int, u, ep_len) -> None:
    logs = run_dir / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    lines = ["time/total_timesteps,rollout/disagreement_mean,rollout/shaped_reward_mean,rollout/ep_len_mean"]
    lines += [f"{(start + i + 1) * 64},{v},0.0,{n}" for i, (v, n) in enumerate(zip(u, ep_len, strict=True))]
    (logs / f"progress_{start * 64}.csv").write_text("\n".join(lines) + "\n")


def test_report_reward_signal_joins_segments_and_averages_trials(tmp_path):
    runs_dir = tmp_path / "runs"
    for trial, offset in ((0, 0.0), (1, 1.0)):
        run = write_run(runs_dir, "cmz", trial, [1.0] * 3)
        # two segments (a resumed run), written out of order: the report orders them by start step,
        # and the second (from step 12 * 64) replaces the first's rows logged after that step
        _progress_csv(run, 12, [offset + 3.0] * 12, [500] * 12)
        _progress_csv(run, 0, [offset + 1.0] * 10 + [offset + 2.0] * 2 + [-1e9] * 3, [100] * 15)
    write_run(runs_dir, "bc", 0, [1.0])
    signal = report.reward_signal(report.load_runs(runs_dir), epochs=10)
    assert set(signal) == {("HalfCheetah-v5", "cmz")}  # BC has no rollouts
    cell = signal[("HalfCheetah-v5", "cmz")]
    assert cell["u"] == (pytest.approx(1.5), pytest.approx(3.5))  # mean over trials of 1+o and 3+o
    assert cell["ep_len"] == (pytest.approx(100.0), pytest.approx(500.0))
    assert np.isnan(cell["ubar"][0]) and cell["trials"][0] == 2
    text = report.write_report(runs_dir, tmp_path / "docs", references=(), figures=False).read_text()
    assert "| HalfCheetah-v5 | CMZ-DRIL | 2 | 1.50 → 3.50 | 0 → 0 | n/a → n/a | 100 → 500 |" in text


def test_report_links_the_discussion_and_refuses_a_missing_one(tmp_path, capsys):
    runs_dir = tmp_path / "runs"
    write_run(runs_dir, "bc", 0, [1.0])
    notes = tmp_path / "notes.md"
    notes.write_text("Ours agree with the paper on Hopper.\n")
    assert main(["report", str(runs_dir), "-o", str(tmp_path / "docs"), "--discussion", str(notes),
                 "--no-figures"]) == 0
    text = (tmp_path / "docs" / "results.md").read_text()
    # Linked, relative to the page (mkdocs checks it), near the top; not copied.
    assert "[the discussion](../notes.md)" in text and "Ours agree" not in text
    assert text.index("[the discussion]") < text.index("## Headline")
    assert (tmp_path / "docs" / "../notes.md").resolve() == notes.resolve()
    assert main(["report", str(runs_dir), "-o", str(tmp_path / "x"), "--discussion", str(tmp_path / "nope.md")]) == 2
    assert "discussion file not found" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()  # refused before writing anything


def test_report_copies_one_section_of_the_discussion_with_its_links_made_to_work(tmp_path, capsys):
    runs_dir = tmp_path / "runs"
    write_run(runs_dir, "bc", 0, [1.0])
    docs = tmp_path / "docs"
    (docs / "studies").mkdir(parents=True)
    notes = docs / "studies" / "notes.md"
    notes.write_text("# Notes\n\n## How it was chosen\n\nBy hand.\n\n## Where the targets stand (D14)\n\n"
                     "- Not met: Walker2d-v5 40.6 against 54 ([why](#how-it-was-chosen), [runs](runs.md#walker),\n"
                     "  [code](https://example.org/x.md)).\n\n### A subsection\n\nIt stays.\n\n"
                     "```\n## not a heading inside a fence\n```\n\n## Commands\n\nLeft out.\n")
    assert main(["report", str(runs_dir), "-o", str(docs), "--discussion", str(notes), "--discussion-section",
                 "Where the targets", "--no-figures"]) == 0
    text = (docs / "results.md").read_text()
    copied = text[text.index("## Where the targets stand (D14)"):]
    assert copied.index("Written by hand, copied from [the discussion](studies/notes.md#where-the-targets-stand-d14)") \
        < copied.index("- Not met: Walker2d-v5 40.6 against 54")
    # Links as they pointed from the discussion: into it, beside it, elsewhere on the web.
    assert "[why](studies/notes.md#how-it-was-chosen), [runs](studies/runs.md#walker)" in copied
    assert "[code](https://example.org/x.md)" in copied
    assert "### A subsection" in copied and "## not a heading inside a fence" in copied
    assert "By hand." not in text and "Left out." not in text
    assert "no number is typed in, except the paper's and the section copied from the discussion, labelled" in text
    assert text.index("## Headline") < text.index("## Where the targets stand") < text.index("## Per task")
    for argv, message in (
        (["--discussion", str(notes), "--discussion-section", "Nowhere"],
         "no section of " + str(notes) + " starts with 'Nowhere' (its sections: How it was chosen; Where the "
         "targets stand (D14); Commands)"),
        (["--discussion-section", "Where"], "a discussion section to copy needs the discussion page it is in"),
    ):
        assert main(["report", str(runs_dir), "-o", str(tmp_path / "x"), *argv, "--no-figures"]) == 2
        assert message in capsys.readouterr().err
        assert not (tmp_path / "x").exists()  # refused before writing anything


def test_a_copied_section_s_heading_gets_the_anchor_mkdocs_gives_it():
    from cmzdril_lab.report.excerpt import slug

    assert slug("Where the targets stand (D14)") == "where-the-targets-stand-d14"
    assert slug("Walker2d-v5's ceiling: the budget") == "walker2d-v5s-ceiling-the-budget"
    assert slug("The default from 0.3.0, D14") == "the-default-from-030-d14"


@pytest.mark.slow
def test_the_published_report_stays_a_page_a_reader_finishes(tmp_path):
    # docs/results.md's own inputs (the command at its end), written beside the docs folder it links from.
    root = Path(__file__).resolve().parent.parent
    if not (root / "results" / "runs.tar.xz").is_file():
        pytest.skip("no published run records here")
    docs = tmp_path / "docs"
    shutil.copy(root / "docs" / "discussion.md", tmp_path / "discussion.md")
    text = report.write_report(root / "results" / "runs", docs, reference_runs=root / "results" / "runs_paper_faithful",
                               aggregate_runs=[root / "results" / "outside_env"], label="new defaults",
                               reference_label="paper-faithful", discussion=tmp_path / "discussion.md").read_text()
    assert len(text.splitlines()) <= 300
    assert "[the discussion](../discussion.md)" in text and "### Two grids" not in text
    lines = text.splitlines()
    first = next(i for i, line in enumerate(lines) if line.startswith("|"))
    assert lines[first - 2] == "## Headline" and lines[first].startswith("| Env | BC | DRIL | CMZ-DRIL |")


def test_an_interrupted_report_leaves_the_one_before_whole(main_grid, tmp_path, monkeypatch, capsys):
    import cmzdril_lab.report.report as report_module

    out = tmp_path / "report"
    assert main(["report", str(main_grid), "-o", str(out), "--no-figures"]) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    # A killed report's staging folder (its process is gone) is cleared by the next one.
    (out / f"{report_module.STAGING_PREFIX}999999999").mkdir()
    write_run(main_grid, "bc", 9, [1.0, 2.0], final={"final": [5.0, 6.0]})  # a run that changes the tables

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt  # Ctrl-C after the tables are staged, before results.md

    monkeypatch.setattr(report_module, "render_markdown", interrupted)
    assert main(["report", str(main_grid), "-o", str(out), "--no-figures", "--force"]) == 130
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    monkeypatch.undo()
    assert main(["report", str(main_grid), "-o", str(out), "--no-figures", "--force"]) == 0
    assert not list(out.glob(f"{report_module.STAGING_PREFIX}*"))
    assert (out / "final_table.csv").read_bytes() != before["final_table.csv"]
