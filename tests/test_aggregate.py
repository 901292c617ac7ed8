"""The across-task aggregate (rliable): normalised scores, IQM, probability of improvement, profiles."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import trim_mean

from cmzdril_lab.report import aggregate as agg
from cmzdril_lab.report.final_eval import final_table
from cmzdril_lab.report.records import load_runs
from helpers import write_run
from sb3_cmzdril.errors import UserError

pytest.importorskip("rliable")

TASKS = ("Hopper-v5", "Walker2d-v5")


def _grid(root, methods=("bc", "cmz"), trials=range(5), tasks=TASKS):
    """Final returns of method m, trial t on task k: (100 + 50 m_index + 7 t + 3 k) on two episodes."""
    for k, env in enumerate(tasks):
        for m_index, method in enumerate(methods):
            for t in trials:
                value = 100.0 + 50 * m_index + 7 * t + 3 * k
                write_run(root, method, t, [1.0], env=env, final={"final": [value, value]}, expert=1000.0)
    return final_table(load_runs(root))


def _by_hand(method_index: int) -> np.ndarray:
    # write_run's expert returns on a trial t: 1000 + 10 t and 1001 + 10 t (mean 1000.5 + 10 t).
    return np.array([[(100.0 + 50 * method_index + 7 * t + 3 * k) / (1000.5 + 10 * t) for k in range(len(TASKS))]
                     for t in range(5)])


def test_a_runs_score_is_its_mean_return_over_the_experts_on_the_same_episodes():
    assert agg.normalised_score({"return": np.array([50.0, 150.0]), "expert_return": np.array([-10.0, 410.0])}) == 0.5
    assert math.isnan(agg.normalised_score({"return": np.array([5.0]), "expert_return": np.array([-1.0])}))


def test_score_matrix_is_trials_by_tasks_per_method(tmp_path):
    scores = agg.score_matrix(_grid(tmp_path))
    assert scores.trials == {"bc": (0, 1, 2, 3, 4), "cmz": (0, 1, 2, 3, 4)}
    assert scores.tasks == {"bc": TASKS, "cmz": TASKS}
    np.testing.assert_allclose(scores.by_method["bc"], _by_hand(0))
    np.testing.assert_allclose(scores.by_method["cmz"], _by_hand(1))


def test_the_off_policy_method_is_scored_by_its_longest_episodes_policy_not_its_last_weights(tmp_path):
    # cmz-sac's result is the policy it kept for its longest episodes; its last weights ("final") fell.
    for t in range(5):
        write_run(tmp_path, "cmz-sac", t, [1.0], env=TASKS[0],
                  final={"final": [10.0, 10.0], "longest": [900.0, 900.0]}, expert=1000.0)
    scores = agg.score_matrix(final_table(load_runs(tmp_path)))
    np.testing.assert_allclose(scores.by_method["cmz-sac"][:, 0], [900.0 / (1000.5 + 10 * t) for t in range(5)])


def test_a_task_without_all_of_its_methods_trials_is_left_out_and_named(tmp_path):
    _grid(tmp_path)
    write_run(tmp_path, "env", 0, [1.0], env=TASKS[0], final={"final": [500.0, 500.0]})
    for t in range(3):  # a grid still running: 3 of 5 trials on the second task
        write_run(tmp_path, "env", t, [1.0], env=TASKS[1], final={"final": [600.0, 600.0]})
    scores = agg.score_matrix(final_table(load_runs(tmp_path)))
    assert scores.trials["env"] == (0, 1, 2) and scores.tasks["env"] == (TASKS[1],)
    assert scores.left_out == ((TASKS[0], "Env. reward", "1 of the 3 trials"),)
    assert scores.trials["bc"] == (0, 1, 2, 3, 4)  # the other methods keep theirs


def test_a_task_without_a_positive_expert_does_not_set_the_trials_the_others_need(tmp_path):
    # BC on trials 0-4 of both tasks, and on trials 0-9 of a third whose expert returns are negative (Pendulum's
    # are): that task cannot be scored, so it must not ask trials 5-9 of the two that can.
    _grid(tmp_path, methods=("bc",))
    for t in range(10):
        write_run(tmp_path, "bc", t, [1.0], env="Pendulum-v1", final={"final": [-900.0, -900.0]}, expert=-150.0)
    scores = agg.score_matrix(final_table(load_runs(tmp_path)))
    assert scores.trials["bc"] == (0, 1, 2, 3, 4) and scores.tasks["bc"] == TASKS
    np.testing.assert_allclose(scores.by_method["bc"], _by_hand(0))
    assert scores.left_out == (("Pendulum-v1", "BC", "no positive expert mean"),)


def test_the_left_out_note_names_each_task_and_reason_once_with_its_methods():
    left_out = [agg.LeftOut("Pendulum-v1", "BC", "no positive expert mean"),
                agg.LeftOut("Ant-v5", "DRIL", "1 of the 5 trials"),
                agg.LeftOut("Pendulum-v1", "CMZ-DRIL", "no positive expert mean")]
    assert agg.left_out_text(left_out) == ("Pendulum-v1 (BC, CMZ-DRIL): no positive expert mean; "
                                           "Ant-v5 (DRIL): 1 of the 5 trials")


def test_iqm_mean_median_and_the_probability_of_improvement_match_hand_computed_values(tmp_path):
    result = agg.aggregate(agg.score_matrix(_grid(tmp_path)))
    bc = _by_hand(0).ravel()
    iqm, low, high = result.summary["bc"]["IQM"]
    assert iqm == pytest.approx(trim_mean(bc, 0.25))
    assert low <= iqm <= high
    assert result.summary["bc"]["Mean"][0] == pytest.approx(bc.mean())
    # rliable's median is over tasks of each task's mean over runs.
    assert result.summary["bc"]["Median"][0] == pytest.approx(np.median(_by_hand(0).mean(axis=0)))
    # CMZ-DRIL's every run scores above every BC run of the same task: P(improvement) = 1.
    pair = result.improvement[("cmz", "bc")]
    assert (pair.probability, pair.tasks) == ((1.0, 1.0, 1.0), TASKS)
    assert pair.iqm[0] == pytest.approx(trim_mean(_by_hand(1).ravel(), 0.25)) and pair.baseline_iqm[0] == iqm
    profile, _, _ = result.profiles["bc"]
    assert profile[0] == 1.0 and profile[-1] == 0.0  # every score is above 0, none above 1.25


def test_a_pair_on_fewer_tasks_than_its_baseline_has_compares_their_iqms_on_the_shared_tasks_alone(tmp_path):
    # BC on both tasks, DRIL on the first: the summary's BC IQM pools both, the pair's only the first.
    rows = _grid(tmp_path, methods=("bc",))
    for t in range(5):
        write_run(tmp_path, "dril", t, [1.0], env=TASKS[0], final={"final": [500.0, 500.0]}, expert=1000.0)
    scores = agg.score_matrix(final_table(load_runs(tmp_path)))
    result = agg.aggregate(scores, pairs=[("dril", "bc")])
    pair = result.improvement[("dril", "bc")]
    assert pair.tasks == (TASKS[0],)
    assert pair.baseline_iqm[0] == pytest.approx(trim_mean(_by_hand(0)[:, 0], 0.25))
    assert result.summary["bc"]["IQM"][0] == pytest.approx(trim_mean(_by_hand(0).ravel(), 0.25))
    assert pair.iqm[0] == pytest.approx(trim_mean([500.0 / (1000.5 + 10 * t) for t in range(5)], 0.25))
    text = agg.aggregate_markdown(result)
    assert "the rows do not compare with one another" in text
    assert "| DRIL | BC | 1.00 [1.00, 1.00] | " in text and f" | {TASKS[0]} |" in text
    assert "do not compare" not in agg.aggregate_markdown(agg.aggregate(agg.score_matrix(rows)))


def test_the_per_task_table_gives_each_methods_mean_over_trials_and_a_dash_where_it_has_no_runs(tmp_path):
    _grid(tmp_path)
    for t in range(5):
        write_run(tmp_path, "dril", t, [1.0], env=TASKS[0], final={"final": [500.0, 500.0]}, expert=1000.0)
    table = agg.per_task_markdown(agg.score_matrix(final_table(load_runs(tmp_path)))).splitlines()
    assert table[0] == "| Task | BC, mean % of expert | DRIL, mean % of expert | CMZ-DRIL, mean % of expert |"
    bc, cmz = (100 * _by_hand(i).mean(axis=0) for i in (0, 1))
    dril = 100 * np.mean([500.0 / (1000.5 + 10 * t) for t in range(5)])
    assert table[2] == f"| {TASKS[0]} | {bc[0]:.1f} | {dril:.1f} | {cmz[0]:.1f} |"
    assert table[3] == f"| {TASKS[1]} | {bc[1]:.1f} | — | {cmz[1]:.1f} |"


def test_the_same_runs_give_the_same_intervals(tmp_path):
    rows = _grid(tmp_path)
    first = agg.aggregate(agg.score_matrix(rows)).summary
    assert agg.aggregate(agg.score_matrix(rows)).summary == first


def test_the_report_writes_the_across_task_section_its_csv_and_figure(tmp_path):
    from cmzdril_lab.report.report import write_report

    _grid(tmp_path / "runs")
    _grid(tmp_path / "more", methods=("bc",), tasks=("Swimmer-v5",))
    more = [tmp_path / "more"]
    text = write_report(tmp_path / "runs", tmp_path / "docs", references=(), aggregate_runs=more).read_text()
    # The page's section: short heads, a sentence under the tables; how the numbers are made under "How to read".
    section = text[text.index("## Across tasks"):text.index("## Per task")]
    assert "| Method | Tasks | IQM [CI] | Mean [CI] | Median [CI] |" in section
    assert "| CMZ-DRIL | BC | 1.00 [1.00, 1.00] | " in section and "| Hopper-v5, Walker2d-v5 |" in section
    assert "| Task | BC | CMZ-DRIL |" in section and "Agarwal" not in section
    assert "- **Across tasks**: one number across tasks, as Agarwal et al." in text
    csv = (tmp_path / "docs" / agg.CSV).read_text().splitlines()
    assert csv[0] == "method,task,trial,score" and len(csv) == 1 + (2 + 2 + 1) * 5
    assert (tmp_path / "docs" / agg.FIGURE).read_bytes()[:4] == b"\x89PNG"


def test_a_task_and_method_in_two_grids_is_refused(tmp_path):
    rows = _grid(tmp_path / "a") + _grid(tmp_path / "b", methods=("bc",))
    with pytest.raises(UserError, match="Hopper-v5 BC is in two grids"):
        agg.score_matrix(rows)


def test_nothing_to_aggregate_writes_nothing(tmp_path):
    assert agg.score_matrix([]) is None
    assert agg.write_aggregate([], tmp_path) is None and not list(tmp_path.iterdir())


def test_the_batched_bootstrap_statistics_are_rliables():
    from rliable import metrics

    rng = np.random.default_rng(3)
    x = rng.integers(0, 6, size=(5, 4)) / 4.0  # ties on purpose
    y = rng.integers(0, 6, size=(5, 4)) / 4.0
    iqm, mean, median = agg.batch_statistics(x[None])[0]
    assert iqm == pytest.approx(metrics.aggregate_iqm(x))
    assert mean == pytest.approx(metrics.aggregate_mean(x))
    assert median == pytest.approx(metrics.aggregate_median(x))
    assert agg.batch_improvement(x[None], y[None])[0] == pytest.approx(metrics.probability_of_improvement(x, y))
    assert agg.batch_improvement(x[None], x[None])[0] == 0.5


def test_ten_trials_on_one_task_do_not_crowd_out_five_on_two_others(tmp_path):
    envs = (*TASKS, "HalfCheetah-v5")
    for t in range(10):
        write_run(tmp_path, "bc", t, [1.0], env=envs[0], final={"final": [500.0, 500.0]})
    for env in envs[1:]:
        for t in range(5):
            write_run(tmp_path, "bc", t, [1.0], env=env, final={"final": [600.0, 600.0]})
    scores = agg.score_matrix(final_table(load_runs(tmp_path)))
    # trials 0-4 keep 15 runs on three tasks, trials 0-9 ten on one
    assert scores.trials["bc"] == (0, 1, 2, 3, 4) and set(scores.tasks["bc"]) == set(envs)
    assert scores.left_out == ()
