"""The study tables of docs/new_tasks.md (cmzdril_lab.report.studies), paired by trial,
and benchmarks/studies/new_tasks.py, the script that writes the page, run as a user runs it."""
from __future__ import annotations

import importlib
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cmzdril_lab.report import studies
from helpers import write_run

REPO = Path(__file__).resolve().parent.parent

ENV = "Walker2d-v5"


@pytest.fixture
def root(tmp_path: Path) -> Path:
    # Reference: trials 0-2 return 100/200/300 on two held-out episodes against an expert of
    # 1000 + 10 t + episode. The variant: trials 0-1 only, 250 and 150.
    for trial, value in enumerate([100.0, 200.0, 300.0]):
        write_run(tmp_path / "ref", "cmz", trial, [1.0], env=ENV, final={"final": [value, value]})
    for trial, value in enumerate([250.0, 150.0]):
        write_run(tmp_path / "var", "cmz", trial, [1.0], env=ENV, final={"final": [value, value]})
    # The published grid's BC (trials 0-2: 120/120/120); no DRIL there.
    for trial in range(3):
        write_run(tmp_path / "results" / "runs", "bc", trial, [1.0], env=ENV, final={"final": [120.0, 120.0]})
    return tmp_path


def _variants(*folders: str):
    return tuple(studies.Variant(ENV, "cmz", f"from {f}", f, "pytest") for f in folders)


def test_percent_of_expert_and_paired_count_by_hand(root):
    # A sweep of the demonstrations over the grid's folder, whose runs do not record n_demos.
    demos = studies.Sweep(ENV, ("bc",), "n_demos", "demos", ("results/runs",), "d.png", "pytest")
    text = studies.render(root, _variants("ref", "var", "missing"), sweeps=(demos,))
    lines = {line.split(" | ")[0].strip("| "): line for line in text.splitlines() if line.startswith("| from")}
    # Trial t's expert mean over episodes 0 and 1: 1000.5 + 10 t. Reference: 100 / 1000.5, 200 / 1010.5,
    # 300 / 1020.5 -> 9.995, 19.79, 29.40 %: mean 19.73.
    ref_pct = [100 * 100 / 1000.5, 100 * 200 / 1010.5, 100 * 300 / 1020.5]
    assert f"{sum(ref_pct) / 3:.3g}" in lines["from ref"]
    # Against the grid's BC (120 in every trial): the reference is above it in 2 of 3, the variant in 2 of 2.
    assert "0: 100, 1: 200, 2: 300" in lines["from ref"] and lines["from ref"].endswith("| reference | 2 of 3 | — |")
    # The mean return over trials beside it, with its interval: the column a task with negative returns reads.
    assert "| 200 [" in lines["from ref"] and "| Final policy: return [95% CI] |" in text
    # The variant beats the reference in trial 0 (250 > 100), not in trial 1 (150 < 200); trial 2 is not shared.
    assert lines["from var"].endswith("| 1 of 2 | 2 of 2 | — |") and "n/a" in lines["from var"]  # no CI: 2 trials
    assert "| from missing | 0 | no finished runs |" in lines["from missing"]
    assert "missing: no such runs folder" in text
    assert "config.json has no n_demos" in text  # the demo sweep leaves out a run that does not say


def test_baselines_from_a_second_folder_add_only_the_trials_the_grid_lacks(root):
    # A second folder's BC: trial 0 at 900 (the grid's 120 stands) and trial 3 at 500, the trial the
    # grid lacks; the variant's trial 3 (600) is then paired too.
    for trial, value in [(0, 900.0), (3, 500.0)]:
        write_run(root / "more", "bc", trial, [1.0], env=ENV, final={"final": [value, value]})
    write_run(root / "var", "cmz", 3, [1.0], env=ENV, final={"final": [600.0, 600.0]})
    text = studies.render(root, _variants("ref", "var"), grid=("results/runs", "more"))
    lines = {line.split(" | ")[0].strip("| "): line for line in text.splitlines() if line.startswith("| from")}
    # Variant against BC: trial 0 250 > 120, trial 1 150 > 120, trial 3 600 > 500: 3 of 3.
    assert lines["from var"].endswith("| 1 of 2 | 3 of 3 | — |")
    assert "Final above BC of `results/runs` + `more` (trials)" in text


