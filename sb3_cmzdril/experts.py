"""Experts: training SB3 experts (train_expert), scripted experts, and recording demonstrations.

A *scripted expert* is any object with SB3's ``predict(observation, state=None, episode_start=None,
deterministic=True) -> (actions, None)`` that accepts one observation or a batch of them. It is built
by a factory ``factory(env) -> expert`` (the env gives it the spaces and options it needs) and
registered by name, so that ``collect-demos --expert NAME`` finds it.

Training layout (``train_expert(..., output_dir=DIR)``)::

    DIR/model.zip            best model by periodic deterministic evaluation (written atomically)
    DIR/metadata.json        how it was made: command, versions, steps, seed, hyperparameters, eval
    DIR/checkpoints/         resumable state: model_<N>_steps.zip, replay_buffer_<N>_steps.pkl,
                             state.json (points at the latest pair; written last), best.json

Running again with the same ``DIR`` resumes from ``checkpoints/state.json`` (model, replay buffer,
step count, the best evaluation score so far and the wall time spent) and trains until the requested
*total* number of steps.
"""
from __future__ import annotations

import json
import math
import os
import platform
import shlex
import sys
import time
import zipfile
from pathlib import Path
from typing import Any, Callable, Dict, Optional, Sequence, Tuple, Union

import gymnasium as gym
import numpy as np

from sb3_cmzdril._atomic import PathLike, atomic_path, atomic_write_text
from sb3_cmzdril.demos import Demonstrations

ScriptedExpertFactory = Callable[[gym.Env], Any]
SCRIPTED_EXPERTS: Dict[str, ScriptedExpertFactory] = {}


def register_scripted_expert(name: str, factory: ScriptedExpertFactory) -> None:
    """Make ``factory`` available as ``--expert NAME`` (names are unique)."""
    if name in SCRIPTED_EXPERTS and SCRIPTED_EXPERTS[name] is not factory:
        raise ValueError(f"a scripted expert named {name!r} is already registered")
    SCRIPTED_EXPERTS[name] = factory


# -- helpers -------------------------------------------------------------------------------------
def env_name(env_id: str) -> str:
    """``module:EnvId-v0`` -> ``EnvId-v0`` (used for default folder names)."""
    return env_id.rsplit(":", 1)[-1]


def check_env_id(env_id: str) -> str:
    """The env id if gymnasium knows it (importing a ``module:`` prefix first), else a ValueError.

    Commands call it before they create any folder, so a typo leaves nothing behind.
    """
    import importlib

    import sb3_cmzdril  # noqa: F401  (registers WaypointNav-v0, which a bare id may name)

    module, sep, name = env_id.rpartition(":")
    if sep:
        try:
            importlib.import_module(module)
        except ImportError as e:
            raise ValueError(f"unknown environment {env_id!r}: cannot import module {module!r} ({e})") from None
    try:
        gym.spec(name if sep else env_id)
    except gym.error.Error as e:
        raise ValueError(f"unknown environment {env_id!r}: {e}") from None
    return env_id


def check_seed(seed: int) -> int:
    """A reset/network seed: numpy and gymnasium accept integers in [0, 2**32)."""
    if isinstance(seed, bool) or int(seed) != seed or not 0 <= int(seed) < 2**32:
        raise ValueError(f"seed must be an integer in [0, 2**32), got {seed!r}")
    return int(seed)


def check_threads(n_threads: Optional[int]) -> Optional[int]:
    """``torch.set_num_threads`` value: None (torch's default) or >= 1 (0 would make torch raise)."""
    if n_threads is not None and (isinstance(n_threads, bool) or int(n_threads) < 1):
        raise ValueError(f"threads must be >= 1, got {n_threads!r}")
    return n_threads


def load_demonstrations(path: PathLike) -> Demonstrations:
    """:meth:`Demonstrations.load` with every kind of damaged file turned into a ValueError.

    A compressed npz whose deflate stream is damaged (rather than its CRC) fails inside zlib with
    ``zlib.error``, which names neither the file nor the problem.
    """
    import zlib

    try:
        return Demonstrations.load(path)
    except zlib.error as e:
        raise ValueError(f"demo file {path} is corrupt: {e}") from e


def algorithm_classes() -> Dict[str, type]:
    """SB3 algorithms by the zoo's lowercase names."""
    from stable_baselines3 import A2C, DDPG, DQN, PPO, SAC, TD3

    return {"sac": SAC, "td3": TD3, "ddpg": DDPG, "ppo": PPO, "a2c": A2C, "dqn": DQN}


def _algo_class(algo: str) -> type:
    classes = algorithm_classes()
    if algo.lower() not in classes:
        raise ValueError(f"unknown algorithm {algo!r}; available: {sorted(classes)}")
    return classes[algo.lower()]


