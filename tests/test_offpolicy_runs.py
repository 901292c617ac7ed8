"""The off-policy method ``cmz-sac`` (CMZ-DRIL's reward, CMZDRILSAC) in the run layer: train,
benchmark and report, with the grid's folder layout, its resume and its reward-free choice.

An off-policy epoch is ``OFFPOLICY_EPOCH_STEPS`` (2,048) env steps; here it is cut to 64, so that a
run of a few epochs on Pendulum-v1's 50-step episodes takes a few seconds.
"""
from __future__ import annotations

import csv
import json
import pickle
from pathlib import Path

import numpy as np
import pytest

from cmzdril_lab.run.grid import plan_grid
from helpers import ENV, POOL_EPISODES, SHORT_OFFPOLICY_EPOCH, TINY_SAC, Interrupt, write_tiny_yaml
from sb3_cmzdril.cli import main
from sb3_cmzdril.cmzdril_sac import CMZDRILSAC
from sb3_cmzdril.errors import UserError
from sb3_cmzdril.training.runs import plan_run, run_experiment, split_episodes
from sb3_cmzdril.training.spec import PAPER_METHODS, train_command

EPOCH = SHORT_OFFPOLICY_EPOCH
#: CMZDRILSAC's imitation options at the tests' size, and the shipped file's settings that matter here
TINY_CMZ_SAC = dict(
    TINY_SAC,
    ensemble_hidden=(16, 16),
    ensemble_epochs=5,
    bc_pretrain_epochs=5,
    cmz_clip_quantile=0.98,
    absorbing=True,
)


#: Every run here has off-policy epochs of EPOCH steps (conftest.py).
pytestmark = pytest.mark.usefixtures("short_offpolicy_epochs")


@pytest.fixture(scope="module")
def sac_yaml(tiny_experiment) -> Path:
    return write_tiny_yaml(tiny_experiment["root"] / "cmzdril_sac.yml", TINY_CMZ_SAC)


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _train_args(tiny_experiment, sac_yaml, out: Path, *extra: str) -> list[str]:
    return ["train", "--env", ENV, "--reward", "cmz-sac", "--demos", str(tiny_experiment["pool"]),
            "--eval-episodes", "2", "--checkpoint-every", "2", "--hyperparams", str(sac_yaml), "-o", str(out),
            "--no-progress", *extra]


def test_train_cmz_sac_writes_the_grid_layout_with_the_longest_episodes_choice(tiny_experiment, sac_yaml,
                                                                               tmp_path, capsys):
    out = tmp_path / "run"
    assert main(_train_args(tiny_experiment, sac_yaml, out)) == 0
    printed = capsys.readouterr().out
    # The method's result is the longest-episodes choice; the last weights are printed as such.
    assert "final evaluation, last weights: return" in printed
    assert "longest-episodes policy, the method's result (epoch" in printed
    config = json.loads((out / "config.json").read_text())
    assert config["method"] == "cmz-sac" and config["timesteps"] == 256
    assert config["model_kwargs"]["cmz_clip_quantile"] == 0.98 and config["model_kwargs"]["absorbing"] is True
    assert "train --env Pendulum-v1 --reward cmz-sac --timesteps 256" in config["train_command"]
    assert (config["train_episodes"], config["eval_episodes"]) == split_episodes(POOL_EPISODES, 1, 2, 0)
    # One evaluation per 64-step epoch, epoch 0 being the clone before any SAC step.
    rows = _rows(out / "eval.csv")
    assert [(int(r["epoch"]), int(r["timesteps"])) for r in rows] == [(e, EPOCH * e) for e in range(5)]
    done = json.loads((out / "done.json").read_text())
    assert done["method"] == "cmz-sac" and done["num_timesteps"] == 256 and done["epochs"] == 4
    assert done["final_window"]["last_epoch"] == 4 and done["cpu_time_s"] > 0
    # Every held-out episode, replayed by the last weights and by the longest-episodes choice.
    held_out = [i for i in range(POOL_EPISODES) if i not in config["train_episodes"]]
    final_rows = _rows(out / "final_eval.csv")
    assert [(r["policy"], int(r["episode"])) for r in final_rows] == [
        (p, i) for p in ("final", "longest") for i in held_out]
    longest = done["final_evaluation"]["longest"]
    assert longest["timesteps"] % EPOCH == 0 and longest["epoch"] == longest["timesteps"] // EPOCH
    assert longest["return_mean"] == pytest.approx(
        np.mean([float(r["return"]) for r in final_rows if r["policy"] == "longest"]), rel=1e-5)
    assert {"model.zip", "model_longest.zip", "longest.pt", "pretrain.csv"} <= {p.name for p in out.iterdir()}
    assert not (out / "replay_buffer.pkl").exists()  # a finished run has no use for it
    model = CMZDRILSAC.load(out / "model.zip", device="cpu")
    assert model.num_timesteps == 256 and model.cmz_clip_quantile == 0.98
    # `evaluate` loads the run's CMZDRILSAC zip and replays its held-out episodes as the run did.
    assert main(["evaluate", "--model", str(out / "model.zip"), "--env", ENV, "--demos", str(tiny_experiment["pool"]),
                 "--episodes", ",".join(map(str, config["eval_episodes"]))]) == 0
    assert f"{float(rows[-1]['return_mean']):.2f}" in capsys.readouterr().out


