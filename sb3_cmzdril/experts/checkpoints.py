"""Resumable state of expert training: ``checkpoints/`` in the expert's folder.

``checkpoints/model_<N>_steps.zip`` and ``replay_buffer_<N>_steps.pkl`` hold the latest step,
``state.json`` points at them (written last, so it always names a complete pair) and records the
step count, evaluations and wall time; ``best.json`` holds the score of ``model.zip``.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

from sb3_cmzdril.errors import MissingFileError, UserError
from sb3_cmzdril.experts.loading import load_sb3_model
from sb3_cmzdril.io import atomic_path, read_json, write_json

logger = logging.getLogger(__name__)

STATE_FILE = "state.json"
BEST_FILE = "best.json"


def save_checkpoint(model, ckpt_dir: Path, state: dict[str, Any], t_start: float) -> None:
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
    write_json(ckpt_dir / STATE_FILE, {k: v for k, v in state.items() if not k.startswith("_")})
    keep = {model_file, buffer_file, STATE_FILE, BEST_FILE}
    for p in ckpt_dir.iterdir():
        older = p.name.startswith(("model_", "replay_buffer_")) and p.name not in keep
        if p.is_file() and older:  # an atomic write's temporary starts with ".": not ours to remove here
            try:
                p.unlink()
            except OSError:
                pass


def training_state(out: Path, ckpt_dir: Path, env_id: str, algo: str, seed: int,
                   t_start: float) -> tuple[dict[str, Any], bool, int]:
    """The training state to start from: ``(state, resuming, seed)``.

    A fresh state, or the one of ``checkpoints/state.json`` (which must be of this env and
    algorithm; its seed wins over ``seed``). The best score comes from ``best.json`` when that is
    fresher, and is dropped when ``model.zip`` is missing (nothing to protect from being replaced).
    """
    model_path = out / "model.zip"
    state: dict[str, Any] = {"env_id": env_id, "algo": algo, "seed": int(seed), "num_timesteps": 0,
                             "wall_time_s": 0.0, "resumes": 0, "evaluations": [], "best": None}
    state_path = ckpt_dir / STATE_FILE
    resume = state_path.is_file()
    if resume:
        saved = read_json(state_path)
        for key in ("env_id", "algo"):
            if saved.get(key) != state[key]:
                raise UserError(
                    f"{out} holds a checkpoint of {saved.get('algo')} on {saved.get('env_id')}, "
                    f"not {algo} on {env_id}; use another --output folder"
                )
        if int(saved.get("seed", seed)) != int(seed):
            logger.info("note: resuming a run started with seed %s (seed %s ignored)", saved.get("seed"), seed)
            seed = int(saved["seed"])
        state.update(saved)
        state["resumes"] = int(state.get("resumes", 0)) + 1
    best_path = ckpt_dir / BEST_FILE
    if best_path.is_file() and model_path.is_file():
        # best.json is written right after model.zip: it is the freshest record of the best score.
        best = read_json(best_path)
        if state.get("best") is None or float(best["mean_reward"]) >= float(state["best"]["mean_reward"]):
            state["best"] = best
    elif not model_path.is_file():
        state["best"] = None
    state["_segment_start"] = t_start
    return state, resume, seed


def load_checkpoint(algo_cls: type[BaseAlgorithm], ckpt_dir: Path, state: dict[str, Any], env, seed: int):
    """The model (with its replay buffer) of the checkpoint ``state`` names, attached to ``env``.

    :raises ValueError: a damaged model or buffer, or one whose step count disagrees with state.json.
    """
    ckpt_model = ckpt_dir / state["model_file"]
    model = load_sb3_model(algo_cls, ckpt_model, env=env)
    buffer_file = state.get("replay_buffer_file")
    if buffer_file and isinstance(model, OffPolicyAlgorithm) and model.replay_buffer is not None:
        buffer_path = ckpt_dir / buffer_file
        if not buffer_path.is_file():
            raise MissingFileError(f"checkpoint replay buffer missing: {buffer_path}")
        try:
            model.load_replay_buffer(buffer_path)
        except Exception as e:  # pickle errors come in many types
            raise UserError(f"checkpoint replay buffer {buffer_path} is corrupt: {e}") from e
    if int(model.num_timesteps) != int(state["num_timesteps"]):
        raise UserError(
            f"checkpoint {ckpt_model} has {model.num_timesteps} steps, state.json says {state['num_timesteps']}"
        )
    # Each segment draws fresh random numbers: the seed moves with the step count.
    model.set_random_seed(seed + int(model.num_timesteps))
    return model