def test_a_variant_limited_to_some_trials_counts_only_those(root):
    # The reference folder's trials 1-2 only (200, 300): paired with the whole reference, it is
    # the reference itself on those trials, so above it in 0 of 2; above the grid's BC (120) in 2 of 2.
    tail = studies.Variant(ENV, "cmz", "from ref, trials 1-2", "ref", "pytest", trials=(1, 2))
    none = studies.Variant(ENV, "cmz", "from ref, trial 7", "ref", "pytest", trials=(7,))
    text = studies.render(root, (*_variants("ref"), tail, none))
    lines = {line.split(" | ")[0].strip("| "): line for line in text.splitlines() if line.startswith("| from")}
    assert "| 2 |" in lines["from ref, trials 1-2"] and "1: 200, 2: 300" in lines["from ref, trials 1-2"]
    assert "0: 100" not in lines["from ref, trials 1-2"]
    assert lines["from ref, trials 1-2"].endswith("| 0 of 2 | 2 of 2 | — |")
    assert "| from ref, trial 7 | 0 | no finished runs |" in lines["from ref, trial 7"]


def test_a_confirmation_row_of_the_reference_pairs_the_variants_on_its_trials(root):
    # The reference's trials 5-6 live in another folder (90, 210); the variant's trials 5-6 (100, 200) are
    # above it in 1 of 2; without the extension they would share no trial with the reference.
    for trial, (theirs, mine) in zip((5, 6), ((90.0, 100.0), (210.0, 200.0)), strict=True):
        write_run(root / "ref5", "cmz", trial, [1.0], env=ENV, final={"final": [theirs] * 2})
        write_run(root / "var5", "cmz", trial, [1.0], env=ENV, final={"final": [mine] * 2})
    confirmation = studies.Variant(ENV, "cmz", "ref, trials 5-6", "ref5", "pytest", extends_reference=True)
    variant = studies.Variant(ENV, "cmz", "var, trials 5-6", "var5", "pytest")
    text = studies.render(root, (*_variants("ref"), confirmation, variant))
    lines = {line.split(" | ")[0].strip("| "): line for line in text.splitlines() if line.startswith("| ")}
    assert lines["ref, trials 5-6"].endswith("| reference | 0 of 0 | — |")
    assert lines["var, trials 5-6"].endswith("| 1 of 2 | 0 of 0 | — |")
    plain = studies.render(root, (*_variants("ref"), studies.Variant(ENV, "cmz", "ref, trials 5-6", "ref5", "pytest"),
                                  variant))
    assert next(line for line in plain.splitlines() if line.startswith("| var, trials 5-6")).endswith(
        "| 0 of 0 | 0 of 0 | — |")


def test_the_reward_free_choice_is_paired_with_bc_and_dril_by_hand(root):
    # The variant's lowest-u policies: 130 and 90 (trials 0-1); the grid's BC 120 in every trial, its DRIL
    # 100 (trial 0) and 80 (trial 1): the choice is above BC in 1 of 2 and above DRIL in 2 of 2.
    for trial, value in enumerate([130.0, 90.0]):
        write_run(root / "choice", "cmz", trial, [1.0], env=ENV, final={"final": [50.0, 50.0], "lowest_u": [value] * 2})
        write_run(root / "results" / "runs", "dril", trial, [1.0], env=ENV, final={"final": [100.0 - 20 * trial] * 2})
    text = studies.render(root, _variants("ref", "choice"))
    line = next(line for line in text.splitlines() if line.startswith("| from choice"))
    assert "(above BC 1 of 2, DRIL 2 of 2) |" in line
    assert line.endswith("| 0 of 2 | 0 of 2 | 0 of 2 |")  # the last weights (50) are below all three
    assert "policy: % of expert (above BC, DRIL: trials)" in text


