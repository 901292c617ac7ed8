"""benchmarks/new_tasks.py: the ablation tables of docs/new_tasks.md, paired by trial."""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest
from test_report import write_run

_PATH = Path(__file__).resolve().parent.parent / "benchmarks" / "new_tasks.py"
_spec = importlib.util.spec_from_file_location("new_tasks", _PATH)
assert _spec is not None and _spec.loader is not None
new_tasks = importlib.util.module_from_spec(_spec)
sys.modules["new_tasks"] = new_tasks  # dataclasses look their module up there
_spec.loader.exec_module(new_tasks)

ENV = "Walker2d-v5"


@pytest.fixture
def root(tmp_path: Path) -> Path:
    # Reference: trials 0-2 return 100/200/300 on two held-out episodes against an expert of
    # 1000 + 10 t + episode. The variant: trials 0-1 only, 250 and 150.
    for trial, value in enumerate([100.0, 200.0, 300.0]):
        write_run(tmp_path / "ref", "cmz", trial, [1.0], env=ENV, final={"final": [value, value]})
    for trial, value in enumerate([250.0, 150.0]):
        write_run(tmp_path / "var", "cmz", trial, [1.0], env=ENV, final={"final": [value, value]})
    return tmp_path


def _variants(*folders: str):
    return tuple(new_tasks.Variant(ENV, "cmz", f"from {f}", f, "pytest") for f in folders)


def test_percent_of_expert_and_paired_count_by_hand(root):
    text = new_tasks.render(root, _variants("ref", "var", "missing"))
    lines = {line.split(" | ")[0].strip("| "): line for line in text.splitlines() if line.startswith("| from")}
    # Trial t's expert mean over episodes 0 and 1: 1000.5 + 10 t. Reference: 100 / 1000.5, 200 / 1010.5,
    # 300 / 1020.5 -> 9.995, 19.79, 29.40 %: mean 19.73.
    ref_pct = [100 * 100 / 1000.5, 100 * 200 / 1010.5, 100 * 300 / 1020.5]
    assert f"{sum(ref_pct) / 3:.3g}" in lines["from ref"]
    assert "0: 100, 1: 200, 2: 300" in lines["from ref"] and lines["from ref"].endswith("| reference |")
    # The variant beats the reference in trial 0 (250 > 100), not in trial 1 (150 < 200); trial 2 is not shared.
    assert "| 1 of 2 |" in lines["from var"] and "n/a" in lines["from var"]  # no interval with 2 trials
    assert "| from missing | 0 | no finished runs |" in lines["from missing"]
    assert "missing: no such runs folder" in text


def test_refuses_to_replace_without_force(root, capsys):
    (root / "docs").mkdir()
    (root / "docs" / "new_tasks.md").write_text("mine")
    assert new_tasks.main([], root=root) == 2
    assert "exists; pass --force" in capsys.readouterr().err
    assert (root / "docs" / "new_tasks.md").read_text() == "mine"


def test_episode_lengths_by_hand(tmp_path):
    # Trial 0's rollouts last 100, 110, ..., 210 steps over 12 epochs: the first 10 average 145, the last
    # 10 165. Trial 1's last 300 throughout. Over the two trials: 222.5 and 232.5. BC has no rollouts.
    for trial, lengths in enumerate([[100 + 10 * i for i in range(12)], [300] * 12]):
        run = write_run(tmp_path / "runs", "cmz", trial, [1.0], env=ENV, final={"final": [5.0, 5.0]})
        (run / "logs").mkdir()
        rows = ["time/iterations,rollout/ep_len_mean"] + [f"{i},{n}" for i, n in enumerate(lengths)]
        (run / "logs" / "progress_0.csv").write_text("\n".join(rows) + "\n")
    write_run(tmp_path / "runs", "bc", 0, [1.0], env=ENV, final={"final": [5.0, 5.0]})
    table = new_tasks.RolloutTable("rollout/ep_len_mean", "length", (ENV,), "runs", final_column="length")
    text = new_tasks.rollout_markdown(tmp_path, [], (table,))
    cmz = next(line for line in text.splitlines() if line.startswith("| CMZ-DRIL")).removesuffix(" |")
    assert cmz.split(" | ")[1:5] == ["2", f"{new_tasks.fmt(222.5)} [n/a]", f"{new_tasks.fmt(232.5)} [n/a]",
                                     f"{new_tasks.fmt(1000.0)} [n/a]"]
    assert next(line for line in text.splitlines() if line.startswith("| BC")).split(" | ")[2:4] == ["—", "—"]


def test_a_rollout_only_table_leaves_out_methods_without_rollouts(tmp_path):
    run = write_run(tmp_path / "runs", "dril", 0, [1.0], env=ENV, final={"final": [5.0]})
    (run / "logs").mkdir()
    (run / "logs" / "progress_0.csv").write_text("rollout/disagreement_mean\n0.5\n0.25\n")
    write_run(tmp_path / "runs", "bc", 0, [1.0], env=ENV, final={"final": [5.0]})
    table = new_tasks.RolloutTable("rollout/disagreement_mean", "u", (ENV,), "runs")
    lines = [line for line in new_tasks.rollout_markdown(tmp_path, [], (table,)).splitlines() if line.startswith("| ")]
    # Header, then DRIL alone: two epochs, so both ends average both values (0.375).
    assert len(lines) == 2 and lines[1].startswith("| DRIL | 1 | 0.375")