def test_a_run_ending_inside_an_epoch_evaluates_that_epoch_once(tiny_experiment, sac_yaml, tmp_path):
    out = tmp_path / "run"
    assert main(_train_args(tiny_experiment, sac_yaml, out, "--timesteps", "200")) == 0
    rows = _rows(out / "eval.csv")
    # Epochs 0-3 at their first step; the end, 8 steps into epoch 4, is epoch 4's row, not a second epoch 3.
    assert [(int(r["epoch"]), int(r["timesteps"])) for r in rows] == [(0, 0), (1, 64), (2, 128), (3, 192), (4, 200)]


def _interrupted_run(tiny_experiment, sac_yaml, out: Path, trial: int):
    """A cmz-sac run of 256 steps interrupted at step 192, after its checkpoint at epoch 2 (128 steps)."""
    spec = plan_run(ENV, "cmz-sac", trial, demos=tiny_experiment["pool"], n_eval_episodes=2, timesteps=256,
                    output_dir=out, hyperparams=sac_yaml, checkpoint_every=2)
    with pytest.raises(KeyboardInterrupt):
        run_experiment(spec, callbacks=[Interrupt(at=192)])
    return spec


@pytest.mark.slow
def test_cmz_sac_resumes_from_its_checkpoint_with_the_replay_buffer(tiny_experiment, sac_yaml, tmp_path):
    out = tmp_path / "run"
    spec = _interrupted_run(tiny_experiment, sac_yaml, out, trial=1)
    # The checkpoint at epoch 2: the model, its buffer of 128 transitions and the choice so far.
    with open(out / "replay_buffer.pkl", "rb") as f:
        assert pickle.load(f).pos == 2 * EPOCH
    assert (out / "longest.pt").is_file() and not (out / "done.json").exists()
    summary = run_experiment(spec)
    assert summary["status"] == "done" and summary["num_timesteps"] == 256 and summary["segments"] == 2
    state = json.loads((out / "state.json").read_text())
    assert [s["from_timesteps"] for s in state["segments"]] == [0, 2 * EPOCH]
    assert [int(r["epoch"]) for r in _rows(out / "eval.csv")] == [0, 1, 2, 3, 4]
    assert not (out / "replay_buffer.pkl").exists()


def test_a_checkpoint_without_its_replay_buffer_is_refused(tiny_experiment, sac_yaml, tmp_path):
    out = tmp_path / "run"
    spec = _interrupted_run(tiny_experiment, sac_yaml, out, trial=0)
    (out / "replay_buffer.pkl").unlink()
    before = sorted(p.name for p in out.iterdir())
    with pytest.raises(UserError, match="holds model.zip but not replay_buffer.pkl"):
        run_experiment(spec)
    assert sorted(p.name for p in out.iterdir()) == before