def test_the_runs_line_names_each_folder_and_command_once_with_its_methods_and_trials():
    variants = [studies.Variant(ENV, method, f"{method} {trials}", "results/tuning/X", "tune.py X", trials)
                for method in ("bc", "cmz") for trials in ((0, 1, 2, 3, 4), (5, 6, 7, 8, 9))]
    variants += [studies.Variant(ENV, "cmz", "averaged", "results/tuning/X", "tune.py X", (1, 3), "averaged"),
                 studies.Variant(ENV, "dril", "all of Y", "results/tuning/Y", "")]
    assert studies.runs_sentence(studies.variant_groups(variants)) == (
        "Runs: `results/tuning/X` (BC: trials 0-4, 5-9; CMZ-DRIL: trials 0-4, 5-9, 1, 3), made by `tune.py X`; "
        "`results/tuning/Y` (DRIL).")


def test_cpu_minutes_are_the_median_of_the_runs_that_recorded_them(root):
    # The variant's two runs took 120 and 180 CPU seconds: median 2.5 minutes. The reference's runs
    # recorded none; with one of its three runs at 600 s, the column says which share it covers.
    for trial, seconds in enumerate([120.0, 180.0]):
        done = root / "var" / ENV / "cmz" / f"trial{trial}" / "done.json"
        done.write_text(json.dumps({**json.loads(done.read_text()), "cpu_time_s": seconds}))
    text = studies.render(root, _variants("ref", "var"))
    rows = [line.split(" | ") for line in text.splitlines() if line.startswith("| from")]
    lines = {cells[0].strip("| "): cells for cells in rows}
    assert lines["from var"][7] == "2.5" and lines["from ref"][7] == "—"
    done = root / "ref" / ENV / "cmz" / "trial1" / "done.json"
    done.write_text(json.dumps({**json.loads(done.read_text()), "cpu_time_s": 600.0}))
    text = studies.render(root, _variants("ref", "var"))
    assert "| 10.0 (1 of 3 runs) |" in text
    # Runs made on two processors: the cell names both, since their CPU seconds do not compare.
    for trial, cpu in enumerate(["CPU B", "CPU A"]):
        done = root / "var" / ENV / "cmz" / f"trial{trial}" / "done.json"
        done.write_text(json.dumps({**json.loads(done.read_text()), "cpus": [cpu]}))
    text = studies.render(root, _variants("ref", "var"))
    assert "| 2.5 (on 2 CPU models: CPU A, CPU B) |" in text


def _with_cost(run: Path, cpu_seconds: float, steps: int) -> None:
    done = run / "done.json"
    done.write_text(json.dumps({**json.loads(done.read_text()), "cpu_time_s": cpu_seconds, "num_timesteps": steps}))


def test_cost_curves_put_the_runs_on_one_cpu_time_axis_by_hand(tmp_path):
    # Evaluations 0, 100, 200 at steps 0, 2048, 4096 of 4096. Run 0 spent 120 CPU seconds: its evaluations
    # sit at 0, 1 and 2 CPU minutes; run 1 spent 240: at 0, 2 and 4. Run 2 kept no CPU time.
    runs = [write_run(tmp_path / "v", "cmz", t, [0.0, 100.0, 200.0], env=ENV, final={"final": [1.0]})
            for t in range(3)]
    _with_cost(runs[0], 120.0, 4096)
    _with_cost(runs[1], 240.0, 4096)
    records = studies.variant_rows(studies.Variant(ENV, "cmz", "v", "v", ""), tmp_path, [])["final"].runs
    assert studies.cpu_minutes_axis(records[0]).tolist() == [0.0, 1.0, 2.0]
    assert studies.cpu_minutes_axis(records[2]) is None
    axis, mean, std, n = studies.cost_band(records)
    # The axis ends where run 0 ended (2 minutes). There run 0 is at 200 and run 1 at 100; at 1 minute
    # 100 and 50.
    assert n == 2 and axis[-1] == 2.0
    assert mean[-1] == pytest.approx(150.0) and std[-1] == pytest.approx(50.0)
    assert float(np.interp(1.0, axis, mean)) == pytest.approx(75.0)
    curves = studies.CostCurves(ENV, "against CPU", "cost.png",
                                (studies.Variant(ENV, "cmz", "v", "v", ""), studies.Variant(ENV, "cmz", "w", "w", "")))
    text = studies.render(tmp_path, cost_curves=(curves,), figures=tmp_path / "figures")
    # Steps per CPU second: 4096 / 120 = 34.1 and 4096 / 240 = 17.1, median 25.6; CPU minutes: 2 and 4, median 3.
    assert "| v | 3 | 25.6 | 3.0 (2 of 3 runs) |" in text
    assert (tmp_path / "figures" / "cost.png").stat().st_size > 0 and "## Against CPU time" in text
    empty = studies.CostCurves(ENV, "nothing", "none.png", (studies.Variant(ENV, "cmz", "w", "w", ""),))
    assert "No finished runs yet." in studies.render(tmp_path, cost_curves=(empty,))
    assert "## Against CPU time" not in studies.render(tmp_path)


