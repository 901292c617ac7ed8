"""benchmarks/studies/longest_checks.py: the other tie break's choice, replayed from a run's records."""
from __future__ import annotations

import importlib
import json
from pathlib import Path

import pytest

from helpers import write_run

REPO = Path(__file__).resolve().parents[1]
ENV = "Pendulum-v1"


def _study(monkeypatch):
    monkeypatch.syspath_prepend(str(REPO / "benchmarks" / "studies"))
    return importlib.import_module("longest_checks")


def _off_policy_run(root: Path, trial: int, checks: list | None, kept_steps: int) -> Path:
    """A finished cmz-sac run: eval.csv returns -1000, -200, -800 at 0, 2048 and 4096 steps; done.json
    lists ``checks`` (None: a run made before it did) and the kept check's steps."""
    run = write_run(root, "cmz-sac", trial, [-1000.0, -200.0, -800.0], env=ENV,
                    final={"final": [-810.0, -790.0], "longest": [-810.0, -790.0]})
    config = json.loads((run / "config.json").read_text())
    (run / "config.json").write_text(json.dumps({**config, "env_id": ENV, "n_eval_episodes": 5}))
    longest = {"timesteps": kept_steps, **({"checks": checks} if checks is not None else {})}
    (run / "done.json").write_text(json.dumps({"status": "done", "final_evaluation": {"longest": longest}}))
    return run


def test_each_tie_break_keeps_its_check_and_the_eval_return_there_is_reported(tmp_path, monkeypatch, capsys):
    study = _study(monkeypatch)
    # Every check at the time limit (200): latest keeps 4096, lowest u (0.1) keeps 2048; u "nan" as jsonable writes it.
    _off_policy_run(tmp_path, 0, [[0, 200.0, 0.2], [2048, 200.0, 0.1], [4096, 200.0, 0.5]], kept_steps=4096)
    _off_policy_run(tmp_path, 1, [[0, 200.0, "nan"], [2048, 200.0, "nan"], [4096, 200.0, "nan"]], kept_steps=4096)
    _off_policy_run(tmp_path, 2, None, kept_steps=4096)
    out = tmp_path / "out.txt"
    assert study.main([str(tmp_path), "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert text == out.read_text()
    assert "    latest: keeps the check at 4096 steps (length 200, u 0.500, eval.csv -800)" in text
    assert "  lowest_u: keeps the check at 2048 steps (length 200, u 0.100, eval.csv -200)" in text
    assert "  final evaluation (every held-out episode): final -800, longest -800" in text
    assert f"{ENV} cmz-sac: 2 runs (trials 0, 1), 1 differ: trial 0: -800 -> -200" in text
    assert text.endswith(f"no longest.pt here): {tmp_path / ENV / 'cmz-sac' / 'trial2'}\n")


def test_a_run_whose_record_is_not_the_replayed_choice_is_an_error(tmp_path, monkeypatch):
    study = _study(monkeypatch)
    run = _off_policy_run(tmp_path, 0, [[0, 200.0, 0.2], [2048, 200.0, 0.1]], kept_steps=0)
    with pytest.raises(RuntimeError, match=f"{run}: the run kept the check at 0 steps, the replay of 'latest' "
                                           "the one at 2048"):
        study.main([str(tmp_path)])


def test_no_run_with_a_longest_episodes_choice_is_one_line(tmp_path, monkeypatch, capsys):
    study = _study(monkeypatch)
    with pytest.raises(SystemExit) as stop:
        study.main([str(tmp_path)])
    assert stop.value.code == 2
    assert f"no finished run with a longest-episodes choice under {tmp_path}" in capsys.readouterr().err


def _goal_task_run(root: Path, tie_break: str) -> Path:
    """A run that aimed at the expert's episode length, 480 steps (its expert ends its episodes): it
    kept the check at 4096 (500 steps); the longest (0, 999 steps) and the lowest u (2048) differ."""
    run = _off_policy_run(root, 0, [[0, 999.0, 0.3], [2048, 120.0, 0.1], [4096, 500.0, 0.2]], kept_steps=4096)
    config = json.loads((run / "config.json").read_text())
    config["hyperparams_values"] = {"longest_tie_break": tie_break}
    (run / "config.json").write_text(json.dumps(config))
    done = json.loads((run / "done.json").read_text())
    done["final_evaluation"]["longest"]["target_length"] = 480.0
    (run / "done.json").write_text(json.dumps(done))
    return run


def test_a_run_that_aimed_at_the_expert_length_is_replayed_beside_the_other_rules(tmp_path, monkeypatch, capsys):
    study = _study(monkeypatch)
    run = _goal_task_run(tmp_path, "lowest_u")
    assert study.main([str(tmp_path)]) == 0
    text = capsys.readouterr().out
    assert f"{run} (trial 0; the run's tie break: expert length)" in text
    assert "  expert length: keeps the check at 4096 steps (length 500, u 0.200, eval.csv -800)" in text
    assert "   u alone: keeps the check at 2048 steps (length 120, u 0.100, eval.csv -200)" in text
    assert "  lowest_u: keeps the check at 0 steps (length 999, u 0.300, eval.csv -1000)" in text
    after = text.split("(lowest_u -> expert length)")[1]
    assert f"{ENV} cmz-sac: 1 runs (trials 0), 1 differ: trial 0: -1000 -> -800" in after


def test_a_run_that_aimed_at_the_expert_length_with_the_latest_is_not_replayed(tmp_path, monkeypatch):
    study = _study(monkeypatch)
    run = _goal_task_run(tmp_path, "latest")
    with pytest.raises(RuntimeError, match=f"{run}: aimed at the expert's length with the tie break 'latest'"):
        study.main([str(tmp_path)])


def test_a_run_that_kept_the_lowest_u_alone_is_replayed_as_such(tmp_path, monkeypatch, capsys):
    # commit d75d34b4's rule where the expert ends its episodes: no length compared (length_compared: false)
    study = _study(monkeypatch)
    run = _goal_task_run(tmp_path, "lowest_u")
    done = json.loads((run / "done.json").read_text())
    longest = done["final_evaluation"]["longest"]
    del longest["target_length"]
    longest.update(length_compared=False, timesteps=2048)
    (run / "done.json").write_text(json.dumps(done))
    assert study.main([str(tmp_path)]) == 0
    assert f"{run} (trial 0; the run's tie break: u alone)" in capsys.readouterr().out


def test_runs_of_one_task_from_several_folders_are_named_by_folder(tmp_path, monkeypatch, capsys):
    study = _study(monkeypatch)
    checks = [[0, 200.0, 0.2], [2048, 200.0, 0.1], [4096, 200.0, 0.5]]
    _off_policy_run(tmp_path / "task", 0, checks, kept_steps=4096)
    _off_policy_run(tmp_path / "study", 0, checks, kept_steps=4096)
    assert study.main([str(tmp_path / "task"), str(tmp_path / "study")]) == 0
    task, other = tmp_path / "task", tmp_path / "study"
    assert (f"{ENV} cmz-sac: 2 runs (trials 0 in {other}, 0 in {task}), 2 differ: trial 0 in {other}: -800 -> -200; "
            f"trial 0 in {task}: -800 -> -200") in capsys.readouterr().out
