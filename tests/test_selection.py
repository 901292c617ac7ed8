"""The averaged policy (:class:`sb3_cmzdril.selection.AveragedPolicy`): the mean it keeps, how it
resumes, what it refuses, and its key in a run's hyperparameters."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch as th
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.callbacks import BaseCallback

from helpers import ENV
from sb3_cmzdril import UserError
from sb3_cmzdril.selection import AveragedPolicy
from sb3_cmzdril.training.runs import plan_run, resolve_run, run_experiment

N_STEPS = 32


class _Snapshots(BaseCallback):
    """The policy's weights at every rollout's start and at the end, by training step."""

    def __init__(self) -> None:
        super().__init__()
        self.states: dict[int, dict[str, th.Tensor]] = {}

    def _snap(self) -> None:
        self.states[int(self.model.num_timesteps)] = {k: v.clone() for k, v in self.model.policy.state_dict().items()}

    def _on_rollout_start(self) -> None:
        self._snap()

    def _on_training_end(self) -> None:
        self._snap()

    def _on_step(self) -> bool:
        return True


def _ppo(seed: int = 0) -> PPO:
    return PPO("MlpPolicy", "Pendulum-v1", n_steps=N_STEPS, batch_size=16, n_epochs=1, seed=seed,
               policy_kwargs=dict(net_arch=[8]))


def _mean(states: list[dict[str, th.Tensor]], key: str) -> th.Tensor:
    return th.stack([s[key].double() for s in states]).mean(0).float()


def test_the_averaged_policy_is_the_mean_of_the_policies_after_each_update_from_its_start():
    model = _ppo()
    averaged, snaps = AveragedPolicy(start_timesteps=3 * N_STEPS), _Snapshots()
    model.learn(6 * N_STEPS, callback=[averaged, snaps])
    # After 3, 4 and 5 updates (rollout starts) and after the 6th (training's end); not the earlier ones.
    assert sorted(snaps.states) == [k * N_STEPS for k in range(7)]
    chosen = [snaps.states[k * N_STEPS] for k in (3, 4, 5, 6)]
    assert averaged.kept() == {"n_averaged": 4, "first_timesteps": 3 * N_STEPS, "last_timesteps": 6 * N_STEPS}
    assert averaged.best_state is not None
    for key, value in averaged.best_state.items():
        assert value.dtype == chosen[0][key].dtype
        assert th.allclose(value, _mean(chosen, key), atol=1e-7), key
    # Not a copy of the last weights: the updates moved the policy.
    key = "mlp_extractor.policy_net.0.weight"
    assert not th.equal(averaged.best_state[key], chosen[-1][key])
    final = {k: v.clone() for k, v in model.policy.state_dict().items()}
    averaged.apply(model)
    assert th.equal(model.policy.state_dict()[key], averaged.best_state[key])
    assert not th.equal(model.policy.state_dict()[key], final[key])


def test_a_resumed_average_takes_each_policy_once(tmp_path):
    """Saved with a checkpoint and loaded into the next segment's callback, the average goes on over
    the same policies an uninterrupted run averages: the policy the checkpoint holds is not added twice."""
    model = _ppo()
    first, snaps = AveragedPolicy(start_timesteps=0), _Snapshots()
    model.learn(3 * N_STEPS, callback=[first, snaps])
    first.save(tmp_path / "averaged.pt")
    second = AveragedPolicy(start_timesteps=0)
    assert second.load(tmp_path / "averaged.pt") and second.kept() == first.kept()
    model.learn(2 * N_STEPS, callback=[second, snaps], reset_num_timesteps=False)
    assert second.kept() == {"n_averaged": 6, "first_timesteps": 0, "last_timesteps": 5 * N_STEPS}
    every = [snaps.states[k * N_STEPS] for k in range(6)]
    assert second.best_state is not None
    for key, value in second.best_state.items():
        assert th.allclose(value, _mean(every, key), atol=1e-7), key
    assert not AveragedPolicy(0).load(tmp_path / "absent.pt")
    damaged = tmp_path / "averaged.pt"
    damaged.write_bytes(damaged.read_bytes()[: damaged.stat().st_size // 2])
    with pytest.raises(UserError, match=r"averaged.pt is truncated or not a policy-average file"):
        AveragedPolicy(0).load(damaged)


def test_the_averaged_policy_refuses_what_it_cannot_average():
    for bad in (-1, 0.5, True):
        with pytest.raises(UserError, match=f"start_timesteps must be a non-negative integer, got {bad!r}"):
            AveragedPolicy(bad)  # type: ignore[arg-type]
    sac = SAC("MlpPolicy", "Pendulum-v1", learning_starts=10, policy_kwargs=dict(net_arch=[8]))
    with pytest.raises(UserError, match="it needs an on-policy learner, not SAC"):
        sac.learn(20, callback=AveragedPolicy(0))


def _with(hp: Path, tmp_path: Path, line: str) -> Path:
    path = tmp_path / "average_from.yml"
    path.write_text(hp.read_text() + f"  {line}\n")
    return path


def test_average_from_in_the_yaml_adds_the_averaged_policy_to_a_runs_final_evaluation(tiny_experiment, tmp_path):
    hp = _with(tiny_experiment["hp"], tmp_path, "average_from: 0.5")
    out = tmp_path / "run"
    spec = plan_run(ENV, "cmz", 0, demos=tiny_experiment["pool"], hyperparams=hp, output_dir=out, timesteps=256,
                    n_eval_episodes=1)
    run = resolve_run(spec)
    assert run.settings["average_from"] == 0.5 and "average_from" not in run.model_kwargs()
    run_experiment(spec)
    final = json.loads((out / "done.json").read_text())["final_evaluation"]
    # 256 steps of 64-step rollouts: the policies after updates 2, 3 and the last, 4.
    assert final["averaged"]["n_averaged"] == 3
    assert (final["averaged"]["first_timesteps"], final["averaged"]["last_timesteps"]) == (128, 256)
    policies = [line.split(",")[0] for line in (out / "final_eval.csv").read_text().splitlines()[1:]]
    assert sorted(set(policies)) == ["averaged", "final", "lowest_u"]
    assert policies.count("averaged") == len(final["episodes"])
    assert (out / "averaged.pt").is_file() and (out / "model_averaged.zip").is_file()
    # bc has no updates to average: the key is left alone, as the reward's keys are.
    bc = plan_run(ENV, "bc", 0, demos=tiny_experiment["pool"], hyperparams=hp, output_dir=tmp_path / "bc",
                  n_eval_episodes=1)
    run_experiment(bc)
    assert set(json.loads((tmp_path / "bc" / "done.json").read_text())["final_evaluation"]) == {"episodes", "final"}


def test_keep_longest_adds_the_longest_episodes_choice_to_a_ppo_runs_final_evaluation(tiny_experiment, tmp_path):
    hp = _with(tiny_experiment["hp"], tmp_path, "keep_longest: true")
    out = tmp_path / "run"
    spec = plan_run(ENV, "cmz", 0, demos=tiny_experiment["pool"], hyperparams=hp, output_dir=out, timesteps=256,
                    n_eval_episodes=1, eval_every=2)
    run = resolve_run(spec)
    assert run.settings["keep_longest"] is True and "keep_longest" not in run.model_kwargs()
    run_experiment(spec)
    final = json.loads((out / "done.json").read_text())["final_evaluation"]
    # Checked at the start, every 2 epochs of 64 steps (128, 256) and at the end (256 again: one check).
    assert final["longest"]["timesteps"] in (0, 128, 256)
    assert final["longest"]["epoch"] == final["longest"]["timesteps"] // 64
    policies = [line.split(",")[0] for line in (out / "final_eval.csv").read_text().splitlines()[1:]]
    assert sorted(set(policies)) == ["final", "longest", "lowest_u"]
    assert (out / "longest.pt").is_file() and (out / "model_longest.zip").is_file()
    blob = th.load(out / "longest.pt", weights_only=True)
    assert blob["history"][:, 0].tolist() == [0.0, 128.0, 256.0]


def test_keep_longest_must_be_true_or_false(tiny_experiment, tmp_path):
    hp = _with(tiny_experiment["hp"], tmp_path, "keep_longest: 1")
    with pytest.raises(UserError, match="keep_longest must be true or false, got 1"):
        plan_run(ENV, "cmz", 0, demos=tiny_experiment["pool"], hyperparams=hp, output_dir=tmp_path / "x")
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize(("line", "message"), [
    ("average_from: 1.0", "average_from must be a fraction of the run's steps in [0, 1) or null, got 1.0"),
    ("average_from: -0.1", "average_from must be a fraction of the run's steps in [0, 1) or null, got -0.1"),
    ("average_from: last", "average_from must be a fraction of the run's steps in [0, 1) or null, got 'last'"),
])
def test_a_bad_average_from_is_refused_before_a_file_is_written(tiny_experiment, tmp_path, line, message):
    hp = _with(tiny_experiment["hp"], tmp_path, line)
    with pytest.raises(UserError, match=message.replace("[", r"\[").replace("(", r"\(").replace(")", r"\)")):
        plan_run(ENV, "cmz", 0, demos=tiny_experiment["pool"], hyperparams=hp, output_dir=tmp_path / "x")
    assert not (tmp_path / "x").exists()