@pytest.mark.slow
def test_the_script_refuses_to_replace_the_page_without_force(tmp_path):
    (tmp_path / "new_tasks.md").write_text("mine")
    script = REPO / "benchmarks" / "studies" / "new_tasks.py"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    result = subprocess.run([sys.executable, str(script), "--output", str(tmp_path)], capture_output=True, text=True,
                            cwd=tmp_path, env=env, timeout=120)
    assert result.returncode == 2, result.stderr[-2000:]
    assert "exists; pass --force" in result.stderr
    assert (tmp_path / "new_tasks.md").read_text() == "mine"


def test_episode_lengths_by_hand(tmp_path):
    # Trial 0's rollouts last 100, 110, ..., 210 steps over 12 epochs: the first 10 average 145, the last
    # 10 165. Trial 1's last 300 throughout. Over the two trials: 222.5 and 232.5. BC has no rollouts.
    for trial, lengths in enumerate([[100 + 10 * i for i in range(12)], [300] * 12]):
        run = write_run(tmp_path / "runs", "cmz", trial, [1.0], env=ENV, final={"final": [5.0, 5.0]})
        (run / "logs").mkdir()
        rows = ["time/total_timesteps,rollout/ep_len_mean"] + [f"{i},{n}" for i, n in enumerate(lengths)]
        (run / "logs" / "progress_0.csv").write_text("\n".join(rows) + "\n")
    write_run(tmp_path / "runs", "bc", 0, [1.0], env=ENV, final={"final": [5.0, 5.0]})
    table = studies.RolloutTable("rollout/ep_len_mean", "length", (ENV,), "runs", final_column="length")
    text = studies.rollout_markdown(tmp_path, [], (table,))
    cmz = next(line for line in text.splitlines() if line.startswith("| CMZ-DRIL")).removesuffix(" |")
    assert cmz.split(" | ")[1:5] == ["2", f"{studies.fmt(222.5)} [n/a]", f"{studies.fmt(232.5)} [n/a]",
                                     f"{studies.fmt(1000.0)} [n/a]"]
    assert next(line for line in text.splitlines() if line.startswith("| BC")).split(" | ")[2:4] == ["—", "—"]


def test_a_resumed_runs_rollout_ends_come_from_every_segment(tmp_path):
    # Segment 0 logged steps 1-12 (u = 1 each), then the run resumed from its checkpoint at step 8:
    # steps 9-12 of segment 0 are replaced by segment 8's steps 9-20 (u = 3). The first ten steps hold
    # eight 1s and two 3s; the last ten, 3s only.
    (tmp_path / "logs").mkdir()
    header = "time/total_timesteps,rollout/disagreement_mean"
    (tmp_path / "logs" / "progress_0.csv").write_text("\n".join([header] + [f"{t},1" for t in range(1, 13)]) + "\n")
    (tmp_path / "logs" / "progress_8.csv").write_text("\n".join([header] + [f"{t},3" for t in range(9, 21)]) + "\n")
    first, last = studies.rollout_edges(tmp_path, "rollout/disagreement_mean")
    assert (first, last) == (pytest.approx((8 * 1 + 2 * 3) / 10), 3.0)


def test_a_rollout_only_table_leaves_out_methods_without_rollouts(tmp_path):
    run = write_run(tmp_path / "runs", "dril", 0, [1.0], env=ENV, final={"final": [5.0]})
    (run / "logs").mkdir()
    (run / "logs" / "progress_0.csv").write_text("time/total_timesteps,rollout/disagreement_mean\n1,0.5\n2,0.25\n")
    write_run(tmp_path / "runs", "bc", 0, [1.0], env=ENV, final={"final": [5.0]})
    table = studies.RolloutTable("rollout/disagreement_mean", "u", (ENV,), "runs")
    lines = [line for line in studies.rollout_markdown(tmp_path, [], (table,)).splitlines() if line.startswith("| ")]
    # Header, then DRIL alone: two epochs, so both ends average both values (0.375).
    assert len(lines) == 2 and lines[1].startswith("| DRIL | 1 | 0.375")


