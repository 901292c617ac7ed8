"""What a run's records say and what a resume accepts: a finished off-policy run's advice, a checkpoint
as one unit, the held-out starts and the pool's episode lengths checked before anything is written,
the keys a run sets itself, TensorBoard and the device as recorded, and the kept policy's epoch.

Off-policy epochs are cut to 64 steps here, as in test_offpolicy_runs.py."""
from __future__ import annotations

import csv
import json
import logging
import shutil
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from helpers import (
    ENV,
    SHORT_EPISODES,
    SHORT_OFFPOLICY_EPOCH,
    TINY,
    TINY_SAC,
    Interrupt,
    pendulum_expert,
    record,
    write_tiny_yaml,
    zoo_yaml,
)
from sb3_cmzdril.cli import main
from sb3_cmzdril.data.demos import Demonstrations
from sb3_cmzdril.errors import UserError
from sb3_cmzdril.metrics import evaluate_against_expert
from sb3_cmzdril.training import spec as spec_module
from sb3_cmzdril.training.runs import plan_run, run_experiment

EPOCH = SHORT_OFFPOLICY_EPOCH
TINY_CMZ_SAC = dict(TINY_SAC, ensemble_hidden=(16, 16), ensemble_epochs=5, bc_pretrain_epochs=5)


#: Every run here has off-policy epochs of EPOCH steps (conftest.py).
pytestmark = pytest.mark.usefixtures("short_offpolicy_epochs")


@pytest.fixture(scope="module")
def sac_yaml(tiny_experiment) -> Path:
    return write_tiny_yaml(tiny_experiment["root"] / "records_sac.yml", TINY_CMZ_SAC)


def _yaml(tiny_experiment, name: str, **extra: Any) -> Path:
    """The tiny CMZDRIL file with ``extra`` keys."""
    path = tiny_experiment["root"] / name
    path.write_text(zoo_yaml("default", TINY, n_timesteps=128, env_kwargs=SHORT_EPISODES, n_demos=1, **extra))
    return path


def _sac_spec(tiny_experiment, sac_yaml, out: Path, timesteps: int, trial: int = 0):
    return plan_run(ENV, "cmz-sac", trial, demos=tiny_experiment["pool"], n_eval_episodes=2, timesteps=timesteps,
                    output_dir=out, hyperparams=sac_yaml, checkpoint_every=2)


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


