"""The bad-input corpus: every command, a list of mistakes a user makes (the issues' repros among
them), each ending as exit code 2, exactly one line on stderr, no traceback, and every file of the
workspace (inputs and output folders) byte-identical and untouched afterwards.

All cases share one workspace made once (a demo pool, tiny hyperparameters, an untrained CMZDRIL
model, a finished tiny cmz run, a fake expert folder); a case that needs a damaged file makes it in
its own ``case/`` folder, removed after the case. The commands run in-process through
``sb3_cmzdril.cli.main`` with the workspace as working directory (where default outputs go).
"""
from __future__ import annotations

import hashlib
import json
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from helpers import ENV, POOL_EPISODES, TINY, cartpole_expert, pendulum_expert, record, with_entry
from helpers import TINY_PPO_YAML as TINY_PPO
from helpers import TINY_SAC_YAML as TINY_SAC
from sb3_cmzdril import CMZDRIL, CMZReward, UserError
from sb3_cmzdril.cli import main
from sb3_cmzdril.data.demos import FORMAT_VERSION, Demonstrations


@pytest.fixture(scope="module")
def ws(tmp_path_factory) -> Path:
    """The shared workspace; no case may change it."""
    root = tmp_path_factory.mktemp("corpus")
    pool = record(ENV, pendulum_expert, n_episodes=POOL_EPISODES, max_steps=50, seed=100)
    pool.save(root / "demos.npz")
    Demonstrations(pool.observations, pool.actions, pool.episode_lengths).save(root / "noseeds.npz")
    arrays = {"observations": pool.observations, "actions": pool.actions, "episode_lengths": pool.episode_lengths,
              "seeds": pool.seeds}
    np.savez(root / "future.npz", format_version=np.asarray(FORMAT_VERSION + 1), **arrays)
    (root / "cmzdril.yml").write_text(TINY_PPO)
    (root / "sac.yml").write_text(TINY_SAC)
    CMZDRIL("MlpPolicy", ENV, demonstrations=pool, **TINY).save(root / "model.zip")
    expert = root / "experts" / ENV  # what train-expert leaves: someone's expert, not a run
    expert.mkdir(parents=True)
    shutil.copy(root / "model.zip", expert / "model.zip")
    (expert / "metadata.json").write_text(json.dumps({"algo": "ppo", "env_id": ENV}))
    assert main(_train(root / "cmzrun", "--reward", "cmz", "--demos", str(root / "demos.npz"),
                       "--hyperparams", str(root / "cmzdril.yml"))) == 0
    assert (root / "cmzrun" / "lowest_u.pt").is_file()
    return root


def _train(out: Path | str, *extra: str) -> list[str]:
    return ["train", "--env", ENV, "--eval-episodes", "1", "--timesteps", "128", "--no-progress", "-o", str(out),
            *extra]


def _cmz(ws: Path, out: Path | str, demos: str = "demos.npz", hyperparams: str | None = None) -> list[str]:
    """``train --reward cmz`` on a workspace demo pool and hyperparameters (the tiny ones by default)."""
    return _train(out, "--reward", "cmz", "--demos", str(ws / demos),
                  "--hyperparams", hyperparams or str(ws / "cmzdril.yml"))


def _cmz_yaml(ws: Path, case: Path, entry: str) -> list[str]:
    """``train --reward cmz`` into the case's folder, with ``entry`` added to the tiny YAML."""
    return _cmz(ws, case / "out", hyperparams=_yaml(ws, case, entry))


def _expert(ws: Path, out: Path | str, *extra: str) -> list[str]:
    return ["train-expert", "--env", ENV, "--hyperparams", str(ws / "sac.yml"), "-o", str(out), *extra]


def _collect(ws: Path, case: Path, expert: str, *extra: str, env: str = ENV) -> list[str]:
    return ["collect-demos", "--expert", expert, "--env", env, "-o", str(case / "d.npz"), *extra]


def _yaml(ws: Path, case: Path, entry: str, base: str = "cmzdril.yml") -> str:
    """A copy of a workspace YAML with one more entry under its env key (replacing that key's line)."""
    path = case / "bad.yml"
    path.write_text(with_entry((ws / base).read_text(), entry))
    return str(path)


def _run_copy(ws: Path, case: Path) -> Path:
    """A copy of the finished cmz run (same config, so the same run) to damage."""
    run = case / "run"
    shutil.copytree(ws / "cmzrun", run)
    (run / ".lock").unlink(missing_ok=True)
    return run