def test_cmz_sac_reads_its_own_hyperparameter_file(tiny_experiment, sac_yaml, tmp_path):
    spec = plan_run("Walker2d-v5", "cmz-sac", 0)  # the shipped pool and file
    assert Path(spec.hyperparams).name == "cmzdril_sac.yml" and spec.timesteps == 70_000
    assert "--reward cmz-sac" in train_command(spec)
    # A PPO key is not a CMZDRILSAC argument: refused before any file is written.
    ppo_keys = tmp_path / "ppo_keys.yml"
    ppo_keys.write_text(sac_yaml.read_text().replace("n_demos: 1", "n_demos: 1\n  n_epochs: 3"))
    with pytest.raises(UserError, match=r"\['n_epochs'\] are not CMZDRILSAC/SAC arguments"):
        plan_run(ENV, "cmz-sac", 0, demos=tiny_experiment["pool"], hyperparams=ppo_keys, output_dir=tmp_path / "x")
    assert not (tmp_path / "x").exists()


def test_longest_tie_break_in_the_yaml_reaches_the_runs_choice_and_is_refused_where_it_cannot_apply(
    tiny_experiment, sac_yaml, tmp_path
):
    from sb3_cmzdril.training.runs import resolve_run

    tie_yaml = tmp_path / "tie.yml"
    tie_yaml.write_text(sac_yaml.read_text().replace("n_demos: 1", "n_demos: 1\n  longest_tie_break: lowest_u"))
    out = tmp_path / "run"
    spec = plan_run(ENV, "cmz-sac", 0, demos=tiny_experiment["pool"], hyperparams=tie_yaml, output_dir=out)
    run = resolve_run(spec)
    assert run.settings == {"n_demos": 1, "longest_tie_break": "lowest_u"}
    assert "longest_tie_break" not in run.model_kwargs()  # an experiment key, not a constructor argument
    run_experiment(spec)
    done = json.loads((out / "done.json").read_text())
    # Every check of the run records u; Pendulum never ends an episode early, so all tie in length and
    # the kept policy is the one with the lowest u.
    import torch as th

    history = th.load(out / "longest.pt", weights_only=True)["history"].numpy()
    assert len(history) == 5 and (history[:, 1] == history[0, 1]).all() and np.isfinite(history[:, 2]).all()
    assert done["final_evaluation"]["longest"]["mean_u"] == pytest.approx(history[:, 2].min())
    assert done["final_evaluation"]["longest"]["timesteps"] == int(history[history[:, 2].argmin(), 0])
    # lowest_u leaves episode_length at "expert": the record has the length it aimed at (None: the longest)
    assert "target_length" in done["final_evaluation"]["longest"]

    bad = tmp_path / "bad.yml"
    bad.write_text(tie_yaml.read_text().replace("lowest_u", "earliest"))
    with pytest.raises(UserError, match=r"longest_tie_break must be one of \['latest', 'lowest_u'\], got 'earliest'"):
        plan_run(ENV, "cmz-sac", 0, demos=tiny_experiment["pool"], hyperparams=bad, output_dir=tmp_path / "x")
    ppo = tmp_path / "ppo.yml"
    ppo.write_text(tiny_experiment["hp"].read_text() + "  longest_tie_break: lowest_u\n")
    with pytest.raises(UserError, match="longest_tie_break applies only to the off-policy methods \\['cmz-sac', 'dril"):
        plan_run(ENV, "cmz", 0, demos=tiny_experiment["pool"], hyperparams=ppo, output_dir=tmp_path / "y")
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()


@pytest.mark.parametrize(("method", "value", "message"), [
    ("cmz-sac", "shortest", r"episode_length must be one of \['longest', 'expert'\], got 'shortest'"),
    ("cmz", "expert", r"episode_length applies only to the off-policy methods \['cmz-sac'"),
])
def test_episode_length_in_the_yaml_is_refused_before_a_file_is_written_where_it_cannot_apply(
    tiny_experiment, sac_yaml, tmp_path, method, value, message
):
    base = sac_yaml if method == "cmz-sac" else tiny_experiment["hp"]
    bad = tmp_path / "bad.yml"
    bad.write_text(base.read_text().rstrip("\n") + f"\n  episode_length: {value}\n")
    with pytest.raises(UserError, match=message):
        plan_run(ENV, method, 0, demos=tiny_experiment["pool"], hyperparams=bad, output_dir=tmp_path / "x")
    assert not (tmp_path / "x").exists()