def _versions() -> Dict[str, str]:
    import stable_baselines3
    import torch

    import sb3_cmzdril

    versions = {
        "python": platform.python_version(),
        "sb3_cmzdril": getattr(sb3_cmzdril, "__version__", "unknown"),
        "stable_baselines3": stable_baselines3.__version__,
        "gymnasium": gym.__version__,
        "torch": torch.__version__,
        "numpy": np.__version__,
    }
    try:
        import mujoco

        versions["mujoco"] = mujoco.__version__
    except ImportError:  # pragma: no cover - mujoco is a dependency but optional for classic control
        versions["mujoco"] = "not installed"
    return versions


def _jsonable(value: Any) -> Any:
    """Hyperparameter values as JSON (classes by qualified name, schedules by their zoo string)."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (bool, int, str)) or value is None:
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else str(value)
    if isinstance(value, np.generic):
        return _jsonable(value.item())
    if isinstance(value, type):
        return f"{value.__module__}.{value.__qualname__}"
    return repr(value)


def _write_json(path: PathLike, data: Dict[str, Any]) -> None:
    atomic_write_text(path, json.dumps(_jsonable(data), indent=2, sort_keys=False) + "\n")


def _read_json(path: Path) -> Dict[str, Any]:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        raise ValueError(f"{path} is unreadable or corrupt: {e}") from e


def _read_json_or_empty(path: Path) -> Dict[str, Any]:
    """A JSON object file, or {} when it is missing, unreadable or not an object."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def _make_vec_env(env_id: str, n_envs: int, seed: int, env_kwargs: Optional[dict]):
    from stable_baselines3.common.env_util import make_vec_env

    return make_vec_env(env_id, n_envs=n_envs, seed=seed, env_kwargs=env_kwargs or None)