def _evaluated_run(ws: Path, case: Path, config: object) -> str:
    """A run folder whose config.json holds ``config`` (hand-edited), beside the workspace's model."""
    run = case / "run"
    run.mkdir()
    shutil.copy(ws / "model.zip", run / "model.zip")
    (run / "config.json").write_text(json.dumps(config))
    return str(run / "model.zip")


def _damaged_model(ws: Path, case: Path, data: bytes | None = None) -> str:
    path = case / "model.zip"
    whole = (ws / "model.zip").read_bytes()
    path.write_bytes(whole[: len(whole) // 2] if data is None else data)
    return str(path)


def _cartpole_model(case: Path) -> str:
    path = case / "cartpole.zip"
    CMZDRIL("MlpPolicy", "CartPole-v1", **TINY).save(path)
    return str(path)


def _evaluate(ws: Path, model: str, *extra: str, demos: str | None = "demos.npz") -> list[str]:
    """``evaluate`` of ``model`` on the workspace pool (``demos=None``: the run's own choice)."""
    pool = ["--demos", str(ws / demos)] if demos else []
    return ["evaluate", "--model", model, "--env", ENV, "--env-kwargs", "dict(max_episode_steps=50)", *pool, *extra]


def _benchmark(ws: Path, case: Path, *extra: str, pool: str | None = None) -> list[str]:
    demos_dir = case / "experts" / ENV
    demos_dir.mkdir(parents=True)
    shutil.copy(pool or ws / "demos.npz", demos_dir / "demos.npz")
    return ["benchmark", "--env", ENV, "--methods", "bc", "--trials", "1", "--timesteps", "128", "--no-progress",
            "--demos-dir", str(case / "experts"), "--hyperparams", str(ws / "cmzdril.yml"), "-o", str(case / "runs"),
            *extra]


def _foreign_config(case: Path) -> Path:
    out = case / "out"
    out.mkdir()
    (out / "config.json").write_text('{"my": "notes"}')
    return out


def _pool_recorded_with(ws: Path, case: Path, env_kwargs: dict) -> str:
    """The workspace pool with a record saying collect-demos made its env with ``env_kwargs``."""
    shutil.copy(ws / "demos.npz", case / "pool.npz")
    (case / "pool.json").write_text(json.dumps({"demos": {"env_id": ENV, "env_kwargs": env_kwargs}}))
    return "pool.npz"


@dataclass(frozen=True)
class Case:
    """argv built from (workspace, this case's folder); ``says``: a regex the error line must match."""

    command: str
    id: str
    argv: Callable[[Path, Path], list[str]]
    says: str = ""
    marks: tuple = ()


def _model(ws: Path) -> str:
    return str(ws / "model.zip")


CASES = [
    # -- train-expert ---------------------------------------------------------------------------------
    Case("train-expert", "unknown env",
         lambda ws, c: ["train-expert", "--env", "NoSuchEnv-v0", "-o", str(c / "e")], "unknown environment 'NoSuch"),
    Case("train-expert", "unknown algo", lambda ws, c: _expert(ws, c / "e", "--algo", "nope")),
    Case("train-expert", "negative timesteps", lambda ws, c: _expert(ws, c / "e", "--timesteps", "-5")),
    Case("train-expert", "negative seed", lambda ws, c: _expert(ws, c / "e", "--seed", "-1")),
    Case("train-expert", "YAML key SAC lacks",
         lambda ws, c: _expert(ws, c / "e", "--hyperparams", _yaml(ws, c, "  n_step: 3\n", "sac.yml")), "n_step"),
    Case("train-expert", "hyperparams file missing",
         lambda ws, c: _expert(ws, c / "e", "--hyperparams", str(c / "none.yml")), "none.yml"),
    Case("train-expert", "-o is someone else's expert", lambda ws, c: _expert(ws, ws / "experts" / ENV)),
    # -- collect-demos --------------------------------------------------------------------------------
    Case("collect-demos", "unknown env", lambda ws, c: _collect(ws, c, _model(ws), env="NoSuchEnv-v0"), "NoSuchEnv"),
    Case("collect-demos", "unknown scripted expert", lambda ws, c: _collect(ws, c, "no-such-expert"),
         "unknown expert 'no-such-expert'"),
    Case("collect-demos", "expert file missing", lambda ws, c: _collect(ws, c, str(c / "none.zip")), "none.zip"),
    Case("collect-demos", "truncated expert zip", lambda ws, c: _collect(ws, c, _damaged_model(ws, c)), "model.zip"),
    Case("collect-demos", "zero episodes", lambda ws, c: _collect(ws, c, _model(ws), "--episodes", "0")),
    Case("collect-demos", "negative seed", lambda ws, c: _collect(ws, c, _model(ws), "--seed", "-3")),
    Case("collect-demos", "env_kwargs the env does not take",
         lambda ws, c: _collect(ws, c, _model(ws), "--env-kwargs", "dict(nonsense=1)"),
         "cannot make Pendulum-v1 with env_kwargs.*nonsense"),
    Case("collect-demos", "env_kwargs not a dict", lambda ws, c: _collect(ws, c, _model(ws), "--env-kwargs", "[1]"),
         "--env-kwargs must be a dict"),
    Case("collect-demos", "output exists",
         lambda ws, c: ["collect-demos", "--expert", _model(ws), "--env", ENV, "-o", str(ws / "demos.npz")],
         "demos.npz"),
    # -- train ----------------------------------------------------------------------------------------
    Case("train", "unknown env", lambda ws, c: ["train", "--env", "NoSuchEnv-v0", "--reward", "cmz",
                                                 "-o", str(c / "out")], "unknown environment"),
    Case("train", "demo pool missing", lambda ws, c: _cmz(ws, c / "out", demos="case/no.npz"), "no.npz"),
    Case("train", "demo pool of a newer format", lambda ws, c: _cmz(ws, c / "out", demos="future.npz"),
         "future.npz.*format_version"),
    Case("train", "more demos than the pool", lambda ws, c: [*_cmz(ws, c / "out"), "--n-demos", "99"]),
    Case("train", "negative timesteps", lambda ws, c: [*_cmz(ws, c / "out"), "--timesteps", "-5"]),
    Case("train", "YAML n_steps not a number",
         lambda ws, c: _cmz(ws, c / "out", hyperparams=_yaml(ws, c, '  n_steps: "lots"\n')), "n_steps"),
    Case("train", "YAML batch_size 0",
         lambda ws, c: _cmz(ws, c / "out", hyperparams=_yaml(ws, c, "  batch_size: 0\n")), "batch_size"),
    Case("train", "YAML n_epochs 0",
         lambda ws, c: _cmz(ws, c / "out", hyperparams=_yaml(ws, c, "  n_epochs: 0\n")), "n_epochs"),
    Case("train", "YAML ensemble_epochs 0",
         lambda ws, c: _cmz(ws, c / "out", hyperparams=_yaml(ws, c, "  ensemble_epochs: 0\n")), "ensemble_epochs"),
    Case("train", "YAML learning_rate nan",
         lambda ws, c: _cmz(ws, c / "out", hyperparams=_yaml(ws, c, "  learning_rate: .nan\n")),
         "learning_rate must be finite, got nan"),
    Case("train", "demo pool recorded with other env_kwargs than the YAML's",
         lambda ws, c: _cmz(c, c / "out", demos=_pool_recorded_with(ws, c, {"max_episode_steps": 50, "g": 9.0}),
                            hyperparams=str(ws / "cmzdril.yml")),
         r"recorded with env_kwargs \{'g': 9.0\}, but hyperparameters .* make the env with \{\}"),
    Case("train", "demo pool without reset seeds", lambda ws, c: _cmz(ws, c / "out", demos="noseeds.npz"), "seed"),
    Case("train", "-o holds someone's config.json", lambda ws, c: _cmz(ws, _foreign_config(c)), "config.json"),
    Case("train", "-o is an expert folder", lambda ws, c: _cmz(ws, ws / "experts" / ENV), ""),
    Case("train", "done.json an array", lambda ws, c: _cmz(ws, _hand_edited(ws, c, "done.json", "[]")),
         "done.json is not what sb3-cmzdril wrote"),
    Case("train", "done.json null", lambda ws, c: _cmz(ws, _hand_edited(ws, c, "done.json", "null")),
         "done.json is not what sb3-cmzdril wrote"),
    Case("train", "config.json an array", lambda ws, c: _cmz(ws, _hand_edited(ws, c, "config.json", "[1, 2]")),
         "run/config.json is not"),
    Case("train", "truncated lowest_u.pt on resume", lambda ws, c: _cmz(ws, _unfinished(ws, c, "lowest_u.pt")),
         "lowest_u.pt is truncated"),
    # -- evaluate -------------------------------------------------------------------------------------
    Case("evaluate", "env_kwargs the env does not take",
         lambda ws, c: _evaluate(ws, _model(ws), "--env-kwargs", "dict(nonsense=1)"),
         "cannot make Pendulum-v1 with env_kwargs.*nonsense"),
    Case("evaluate", "env_kwargs not a dict", lambda ws, c: _evaluate(ws, _model(ws), "--env-kwargs", "[1]"),
         "--env-kwargs must be a dict"),
    Case("evaluate", "env_kwargs code",
         lambda ws, c: _evaluate(ws, _model(ws), "--env-kwargs", "__import__('os').getcwd()")),
    Case("evaluate", "config.json an array", lambda ws, c: _evaluate(ws, _evaluated_run(ws, c, [1, 2]), demos=None),
         "config.json is not what sb3-cmzdril wrote: it holds a JSON array"),
    Case("evaluate", "config.json null", lambda ws, c: _evaluate(ws, _evaluated_run(ws, c, None), demos=None),
         "config.json is not what sb3-cmzdril wrote: it holds a JSON null"),
    Case("evaluate", "config.json demos 123",
         lambda ws, c: _evaluate(ws, _evaluated_run(ws, c, {"demos": 123}), demos=None),
         "config.json: demos must be a path, got 123"),
    Case("evaluate", "config.json eval_episodes out of the pool",
         lambda ws, c: _evaluate(ws, _evaluated_run(ws, c, {"demos": str(ws / "demos.npz"), "eval_episodes": [999]}),
                                 demos=None),
         r"eval_episodes \[999\] of the run's config.json are not episodes of"),
    Case("evaluate", "config.json eval_episodes not indices",
         lambda ws, c: _evaluate(ws, _evaluated_run(ws, c, {"demos": str(ws / "demos.npz"), "eval_episodes": ["a"]}),
                                 demos=None),
         "eval_episodes must be a list of episode indices"),
    Case("evaluate", "config.json env_kwargs a string",
         lambda ws, c: ["evaluate", "--model", _evaluated_run(ws, c, {"env_kwargs": "x"}), "--env", ENV],
         "env_kwargs must be an object"),
    Case("evaluate", "truncated model", lambda ws, c: _evaluate(ws, _damaged_model(ws, c)),
         "model file .*model.zip is corrupt, truncated or not an SB3 model zip"),
    Case("evaluate", "model not a zip", lambda ws, c: _evaluate(ws, _damaged_model(ws, c, b"hello")),
         "model file .*model.zip"),
    Case("evaluate", "model of another env", lambda ws, c: _evaluate(ws, _cartpole_model(c)),
         "cartpole.zip was trained on another environment: its observation space"),
    Case("evaluate", "model missing", lambda ws, c: _evaluate(ws, str(c / "none.zip")), "none.zip"),
    Case("evaluate", "demo file of a newer format", lambda ws, c: _evaluate(ws, _model(ws), demos="future.npz"),
         "future.npz has format_version"),
    Case("evaluate", "episodes not integers", lambda ws, c: _evaluate(ws, _model(ws), "--episodes", "a,b"),
         "--episodes must be comma-separated integers"),
    Case("evaluate", "episode out of range", lambda ws, c: _evaluate(ws, _model(ws), "--episodes", "0,99"),
         f"has {POOL_EPISODES} episodes"),
    Case("evaluate", "vecnormalize file missing",
         lambda ws, c: _evaluate(ws, _model(ws), "--vecnormalize", str(c / "v.pkl")), "v.pkl"),
    Case("evaluate", "unknown env",
         lambda ws, c: ["evaluate", "--model", _model(ws), "--env", "Nope-v0", "--demos", str(ws / "demos.npz")],
         "unknown environment"),
    # -- benchmark ------------------------------------------------------------------------------------
    Case("benchmark", "unknown env", lambda ws, c: ["benchmark", "--env", "NoSuchEnv-v0", "-o", str(c / "runs")],
         "unknown environment"),
    Case("benchmark", "unknown method", lambda ws, c: _benchmark(ws, c, "--methods", "bc,nope"), "nope"),
    Case("benchmark", "zero trials", lambda ws, c: _benchmark(ws, c, "--trials", "0")),
    Case("benchmark", "trials not a count or range", lambda ws, c: _benchmark(ws, c, "--trials", "5..9"),
         "write a count"),
    Case("benchmark", "trial range backwards", lambda ws, c: _benchmark(ws, c, "--trials", "9-5"), "runs backwards"),
    Case("benchmark", "a trial twice", lambda ws, c: _benchmark(ws, c, "--trials", "0-2,1"), "names a trial twice"),
    Case("benchmark", "zero workers", lambda ws, c: _benchmark(ws, c, "--workers", "0")),
    Case("benchmark", "unknown backend", lambda ws, c: _benchmark(ws, c, "--backend", "carrier-pigeon")),
    Case("benchmark", "demos dir missing", lambda ws, c: [*_benchmark(ws, c), "--demos-dir", str(c / "nowhere")],
         "nowhere"),
    Case("benchmark", "YAML n_epochs 0",
         lambda ws, c: _benchmark(ws, c, "--hyperparams", _yaml(ws, c, "  n_epochs: 0\n")), "n_epochs"),
    # -- report ---------------------------------------------------------------------------------------
    Case("report", "runs folder missing", lambda ws, c: ["report", str(c / "nowhere"), "-o", str(c / "rep")],
         "nowhere"),
    Case("report", "reference runs missing",
         lambda ws, c: ["report", str(ws / "cmzrun"), "--reference-runs", str(c / "nowhere"), "-o", str(c / "rep")],
         "nowhere"),
    Case("report", "zero window", lambda ws, c: ["report", str(ws / "cmzrun"), "--window", "0", "-o", str(c / "rep")]),
    # -- issue 30's probe -----------------------------------------------------------------------------
    Case("train", "-o holds the user's error.txt, log.txt and .draft.tmp.md (30.1)",
         lambda ws, c: _cmz(ws, _users_folder(c)), "holds files that are not an sb3-cmzdril run's"),
    Case("train", "pool with a negative reset seed (30.4)", lambda ws, c: _cmz(ws, c / "out", demos=_pool(ws, c, -5)),
         r"pool.npz: reset seeds must be integers in \[0, 2\*\*32\)"),
    Case("evaluate", "pool with a negative reset seed (30.4)",
         lambda ws, c: _evaluate(ws, _model(ws), demos=_pool(ws, c, -5)), r"reset seeds must be integers"),
    Case("train", "done.json num_timesteps null (30.6)", lambda ws, c: _cmz(ws, _done_with(ws, c, num_timesteps=None)),
         "done.json is not what sb3-cmzdril wrote: num_timesteps is None"),
    Case("train", "done.json num_timesteps [1] (30.6)", lambda ws, c: _cmz(ws, _done_with(ws, c, num_timesteps=[1])),
         r"done.json is not what sb3-cmzdril wrote: num_timesteps is \[1\]"),
    Case("train", "done.json num_timesteps 'abc' (30.15)",
         lambda ws, c: _cmz(ws, _done_with(ws, c, num_timesteps="abc")),
         "run/done.json is not what sb3-cmzdril wrote: num_timesteps is 'abc'"),
    Case("train", "YAML n_envs 2.5 (30.7)", lambda ws, c: _cmz_yaml(ws, c, "  n_envs: 2.5\n"),
         "n_envs must be an integer >= 1, got 2.5"),
    Case("train", "YAML n_envs '3' (30.7)",
         lambda ws, c: _cmz_yaml(ws, c, '  n_envs: "3"\n'),
         "n_envs must be an integer >= 1, got '3'"),
    Case("train", "YAML n_envs true (30.7)",
         lambda ws, c: _cmz_yaml(ws, c, "  n_envs: true\n"),
         "n_envs must be an integer >= 1, got True"),
    Case("train", "YAML n_demos 'x'", lambda ws, c: _cmz_yaml(ws, c, '  n_demos: "x"\n'),
         "n_demos must be a positive integer, got 'x'"),
    Case("train", "-o empty (30.8)", lambda ws, c: _cmz(ws, ""), r"-o/--output is empty"),
    Case("train-expert", "-o empty (30.8)", lambda ws, c: _expert(ws, ""), r"-o/--output is empty"),
    Case("collect-demos", "-o empty (30.8)",
         lambda ws, c: ["collect-demos", "--expert", _model(ws), "--env", ENV, "-o", ""], r"-o/--output is empty"),
    Case("benchmark", "-o empty (30.8)", lambda ws, c: [*_benchmark(ws, c), "-o", ""], r"-o/--output is empty"),
    Case("report", "-o empty (30.8)", lambda ws, c: ["report", str(ws / "cmzrun"), "-o", ""], r"-o/--output is empty"),
    Case("train", "pool whose seeds do not reproduce its starts (30.9)",
         lambda ws, c: _cmz(ws, c / "out", demos=_pool(ws, c, None, shift=1000)),
         "pool.npz was not recorded on Pendulum-v1 with these env_kwargs: resetting its episode"),
    Case("benchmark", "pool whose seeds do not reproduce its starts (30.9)",
         lambda ws, c: _benchmark(ws, c, pool=_pool(ws, c, None, shift=1000)), "was not recorded on Pendulum-v1"),
    Case("train", "YAML alpha .inf (30.11)",
         lambda ws, c: _cmz_yaml(ws, c, "  alpha: .inf\n"),
         "alpha must be finite, got inf"),
    Case("train", "YAML alpha .nan (30.11)",
         lambda ws, c: _cmz_yaml(ws, c, "  alpha: .nan\n"),
         "alpha must be finite, got nan"),
    Case("train-expert", "YAML tau .inf (30.11)",
         lambda ws, c: _expert(ws, c / "e", "--hyperparams", _yaml(ws, c, "  tau: .inf\n", "sac.yml")),
         "tau must be finite, got inf"),
    Case("train", "YAML of random bytes (30.12)", lambda ws, c: _cmz(ws, c / "out", hyperparams=_bytes(c)),
         r"hyperparameter file .*random.yml is not UTF-8 text"),
    Case("train-expert", "YAML of random bytes (30.12)", lambda ws, c: _expert(ws, c / "e", "--hyperparams", _bytes(c)),
         r"random.yml is not UTF-8 text"),
    Case("evaluate", "model and demos of another env (30.14)",
         lambda ws, c: _evaluate(ws, _cartpole_model(c), demos=_cartpole_pool(c)),
         r"cartpole.zip was trained on another environment: its observation space is Box of shape \(4,\), "
         r"Pendulum-v1's is Box of shape \(3,\)"),
    # -- the output probe: a pool or its record over another file --------------------------------------
    Case("collect-demos", "-o X.json: the record NAME.json would be the pool itself",
         lambda ws, c: ["collect-demos", "--expert", _model(ws), "--env", ENV, "-o", str(c / "pool.json")],
         r"case/pool.json must end in .npz"),
    Case("collect-demos", "-o without .npz", lambda ws, c: ["collect-demos", "--expert", _model(ws), "--env", ENV,
                                                           "-o", str(c / "pool")], r"case/pool must end in .npz"),
    Case("collect-demos", "the record would replace the expert's zip (--force)",
         lambda ws, c: ["collect-demos", "--expert", _expert_named(ws, c, "agent.json"), "--env", ENV,
                        "-o", str(c / "agent.npz"), "--force"],
         r"provenance .*agent.json would replace the expert's file .*agent.json"),
    Case("collect-demos", "-o is the expert's zip (--force)",
         lambda ws, c: ["collect-demos", "--expert", _expert_named(ws, c, "agent.npz"), "--env", ENV,
                        "-o", str(c / "agent.npz"), "--force"],
         r"pool .*agent.npz would replace the expert's file .*agent.npz"),
    Case("train-expert", "timesteps -1 (30.16)", lambda ws, c: _expert(ws, c / "e", "--timesteps", "-1"),
         r"timesteps \(--timesteps\) must be a positive integer, got -1"),
    # -- the fourth probe (issue 75) ------------------------------------------------------------------
    Case("train", "YAML key written twice (75.10)",
         lambda ws, c: _cmz(ws, c / "out", hyperparams=_appended(ws, c, "  n_epochs: 3\n  n_epochs: 4\n")),
         r"duplicate key 'n_epochs' at line \d+ \(first at line \d+\)"),
    Case("train", "YAML verbose (75.15)", lambda ws, c: _cmz_yaml(ws, c, "  verbose: 1\n"), "verbose"),
    Case("train", "cmz-sac YAML gradient_steps 0 (75.6)",
         lambda ws, c: _train(c / "out", "--reward", "cmz-sac", "--demos", str(ws / "demos.npz"),
                              "--hyperparams", _yaml(ws, c, "  gradient_steps: 0\n", "sac.yml")), "gradient_steps"),
    Case("benchmark", "--hyperparams that no method reads (75.5)",
         lambda ws, c: [*_benchmark(ws, c), "--methods", "cmz-sac"],
         r"--hyperparams .* is read by the PPO methods only and --methods has none \(cmz-sac\)"),
    Case("benchmark", "a per_method n_demos (75.3)",
         lambda ws, c: [*_benchmark(ws, c), "--methods", "bc,cmz", "--eval-episodes", "2", "--hyperparams",
                        _appended(ws, c, "  per_method:\n    cmz:\n      n_demos: 2\n")],
         r"trial 0: the methods would split the demo pool differently"),
]


def _appended(ws: Path, case: Path, text: str) -> str:
    """A copy of the workspace's tiny YAML with ``text`` appended under its env key, as it is."""
    path = case / "appended.yml"
    path.write_text((ws / "cmzdril.yml").read_text() + text)
    return str(path)


def _expert_named(ws: Path, case: Path, name: str) -> str:
    """The workspace's model zip as an expert file named ``name``."""
    shutil.copy(ws / "model.zip", case / name)
    return str(case / name)


def _users_folder(case: Path) -> Path:
    """A folder holding the user's own files, named as a run's would be."""
    out = case / "out"
    out.mkdir()
    (out / "error.txt").write_text("what went wrong with my robot\n")
    (out / "log.txt").write_text("my lab notes\n")
    (out / ".draft.tmp.md").write_text("a draft\n")
    return out


def _pool(ws: Path, case: Path, seed: int | None, shift: int = 0) -> str:
    """The workspace pool with episode 0's reset seed set to ``seed`` and every seed moved by ``shift``."""
    with np.load(ws / "demos.npz") as data:
        arrays = {k: data[k] for k in data.files}
    arrays["seeds"] = arrays["seeds"] + shift
    if seed is not None:
        arrays["seeds"][0] = seed
    path = case / "pool.npz"
    np.savez(path, **arrays)
    return str(path)


def _done_with(ws: Path, case: Path, **changes: object) -> Path:
    """A copy of the finished run whose done.json has ``changes`` edited in by hand."""
    run = _run_copy(ws, case)
    done = json.loads((run / "done.json").read_text())
    (run / "done.json").write_text(json.dumps({**done, **changes}))
    return run


def _bytes(case: Path) -> str:
    path = case / "random.yml"
    path.write_bytes(bytes(np.random.default_rng(0).integers(128, 256, size=200, dtype=np.uint8)))
    return str(path)


def _cartpole_pool(case: Path) -> str:
    path = case / "cartpole.npz"
    record("CartPole-v1", cartpole_expert, n_episodes=2, max_steps=20).save(path)
    return str(path)


def _hand_edited(ws: Path, case: Path, name: str, text: str) -> Path:
    """A copy of the finished run with one of its JSON files edited by hand."""
    run = _run_copy(ws, case)
    (run / name).write_text(text)
    return run


def _unfinished(ws: Path, case: Path, truncate: str) -> Path:
    """A copy of the run as an interruption leaves it (no done.json), one file cut in half."""
    run = _run_copy(ws, case)
    (run / "done.json").unlink()
    data = (run / truncate).read_bytes()
    (run / truncate).write_bytes(data[: len(data) // 2])
    return run


def snapshot(folder: Path) -> dict[str, tuple]:
    """Every path below ``folder``: kind, and for a file its bytes' hash, size and modification time."""
    state: dict[str, tuple] = {}
    for path in sorted(folder.rglob("*")):
        if path.is_dir():
            state[str(path.relative_to(folder))] = ("dir",)
        else:
            stat = path.stat()
            digest = hashlib.sha256(path.read_bytes()).hexdigest()
            state[str(path.relative_to(folder))] = ("file", digest, stat.st_size, stat.st_mtime_ns)
    return state


@pytest.mark.parametrize(
    "case", [pytest.param(c, id=f"{c.command}: {c.id}", marks=c.marks) for c in CASES]
)
def test_bad_input_is_one_line_exit_2_and_nothing_written(case, ws, capsys, monkeypatch):
    import re

    monkeypatch.chdir(ws)  # default output folders (experts/<Env>, runs/) would land here
    folder = ws / "case"
    folder.mkdir()
    try:
        argv = case.argv(ws, folder)
        before = snapshot(ws)
        capsys.readouterr()
        code = main(argv)
        out, err = capsys.readouterr()
        after = snapshot(ws)
    finally:
        shutil.rmtree(folder)
    lines = err.strip().splitlines()
    assert "Traceback" not in out + err, err
    assert code == 2, (code, err)
    assert len(lines) == 1, err
    assert lines[0].startswith(f"sb3-cmzdril {case.command}: error: "), err
    if case.says:
        assert re.search(case.says, lines[0]), lines[0]
    if case.command == "evaluate":
        assert "expert" not in lines[0], lines[0]  # evaluate's model is a model, whatever trained it
    changed = sorted(k for k in before.keys() | after.keys() if before.get(k) != after.get(k))
    assert not changed, f"written or changed: {changed}"


def test_every_command_has_cases():
    from sb3_cmzdril.cli import build_parser

    commands = set(build_parser()._subparsers._group_actions[0].choices)
    assert commands == {c.command for c in CASES}


# -- the library's side of the same causes -------------------------------------------------------------
@pytest.mark.parametrize("final_evaluation", [[1], "lowest", {"lowest_u": 3}, {"lowest_u": {"epoch": "x"}}])
def test_report_leaves_out_a_done_json_final_evaluation_of_another_shape(final_evaluation, ws, tmp_path, capsys):
    """Issue 30, cause 5: a hand-edited final_evaluation in done.json ended `report` with an
    AttributeError; the run still counts, its selected epoch is left out with a note naming the file."""
    run = tmp_path / "runs" / "cmzrun"
    shutil.copytree(ws / "cmzrun", run)
    done = json.loads((run / "done.json").read_text())
    (run / "done.json").write_text(json.dumps({**done, "final_evaluation": final_evaluation}))
    assert main(["report", str(tmp_path / "runs"), "-o", str(tmp_path / "report")]) == 0
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    results = (tmp_path / "report" / "results.md").read_text()
    assert "done.json" in results and "its final_evaluation" in results, results


def test_report_reads_a_final_evaluation_as_runs_write_it(ws, tmp_path):
    """A run's done.json also records its held-out episodes in final_evaluation: that is no hand edit."""
    run = tmp_path / "runs" / "cmzrun"
    shutil.copytree(ws / "cmzrun", run)
    done = json.loads((run / "done.json").read_text())
    final = {"episodes": [0, 2], "final": {"return_mean": 1.0}, "lowest_u": {"return_mean": 1.0, "epoch": 3}}
    (run / "done.json").write_text(json.dumps({**done, "final_evaluation": final}))
    assert main(["report", str(tmp_path / "runs"), "-o", str(tmp_path / "report")]) == 0
    assert "its final_evaluation" not in (tmp_path / "report" / "results.md").read_text()


@pytest.mark.parametrize("option", ["alpha", "ema", "u0", "dril_quantile", "ensemble_learning_rate", "bc_learning_rate",
                                    "learning_rate", "gamma", "ent_coef", "vf_coef", "max_grad_norm", "target_kl"])
@pytest.mark.parametrize("value", [float("inf"), float("-inf"), float("nan")])
def test_every_float_option_of_cmzdril_must_be_finite(option, value, pendulum_demos):
    """Issue 30, cause 11: CMZDRIL(alpha=inf) passed (``not alpha > 0``) and failed in torch once
    training ran; every float option is refused, named, before anything is built."""
    with pytest.raises(UserError, match=f"^{option} must be finite, got {value}$"):
        CMZDRIL("MlpPolicy", ENV, demonstrations=pendulum_demos, **{**TINY, option: value})
    with pytest.raises(UserError, match="alpha must be > 0 and finite"):
        CMZReward(alpha=float("inf"))


@pytest.mark.parametrize("seed", [-5, -2, 2**32])
def test_reset_seeds_outside_what_gymnasium_takes_are_refused_up_front(seed, pendulum_demos, tmp_path):
    """Issue 30, cause 4: only -1 (unknown) was checked; -5 failed deep inside gymnasium's reset,
    after a run's files were written. A pool with such a seed is refused when built or loaded."""
    d = pendulum_demos
    with pytest.raises(UserError, match=r"reset seeds must be integers in \[0, 2\*\*32\)"):
        Demonstrations(d.observations, d.actions, d.episode_lengths, seeds=[seed, 0])
    np.savez(tmp_path / "d.npz", format_version=np.asarray(FORMAT_VERSION), observations=d.observations,
             actions=d.actions, episode_lengths=d.episode_lengths, seeds=np.asarray([0, seed]))
    with pytest.raises(UserError, match=r"d.npz: reset seeds must be integers .* episodes \[1\]"):
        Demonstrations.load(tmp_path / "d.npz")
