"""The report on hand-written run folders: Table I, the final evaluation with its bootstrap CIs, two
grids side by side, partial grids, the README block and the figures.

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
        assert f"| {ENV} | {name} | 4 | 3 | {report.fmt_ci(mean, low, high)} |" in text
    assert "| HalfCheetah-v5 | CMZ-DRIL | 3 of 4 | " + report.fmt_ci(*mean_ci([100, -40, 400, 20])) in text
    assert "| 3 of 4 | " + report.fmt_ci(*mean_ci([50, -20, 100, 30])) + " | — |" in text  # CMZ-DRIL vs no reward
    assert "| HalfCheetah-v5 | CMZ-DRIL (lowest u) | 4 of 4 |" in text  # 220, 160, 300, 100 vs 200, 150, 200, 70
    assert "| 10, 11, 12, 13 |" in text  # the epochs each lowest-u choice came from
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
    assert f"| {ENV} | CMZ-DRIL | 4 | 3 | {ret} | {report.fmt_ci(np.mean(cmz), low, high)} |" in text
    assert "| Return | % of expert | Fréchet distance |" in text  # right after Return
    lowest = [_pct(v, t) for t, v in enumerate(LOWEST["cmz"])]
    assert float(table[("cmz", "lowest_u")]["pct_of_expert_mean"]) == pytest.approx(np.mean(lowest), rel=1e-12)
    # Paired: trial by trial against BC's 200, 150, 200, 70 on the same episodes
    bc = [_pct(v, t) for t, v in enumerate(FINAL["bc"])]
    diff = report.fmt_ci(*mean_ci([c - b for c, b in zip(cmz, bc, strict=True)]))
    assert f"| {ENV} | CMZ-DRIL | 3 of 4 | {report.fmt_ci(*mean_ci([100, -40, 400, 20]))} | {diff} | 3 of 4 |" in text
    assert "| Return − BC, mean [CI] | % of expert − BC, mean [CI] |" in text
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
    assert f"| {ENV} | CMZ-DRIL | 3 | 2 | {ret} | n/a | " in text  # final table: % of expert
    assert f"| 0.02 [0.01, 0.03] | n/a | {expert} |" in text  # and episodes at expert level, as before
    assert f"| {ENV} | CMZ-DRIL | {ret}, n=3 | n/a, n=3 |" in text  # headline
    assert f"| {ENV} | CMZ-DRIL | 3 of 3 | 200 [200, 200] | n/a | — | — | — |" in text  # return: paired; % n/a
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
    assert "| HalfCheetah-v5 | BC | 2 | 2 | 70.0 [n/a] |" in text  # (50 + 90) / 2, no CI from 2 trials
    assert "| HalfCheetah-v5 | CMZ-DRIL | 1 | 2 | 40.0 [n/a] |" in text
    assert "| HalfCheetah-v5 | CMZ-DRIL | 0 of 1 | -10.0 [n/a] |" in text  # 40 - 50 on trial 0
    assert "| HalfCheetah-v5 | CMZ-DRIL | 2 | 17.5 (2.50) |" in text  # Table I: (15 + 20) / 2
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
    assert "None: no run of this grid has a final_eval.csv" in text
    assert "| HalfCheetah-v5 | CMZ-DRIL | 150 (0.25), n=2 |" in text  # headline, Table I only: 150 and 150.5
    assert not (out / "final_table.csv").exists()
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
    for name in ("table1.csv", "final_table.csv"):
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
    assert "| HalfCheetah-v5 | CMZ-DRIL | 4 |" in text  # still the four trials of the fixture


def test_a_nan_row_is_left_out_not_the_method(tmp_path):
    root = tmp_path / "runs"
    for trial in (0, 1):
        write_run(root, "cmz", trial, [100.0, float("nan") if trial else 150.0, 200.0])
    text = report.write_report(root, tmp_path / "docs", references=(), figures=False).read_text()
    # Table I: trial 0 (100 + 150 + 200) / 3 = 150, trial 1 (100 + 200) / 2 = 150
    assert "| HalfCheetah-v5 | CMZ-DRIL | 2 | 150 (0) |" in text
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
    header = ("| Env | Method | new: final evaluation, mean [95% CI] "
              "| new: final evaluation, % of expert [95% CI] | new: Table I, mean (std) "
              "| old: Table I, mean (std) | The paper's Table I, mean (std) |")
    assert header in text
    row = next(line for line in text.splitlines() if line.startswith(f"| {ENV} | CMZ-DRIL |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[2] == f"{report.fmt_ci(*mean_ci([300, 110, 600, 90]))}, n=4"  # final evaluation
    assert cells[3] == f"{report.fmt_ci(*mean_ci([_pct(v, t) for t, v in enumerate(FINAL['cmz'])]))}, n=4"
    window = [(0.0 + 100 + t + 200 + t) / 3 for t in range(4)]  # Table I: 3 epochs, all in the window
    assert cells[4] == f"{report.fmt_mean_std(np.mean(window), np.std(window))}, n=4"
    assert cells[5:] == ["25.0 (5.00), n=2", "1690 (360)"]  # old: mean of 20 and 30 (2 epochs each); the paper
    bc = report.fmt_ci(*mean_ci([200, 150, 200, 70]))
    bc_pct = report.fmt_ci(*mean_ci([_pct(v, t) for t, v in enumerate(FINAL["bc"])]))
    assert f"| {ENV} | BC | {bc}, n=4 | {bc_pct}, n=4 | 155 (53.2), n=4 | 30.0 (0), n=1 | 708 (162) |" in text
    lowest, lowest_pct = mean_ci([220, 160, 300, 100]), mean_ci([_pct(v, t) for t, v in enumerate(LOWEST["cmz"])])
    assert (f"| {ENV} | CMZ-DRIL (lowest u) | {report.fmt_ci(*lowest)}, n=4 | {report.fmt_ci(*lowest_pct)}, n=4 "
            "| — | — | — |") in text
    expert = report.fmt_ci(*mean_ci([1001 + 10 * t for t in range(4)]))
    assert f"| {ENV} | Expert (held-out demos) | {expert}, n=4 | — |" in text  # no % of the expert itself
    assert "old: no final evaluation (its runs have no final_eval.csv)" in text
    assert f"- {ENV}: `bc_pretrain_epochs` 1000 vs 100" in text
    assert "## new" in text and "## old" in text and f"`{ref}`" in text
    assert {p.name for p in out.iterdir()} == {"results.md", "table1.csv", "table1_reference.csv", "final_table.csv",
                                              "fig1_bc_dril_cmz.png", "fig2_cmz_env_zero.png", "fig3_final_eval.png",
                                              "across_tasks.csv", "fig4_across_tasks.png"}
    assert _rows(out / "table1_reference.csv")[1]["run_dirs"] == f"{ENV}/cmz/trial0;{ENV}/cmz/trial1"
    # Existing report files are kept unless --force; two grids need two names.
    assert main(["report", str(main_grid), "-o", str(out)]) == 2
    assert "final_table.csv" in capsys.readouterr().err
    assert main(["report", str(main_grid), "--reference-runs", str(ref), "-o", str(tmp_path / "x"),
                 "--label", "same", "--reference-label", "same"]) == 2
    assert "both grids are labelled 'same'" in capsys.readouterr().err


def test_setting_differences_name_missing_settings(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    write_run(a, "bc", 0, [1.0], hyperparams={"standardize_observations": True, "n_steps": 2048})
    write_run(b, "bc", 0, [1.0], hyperparams={"n_steps": 2048})
    write_run(b, "bc", 0, [1.0], env="Hopper-v5", hyperparams={"n_steps": 1})  # only in b: not compared
    write_run(a, "cmz-sac", 0, [1.0], hyperparams={"buffer_size": 10})  # a method only a has: not compared
    assert setting_differences(load_runs(a), load_runs(b)) == {ENV: [("standardize_observations", "true", NOT_SET)]}


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
    assert f"From 12 runs in `{main_grid}`;" in block
    assert "details in [results.md](docs/results.md)" in block
    assert len(block.splitlines()) <= 12
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
    assert "| HalfCheetah-v5 | CMZ-DRIL | 2 | 210 (10.0) | 4.00 (0) | 0.4 (0) |" in text
    assert "| HalfCheetah-v5 | BC | 2 | 60.0 (10.0) | 6.00 (0) | 0.6 (0) |" in text
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


def test_report_includes_the_discussion_and_refuses_a_missing_one(tmp_path, capsys):
    runs_dir = tmp_path / "runs"
    write_run(runs_dir, "bc", 0, [1.0])
    notes = tmp_path / "notes.md"
    notes.write_text("Ours agree with the paper on Hopper.\n")
    assert main(["report", str(runs_dir), "-o", str(tmp_path / "docs"), "--discussion", str(notes),
                 "--no-figures"]) == 0
    assert "## Discussion\n\nOurs agree with the paper on Hopper.\n" in (tmp_path / "docs" / "results.md").read_text()
    assert main(["report", str(runs_dir), "-o", str(tmp_path / "x"), "--discussion", str(tmp_path / "nope.md")]) == 2
    assert "discussion file not found" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()  # refused before writing anything