def _sweep_run(
    root: Path, method: str, trial: int, value: float, setting: str, setting_value: int, lowest_u: float | None = None
) -> Path:
    final = {"final": [value, value]} | ({} if lowest_u is None else {"lowest_u": [lowest_u, lowest_u]})
    run = write_run(root, method, trial, [1.0, 2.0, 3.0], env=ENV, final=final)
    config = json.loads((run / "config.json").read_text())
    (run / "config.json").write_text(json.dumps({**config, setting: setting_value}))
    return run


def _table_line(text: str, method: str, value: str) -> list[str]:
    line = next(line for line in text.splitlines() if line.startswith(f"| {method} | {value} |"))
    return line.removeprefix("| ").removesuffix(" |").split(" | ")


def test_a_sweep_groups_by_the_config_value_and_pairs_by_trial(tmp_path):
    # 1 demo: BC 100/200, CMZ 150/150 in trials 0/1. 3 demos (folder "three"): BC 300 in trial 0 only,
    # CMZ 400/100 (lowest-u policy 500/300). Folder "again" repeats CMZ trial 0 with 3 demos: counted
    # once, listed as left out.
    for trial, (bc, cmz) in enumerate([(100.0, 150.0), (200.0, 150.0)]):
        _sweep_run(tmp_path / "one", "bc", trial, bc, "n_demos", 1)
        _sweep_run(tmp_path / "one", "cmz", trial, cmz, "n_demos", 1)
    _sweep_run(tmp_path / "three", "bc", 0, 300.0, "n_demos", 3)
    for trial, (cmz, lowest) in enumerate([(400.0, 500.0), (100.0, 300.0)]):
        _sweep_run(tmp_path / "three", "cmz", trial, cmz, "n_demos", 3, lowest_u=lowest)
    _sweep_run(tmp_path / "again", "cmz", 0, 999.0, "n_demos", 3)
    folders = ("one", "three", "again", "gone")
    sweep = studies.Sweep(ENV, ("bc", "cmz"), "n_demos", "demos", folders, "s.png", "pytest")
    skipped: list = []
    text = studies.sweeps_markdown(tmp_path, skipped, tmp_path / "figures", (sweep,))
    cmz3 = _table_line(text, "CMZ-DRIL", "3")
    # Trial t's expert mean over its two episodes: 1000.5 + 10 t.
    assert cmz3[2:4] == ["2", "2"]
    assert cmz3[4].startswith(f"{(100 * 400 / 1000.5 + 100 * 100 / 1010.5) / 2:.3g} ")
    assert cmz3[5] == "0: 400, 1: 100"
    assert cmz3[6].startswith(f"{(100 * 500 / 1000.5 + 100 * 300 / 1010.5) / 2:.3g} ")  # the lowest-u policy
    assert cmz3[8:] == ["1 of 1", "1 of 2"]  # 400 > BC's 300 (trial 1 has no BC); 400 > 150, 100 < 150
    assert _table_line(text, "CMZ-DRIL", "1")[6] == "—"  # no lowest-u policy in these runs
    assert _table_line(text, "CMZ-DRIL", "1")[8:] == ["1 of 2", "—"]  # 150 > 100, 150 < 200
    bc3 = _table_line(text, "BC", "3")
    assert bc3[2] == "1" and bc3[6:] == ["—", "—", "—", "1 of 1"]  # BC has no RL phase
    reasons = [s.text(tmp_path) for s in skipped]
    assert any(r.startswith("again/") and "trial 0 is already counted from three/" in r for r in reasons)
    assert "gone: no such runs folder" in reasons
    assert (tmp_path / "figures" / "s.png").stat().st_size > 0 and "![demos](figures/s.png)" in text


