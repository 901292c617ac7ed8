"""Training SB3 experts with zoo hyperparameters (``train_expert``, the ``train-expert`` command).

Layout (``train_expert(..., output_dir=DIR)``)::

    DIR/model.zip            best model by periodic deterministic evaluation (written atomically)
    DIR/metadata.json        how it was made: command, versions, steps, seed, hyperparameters, eval
    DIR/checkpoints/         resumable state: model_<N>_steps.zip, replay_buffer_<N>_steps.pkl,
                             state.json (points at the latest pair; written last), best.json

Running again with the same ``DIR`` resumes from ``checkpoints/state.json`` (model, replay buffer,
step count, the best evaluation score so far and the wall time spent) and trains until the requested
*total* number of steps. Progress notes go to this module's logger (the CLI prints them).
"""
from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import numpy as np

from sb3_cmzdril.errors import OutputExistsError, UserError
from sb3_cmzdril.experts.callbacks import ExpertEvalCallback, ProgressCallback, ResumableCheckpointCallback
from sb3_cmzdril.experts.checkpoints import BEST_FILE, STATE_FILE, load_checkpoint, save_checkpoint, training_state
from sb3_cmzdril.experts.envs import check_env_id, check_seed, env_name, make_vec_env
from sb3_cmzdril.experts.loading import algo_class, load_sb3_model
from sb3_cmzdril.io import (
    LOCK_FILE,
    OutputLock,
    PathLike,
    lock_output,
    portable_path,
    read_json,
    read_json_or_empty,
    remove_stale_temporaries,
    unlock_output,
    versions,
    write_json,
)

logger = logging.getLogger(__name__)


def check_threads(n_threads: int | None) -> int | None:
    """``torch.set_num_threads`` value: None (torch's default) or >= 1 (0 would make torch raise)."""
    if n_threads is not None and (isinstance(n_threads, bool) or int(n_threads) < 1):
        raise UserError(f"threads must be >= 1, got {n_threads!r}")
    return n_threads