# -- a finished cmz-sac run: its kept policy's epoch, and the advice when more steps are asked -------
def test_a_finished_cmz_sac_run_labels_its_kept_policy_as_eval_csv_and_advises_what_works(
    tiny_experiment, sac_yaml, tmp_path, capsys
):
    out = tmp_path / "run"
    args = ["train", "--env", ENV, "--reward", "cmz-sac", "--demos", str(tiny_experiment["pool"]), "--eval-episodes",
            "2", "--checkpoint-every", "2", "--hyperparams", str(sac_yaml), "--no-progress", "--timesteps"]
    # 200 steps: 8 steps into epoch 4, whose end eval.csv calls epoch 4.
    assert main([*args, "200", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    done = json.loads((out / "done.json").read_text())
    longest = done["final_evaluation"]["longest"]
    epochs = {int(r["timesteps"]): int(r["epoch"]) for r in _rows(out / "eval.csv")}
    # Pendulum never ends an episode early: every check ties, and the latest, at the run's end, is kept.
    assert longest["timesteps"] == 200 and longest["epoch"] == epochs[200] == 4
    assert "longest-episodes policy, the method's result (epoch 4)" in printed

    # Asked for more steps: the advice is to train into another folder (the replay buffer went with the
    # finish), never to delete done.json, after which the run would refuse to resume.
    with pytest.raises(UserError) as error:
        run_experiment(_sac_spec(tiny_experiment, sac_yaml, out, 256))
    message = str(error.value)
    assert "done.json and run" not in message and "\n" not in message
    assert message.endswith("train 256 steps into another output folder")
    # The advice, followed.
    assert main([*args, "256", "-o", str(tmp_path / "another")]) == 0
    assert json.loads((tmp_path / "another" / "done.json").read_text())["num_timesteps"] == 256


def test_a_finished_ppo_run_asked_for_more_steps_continues_as_its_advice_says(tiny_experiment, tmp_path):
    hp = tiny_experiment["hp"]
    out = tmp_path / "run"
    spec = plan_run(ENV, "cmz", 0, demos=tiny_experiment["pool"], n_eval_episodes=2, timesteps=128, output_dir=out,
                    hyperparams=hp)
    assert run_experiment(spec)["status"] == "done"
    longer = plan_run(ENV, "cmz", 0, demos=tiny_experiment["pool"], n_eval_episodes=2, timesteps=192,
                      output_dir=out, hyperparams=hp)
    with pytest.raises(UserError, match=r"delete \S+done.json and run the command again \(it continues from model"):
        run_experiment(longer)
    (out / "done.json").unlink()
    summary = run_experiment(longer)
    assert summary["status"] == "done" and summary["num_timesteps"] == 192 and summary["segments"] == 2


# -- a checkpoint is one unit -------------------------------------------------------------------------
@pytest.fixture(scope="module")
def interrupted_sac(tiny_experiment, sac_yaml, tmp_path_factory):
    """A cmz-sac run of 256 steps interrupted at step 192, after its checkpoint at 128 steps."""
    import sb3_cmzdril.training.runs as runs

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(spec_module, "OFFPOLICY_EPOCH_STEPS", EPOCH)
        patch.setattr(runs, "OFFPOLICY_EPOCH_STEPS", EPOCH)
        out = tmp_path_factory.mktemp("interrupted") / "run"
        with pytest.raises(KeyboardInterrupt):
            run_experiment(_sac_spec(tiny_experiment, sac_yaml, out, 256), callbacks=[Interrupt(at=192)])
    return out


def _copy(folder: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "run"
    shutil.copytree(folder, copy)
    return copy


def _model_at(path: Path, steps: int) -> None:
    """model.zip as a checkpoint at ``steps`` writes it, the rest of the folder left as it was: what a
    process killed after writing model.zip, before the replay buffer, longest.pt and state.json, leaves."""
    from sb3_cmzdril.cmzdril_sac import CMZDRILSAC

    model = CMZDRILSAC.load(path, device="cpu")
    model.num_timesteps = steps
    model.save(path)


@pytest.mark.parametrize("damage, refusal", [
    (lambda out: _model_at(out / "model.zip", 4 * EPOCH),
     r"run/model.zip is truncated, damaged or from another checkpoint than the one at 128 steps that state.json "
     r"records \(a process killed while it wrote a checkpoint leaves its files so\); delete \S+ \(or train into "
     r"another output folder\) to start the run again$"),
    (lambda out: (out / "longest.pt").unlink(),
     r"holds model.zip but not longest.pt, which its checkpoint at 128 steps needs to resume"),
    (lambda out: (out / "replay_buffer.pkl").unlink(), r"holds model.zip but not replay_buffer.pkl"),
    (lambda out: (out / "state.json").unlink(), r"holds model.zip but not state.json, which records its checkpoint"),
    (lambda out: (out / "longest.pt").write_bytes((out / "longest.pt").read_bytes()[:100]),
     r"longest.pt is truncated, damaged or from another checkpoint"),
], ids=["model newer than the rest", "longest.pt deleted", "replay buffer deleted", "state.json deleted",
        "longest.pt cut short"])
def test_a_checkpoint_whose_files_are_not_one_unit_is_refused_naming_the_file(
    interrupted_sac, tiny_experiment, sac_yaml, tmp_path, damage, refusal
):
    out = _copy(interrupted_sac, tmp_path)
    damage(out)
    before = _snapshot(out)
    with pytest.raises(UserError, match=refusal):
        run_experiment(_sac_spec(tiny_experiment, sac_yaml, out, 256))
    assert _snapshot(out) == before  # refused before a file was written


def test_the_checkpoint_record_names_each_file_with_its_digest_and_a_whole_one_resumes(
    interrupted_sac, tiny_experiment, sac_yaml, tmp_path
):
    from sb3_cmzdril.training.run_folder import file_sha256

    out = _copy(interrupted_sac, tmp_path)
    record = json.loads((out / "state.json").read_text())["checkpoint"]
    assert record["timesteps"] == 2 * EPOCH
    assert record["sha256"] == {name: file_sha256(out / name) for name in ("model.zip", "replay_buffer.pkl",
                                                                             "longest.pt")}
    summary = run_experiment(_sac_spec(tiny_experiment, sac_yaml, out, 256))
    assert summary["status"] == "done" and summary["segments"] == 2


def test_a_ppo_checkpoint_without_its_lowest_u_choice_is_refused(tiny_experiment, tmp_path):
    out = tmp_path / "run"
    spec = plan_run(ENV, "cmz", 0, demos=tiny_experiment["pool"], n_eval_episodes=2, timesteps=256, output_dir=out,
                    hyperparams=tiny_experiment["hp"], checkpoint_every=2)
    with pytest.raises(KeyboardInterrupt):
        run_experiment(spec, callbacks=[Interrupt(at=192)])
    (out / "lowest_u.pt").unlink()
    with pytest.raises(UserError, match="holds model.zip but not lowest_u.pt, which its checkpoint at 128 steps"):
        run_experiment(spec)


def test_a_state_json_without_a_checkpoint_record_still_holds_model_zip_to_its_step_count(
    interrupted_sac, tiny_experiment, sac_yaml, tmp_path
):
    """A state.json written before checkpoints were recorded: model.zip must be at its step count."""
    out = _copy(interrupted_sac, tmp_path)
    state = json.loads((out / "state.json").read_text())
    del state["checkpoint"]
    (out / "state.json").write_text(json.dumps(state))
    _model_at(out / "model.zip", 4 * EPOCH)
    with pytest.raises(UserError, match=r"model.zip is at 256 steps, but state.json, which each checkpoint writes "
                                        r"last, at 128"):
        run_experiment(_sac_spec(tiny_experiment, sac_yaml, out, 512))


# -- the pool checked against the env before anything is written -------------------------------------
def _pool_with_seed(tiny_experiment, tmp_path: Path, episode: int, seed: int) -> Path:
    pool = Demonstrations.load(tiny_experiment["pool"])
    seeds = pool.seeds.copy()
    seeds[episode] = seed
    path = tmp_path / "pool.npz"
    Demonstrations(pool.observations, pool.actions, pool.episode_lengths, pool.rewards, seeds=seeds).save(path)
    return path


def test_every_held_out_start_is_checked_and_the_refusal_names_each_that_differs(tiny_experiment, tmp_path):
    from sb3_cmzdril.training.spec import split_episodes

    train, evaluated = split_episodes(6, 1, 2, 0)
    later = [i for i in range(6) if i not in train and i != evaluated[0]]  # held out, not the first evaluated one
    pool = _pool_with_seed(tiny_experiment, tmp_path, later[-1], 4242)
    with pytest.raises(UserError, match=rf"resetting its episode {later[-1]} \(of 5 held out\) with its seed 4242 "
                                        "does not give the episode's first observation"):
        plan_run(ENV, "cmz", 0, demos=pool, n_eval_episodes=2, hyperparams=tiny_experiment["hp"],
                 output_dir=tmp_path / "out")
    assert not (tmp_path / "out").exists()


class _Rule:
    """The pendulum expert as a model: predict on a batch."""

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        return pendulum_expert(observation), state


def test_the_evaluation_names_every_episode_whose_start_differs():
    demos = record(ENV, pendulum_expert, n_episodes=3, max_steps=20, seed=11)
    wrong = Demonstrations(demos.observations, demos.actions, demos.episode_lengths, demos.rewards,
                           seeds=[99, 12, 98])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = evaluate_against_expert(_Rule(), ENV, wrong)
    starts = [w for w in caught if "does not reproduce" in str(w.message)]
    assert len(starts) == 1 and str(starts[0].message).startswith("episodes 0 (seed 99), 2 (seed 98) of 3:")
    assert result.start_matches.tolist() == [False, True, False]
    with pytest.raises(UserError, match=r"^episodes 0 \(seed 99\), 2 \(seed 98\) of 3: the reset observation"):
        evaluate_against_expert(_Rule(), ENV, wrong, start_mismatch="raise")


@pytest.fixture(scope="module")
def waypoint_pool(tmp_path_factory) -> Path:
    """Six WaypointNav-v0 episodes of the shipped pool (up to 89 steps; its own limit is 300 steps),
    with no record beside them."""
    shipped = Path(__file__).parents[1] / "experts" / "WaypointNav-v0" / "demos.npz"
    pool = Demonstrations.load(shipped).select(list(range(6)))
    path = tmp_path_factory.mktemp("waypoint") / "demos.npz"
    pool.save(path)
    assert pool.episode_lengths.max() > 30 and not path.with_suffix(".json").exists()
    return path


@pytest.mark.parametrize("record_text", [None, "{not json"], ids=["no record", "corrupt record"])
def test_a_pool_without_a_sound_record_is_held_to_the_env_by_its_episode_lengths(waypoint_pool, tmp_path,
                                                                                   record_text, capsys):
    pool = tmp_path / "demos.npz"
    shutil.copy(waypoint_pool, pool)
    if record_text is not None:
        pool.with_suffix(".json").write_text(record_text)
    env_id = "sb3_cmzdril:WaypointNav-v0"
    short = tmp_path / "short.yml"
    short.write_text(zoo_yaml("default", TINY, n_timesteps=128, env_kwargs=dict(max_steps=30), n_demos=1))
    out = tmp_path / "out"
    assert main(["train", "--env", env_id, "--reward", "cmz", "--demos", str(pool), "--eval-episodes", "2",
                 "--hyperparams", str(short), "-o", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert "last up to" in err and "longer than the 30-step limit of sb3_cmzdril:WaypointNav-v0 made with env_kwargs " \
        "{'max_steps': 30}" in err
    assert not out.exists()
    # gym.make's own time limit over the same env is a quick run, not another env: accepted.
    quick = tmp_path / "quick.yml"
    quick.write_text(zoo_yaml("default", TINY, n_timesteps=128, env_kwargs=dict(max_episode_steps=30), n_demos=1))
    plan_run(env_id, "cmz", 0, demos=pool, n_eval_episodes=2, hyperparams=quick, output_dir=tmp_path / "quick")


# -- keys of the YAML: those the run sets, tensorboard_log, device -----------------------------------
@pytest.mark.parametrize("key, value", [("verbose", 1), ("seed", 3), ("reward", "env")])
def test_a_yaml_key_the_run_sets_itself_is_refused_in_one_line_before_a_file_is_written(
    tiny_experiment, tmp_path, capsys, key, value
):
    hp = _yaml(tiny_experiment, f"with_{key}.yml")
    hp.write_text(hp.read_text() + f"  {key}: {value}\n")
    out = tmp_path / "out"
    assert main(["train", "--env", ENV, "--reward", "cmz", "--demos", str(tiny_experiment["pool"]), "--eval-episodes",
                 "2", "--hyperparams", str(hp), "-o", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{key} is set by the run, with --" in err
    assert not out.exists()


def test_tensorboard_log_in_the_yaml_is_written_and_continued_by_a_resume(tiny_experiment, tmp_path):
    pytest.importorskip("tensorboard", reason="tensorboard is in the test extra")
    board = tmp_path / "board"
    hp = _yaml(tiny_experiment, "tensorboard.yml", tensorboard_log=str(board))
    out = tmp_path / "run"
    spec = plan_run(ENV, "cmz", 0, demos=tiny_experiment["pool"], n_eval_episodes=2, timesteps=256, output_dir=out,
                    hyperparams=hp, checkpoint_every=2)
    with pytest.raises(KeyboardInterrupt):
        run_experiment(spec, callbacks=[Interrupt(at=192)])
    run_experiment(spec)
    folder = board / "Pendulum-v1_cmz_trial0_1"
    assert sorted(p.name for p in board.iterdir()) == [folder.name]
    assert len(list(folder.glob("events.out.tfevents.*"))) == 2  # one per segment, in the same folder
    segments = json.loads((out / "state.json").read_text())["segments"]
    assert [s["tensorboard"] for s in segments] == [str(folder)] * 2


def test_the_device_recorded_is_the_one_the_run_used(tiny_experiment, tmp_path, monkeypatch, caplog):
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    hp = _yaml(tiny_experiment, "cuda.yml", device="cuda")
    out = tmp_path / "run"
    spec = plan_run(ENV, "cmz", 0, demos=tiny_experiment["pool"], n_eval_episodes=2, timesteps=64, output_dir=out,
                    hyperparams=hp)
    with caplog.at_level(logging.WARNING, logger="sb3_cmzdril"):
        run_experiment(spec)
    config = json.loads((out / "config.json").read_text())
    assert config["model_kwargs"]["device"] == "cuda" and config["device"] == "cpu"  # asked, and used
    assert [s["device"] for s in json.loads((out / "state.json").read_text())["segments"]] == ["cpu"]
    assert [r.getMessage() for r in caplog.records if "device" in r.getMessage()] == [
        f"hyperparameters 'default' in {hp} ask for device 'cuda', which this machine does not have: the run uses "
        "'cpu' (recorded in config.json)"]
    assert np.isfinite(json.loads((out / "done.json").read_text())["final_window"]["return"])
