"""benchmarks/studies/offpolicy.py, the off-policy study's runner: a run interrupted after a
checkpoint resumes from it, with the grid's record of segments, and leaves no checkpoint behind."""
from __future__ import annotations

import importlib
import json
from pathlib import Path
from types import ModuleType

import pytest

from sb3_cmzdril import UserError

STUDIES = Path(__file__).resolve().parent.parent / "benchmarks" / "studies"
#: A CMZDRILSAC on Hopper-v5 (the shipped pool) whose 300 steps take seconds.
SMALL = {"net_arch": [16, 16], "buffer_size": 2000, "ensemble_epochs": 5, "ensemble_hidden": [16, 16],
         "bc_pretrain_epochs": 5, "batch_size": 32, "bc_batch_size": 64, "learning_starts": 50}


@pytest.fixture
def offpolicy(monkeypatch: pytest.MonkeyPatch) -> ModuleType:
    monkeypatch.syspath_prepend(str(STUDIES))  # as when the script runs: its sibling tune.py imports
    return importlib.import_module("offpolicy")


def run(offpolicy: ModuleType, out: Path, **kwargs) -> dict | None:
    # NAME, env, trial, CPU minutes (never the limit here), eval every 100 steps, settings, 300 steps at most
    settings = {**SMALL, **kwargs}
    return offpolicy.run_trial("t", "Hopper-v5", 0, 60.0, 100, settings, out, "cmd", "longest", 300)


def interrupted_at(steps: int, offpolicy: ModuleType, out: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Run until Ctrl-C at step ``steps``, as a killed process stops; then let runs go on again."""
    budget = offpolicy.CPUBudget._on_step

    def killed(self) -> bool:
        if self.model.num_timesteps == steps:
            raise KeyboardInterrupt
        return budget(self)

    with monkeypatch.context() as patch:
        patch.setattr(offpolicy.CPUBudget, "_on_step", killed)
        with pytest.raises(KeyboardInterrupt):
            run(offpolicy, out)


def test_an_interrupted_run_resumes_from_its_last_checkpoint(offpolicy, tmp_path, monkeypatch):
    interrupted_at(250, offpolicy, tmp_path, monkeypatch)
    folder = tmp_path / "t" / "Hopper-v5" / "cmz" / "trial0"
    assert sorted(p.name for p in (folder / "checkpoint").iterdir()) == ["model.zip", "replay_buffer.pkl",
                                                                         "selection.pt"]
    assert json.loads((folder / "state.json").read_text())["num_timesteps"] == 200

    done = run(offpolicy, tmp_path)
    assert done is not None and done["num_timesteps"] == 300 and done["segments"] == [0, 200]
    timesteps = [int(line.split(",")[1]) for line in (folder / "eval.csv").read_text().splitlines()[1:]]
    assert timesteps == [0, 100, 200, 300]  # each once: the resumed run evaluates from after its checkpoint
    assert [steps for steps, *_ in done["selection"]["checks"]] == [0, 100, 200, 300]
    assert sorted(p.name for p in (folder / "logs").iterdir()) == ["progress_0.csv", "progress_200.csv"]
    assert not (folder / "checkpoint").exists()
    assert run(offpolicy, tmp_path) is None  # finished: skipped


def test_a_checkpoint_of_other_settings_is_not_resumed(offpolicy, tmp_path, monkeypatch):
    interrupted_at(150, offpolicy, tmp_path, monkeypatch)
    with pytest.raises(UserError, match="holds a checkpoint of a run with other settings"):
        run(offpolicy, tmp_path, batch_size=64)


def test_no_steps_evaluates_the_clone_the_runs_start_from(offpolicy, tmp_path):
    done = offpolicy.run_trial("t", "Hopper-v5", 0, 60.0, 100, SMALL, tmp_path, "cmd", "longest", 0)
    assert done is not None and done["num_timesteps"] == 0 and done["segments"] == [0]
    assert done["selection"]["kept_timesteps"] == 0 and [c[0] for c in done["selection"]["checks"]] == [0]
    folder = tmp_path / "t" / "Hopper-v5" / "cmz" / "trial0"
    rows = (folder / "eval.csv").read_text().splitlines()[1:]
    assert [int(line.split(",")[1]) for line in rows] == [0]
    # The clone is both the kept policy and the last weights.
    assert done["final_evaluation"]["final"] == done["final_evaluation"]["last"]


def test_a_negative_step_cap_is_refused_in_one_line(offpolicy, capsys):
    with pytest.raises(SystemExit) as exit_info:
        offpolicy.main(["x", "--max-timesteps", "-1"])
    assert exit_info.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1].endswith("--max-timesteps must be 0 or more, got -1")


def test_the_yaml_entry_gives_the_env_its_kwargs_and_the_run_its_demos(offpolicy, tmp_path):
    # A hopper that is never healthy: every held-out episode ends at its first step. The shipped pool's
    # record names the env it was recorded in, which a run holds its entry to; a copy without the record
    # lets the run make another env.
    yaml = tmp_path / "outside.yml"
    yaml.write_text("Hopper-v5:\n  env_kwargs: dict(healthy_z_range=(10.0, 20.0))\n  n_demos: 2\n")
    pool = tmp_path / "pool" / "demos.npz"
    pool.parent.mkdir()
    pool.write_bytes((STUDIES.parent.parent / "experts" / "Hopper-v5" / "demos.npz").read_bytes())
    done = offpolicy.run_trial("t", "Hopper-v5", 0, 60.0, 100, SMALL, tmp_path, "cmd", "last", 0, demos=pool,
                               hyperparams=yaml)
    assert done is not None and done["final_evaluation"]["final"]["length_mean"] == 1
    config = json.loads((tmp_path / "t" / "Hopper-v5" / "cmz" / "trial0" / "config.json").read_text())
    assert config["env_kwargs"] == {"healthy_z_range": [10.0, 20.0]}
    assert len(config["train_episodes"]) == 2 and Path(config["demos"]) == pool