def test_episode_length_in_the_yaml_reaches_the_runs_choice(tiny_experiment, sac_yaml, tmp_path):
    from sb3_cmzdril.training.runs import _longest_policy, resolve_run

    yaml = tmp_path / "length.yml"
    yaml.write_text(sac_yaml.read_text().rstrip("\n") + "\n  episode_length: expert\n")
    run = resolve_run(plan_run(ENV, "cmz-sac", 0, demos=tiny_experiment["pool"], hyperparams=yaml,
                               output_dir=tmp_path / "run"))
    assert run.settings["episode_length"] == "expert" and "episode_length" not in run.model_kwargs()
    selector = _longest_policy(run, 2048)
    assert selector.episode_length == "expert" and selector.tie_break == "latest"
    selector.close()


def test_a_grid_runs_the_papers_methods_unless_told_and_gives_cmz_sac_its_file(tiny_experiment, sac_yaml, tmp_path):
    specs = plan_grid(ENV, trials=1, runs_dir=tmp_path, demos_dir=tiny_experiment["demos_dir"],
                      hyperparams=tiny_experiment["hp"])
    assert tuple(s.method for s in specs) == PAPER_METHODS and "cmz-sac" not in PAPER_METHODS
    specs = plan_grid(ENV, "cmz,cmz-sac", 1, tmp_path, demos_dir=tiny_experiment["demos_dir"],
                      hyperparams=tiny_experiment["hp"], offpolicy_hyperparams=sac_yaml)
    assert [(s.method, Path(s.hyperparams)) for s in specs] == [
        ("cmz", tiny_experiment["hp"]), ("cmz-sac", sac_yaml)]
    assert Path(specs[1].output_dir) == tmp_path / ENV / "cmz-sac" / "trial0"


@pytest.mark.parametrize("method, reward", [("dril-sac", "dril"), ("zero-sac", "zero"), ("env-sac", "env")])
def test_the_off_policy_comparisons_train_cmzdrilsac_with_the_reward_they_name(method, reward, tiny_experiment,
                                                                              sac_yaml, tmp_path):
    out = tmp_path / method
    spec = plan_run(ENV, method, 0, demos=tiny_experiment["pool"], hyperparams=sac_yaml, output_dir=out,
                    timesteps=128, n_eval_episodes=2)
    assert spec.hyperparams == str(sac_yaml) and spec.off_policy
    run_experiment(spec)
    model = CMZDRILSAC.load(out / "model.zip", device="cpu")
    assert model.reward == reward and model.num_timesteps == 128
    assert json.loads((out / "config.json").read_text())["method"] == method
    assert {r["policy"] for r in _rows(out / "final_eval.csv")} == {"final", "longest"}


@pytest.mark.slow
def test_the_report_names_the_off_policy_learner_and_its_choice(tiny_experiment, sac_yaml, tmp_path):
    runs_dir = tmp_path / "runs"
    assert main(["benchmark", "--env", ENV, "--methods", "bc,cmz-sac", "--trials", "1", "--eval-episodes", "2",
                 "--demos-dir", str(tiny_experiment["demos_dir"]), "--hyperparams", str(tiny_experiment["hp"]),
                 "--sac-hyperparams", str(sac_yaml), "-o", str(runs_dir), "--no-progress"]) == 0
    assert (runs_dir / ENV / "cmz-sac" / "trial0" / "done.json").is_file()
    assert main(["report", str(runs_dir), "-o", str(tmp_path / "report")]) == 0
    page = (tmp_path / "report" / "results.md").read_text()
    # The plain name is the method's result (its longest-episodes policy); its last weights are named so.
    assert "| CMZ-DRIL (SAC) |" in page and "| CMZ-DRIL (SAC) (last weights) |" in page


@pytest.mark.parametrize(("line", "message"), [
    ("average_from: 0.5", r"average_from applies only to the PPO methods .*not to 'cmz-sac'"),
    ("keep_longest: true", r"keep_longest applies only to the PPO methods; 'cmz-sac' always keeps the longest"),
])
def test_ppo_only_experiment_keys_are_refused_for_the_off_policy_learner(tiny_experiment, sac_yaml, tmp_path, line,
                                                                        message):
    hp = tmp_path / "ppo_only.yml"
    hp.write_text(sac_yaml.read_text() + f"  {line}\n")
    with pytest.raises(UserError, match=message):
        plan_run(ENV, "cmz-sac", 0, demos=tiny_experiment["pool"], hyperparams=hp, output_dir=tmp_path / "x")
    assert not (tmp_path / "x").exists()