def test_a_budget_sweep_draws_its_curves_and_a_sweep_without_runs_says_so(tmp_path):
    for trial in range(2):
        _sweep_run(tmp_path / "short", "dril", trial, 100.0, "timesteps", 4096)
    sweep = studies.Sweep(ENV, ("dril",), "timesteps", "steps", ("short",), "b.png", "pytest")
    text = studies.sweeps_markdown(tmp_path, [], tmp_path / "figures", (sweep,))
    assert _table_line(text, "DRIL", "4,096")[2] == "2" and (tmp_path / "figures" / "b.png").is_file()
    empty = studies.Sweep(ENV, ("cmz",), "timesteps", "steps", ("short",), "e.png", "pytest", fixed="clip")
    empty_text = studies.sweeps_markdown(tmp_path, [], tmp_path / "figures", (empty,))
    assert f"### {ENV}: steps, clip\n\nNo finished runs yet." in empty_text
    assert not (tmp_path / "figures" / "e.png").exists()


def test_selection_table_puts_the_kept_policy_beside_the_last_weights_by_hand(tmp_path):
    # Expert returns on the two held-out episodes: 1000 + 10 t + (0, 1), mean 1000.5 + 10 t. Kept policies
    # at 100%, 50% and 100% of it, last weights at 50%, 100% and 0%: the kept one is above in 2 of 3.
    kept, last = [100.0, 50.0, 100.0], [50.0, 100.0, 0.0]
    for t in range(3):
        expert = 1000.5 + 10 * t
        run = write_run(tmp_path / "v", "cmz", t, [1.0], env=ENV,
                        final={"final": [kept[t] * expert / 100] * 2, "last": [last[t] * expert / 100] * 2})
        done = json.loads((run / "done.json").read_text())
        done.update(num_timesteps=20480, selection={"rule": "longest", "kept_timesteps": 10240 * t,
                                                    "kept_mean_length": 900.0 + t, "checks": [[0, 1.0]] * 3,
                                                    "env_steps": 15})
        (run / "done.json").write_text(json.dumps(done))
    # A run of the folder that chose nothing (no selection, no last weights) is not in the table.
    write_run(tmp_path / "v", "cmz", 3, [1.0], env=ENV, final={"final": [1.0, 1.0]})
    variant = studies.Variant(ENV, "cmz", "kept", "v", "python make_it.py")
    kept_row, last_row = studies.kept_and_last(variant, tmp_path, [])
    assert [r.trial for r in kept_row.runs] == [0, 1, 2] and last_row.policy == "last"
    text = studies.render(tmp_path, selections=(variant,))
    assert "## Keeping the policy that lasts longest" in text
    assert "| 1 | 3 (15) | 10240 of 20480 | 901 | n/a | 100 | 50.0 |" in text  # the study recorded no u
    # Trial 2 kept its last policy (step 20480 of 20480); of trials 0 and 1 the kept one is above in trial 0.
    assert ("is the last one in 1 of 3 trials; where it is an earlier one, it is above the last weights in 1 of 2"
            in text)
    assert "`python make_it.py`" in text
    assert "| mean [95% CI] |  |  |  |  | 50.0 [0, 100] | 83.3 [50.0, 100] |" in text
    empty = studies.Variant(ENV, "cmz", "none", "absent", "")
    assert "No finished runs yet." in studies.selection_markdown(tmp_path, [], (empty,))
    assert "## Keeping the policy" not in studies.render(tmp_path)


def test_selection_table_reads_the_package_cmz_sac_runs_kept_check_and_its_u(tmp_path):
    # The package's runs: final_eval.csv's "longest" is the kept policy and "final" the last weights; where
    # it was found (and its u) is done.json's final_evaluation.longest. Expert mean 1000.5 + 10 t.
    kept, last = [100.0, 80.0], [50.0, 80.0]
    for t in range(2):
        expert = 1000.5 + 10 * t
        run = write_run(tmp_path / "v", "cmz-sac", t, [1.0], env=ENV,
                        final={"final": [last[t] * expert / 100] * 2, "longest": [kept[t] * expert / 100] * 2})
        done = json.loads((run / "done.json").read_text())
        done.update(num_timesteps=70000, final_evaluation={"longest": {
            "timesteps": (61440, 70000)[t], "mean_length": 1000.0, "mean_u": (0.0427, 0.05)[t], "env_steps": 40000}})
        (run / "done.json").write_text(json.dumps(done))
    variant = studies.Variant(ENV, "cmz-sac", "tie", "v", "python make_it.py")
    kept_row, last_row = studies.kept_and_last(variant, tmp_path, [])
    assert (kept_row.policy, last_row.policy) == ("longest", "final") and [r.trial for r in kept_row.runs] == [0, 1]
    text = studies.selection_markdown(tmp_path, [], (variant,))
    assert "| 0 | (40000) | 61440 of 70000 | 1000 | 0.0427 | 50.0 | 100 |" in text
    assert "| 1 | (40000) | 70000 of 70000 | 1000 | 0.05 | 80.0 | 80.0 |" in text
    assert ("is the last one in 1 of 2 trials; where it is an earlier one, it is above the last weights in 1 of 1"
            in text)


