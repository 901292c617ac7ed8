"""Loading experts: SB3 model zips of any algorithm, and resolving ``--expert`` to a policy."""
from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path
from typing import Any

import gymnasium as gym

from sb3_cmzdril.experts.scripted import SCRIPTED_EXPERTS
from sb3_cmzdril.io import PathLike


def algorithm_classes() -> dict[str, type]:
    """SB3 algorithms by the zoo's lowercase names."""
    from stable_baselines3 import A2C, DDPG, DQN, PPO, SAC, TD3

    return {"sac": SAC, "td3": TD3, "ddpg": DDPG, "ppo": PPO, "a2c": A2C, "dqn": DQN}


def algo_class(algo: str) -> type:
    """The SB3 class of ``algo`` (case-insensitive); a ValueError listing the known ones."""
    classes = algorithm_classes()
    if algo.lower() not in classes:
        raise ValueError(f"unknown algorithm {algo!r}; available: {sorted(classes)}")
    return classes[algo.lower()]


def load_sb3_model(algo_cls: type, path: Path, env=None):
    """Load an SB3 zip for inference/continuation with a clear error naming the path."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"model file not found: {path}")
    try:
        return algo_cls.load(path, env=env, device="cpu")
    except (zipfile.BadZipFile, EOFError, KeyError, ValueError, RuntimeError, OSError, AttributeError, TypeError) as e:
        raise ValueError(f"cannot load {algo_cls.__name__} model from {path} (corrupt or not an SB3 zip?): {e}") from e


def _infer_algo(path: Path) -> str | None:
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


def load_expert_model(path: PathLike, algo: str | None = None):
    """Load an SB3 model zip of any algorithm (``algo`` given, from metadata.json, or tried in turn)."""
    path = Path(path)
    if path.is_dir():
        if not (path / "model.zip").is_file():
            raise FileNotFoundError(f"expert folder {path} has no model.zip")
        path = path / "model.zip"
    if not path.is_file():
        raise FileNotFoundError(f"expert model not found: {path}")
    algo = algo or _infer_algo(path)
    # Inference only: schedules may be lambdas SB3 cannot unpickle in another Python; they are unused.
    custom = {"learning_rate": 0.0, "lr_schedule": lambda _: 0.0, "clip_range": lambda _: 0.0}
    candidates = [algo] if algo else list(algorithm_classes())
    errors = []
    for name in candidates:
        cls = algo_class(name)
        try:
            return cls.load(path, device="cpu", custom_objects=custom)
        except Exception as e:  # wrong algorithm or corrupt file: try the next one
            errors.append(f"{cls.__name__}: {type(e).__name__}: {e}")
    raise ValueError(f"cannot load expert model {path} (corrupt or not an SB3 zip?): " + "; ".join(errors))


def resolve_expert(expert: str | PathLike | Any, env: gym.Env) -> tuple[Any, str]:
    """An object with ``predict`` and a description, from a path, a folder or a scripted name."""
    if hasattr(expert, "predict") and not isinstance(expert, (str, Path)):
        return expert, type(expert).__name__
    name = str(expert)
    if isinstance(expert, str) and name in SCRIPTED_EXPERTS:
        return SCRIPTED_EXPERTS[name](env), f"scripted:{name}"
    path = Path(name)
    if path.exists():
        return load_expert_model(path), str(path)
    looks_like_path = (isinstance(expert, Path) or os.sep in name or name.endswith((".zip", ".pkl"))
                       or name.startswith("."))
    if looks_like_path:
        raise FileNotFoundError(f"expert model not found: {path}")
    raise ValueError(
        f"unknown expert {name!r}: no such file or folder, and no scripted expert of that name; "
        f"scripted experts: {sorted(SCRIPTED_EXPERTS) or 'none registered'}"
    )