def train_expert(
    env_id: str,
    algo: str = "sac",
    timesteps: int | None = None,
    seed: int = 0,
    hyperparams_path: PathLike | None = None,
    output_dir: PathLike | None = None,
    eval_freq: int = 10_000,
    n_eval_episodes: int = 5,
    checkpoint_freq: int = 20_000,
    progress_bar: bool = True,
    final_eval_episodes: int = 10,
    n_threads: int | None = 1,
    command: str | None = None,
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
    algo_cls = algo_class(algo)
    hp_path = Path(hyperparams_path) if hyperparams_path is not None else default_hyperparams_path(algo)
    # Everything that can be checked is checked before the output folder exists.
    check_env_id(env_id)
    seed = check_seed(seed)
    hp = load_hyperparams(hp_path, env_id)
    hp.check_supported(what="train-expert")
    check_constructor_kwargs(hp, [algo_cls])
    if timesteps is None and hp.n_timesteps is None:
        raise UserError(f"no number of timesteps: pass timesteps= / --timesteps or set n_timesteps in {hp_path}")
    # Whichever gave the number is named: "no number" for a number given would send the user looking elsewhere.
    given, source = (timesteps, "timesteps (--timesteps)") if timesteps is not None else (
        hp.n_timesteps, f"n_timesteps in {hp_path}")
    if isinstance(given, bool) or not isinstance(given, (int, float)) or not float(given).is_integer() or given < 1:
        raise UserError(f"{source} must be a positive integer, got {given!r}")
    total = int(given)
    if final_eval_episodes < 1 or n_eval_episodes < 1:
        raise UserError("n_eval_episodes and final_eval_episodes must be >= 1")
    if eval_freq < 0 or checkpoint_freq < 0:
        raise UserError(f"eval_freq and checkpoint_freq must be >= 0, got {eval_freq} and {checkpoint_freq}")
    out = Path(output_dir) if output_dir is not None else Path("experts") / env_name(env_id)
    model_path = out / "model.zip"
    finished_steps = _check_expert_folder(out, env_id, algo, total, force)
    if finished_steps is not None:
        logger.info("%s holds a finished %s expert on %s (%s >= %s steps, metadata.json); nothing to do",
                    out, algo, env_id, finished_steps, total)
        return model_path
    if n_threads is not None:
        torch.set_num_threads(int(n_threads))
    ckpt_dir = out / "checkpoints"
    created = [d for d in (*reversed(out.parents), out, ckpt_dir) if not d.exists()]
    ckpt_dir.mkdir(parents=True, exist_ok=True)
    lock: OutputLock | None = lock_output(
        ckpt_dir, f"another train-expert is already running in {out} (lock {ckpt_dir / LOCK_FILE})"
    )
    try:
        return _train_expert_locked(
            env_id, algo, algo_cls, hp, hp_path, total, seed, out, ckpt_dir, model_path, eval_freq, n_eval_episodes,
            checkpoint_freq, progress_bar, final_eval_episodes, command, verbose, _callback, t_start,
        )
    except BaseException:
        # A first attempt that failed before writing anything leaves no empty folders behind.
        unlock_output(ckpt_dir, lock)
        lock = None
        if ckpt_dir in created:
            # The lock file stays after a release; in a folder this attempt made and now removes,
            # it goes too (no other process had a reason to open it: the folder is new).
            (ckpt_dir / LOCK_FILE).unlink(missing_ok=True)
        for folder in reversed(created):
            try:
                folder.rmdir()
            except OSError:  # not empty: it holds a checkpoint or a model worth keeping
                break
        raise
    finally:
        unlock_output(ckpt_dir, lock)


def _check_expert_folder(out: Path, env_id: str, algo: str, total: int, force: bool) -> int | None:
    """Refuse to train over an expert that resuming would not continue; returns its step count
    when it is a finished expert of this env and algorithm with at least ``total`` steps.

    A folder is resumed only from its checkpoints (``checkpoints/state.json``). A model.zip or
    metadata.json without them (a shipped expert, another tool's model) would be silently replaced by
    the first evaluation of a fresh training, so that needs ``force``, as does training a finished
    expert further.
    """
    model_path, meta_path = out / "model.zip", out / "metadata.json"
    resumable = (out / "checkpoints" / STATE_FILE).is_file()
    meta = read_json(meta_path) if meta_path.is_file() else {}
    steps = meta.get("total_timesteps")
    if model_path.is_file() and steps is not None:
        if (meta.get("env_id"), meta.get("algo")) != (env_id, algo) and not force:
            raise OutputExistsError(
                f"{out} holds a {meta.get('algo')} expert on {meta.get('env_id')}, not {algo} on {env_id}; "
                "use another --output folder (or --force to train over it)"
            )
        if (meta.get("env_id"), meta.get("algo")) == (env_id, algo) and int(steps) >= total:
            return int(steps)
        if not force:
            how = ("continue it from its checkpoint" if resumable
                   else "train a new expert over it (it has no checkpoint)")
            raise OutputExistsError(
                f"{out} holds a finished expert trained for {steps} steps, fewer than the {total} asked; pass --force "
                f"to {how}, or use another --output folder"
            )
        return None
    if not resumable and not force and (model_path.is_file() or meta_path.is_file()):
        found = " and ".join(p.name for p in (model_path, meta_path) if p.is_file())
        raise OutputExistsError(
            f"{out} already holds {found} but no checkpoint to resume from; pass --force to train a new expert "
            "there (replacing them), or use another --output folder"
        )
    return None


def _train_expert_locked(env_id, algo, algo_cls, hp, hp_path, total, seed, out, ckpt_dir, model_path, eval_freq,
                         n_eval_episodes, checkpoint_freq, progress_bar, final_eval_episodes, command, verbose,
                         _callback, t_start) -> Path:
    from stable_baselines3.common.evaluation import evaluate_policy

    remove_stale_temporaries(out, ckpt_dir)
    state, resume, seed = training_state(out, ckpt_dir, env_id, algo, seed, t_start)

    env = make_vec_env(env_id, hp.n_envs, seed + int(state["num_timesteps"]), hp.env_kwargs)
    eval_env = make_vec_env(env_id, 1, seed + 10_000 + int(state["num_timesteps"]), hp.env_kwargs)
    try:
        if resume:
            model = load_checkpoint(algo_cls, ckpt_dir, state, env, seed)
            logger.info("resuming %s on %s from %s at %s steps%s", algo, env_id, ckpt_dir / state["model_file"],
                        model.num_timesteps,
                        f" (best eval so far {state['best']['mean_reward']:.1f})" if state.get("best") else "")
        else:
            model = algo_cls(hp.policy or "MlpPolicy", env, seed=seed, verbose=verbose, device="cpu",
                             **hp.model_kwargs())

        eval_cb = ExpertEvalCallback(eval_env, eval_freq, n_eval_episodes, model_path, ckpt_dir / BEST_FILE, state)
        ckpt_cb = ResumableCheckpointCallback(checkpoint_freq, ckpt_dir, state, t_start)
        callbacks = [ProgressCallback(total, show=progress_bar), eval_cb, ckpt_cb]
        if _callback is not None:
            callbacks.append(_callback)
        remaining = total - int(model.num_timesteps)
        if remaining > 0:
            logger.info("training %s on %s: %s -> %s steps, output %s", algo, env_id, model.num_timesteps, total, out)
            model.learn(remaining, callback=callbacks, reset_num_timesteps=not resume, progress_bar=False)
        else:
            logger.info("%s already holds %s >= %s steps; not training further", out, model.num_timesteps, total)
        eval_cb.model = model
        if state.get("last_eval_step") != int(model.num_timesteps) or not model_path.is_file():
            eval_cb.evaluate()  # the final model competes for model.zip too
        save_checkpoint(model, ckpt_dir, state, t_start)  # also records the final evaluation and wall time

        # Final evaluation of the shipped model on fresh, seeded episodes.
        best_model = load_sb3_model(algo_cls, model_path)
        final_env = make_vec_env(env_id, 1, seed + 20_000, hp.env_kwargs)
        try:
            returns, lengths = evaluate_policy(best_model, final_env, n_eval_episodes=final_eval_episodes,
                                               deterministic=True, return_episode_rewards=True, warn=False)
        finally:
            final_env.close()
        wall = float(state.get("wall_time_s", 0.0)) + (time.time() - state.get("_segment_start", t_start))
        metadata = _expert_metadata(env_id, algo, seed, total, model, state, returns, lengths, final_eval_episodes,
                                    eval_freq, n_eval_episodes, hp, hp_path, command, wall)
        previous = read_json_or_empty(out / "metadata.json")
        if isinstance(previous.get("demos"), dict):
            # A pool recorded beside the expert before each pool had its own NAME.json keeps its
            # provenance here; it names the expert's step count when it was recorded, which a
            # continued (--force) training has since moved past.
            metadata["demos"] = {"expert_total_timesteps": previous.get("total_timesteps"), **previous["demos"]}
        write_json(out / "metadata.json", metadata)
        logger.info(
            "done: %s (from step %s), final eval over %s episodes %.1f +/- %.1f; wall time %.1f min",
            model_path, metadata["model_timesteps"], final_eval_episodes, metadata["eval"]["mean_reward"],
            metadata["eval"]["std_reward"], wall / 60,
        )
        return model_path
    finally:
        env.close()
        eval_env.close()


def _expert_metadata(env_id, algo, seed, total, model, state, returns, lengths, final_eval_episodes, eval_freq,
                     n_eval_episodes, hp, hp_path, command, wall) -> dict[str, Any]:
    """metadata.json of a finished expert: what was trained, how, how well, and with what."""
    import torch

    return {
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
        "hyperparams": {"file": portable_path(hp_path), "key": hp.key, "values": hp.raw},
        "versions": versions(),
        "torch_threads": torch.get_num_threads(),
        "command": command,
        "wall_time_s": round(wall, 1),
        "resumes": int(state.get("resumes", 0)),
        "finished_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