# -- callbacks -----------------------------------------------------------------------------------
def _callbacks():
    """Callback classes (built lazily so importing this module stays light)."""
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.evaluation import evaluate_policy

    class ProgressCallback(BaseCallback):
        """tqdm bar on a terminal; on a file (nohup, CI) a plain line every ``line_every`` steps."""

        def __init__(self, total: int, show: bool = True, line_every: Optional[int] = None) -> None:
            super().__init__()
            self.total = int(total)
            self.show = show
            self.line_every = line_every or max(1000, self.total // 50)
            self.bar = None
            self._t0 = 0.0
            self._n0 = 0
            self._next_line = 0

        def _on_training_start(self) -> None:
            self._t0 = time.time()
            self._n0 = self.model.num_timesteps
            self._t_last, self._n_last = self._t0, self._n0
            self._next_line = (self._n0 // self.line_every + 1) * self.line_every
            if not self.show:
                return
            if sys.stderr.isatty():
                from tqdm import tqdm

                self.bar = tqdm(total=self.total, initial=self._n0, unit="step", dynamic_ncols=True, smoothing=0.05)

        def _on_step(self) -> bool:
            n = self.num_timesteps
            if self.bar is not None:
                self.bar.update(n - self.bar.n)
            elif self.show and n >= self._next_line:
                self._next_line = (n // self.line_every + 1) * self.line_every
                now = time.time()
                elapsed = now - self._t_last
                rate = (n - self._n_last) / elapsed if elapsed > 0 else float("nan")  # since the last line
                self._t_last, self._n_last = now, n
                eta = (self.total - n) / rate if rate > 0 else float("nan")
                print(
                    f"[{time.strftime('%H:%M:%S')}] steps {n}/{self.total} ({100.0 * n / self.total:.0f}%), "
                    f"{rate:.0f} steps/s, eta {eta / 60:.1f} min",
                    flush=True,
                )
            return True

        def _on_training_end(self) -> None:
            if self.bar is not None:
                self.bar.close()
                self.bar = None

    class ExpertEvalCallback(BaseCallback):
        """Evaluate deterministically every ``eval_freq`` total steps; keep the best as ``model.zip``.

        Like SB3's EvalCallback (deterministic ``evaluate_policy`` on a separate env, best model
        kept), but: the schedule is on the *total* step count so it survives resumes; the best score
        is restored from ``best.json`` so a resumed run never overwrites a better model; model.zip
        and the score are written atomically; the history goes into ``state``.
        """

        def __init__(self, eval_env, eval_freq: int, n_eval_episodes: int, model_path: Path, best_path: Path,
                     state: Dict[str, Any], log: bool = True) -> None:
            super().__init__()
            self.eval_env = eval_env
            self.eval_freq = int(eval_freq)
            self.n_eval_episodes = int(n_eval_episodes)
            self.model_path = model_path
            self.best_path = best_path
            self.state = state
            self.log = log

        @property
        def best_mean_reward(self) -> float:
            best = self.state.get("best")
            return -math.inf if best is None else float(best["mean_reward"])

        def _on_step(self) -> bool:
            if self.eval_freq > 0 and self.num_timesteps % self.eval_freq < self.training_env.num_envs:
                if self.num_timesteps != self.state.get("last_eval_step"):
                    self.evaluate()
            return True

        def evaluate(self) -> Tuple[float, float]:
            returns, lengths = evaluate_policy(
                self.model, self.eval_env, n_eval_episodes=self.n_eval_episodes, deterministic=True,
                return_episode_rewards=True, warn=False,
            )
            mean, std = float(np.mean(returns)), float(np.std(returns))
            step = int(self.model.num_timesteps)
            self.state["last_eval_step"] = step
            self.state.setdefault("evaluations", []).append(
                {"timesteps": step, "mean_reward": mean, "std_reward": std, "mean_ep_length": float(np.mean(lengths))}
            )
            new_best = mean > self.best_mean_reward
            if new_best:
                with atomic_path(self.model_path, suffix=".zip") as tmp:
                    self.model.save(tmp)
                self.state["best"] = {"mean_reward": mean, "std_reward": std, "timesteps": step,
                                      "n_episodes": self.n_eval_episodes}
                _write_json(self.best_path, self.state["best"])
            logger = getattr(self.model, "_logger", None)
            if logger is not None:
                logger.record("eval/mean_reward", mean)
                logger.record("eval/mean_ep_length", float(np.mean(lengths)))
            if self.log:
                print(
                    f"[{time.strftime('%H:%M:%S')}] eval at {step} steps: {mean:.1f} +/- {std:.1f} "
                    f"(length {np.mean(lengths):.0f})" + ("  new best -> model.zip" if new_best else
                                                         f"  (best {self.best_mean_reward:.1f})"),
                    flush=True,
                )
            return mean, std

    class ResumableCheckpointCallback(BaseCallback):
        """Every ``save_freq`` total steps: model + replay buffer + state.json, each atomic.

        state.json is written last and names the model/buffer files, so a crash at any moment leaves
        either the previous or the new checkpoint complete. Older checkpoint files are removed.
        """

        def __init__(self, save_freq: int, ckpt_dir: Path, state: Dict[str, Any], t_start: float) -> None:
            super().__init__()
            self.save_freq = int(save_freq)
            self.ckpt_dir = ckpt_dir
            self.state = state
            self.t_start = t_start

        def _on_step(self) -> bool:
            if self.save_freq > 0 and self.num_timesteps % self.save_freq < self.training_env.num_envs:
                if self.num_timesteps != self.state.get("num_timesteps"):
                    self.save()
            return True

        def save(self) -> None:
            save_checkpoint(self.model, self.ckpt_dir, self.state, self.t_start)

    return ProgressCallback, ExpertEvalCallback, ResumableCheckpointCallback


STATE_FILE = "state.json"
BEST_FILE = "best.json"


def save_checkpoint(model, ckpt_dir: Path, state: Dict[str, Any], t_start: float) -> None:
    """Write model (+ replay buffer) then ``state.json`` pointing at them; prune older files."""
    steps = int(model.num_timesteps)
    model_file = f"model_{steps}_steps.zip"
    buffer_file = None
    with atomic_path(ckpt_dir / model_file, suffix=".zip") as tmp:
        model.save(tmp)
    if getattr(model, "replay_buffer", None) is not None:
        buffer_file = f"replay_buffer_{steps}_steps.pkl"
        with atomic_path(ckpt_dir / buffer_file, suffix=".pkl") as tmp:
            model.save_replay_buffer(tmp)
    now = time.time()
    state["wall_time_s"] = float(state.get("wall_time_s", 0.0)) + (now - state.pop("_segment_start", t_start))
    state["_segment_start"] = now
    state.update(num_timesteps=steps, model_file=model_file, replay_buffer_file=buffer_file)
    _write_json(ckpt_dir / STATE_FILE, {k: v for k, v in state.items() if not k.startswith("_")})
    keep = {model_file, buffer_file, STATE_FILE, BEST_FILE}
    for p in ckpt_dir.iterdir():
        if p.is_file() and p.name not in keep and p.name.startswith(("model_", "replay_buffer_")) and not p.name.startswith("."):
            try:
                p.unlink()
            except OSError:
                pass


# -- training ------------------------------------------------------------------------------------
LOCK_FILE = ".lock"


def _lock_output(ckpt_dir: Path):
    """Hold an exclusive lock on the run folder for this process's lifetime (None where unsupported)."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows: no locking
        return None
    handle = open(ckpt_dir / LOCK_FILE, "a+")
    try:
        fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        handle.close()
        raise ValueError(f"another train-expert is already running in {ckpt_dir.parent} (lock {ckpt_dir / LOCK_FILE})") from None
    return handle


def _remove_stale_temporaries(*folders: Path) -> None:
    """Temporary files of atomic writes cut short by a hard kill (we hold the folder's lock)."""
    for folder in folders:
        for p in folder.glob(".*.tmp*"):
            if p.is_file():
                try:
                    p.unlink()
                except OSError:
                    pass


def train_expert(
    env_id: str,
    algo: str = "sac",
    timesteps: Optional[int] = None,
    seed: int = 0,
    hyperparams_path: Optional[PathLike] = None,
    output_dir: Optional[PathLike] = None,
    eval_freq: int = 10_000,
    n_eval_episodes: int = 5,
    checkpoint_freq: int = 20_000,
    progress_bar: bool = True,
    final_eval_episodes: int = 10,
    n_threads: Optional[int] = 1,
    command: Optional[str] = None,
    verbose: int = 0,
    force: bool = False,
    _callback: Any = None,
) -> Path:
    """Train an SB3 expert with zoo hyperparameters; resumable; returns the path of ``model.zip``.

    :param timesteps: total training steps (default: ``n_timesteps`` from the hyperparameter file).
        When ``output_dir`` holds a checkpoint, training resumes there and stops at this total.
    :param hyperparams_path: zoo YAML (default: the repository's ``hyperparams/<algo>.yml``).
    :param output_dir: default ``experts/<EnvId>`` (module prefix removed), relative to the cwd.
    :param eval_freq: evaluate (deterministic, ``n_eval_episodes`` episodes) every this many steps;
        the best model so far is ``output_dir/model.zip``.
    :param checkpoint_freq: write a resumable checkpoint every this many steps (0: only at the end).
    :param final_eval_episodes: episodes of the final deterministic evaluation of model.zip,
        reported in metadata.json.
    :param n_threads: ``torch.set_num_threads`` (None leaves torch's default).
    :param command: the command line to record in metadata.json (the CLI passes ``sys.argv``).
    :param force: train in ``output_dir`` even though it holds an expert that resuming would not
        continue (a model.zip or metadata.json without checkpoints: replaced), or a finished
        expert with fewer than ``timesteps`` steps (continued from its checkpoint).
    :raises FileExistsError: without ``force``, in those two cases.
    """
    import torch

    from sb3_cmzdril.hyperparams import check_constructor_kwargs, default_hyperparams_path, load_hyperparams

    t_start = time.time()
    check_threads(n_threads)
    algo = algo.lower()
    algo_cls = _algo_class(algo)
    hp_path = Path(hyperparams_path) if hyperparams_path is not None else default_hyperparams_path(algo)
    # Everything that can be checked is checked before the output folder exists.
    check_env_id(env_id)
    seed = check_seed(seed)
    hp = load_hyperparams(hp_path, env_id)
    hp.check_supported(what="train-expert")
    check_constructor_kwargs(hp, [algo_cls])
    total = int(timesteps if timesteps is not None else (hp.n_timesteps or 0))
    if total <= 0:
        raise ValueError(f"no number of timesteps: pass timesteps= / --timesteps or set n_timesteps in {hp_path}")
    if final_eval_episodes < 1 or n_eval_episodes < 1:
        raise ValueError("n_eval_episodes and final_eval_episodes must be >= 1")
    if eval_freq < 0 or checkpoint_freq < 0:
        raise ValueError(f"eval_freq and checkpoint_freq must be >= 0, got {eval_freq} and {checkpoint_freq}")
    out = Path(output_dir) if output_dir is not None else Path("experts") / env_name(env_id)
    model_path = out / "model.zip"
    finished_steps = _check_expert_folder(out, env_id, algo, total, force)
    if finished_steps is not None:
        print(f"{out} holds a finished {algo} expert on {env_id} ({finished_steps} >= {total} steps, metadata.json); "
              "nothing to do", flush=True)
        return model_path
    if n_threads is not None:
        torch.set_num_threads(int(n_threads))
    ckpt_dir = out / "checkpoints"
    created = [d for d in (*reversed(out.parents), out, ckpt_dir) if not d.exists()]
    ckpt_dir.mkdir(parents=True, exist_ok=True)
    lock = _lock_output(ckpt_dir)
    try:
        return _train_expert_locked(
            env_id, algo, algo_cls, hp, hp_path, total, seed, out, ckpt_dir, model_path, eval_freq, n_eval_episodes,
            checkpoint_freq, progress_bar, final_eval_episodes, command, verbose, _callback, t_start,
        )
    except BaseException:
        # A first attempt that failed before writing anything leaves no empty folders behind.
        if lock is not None:
            _unlock(ckpt_dir, lock)
            lock = None
        for folder in reversed(created):
            try:
                folder.rmdir()
            except OSError:  # not empty: it holds a checkpoint or a model worth keeping
                break
        raise
    finally:
        if lock is not None:
            _unlock(ckpt_dir, lock)


def _unlock(ckpt_dir: Path, lock) -> None:
    try:
        (ckpt_dir / LOCK_FILE).unlink()
    except OSError:
        pass
    lock.close()


def _check_expert_folder(out: Path, env_id: str, algo: str, total: int, force: bool) -> Optional[int]:
    """Refuse to train over an expert that resuming would not continue; returns its step count
    when it is a finished expert of this env and algorithm with at least ``total`` steps.

    A folder is resumed only from its checkpoints (``checkpoints/state.json``). A model.zip or
    metadata.json without them (a shipped expert, another tool's model) would be silently replaced by
    the first evaluation of a fresh training, so that needs ``force``, as does training a finished
    expert further.
    """
    model_path, meta_path = out / "model.zip", out / "metadata.json"
    resumable = (out / "checkpoints" / STATE_FILE).is_file()
    meta = _read_json(meta_path) if meta_path.is_file() else {}
    steps = meta.get("total_timesteps")
    if model_path.is_file() and steps is not None:
        if (meta.get("env_id"), meta.get("algo")) != (env_id, algo) and not force:
            raise FileExistsError(
                f"{out} holds a {meta.get('algo')} expert on {meta.get('env_id')}, not {algo} on {env_id}; "
                "use another --output folder (or --force to train over it)"
            )
        if (meta.get("env_id"), meta.get("algo")) == (env_id, algo) and int(steps) >= total:
            return int(steps)
        if not force:
            how = ("continue it from its checkpoint" if resumable else "train a new expert over it (it has no checkpoint)")
            raise FileExistsError(
                f"{out} holds a finished expert trained for {steps} steps, fewer than the {total} asked; pass --force "
                f"to {how}, or use another --output folder"
            )
        return None
    if not resumable and not force and (model_path.is_file() or meta_path.is_file()):
        found = " and ".join(p.name for p in (model_path, meta_path) if p.is_file())
        raise FileExistsError(
            f"{out} already holds {found} but no checkpoint to resume from; pass --force to train a new expert "
            "there (replacing them), or use another --output folder"
        )
    return None


def _train_expert_locked(env_id, algo, algo_cls, hp, hp_path, total, seed, out, ckpt_dir, model_path, eval_freq,
                         n_eval_episodes, checkpoint_freq, progress_bar, final_eval_episodes, command, verbose,
                         _callback, t_start) -> Path:
    import torch
    from stable_baselines3.common.evaluation import evaluate_policy

    _remove_stale_temporaries(out, ckpt_dir)

    state: Dict[str, Any] = {"env_id": env_id, "algo": algo, "seed": int(seed), "num_timesteps": 0,
                             "wall_time_s": 0.0, "resumes": 0, "evaluations": [], "best": None}
    state_path = ckpt_dir / STATE_FILE
    resume = state_path.is_file()
    if resume:
        saved = _read_json(state_path)
        for key in ("env_id", "algo"):
            if saved.get(key) != state[key]:
                raise ValueError(
                    f"{out} holds a checkpoint of {saved.get('algo')} on {saved.get('env_id')}, not {algo} on {env_id}; "
                    "use another --output folder"
                )
        if int(saved.get("seed", seed)) != int(seed):
            print(f"note: resuming a run started with seed {saved.get('seed')} (seed {seed} ignored)", flush=True)
            seed = int(saved["seed"])
        state.update(saved)
        state["resumes"] = int(state.get("resumes", 0)) + 1
    best_path = ckpt_dir / BEST_FILE
    if best_path.is_file() and model_path.is_file():
        # best.json is written right after model.zip: it is the freshest record of the best score.
        best = _read_json(best_path)
        if state.get("best") is None or float(best["mean_reward"]) >= float(state["best"]["mean_reward"]):
            state["best"] = best
    elif not model_path.is_file():
        state["best"] = None
    state["_segment_start"] = t_start

    env = _make_vec_env(env_id, hp.n_envs, seed + int(state["num_timesteps"]), hp.env_kwargs)
    eval_env = _make_vec_env(env_id, 1, seed + 10_000 + int(state["num_timesteps"]), hp.env_kwargs)
    try:
        if resume:
            ckpt_model = ckpt_dir / state["model_file"]
            model = _load_sb3(algo_cls, ckpt_model, env=env)
            buffer_file = state.get("replay_buffer_file")
            if buffer_file and getattr(model, "replay_buffer", None) is not None:
                buffer_path = ckpt_dir / buffer_file
                if not buffer_path.is_file():
                    raise FileNotFoundError(f"checkpoint replay buffer missing: {buffer_path}")
                try:
                    model.load_replay_buffer(buffer_path)
                except Exception as e:  # pickle errors come in many types
                    raise ValueError(f"checkpoint replay buffer {buffer_path} is corrupt: {e}") from e
            if int(model.num_timesteps) != int(state["num_timesteps"]):
                raise ValueError(f"checkpoint {ckpt_model} has {model.num_timesteps} steps, state.json says {state['num_timesteps']}")
            model.set_random_seed(seed + int(model.num_timesteps))
            print(f"resuming {algo} on {env_id} from {ckpt_model} at {model.num_timesteps} steps"
                  + (f" (best eval so far {state['best']['mean_reward']:.1f})" if state.get("best") else ""), flush=True)
        else:
            model = algo_cls(hp.policy or "MlpPolicy", env, seed=seed, verbose=verbose, device="cpu", **hp.model_kwargs())

        ProgressCallback, ExpertEvalCallback, CheckpointCallback = _callbacks()
        eval_cb = ExpertEvalCallback(eval_env, eval_freq, n_eval_episodes, model_path, best_path, state)
        ckpt_cb = CheckpointCallback(checkpoint_freq, ckpt_dir, state, t_start)
        callbacks = [ProgressCallback(total, show=progress_bar), eval_cb, ckpt_cb]
        if _callback is not None:
            callbacks.append(_callback)
        remaining = total - int(model.num_timesteps)
        if remaining > 0:
            print(f"training {algo} on {env_id}: {model.num_timesteps} -> {total} steps, output {out}", flush=True)
            model.learn(remaining, callback=callbacks, reset_num_timesteps=not resume, progress_bar=False)
        else:
            print(f"{out} already holds {model.num_timesteps} >= {total} steps; not training further", flush=True)
        eval_cb.model = model
        if state.get("last_eval_step") != int(model.num_timesteps) or not model_path.is_file():
            eval_cb.evaluate()  # the final model competes for model.zip too
        save_checkpoint(model, ckpt_dir, state, t_start)  # also records the final evaluation and wall time

        # Final evaluation of the shipped model on fresh, seeded episodes.
        best_model = _load_sb3(algo_cls, model_path)
        final_env = _make_vec_env(env_id, 1, seed + 20_000, hp.env_kwargs)
        try:
            returns, lengths = evaluate_policy(best_model, final_env, n_eval_episodes=final_eval_episodes,
                                               deterministic=True, return_episode_rewards=True, warn=False)
        finally:
            final_env.close()
        now = time.time()
        wall = float(state.get("wall_time_s", 0.0)) + (now - state.get("_segment_start", t_start))
        metadata = {
            "env_id": env_id,
            "algo": algo,
            "seed": int(seed),
            "total_timesteps": int(model.num_timesteps),
            "requested_timesteps": total,
            "model_timesteps": int(state["best"]["timesteps"]) if state.get("best") else None,
            "eval": {
                "mean_reward": float(np.mean(returns)),
                "std_reward": float(np.std(returns)),
                "n_episodes": int(final_eval_episodes),
                "deterministic": True,
                "seed": int(seed + 20_000),
                "episode_returns": [float(r) for r in returns],
                "episode_lengths": [int(n) for n in lengths],
            },
            "best_periodic_eval": state.get("best"),
            "eval_freq": int(eval_freq),
            "n_eval_episodes": int(n_eval_episodes),
            "evaluations": state.get("evaluations", []),
            "hyperparams": {"file": str(hp_path), "key": hp.key, "values": hp.raw},
            "versions": _versions(),
            "torch_threads": torch.get_num_threads(),
            "command": command,
            "cwd": os.getcwd(),
            "wall_time_s": round(wall, 1),
            "resumes": int(state.get("resumes", 0)),
            "finished_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        }
        previous = _read_json_or_empty(out / "metadata.json")
        if isinstance(previous.get("demos"), dict):
            # The demo pool beside the expert keeps its provenance; it names the expert's step count
            # when it was recorded, which a continued (--force) training has since moved past.
            metadata["demos"] = {"expert_total_timesteps": previous.get("total_timesteps"), **previous["demos"]}
        _write_json(out / "metadata.json", metadata)
        print(
            f"done: {model_path} (from step {metadata['model_timesteps']}), final eval over {final_eval_episodes} "
            f"episodes {metadata['eval']['mean_reward']:.1f} +/- {metadata['eval']['std_reward']:.1f}; "
            f"wall time {wall / 60:.1f} min",
            flush=True,
        )
        return model_path
    finally:
        env.close()
        eval_env.close()


# -- loading experts -----------------------------------------------------------------------------
def _load_sb3(algo_cls: type, path: Path, env=None):
    """Load an SB3 zip for inference/continuation with a clear error naming the path."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"model file not found: {path}")
    try:
        return algo_cls.load(path, env=env, device="cpu")
    except (zipfile.BadZipFile, EOFError, KeyError, ValueError, RuntimeError, OSError, AttributeError, TypeError) as e:
        raise ValueError(f"cannot load {algo_cls.__name__} model from {path} (corrupt or not an SB3 zip?): {e}") from e


def _infer_algo(path: Path) -> Optional[str]:
    """The algorithm of an SB3 zip: metadata.json beside it, else the policy class's module."""
    meta = path.parent / "metadata.json"
    if meta.is_file():
        try:
            algo = json.loads(meta.read_text(encoding="utf-8")).get("algo")
            if isinstance(algo, str) and algo.lower() in algorithm_classes():
                return algo.lower()
        except (OSError, ValueError):
            pass
    try:
        with zipfile.ZipFile(path) as zf:
            data = json.loads(zf.read("data").decode("utf-8"))
        module = str(data.get("policy_class", {}).get("__module__", ""))
    except (zipfile.BadZipFile, KeyError, ValueError, OSError, AttributeError) as e:
        raise ValueError(f"expert file {path} is corrupt or not an SB3 model zip: {e}") from e
    parts = module.split(".")
    if len(parts) >= 2 and parts[0] == "stable_baselines3" and parts[1] in algorithm_classes():
        return parts[1]
    return None


def load_expert_model(path: PathLike, algo: Optional[str] = None):
    """Load an SB3 model zip of any algorithm (``algo`` given, from metadata.json, or tried in turn)."""
    path = Path(path)
    if path.is_dir():
        if not (path / "model.zip").is_file():
            raise FileNotFoundError(f"expert folder {path} has no model.zip")
        path = path / "model.zip"
    if not path.is_file():
        raise FileNotFoundError(f"expert model not found: {path}")
    algo = algo or _infer_algo(path)
    custom = {"learning_rate": 0.0, "lr_schedule": lambda _: 0.0, "clip_range": lambda _: 0.0}
    candidates = [algo] if algo else list(algorithm_classes())
    errors = []
    for name in candidates:
        cls = _algo_class(name)
        try:
            return cls.load(path, device="cpu", custom_objects=custom)
        except Exception as e:  # wrong algorithm or corrupt file: try the next one
            errors.append(f"{cls.__name__}: {type(e).__name__}: {e}")
    raise ValueError(f"cannot load expert model {path} (corrupt or not an SB3 zip?): " + "; ".join(errors))


def resolve_expert(expert: Union[str, PathLike, Any], env: gym.Env) -> Tuple[Any, str]:
    """An object with ``predict`` and a description, from a path, a folder or a scripted name."""
    if hasattr(expert, "predict") and not isinstance(expert, (str, Path)):
        return expert, type(expert).__name__
    name = str(expert)
    if isinstance(expert, str) and name in SCRIPTED_EXPERTS:
        return SCRIPTED_EXPERTS[name](env), f"scripted:{name}"
    path = Path(name)
    if path.exists():
        return load_expert_model(path), str(path)
    looks_like_path = isinstance(expert, Path) or os.sep in name or name.endswith((".zip", ".pkl")) or name.startswith(".")
    if looks_like_path:
        raise FileNotFoundError(f"expert model not found: {path}")
    raise ValueError(
        f"unknown expert {name!r}: no such file or folder, and no scripted expert of that name; "
        f"scripted experts: {sorted(SCRIPTED_EXPERTS) or 'none registered'}"
    )


# -- demonstrations ------------------------------------------------------------------------------
def run_episode(expert: Any, env: gym.Env, seed: int) -> Dict[str, Any]:
    """One episode with deterministic expert actions, reset with ``seed``."""
    obs, _ = env.reset(seed=int(seed))
    observations, actions, rewards = [], [], []
    done = False
    while not done:
        action, _ = expert.predict(obs, deterministic=True)
        action = np.asarray(action)
        if isinstance(env.action_space, gym.spaces.Discrete):
            action = action.reshape(()).astype(np.int64)
            step_action = int(action)
        else:
            action = action.reshape(env.action_space.shape)
            step_action = action
        observations.append(np.asarray(obs))
        actions.append(action)
        obs, reward, terminated, truncated, _ = env.step(step_action)
        rewards.append(float(reward))
        done = bool(terminated or truncated)
    return {
        "observations": np.stack(observations),
        "actions": np.stack(actions),
        "rewards": np.asarray(rewards, dtype=np.float64),
        "seed": int(seed),
    }


def _print_summary(demos: Demonstrations, title: str) -> None:
    returns = demos.episode_returns
    rows = [(i, int(demos.seeds[i]), float(returns[i]), int(demos.episode_lengths[i])) for i in range(demos.n_episodes)]
    mean, std = float(np.mean(returns)), float(np.std(returns))
    mean_len = float(np.mean(demos.episode_lengths))
    try:
        from rich.console import Console
        from rich.table import Table

        table = Table(title=title)
        for col in ("episode", "seed", "return", "length"):
            table.add_column(col, justify="right")
        for i, s, r, n in rows:
            table.add_row(str(i), str(s), f"{r:.2f}", str(n))
        table.add_section()
        table.add_row("mean", "", f"{mean:.2f} +/- {std:.2f}", f"{mean_len:.1f}")
        Console().print(table)
    except ImportError:  # pragma: no cover - rich is a dependency
        print(title)
        print(f"{'episode':>8} {'seed':>8} {'return':>12} {'length':>8}")
        for i, s, r, n in rows:
            print(f"{i:>8} {s:>8} {r:>12.2f} {n:>8}")
        print(f"{'mean':>8} {'':>8} {mean:>12.2f} {mean_len:>8.1f}  (std {std:.2f})")


def collect_demos(
    expert: Union[str, PathLike, Any],
    env_id: str,
    n_episodes: int,
    seed: int = 0,
    output: Optional[PathLike] = None,
    env_kwargs: Optional[Dict[str, Any]] = None,
    verbose: bool = True,
    force: bool = False,
) -> Demonstrations:
    """Record ``n_episodes`` deterministic expert episodes; episode ``i`` is reset with ``seed + i``.

    :param expert: a path to an SB3 zip (any algorithm), a folder holding ``model.zip``, a
        registered scripted-expert name, or an object with ``predict``.
    :param output: where to save the demonstrations (npz, written atomically), or None.
    :param force: replace an existing ``output`` and the demos record of a ``metadata.json`` beside
        it that is not the expert's own; without it both raise FileExistsError before any episode runs.
    """
    check_env_id(env_id)
    seed = check_seed(seed)
    if isinstance(n_episodes, bool) or int(n_episodes) < 1:
        raise ValueError(f"n_episodes must be >= 1, got {n_episodes}")
    check_seed(seed + int(n_episodes) - 1)
    if output is not None and not force:
        _check_demos_output(Path(output), env_id, expert)
    env = gym.make(env_id, **(env_kwargs or {}))
    try:
        policy, description = resolve_expert(expert, env)
        episodes = [run_episode(policy, env, seed + i) for i in range(int(n_episodes))]
    finally:
        env.close()
    demos = Demonstrations.from_episodes(episodes)
    if verbose:
        _print_summary(demos, f"{description} on {env_id}: {demos.n_episodes} episodes, {len(demos)} steps")
    if output is not None:
        demos.save(output)
        _record_demos_provenance(Path(output), description, env_id, demos, seed, env_kwargs)
        if verbose:
            print(f"saved {output} (provenance in {Path(output).parent / 'metadata.json'})")
    return demos


def _check_demos_output(output: Path, env_id: str, expert: Any) -> None:
    """FileExistsError when saving to ``output`` would replace a demo pool or another pool's record.

    metadata.json beside the pool gets a ``demos`` section. That is only safe to add where the file
    has none and belongs to this very expert (train-expert's record in the expert's own folder).
    """
    if output.exists():
        raise FileExistsError(
            f"{output} already exists ({_describe_pool(output)}); pass --force to replace it, or choose another -o"
        )
    meta_path = output.parent / "metadata.json"
    if not meta_path.is_file():
        return
    meta = _read_json_or_empty(meta_path)
    recorded = meta.get("demos")
    if isinstance(recorded, dict):
        raise FileExistsError(
            f"{meta_path} already records the demo pool {recorded.get('file')!r} of {recorded.get('expert')}; "
            f"saving {output.name} there would replace that record: pass --force, or choose another folder"
        )
    expert_folder = None
    if isinstance(expert, (str, Path)) and Path(expert).exists():
        expert_folder = Path(expert) if Path(expert).is_dir() else Path(expert).parent
    own = expert_folder is not None and expert_folder.resolve() == output.parent.resolve() and meta.get("env_id") == env_id
    if not own:
        raise FileExistsError(
            f"{meta_path} describes {meta.get('expert') or meta.get('algo') or 'something else'} on {meta.get('env_id')}, "
            f"not this expert; pass --force to add this pool's record to it, or choose another folder"
        )


def _describe_pool(path: Path) -> str:
    """``"a demo pool of N episodes"`` when the file reads as one, else ``"not a readable demo pool"``."""
    try:
        with np.load(path, allow_pickle=False) as data:
            return f"a demo pool of {len(data['episode_lengths'])} episodes"
    except Exception:  # any damage: the file is still there and still not ours to replace
        return "not a readable demo pool"


def _record_demos_provenance(
    output: Path, description: str, env_id: str, demos: Demonstrations, seed: int, env_kwargs: Optional[Dict[str, Any]]
) -> None:
    """Add a ``demos`` section to the ``metadata.json`` beside the demos file (creating the file for
    a scripted expert), so a shipped pool says which expert, command and seeds made it."""
    meta_path = output.parent / "metadata.json"
    meta = _read_json(meta_path) if meta_path.is_file() else {"env_id": env_id, "expert": description, "versions": _versions()}
    returns = demos.episode_returns
    meta["demos"] = {
        "file": output.name,
        "expert": description,
        "env_id": env_id,
        "env_kwargs": _jsonable(env_kwargs or {}),
        "episodes": demos.n_episodes,
        "steps": len(demos),
        "seeds": [int(seed), int(seed) + demos.n_episodes - 1],
        "mean_return": float(np.mean(returns)),
        "std_return": float(np.std(returns)),
        "mean_length": float(np.mean(demos.episode_lengths)),
        "command": command_line(),
    }
    if meta.get("total_timesteps") is not None:
        meta["demos"]["expert_total_timesteps"] = meta["total_timesteps"]
    _write_json(meta_path, meta)


def command_line(argv: Optional[Sequence[str]] = None) -> str:
    """The command line as typed (``sys.argv`` by default), shell-quoted."""
    return shlex.join(list(sys.argv if argv is None else argv))