def test_across_tasks_scores_each_method_on_its_own_folders_by_hand(tmp_path):
    # "new" has trials 0-1 on two tasks, except trial 1 of the second; "bc" both trials on both.
    tasks = ("Hopper-v5", ENV)
    for trial in (0, 1):
        for k, env in enumerate(tasks):
            write_run(tmp_path / "grid", "bc", trial, [1.0], env=env, final={"final": [100.0 + k, 100.0 + k]})
            if (k, trial) != (1, 1):
                write_run(tmp_path / "new", "cmz", trial, [1.0], env=env, final={"final": [900.0, 900.0]})
    study = studies.AcrossTasks(
        "t", trials=(0, 1),
        methods=(("new", "New learner", tuple(studies.Variant(env, "cmz", "x", "new", "") for env in tasks)),
                 ("bc", "BC", tuple(studies.Variant(env, "bc", "x", "grid", "") for env in tasks))),
        pairs=(("new", "bc"), ("bc", "new")), figure="across.png")
    scores = studies.across_scores(study, tmp_path, [])
    assert scores.tasks == {"new": ("Hopper-v5",), "bc": tasks}
    assert scores.left_out == ((ENV, "New learner", "no finished trial 1"),)
    # write_run's expert: 1000 + 10 t + episode on episodes 0 and 1, so a mean of 1000.5 + 10 t.
    np.testing.assert_allclose(scores.by_method["new"][:, 0], [900 / 1000.5, 900 / 1010.5])
    np.testing.assert_allclose(scores.by_method["bc"][:, 1], [101 / 1000.5, 101 / 1010.5])
    pytest.importorskip("rliable")
    page = studies.across_markdown(tmp_path, [], tmp_path / "figures", (study,))
    assert (tmp_path / "figures" / "across.png").is_file() and "](figures/across.png)" in page
    # Every run of the new learner is above every BC run on the one task both have.
    rows = {line.split(" | ")[0] + " | " + line.split(" | ")[1]: line for line in page.splitlines()
            if line.startswith("| New learner | BC |") or line.startswith("| BC | New learner |")}
    assert rows["| New learner | BC"].startswith("| New learner | BC | 1.00 [1.00, 1.00] | ")
    assert rows["| BC | New learner"].startswith("| BC | New learner | 0.00 [0.00, 0.00] | ")
    assert all(line.endswith(" | Hopper-v5 |") for line in rows.values()) and len(rows) == 2
    assert "`new` (New learner on Hopper-v5, Walker2d-v5)" in page


def test_every_reward_free_choice_folder_gets_one_kept_policy_table(monkeypatch):
    """A PPO study's two readouts of one folder (last weights, kept policy) share a table; a folder with
    one row of its own (the lowest-u tie break's) keeps its table."""
    monkeypatch.syspath_prepend(str(REPO / "benchmarks" / "studies"))
    page = importlib.import_module("new_tasks")
    chosen = [(v.runs, v.trials) for v in page.SELECTIONS]
    assert len(chosen) == len(set(chosen))
    folders = {v.runs for v in page.SELECTIONS}
    assert {"results/tuning/W-longest", "results/tuning/H-longest"} <= folders
    assert {"results/tuning/HC-sac-tie-u", "results/tuning/H-sac-tie-u"} <= folders
    assert all(v.policy == "longest" for v in page.SELECTIONS if v.runs.endswith(("W-longest", "H-longest")))
