"""Loading experts: SB3 and sb3-contrib model zips, published RL Zoo agents, and ``--expert`` to a policy.

A model zip says itself which algorithm saved it: ``data`` (the zip's JSON) names the module of its
policy class, ``stable_baselines3.<algo>.policies`` or ``sb3_contrib.<algo>.policies``. Policies
shared by several algorithms (PPO's and A2C's ``ActorCriticPolicy``) are resolved by trying them in
turn; for inference any of them will do.

Published agents (the RL Zoo's ``rl-trained-agents`` repository, the same zips as the Hugging Face
hub's ``sb3`` organisation) load without a conversion step:

- zips saved by older SB3 pickle gym spaces and Python-3.7 schedules, which do not unpickle here
  (``No module named 'gym'``). As rl_zoo3's ``enjoy`` does, the schedules are replaced (an expert
  only predicts); spaces that do not unpickle are taken from the env, after checking the shape the
  zip records in plain JSON; other training state that does not unpickle is left out;
- the zoo's folder layout, ``<Env>.zip`` with ``<Env>/config.yml`` and ``<Env>/vecnormalize.pkl``:
  the expert sees observations normalised with the saved statistics while the demo pool records
  the env's raw ones (:class:`NormalizedObservationExpert`). The pickle's gym spaces are not needed
  and are read as placeholders;
- an agent trained on another version of the env (``Walker2d-v3`` used on ``Walker2d-v5``) is
  used with a warning: the shapes match, the dynamics may differ;
- ``hf://ORG/REPO[@REVISION]``: an agent on the Hugging Face Hub (``hf://sb3/sac-Walker2d-v3``),
  through ``huggingface_hub`` (the ``hub`` extra) and its cache, so ``HF_HUB_OFFLINE``,
  ``HF_HUB_CACHE`` and ``HF_HOME`` apply. The Hub keeps the zoo's files flat: ``<REPO>.zip`` beside
  ``config.yml``, ``args.yml`` and ``vec_normalize.pkl``.

A model saved by this package (:class:`~sb3_cmzdril.CMZDRIL`, a training run's ``model.zip``) is an
expert too: its policy is PPO's, and a run on normalised observations has ``vecnormalize.pkl`` beside it.

Model zips and pickles run code when loaded: SB3 unpickles the ``:serialized:`` entries of a zip's
``data``, and a pickle imports and calls whatever it names. Only the files the user named are loaded
(the zip or folder of ``--expert``, the statistics the zoo keeps beside it, the Hub repository's
files), and the first load in a process says so once (:func:`note_code_on_load`). Everything this
module learns of a zip before SB3 loads it comes from its plain JSON: a pickled entry is read
through without running any of it (:func:`_unresolvable`).
"""
from __future__ import annotations

import base64
import functools
import importlib
import importlib.machinery
import importlib.util
import io
import json
import logging
import os
import pickle
import re
import sys
import warnings
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np

from sb3_cmzdril.errors import MissingFileError, UserError
from sb3_cmzdril.experts.adapters import PaddedLayout, PaddedObservationExpert, check_padding_was_zeros, padded_layout
from sb3_cmzdril.experts.scripted import SCRIPTED_EXPERTS
from sb3_cmzdril.hyperparams import UniqueKeyLoader, load_yaml
from sb3_cmzdril.io import PathLike

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm

logger = logging.getLogger(__name__)

#: ``Name-vN``: an env id as the zoo names its files and folders.
_ENV_ID = re.compile(r"^(?P<name>.+)-v(?P<version>\d+)$")
#: ``hf://ORG/REPO`` or ``hf://ORG/REPO@REVISION``: a model repository on the Hugging Face Hub.
HUB_PREFIX = "hf://"
_HUB_SPEC = re.compile(r"^hf://(?P<repo>[A-Za-z0-9][\w.-]*/[A-Za-z0-9][\w.-]*)(?:@(?P<revision>[\w./-]+))?$")
#: What collect-demos needs of a zoo agent's Hub repository (not its video, logs or metrics).
_HUB_FILES = ("*.zip", "config.yml", "args.yml", "env_kwargs.yml", "vec_normalize.pkl")
#: Schedules are only used for training, and old ones are lambdas that do not unpickle in another
#: Python: an expert that only predicts gets constants (rl_zoo3's enjoy does the same).
_SCHEDULES = ("learning_rate", "lr_schedule", "clip_range", "clip_range_vf", "exploration_schedule")


def algorithm_classes() -> dict[str, type[BaseAlgorithm]]:
    """SB3 algorithms by the zoo's lowercase names."""
    from stable_baselines3 import A2C, DDPG, DQN, PPO, SAC, TD3

    return {"sac": SAC, "td3": TD3, "ddpg": DDPG, "ppo": PPO, "a2c": A2C, "dqn": DQN}


def contrib_classes(required_by: str | None = None) -> dict[str, type[BaseAlgorithm]]:
    """sb3-contrib's algorithms by the name of their subpackage (``tqc``, ``qrdqn``, ``ppo_mask``...).

    :param required_by: what needs them, for the error when sb3-contrib is not installed; None
        returns an empty table instead.
    """
    from sb3_cmzdril.extras import require_extra

    try:
        contrib = require_extra("sb3_contrib", "contrib", feature=required_by)
    except ImportError:
        if required_by is not None:
            raise
        return {}
    classes = (getattr(contrib, name) for name in getattr(contrib, "__all__", ()))
    return {cls.__module__.split(".")[1]: cls for cls in classes if isinstance(cls, type)}


def algo_class(algo: str) -> type[BaseAlgorithm]:
    """The SB3 (or sb3-contrib) class of ``algo`` (case-insensitive); a ValueError listing the known ones."""
    classes = {**contrib_classes(), **algorithm_classes()}
    if algo.lower() not in classes:
        raise UserError(f"unknown algorithm {algo!r}; available: {sorted(classes)}")
    return classes[algo.lower()]


@functools.lru_cache(maxsize=1)
def note_code_on_load() -> None:
    """Say once per process (INFO, which the command line prints) that the model zips and pickles
    about to be loaded can run code. Call it before loading one that the user brought."""
    logger.info(
        "note: model zips and pickles (SB3 models, vecnormalize.pkl, hf:// downloads) can run code when "
        "loaded; sb3-cmzdril loads only the files you name and the statistics the RL Zoo keeps beside them: "
        "use only experts you trust"
    )


def load_sb3_model(algo_cls: type[BaseAlgorithm], path: Path, env: Any = None) -> BaseAlgorithm:
    """Load an SB3 zip for inference/continuation with a clear error naming the path."""
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"model file not found: {path}")
    try:
        return algo_cls.load(path, env=env, device="cpu")
    except (zipfile.BadZipFile, EOFError, KeyError, ValueError, RuntimeError, OSError, AttributeError, TypeError) as e:
        raise UserError(f"cannot load {algo_cls.__name__} model from {path} (corrupt or not an SB3 zip?): {e}") from e


# -- what a zip and the folder around it say ---------------------------------------------------------
def read_model_data(path: Path) -> dict[str, Any]:
    """The JSON ``data`` of an SB3 model zip; a ValueError naming the file when it is not one."""
    try:
        with zipfile.ZipFile(path) as zf:
            data = json.loads(zf.read("data").decode("utf-8"))
    except zipfile.BadZipFile:
        raise UserError(f"expert file {path} is not a zip file (an SB3 model is a zip)") from None
    except KeyError:
        raise UserError(f"expert file {path} is a zip but not an SB3 model (it has no 'data' entry)") from None
    except (ValueError, UnicodeDecodeError, OSError) as e:
        raise UserError(f"expert file {path} is corrupt: its 'data' entry is not readable JSON ({e})") from None
    if not isinstance(data, dict) or "policy_class" not in data:
        raise UserError(f"expert file {path} is not an SB3 model: its 'data' names no policy class")
    return data


def _policy_module(data: dict[str, Any]) -> str:
    policy = data.get("policy_class")
    return str(policy.get("__module__", "")) if isinstance(policy, dict) else ""


def is_cmzdril_data(data: dict[str, Any]) -> bool:
    """Whether a zip's ``data`` is a :class:`~sb3_cmzdril.CMZDRIL` model's (PPO's keys plus the ensemble's).

    Its policy is PPO's ``ActorCriticPolicy``, but PPO.load refuses the zip's extra ``ensemble`` state.
    """
    return all(key in data for key in ("ensemble_size", "ensemble_hidden", "clip_range"))


def _algorithm_from_data(path: Path, data: dict[str, Any]) -> list[type[BaseAlgorithm]]:
    """The algorithm classes that may have saved the zip, most likely first."""
    if is_cmzdril_data(data):
        from sb3_cmzdril.cmzdril import CMZDRIL

        return [CMZDRIL]
    parts = _policy_module(data).split(".")
    if parts[0] == "sb3_contrib":
        contrib = contrib_classes(required_by=f"expert {path} (an sb3-contrib model)")
        if len(parts) >= 2 and parts[1] in contrib:
            return [contrib[parts[1]]]
        return list(contrib.values())
    sb3 = algorithm_classes()
    if len(parts) >= 2 and parts[0] == "stable_baselines3" and parts[1] in sb3:
        return [sb3[parts[1]]]
    # Shared policies (stable_baselines3.common.policies): the zip's keys tell PPO from A2C.
    order = ["ppo", "a2c"] if "clip_range" in data else ["a2c", "ppo"]
    return [sb3[name] for name in order] + [cls for name, cls in sb3.items() if name not in order]


class _Inert:
    """What a pickle read by :class:`_DryRunUnpickler` builds in place of anything it names: it takes
    any arguments, state, items and calls, and does nothing with them."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        pass

    def __call__(self, *args: Any, **kwargs: Any) -> _Inert:
        return _Inert()

    def __setstate__(self, state: Any) -> None:
        pass

    def __setitem__(self, key: Any, value: Any) -> None:
        pass

    def append(self, item: Any) -> None:
        pass

    def extend(self, items: Any) -> None:
        pass


class _DryRunUnpickler(pickle.Unpickler):
    """Reads a pickle to its end without running any of it: each global it names (a class, a
    function) is recorded and stands in as :class:`_Inert`, so nothing the pickle calls is called
    and no module it names is imported."""

    def __init__(self, payload: bytes) -> None:
        super().__init__(io.BytesIO(payload))
        self.names: list[tuple[str, str]] = []

    def find_class(self, module: str, name: str) -> Any:
        self.names.append((module, name))
        return _Inert

    def persistent_load(self, pid: Any) -> Any:
        return _Inert()


def _missing_module(module: str) -> Exception | None:
    """ModuleNotFoundError where ``module`` is plainly not here: its package is not installed, or a
    package on its path is imported and holds no such submodule (numpy 1's lacks numpy 2's
    ``numpy._core``). Looked up in the finders, never imported; a submodule below a package that is not
    imported yet cannot be told that way and counts as here."""
    parts = module.split(".")
    for depth in range(1, len(parts) + 1):
        prefix = ".".join(parts[:depth])
        if prefix in sys.modules:
            continue
        parent = sys.modules.get(".".join(parts[: depth - 1])) if depth > 1 else None
        if depth > 1 and parent is None:
            return None
        try:
            if parent is None:
                spec = importlib.util.find_spec(prefix)  # a top-level name: looked up, not imported
            else:
                path = getattr(parent, "__path__", None)
                spec = None if path is None else importlib.machinery.PathFinder.find_spec(prefix, path)
        except (ImportError, ValueError):
            spec = None
        if spec is None:
            return ModuleNotFoundError(f"No module named {prefix!r}", name=prefix)
        return None
    return None


def _missing_global(module: str, name: str) -> Exception | None:
    """The error unpickling would raise for the global ``module.name`` where it is plainly not here:
    its module is not (:func:`_missing_module`), or it is imported and lacks the name. Nothing is
    imported to tell."""
    missing = _missing_module(module)
    if missing is not None:
        return missing
    found: Any = sys.modules.get(module)
    for part in name.split(".") if found is not None else ():
        if not hasattr(found, part):
            return AttributeError(f"Can't get attribute {name!r} on module {module!r}")
        found = getattr(found, part)
    return None


def _unresolvable(item: dict[str, Any]) -> Exception | None:
    """Why one ``:serialized:`` entry of ``data`` would not unpickle here, or None where it may.

    Found without unpickling it, which would run whatever code the zip put there: the pickle is read
    through (:class:`_DryRunUnpickler`) and the globals it names are looked up. A pickle that does not
    read through (damaged, or of a form this reading refuses) counts as not unpickling.
    """
    try:
        # SB3 writes these with cloudpickle, whose output is a plain pickle.
        reader = _DryRunUnpickler(base64.b64decode(str(item[":serialized:"]).encode()))
        reader.load()
    except Exception as e:  # damaged base64 or pickle: SB3's load could not use it either
        return e
    for module, name in reader.names:
        error = _missing_global(module, name)
        if error is not None:
            return error
    return None


def inference_custom_objects(path: Path, data: dict[str, Any], env: gym.Env | None,
                             layout: PaddedLayout | None = None) -> dict[str, Any]:
    """``custom_objects`` for ``load``: constant schedules, the env's spaces where the zip's pickled
    ones do not unpickle here (the observation space ``layout`` pads them to, with one), and None for
    any other training state that does not."""
    custom: dict[str, Any] = {key: (lambda _: 0.0) for key in _SCHEDULES if key in data}
    if "learning_rate" in custom:
        custom["learning_rate"] = 0.0
    for key, item in data.items():
        if key in custom or not (isinstance(item, dict) and ":serialized:" in item):
            continue
        error = _unresolvable(item)
        if error is None:
            continue
        if key == "policy_class":
            raise UserError(
                f"expert file {path}: its policy class does not load here ({type(error).__name__}: {error})"
            )
        if key in ("observation_space", "action_space"):
            if env is None:
                raise UserError(
                    f"expert file {path} pickles its {key} with {type(error).__name__} ({error}); "
                    "load it with the env it acts in (env=...)"
                )
            space = getattr(env, key)
            if key == "observation_space" and layout is not None:
                space = layout.observation_space
            recorded = item.get("shape")
            if recorded is not None and space.shape is not None and tuple(recorded) != tuple(space.shape):
                raise UserError(
                    f"expert file {path} was trained with {key} of shape {tuple(recorded)}, "
                    f"the env has {tuple(space.shape)}"
                )
            custom[key] = space
        else:
            custom[key] = None  # training state (last observation, episode buffers): unused by predict
    return custom


@dataclass(frozen=True)
class ZooFiles:
    """A model zip and what the RL Zoo keeps beside it (``<Env>/config.yml``, ``vecnormalize.pkl``)."""

    model: Path
    stats: Path | None = None

    @property
    def trained_env_id(self) -> str | None:
        """The env id the agent was trained on: args.yml's ``env``, else the zoo's file names."""
        args = self.stats / "args.yml" if self.stats is not None else None
        if args is not None and args.is_file():
            env = read_zoo_yaml(args).get("env")
            if isinstance(env, str):
                return env
        for name in (self.model.stem, self.stats.name if self.stats is not None else ""):
            algo, _, rest = name.partition("-")
            if algo.lower() in algorithm_classes() or algo.lower() in contrib_classes():
                name = rest  # a Hub repository's zip: <algo>-<Env>.zip
            if _ENV_ID.match(name):
                return name
        return None

    @property
    def vecnormalize(self) -> Path | None:
        # The zoo's log folders name it vecnormalize.pkl, its Hub repositories vec_normalize.pkl.
        for name in ("vecnormalize.pkl", "vec_normalize.pkl"):
            path = self.stats / name if self.stats is not None else None
            if path is not None and path.is_file():
                return path
        return None

    @property
    def config(self) -> dict[str, Any]:
        path = self.stats / "config.yml" if self.stats is not None else None
        return read_zoo_yaml(path) if path is not None and path.is_file() else {}


def _stats_folder(model: Path) -> Path | None:
    """The zoo's ``<Env>/`` folder beside a model zip (``<Env>.zip`` or ``best_model.zip``), or the
    zip's own folder when ``config.yml`` lies beside it (the Hub's flat layout), if any."""
    own = model.parent / model.stem
    if (own / "config.yml").is_file() or (own / "vecnormalize.pkl").is_file():
        return own
    if (model.parent / "config.yml").is_file():
        return model.parent
    beside = [d for d in sorted(model.parent.iterdir()) if d.is_dir() and (d / "config.yml").is_file()]
    return beside[0] if len(beside) == 1 else None


def find_model_files(path: PathLike) -> ZooFiles:
    """The model zip a path means and the zoo files beside it.

    A folder: its ``model.zip`` (our experts), else the zoo's ``<Env>.zip`` (the folder holding
    ``<Env>/config.yml``), else its only zip.
    """
    path = Path(path)
    if path.is_file():
        return ZooFiles(path, _stats_folder(path))
    if not path.is_dir():
        raise MissingFileError(f"expert model not found: {path}")
    if (path / "model.zip").is_file():
        return ZooFiles(path / "model.zip", _stats_folder(path / "model.zip"))
    zips = sorted(path.glob("*.zip"))
    named = [z for z in zips if (path / z.stem).is_dir()]
    chosen = named if named else zips
    if len(chosen) != 1:
        found = ", ".join(z.name for z in zips) or "none"
        raise MissingFileError(
            f"expert folder {path} has no model.zip and no single zoo agent <Env>.zip (zips: {found}); "
            "pass the zip itself"
        )
    return ZooFiles(chosen[0], _stats_folder(chosen[0]))


def expert_files(expert: Any) -> list[Path]:
    """The files an expert given as a path is read from: its model zip and the zoo's files beside it
    (none for a scripted expert, an object, a Hub repository or a path that does not exist), so that
    an output can be refused where it would replace one of them."""
    if not isinstance(expert, (str, Path)) or str(expert).startswith(HUB_PREFIX) or not Path(expert).exists():
        return []
    path = Path(expert)
    try:
        files = find_model_files(path)
    except UserError:  # a folder without a model: loading it fails, one line, before anything is written
        return [path] if path.is_file() else []
    found = [path, files.model, files.model.parent / "vecnormalize.pkl"]
    if files.stats is not None:
        found += [files.stats / name for name in ("config.yml", "args.yml", "env_kwargs.yml", "vecnormalize.pkl",
                                                  "vec_normalize.pkl")]
    return [p for p in dict.fromkeys(found) if p.is_file()]


class _ZooYamlLoader(UniqueKeyLoader):
    """The hyperparameter files' loader (a SafeLoader refusing a key written twice) that also reads the
    zoo's ``!!python/object/apply:collections.OrderedDict`` files."""


def _ordered_dict(loader: Any, node: Any) -> dict[str, Any]:
    # The zoo dumps OrderedDict(list of [key, value] pairs): the node is a sequence holding that list.
    (pairs,) = loader.construct_sequence(node, deep=True)
    return {str(k): v for k, v in pairs}


_ZooYamlLoader.add_constructor("tag:yaml.org,2002:python/object/apply:collections.OrderedDict", _ordered_dict)


def read_zoo_yaml(path: Path) -> dict[str, Any]:
    """A zoo ``config.yml`` / ``args.yml`` as a dict; a ValueError naming the file otherwise."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, ValueError) as e:
        raise UserError(f"zoo file {path} is not readable: {e}") from None
    data = load_yaml(text, f"zoo file {path}", _ZooYamlLoader)
    return data if isinstance(data, dict) else {}


class _Placeholder:
    """Stands in for a class of a package that is not installed (old gym spaces in a pickle)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.args = args

    def __setstate__(self, state: Any) -> None:
        self.state = state


class _GymTolerantUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str) -> Any:
        if module.split(".")[0] == "gym":
            return _Placeholder
        return super().find_class(module, name)


def load_vecnormalize(path: Path) -> Any:
    """A zoo ``vecnormalize.pkl`` (an SB3 ``VecNormalize`` without its env), gym spaces or not."""
    from stable_baselines3.common.vec_env import VecNormalize

    note_code_on_load()
    try:
        with open(path, "rb") as f:
            stats = _GymTolerantUnpickler(f).load()
    except Exception as e:  # truncated, or pickled by something else: say which file
        raise UserError(f"zoo file {path} is not a readable VecNormalize pickle ({type(e).__name__}: {e})") from None
    if not isinstance(stats, VecNormalize) or not hasattr(stats, "obs_rms"):
        raise UserError(f"zoo file {path} does not hold VecNormalize statistics (it holds {type(stats).__name__})")
    stats.training = False  # the statistics are the expert's: never update them from our episodes
    return stats


class NormalizedObservationExpert:
    """A zoo expert trained under ``VecNormalize``: it acts on normalised observations, with the
    statistics saved beside it, while whoever calls :meth:`predict` passes (and records) raw ones."""

    def __init__(self, model: Any, stats: Any) -> None:
        self.model = model
        self.stats = stats
        self.observation_space = model.observation_space
        self.action_space = model.action_space

    def normalize(self, observation: np.ndarray) -> np.ndarray:
        """The observation as the expert saw it in training (clipped like VecNormalize)."""
        return np.asarray(self.stats.normalize_obs(np.asarray(observation, dtype=np.float64)))

    def predict(self, observation: np.ndarray, state: Any = None, episode_start: Any = None,
                deterministic: bool = False) -> tuple[np.ndarray, Any]:
        return self.model.predict(
            self.normalize(observation), state=state, episode_start=episode_start, deterministic=deterministic
        )


def env_name_version(env_id: str | None) -> tuple[str, int] | None:
    """``("Walker2d", 3)`` for ``Walker2d-v3`` (a ``module:`` prefix ignored), None for an id without a version."""
    match = _ENV_ID.match(str(env_id).rsplit(":", 1)[-1]) if env_id else None
    return (match["name"], int(match["version"])) if match else None


def _target_env_id(env: gym.Env | None) -> str | None:
    return getattr(getattr(env, "spec", None), "id", None)


def _check_env_version(files: ZooFiles, env: gym.Env | None) -> None:
    trained, target = files.trained_env_id, _target_env_id(env)
    a, b = env_name_version(trained), env_name_version(target)
    if a and b and a[0] == b[0] and a[1] != b[1]:
        warnings.warn(
            f"expert {files.model} was trained on {trained} and is used on {target}: the dynamics or rewards "
            "of the two versions may differ",
            UserWarning,
            stacklevel=3,
        )


def _check_zoo_config(files: ZooFiles) -> None:
    """Refuse zoo settings that change what the expert observes and that we do not reproduce."""
    config = files.config
    for key in ("env_wrapper", "frame_stack"):
        if config.get(key):
            raise UserError(
                f"expert {files.model}: its {files.stats / 'config.yml' if files.stats else 'config'} sets "
                f"{key}: {config[key]!r}, which changes the observations the expert expects; "
                "collect-demos does not apply it"
            )
    normalize = config.get("normalize")
    if normalize and files.vecnormalize is None:
        raise UserError(
            f"expert {files.model}: config.yml sets normalize: {normalize!r} but there is no "
            f"{files.stats}/vecnormalize.pkl with the statistics the expert needs"
        )


def _infer_algo(path: Path) -> str | None:
    """The algorithm named by a metadata.json beside the zip (our own experts), if any."""
    meta = path.parent / "metadata.json"
    if meta.is_file():
        try:
            algo = json.loads(meta.read_text(encoding="utf-8")).get("algo")
            if isinstance(algo, str) and algo.lower() in algorithm_classes():
                return algo.lower()
        except (OSError, ValueError):
            pass
    return None


def load_expert_model(path: PathLike, algo: str | None = None, env: gym.Env | None = None):
    """Load an expert from an SB3 or sb3-contrib model zip, a folder holding ``model.zip``, or a zoo
    agent (its zip or its folder); see the module docstring.

    :param algo: the algorithm's name; default: a ``metadata.json`` beside the zip, else the zip's
        own data.
    :param env: the env the expert will act in: its spaces replace pickled ones that do not load,
        and its id is compared with the one the agent was trained on.
    :return: the model, or a :class:`NormalizedObservationExpert` around it for a zoo agent trained
        with normalised observations, and that in a
        :class:`~sb3_cmzdril.experts.adapters.PaddedObservationExpert` for an agent whose env's newer
        version lays its observation out differently (the zoo's Ant-v3 agents on Ant-v5).
    """
    files = find_model_files(path)
    model_path = files.model
    data = read_model_data(model_path)
    note_code_on_load()
    _check_zoo_config(files)
    _check_env_version(files, env)
    name = algo or _infer_algo(model_path)
    candidates = [algo_class(name)] if name else _algorithm_from_data(model_path, data)
    layout = _padded_layout(files, data, env)
    custom = inference_custom_objects(model_path, data, env, layout)
    errors = []
    model = None
    for cls in candidates:
        try:
            model = cls.load(model_path, device="cpu", custom_objects=custom)
            break
        except Exception as e:  # wrong algorithm or corrupt file: try the next one
            errors.append(f"{cls.__name__}: {type(e).__name__}: {e}")
    if model is None:
        raise UserError(f"cannot load expert model {model_path}: " + "; ".join(errors))
    if env is not None:
        _check_fits_env(model, env, model_path, layout)
    vecnormalize = files.vecnormalize
    if getattr(model, "vecnormalize_obs", False):
        vecnormalize = _run_statistics(model_path)
    stats = load_vecnormalize(vecnormalize) if vecnormalize is not None else None
    expert = NormalizedObservationExpert(model, stats) if stats is not None and getattr(stats, "norm_obs", True) \
        else model
    if layout is None:
        return expert
    check_padding_was_zeros(layout, stats if expert is not model else None, model_path)
    return PaddedObservationExpert(expert, layout)


def _padded_layout(files: ZooFiles, data: dict[str, Any], env: gym.Env | None) -> PaddedLayout | None:
    """The known layout (:mod:`~sb3_cmzdril.experts.adapters`) that lets this agent act in ``env``, if its
    observations and the env's differ in one."""
    if env is None:
        return None
    recorded = data.get("observation_space")
    # SB3 1.x wrote the space's shape as "shape" in the zip's JSON, SB3 2.x as "_shape".
    shape = (recorded.get("shape") or recorded.get("_shape")) if isinstance(recorded, dict) else None
    return padded_layout(env_name_version(files.trained_env_id), env_name_version(_target_env_id(env)), shape,
                         getattr(env.observation_space, "shape", None))


def _run_statistics(model_path: Path) -> Path:
    """The ``vecnormalize.pkl`` a training run saved beside its model, for a CMZDRIL model trained on
    normalised observations: without it every action would be computed from the wrong inputs."""
    path = model_path.parent / "vecnormalize.pkl"
    if not path.is_file():
        raise UserError(
            f"expert {model_path} was trained on VecNormalize'd observations and {path}, the statistics "
            "saved beside it, is missing"
        )
    return path


def _check_fits_env(model: Any, env: gym.Env, path: Path, layout: PaddedLayout | None = None) -> None:
    for key in ("observation_space", "action_space"):
        ours, theirs = getattr(env, key), getattr(model, key)
        if key == "observation_space" and layout is not None:
            ours = layout.observation_space
        if type(ours) is not type(theirs) or ours.shape != theirs.shape:
            raise UserError(f"expert {path} has {key} {theirs}, the env has {ours}")


def hub_model_files(spec: str) -> tuple[Path, str]:
    """The local copy of a Hugging Face Hub agent ``hf://ORG/REPO[@REVISION]``: its model zip (in the
    Hub cache, fetched there if missing) and ``hf://ORG/REPO@COMMIT``, which names the exact files.

    :raises UserError: ``spec`` is not of that form, or the repository holds no single model zip.
    :raises MissingFileError: the files are neither cached nor fetchable (offline, no such repository).
    """
    match = _HUB_SPEC.match(spec)
    if match is None:
        raise UserError(
            f"expert {spec!r} is not a Hugging Face Hub model: write hf://ORG/REPO or hf://ORG/REPO@REVISION"
        )
    from sb3_cmzdril.extras import require_extra

    hub = require_extra("huggingface_hub", "hub", feature=f"expert {spec}")
    repo, revision = match["repo"], match["revision"]
    # Offline, the cache is all there is: some huggingface_hub releases (1.x) still list the
    # repository online unless told to stay local, and fail on a cached commit.
    offline = bool(getattr(importlib.import_module("huggingface_hub.constants"), "HF_HUB_OFFLINE", False))
    try:
        folder = Path(hub.snapshot_download(repo, revision=revision, allow_patterns=list(_HUB_FILES),
                                            local_files_only=offline))
    except (OSError, ValueError) as e:  # the Hub's errors: no such repo or revision, offline and not cached
        reason = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise MissingFileError(
            f"expert {spec}: cannot get it from the Hugging Face Hub or its cache ({reason})"
        ) from None
    name = repo.split("/", 1)[1]
    zips = [folder / f"{name}.zip"] if (folder / f"{name}.zip").is_file() else sorted(folder.glob("*.zip"))
    if len(zips) != 1:
        raise UserError(
            f"expert {spec}: the repository holds {len(zips) or 'no'} model zips "
            f"({', '.join(z.name for z in zips) or f'expected {name}.zip'}); an SB3 agent's holds <REPO>.zip"
        )
    # The snapshot folder of the Hub cache is named by the commit it holds.
    return zips[0], f"{HUB_PREFIX}{repo}@{folder.name}"


def resolve_expert(expert: str | PathLike | Any, env: gym.Env) -> tuple[Any, str]:
    """An object with ``predict`` and a description, from a path, a folder, a Hugging Face Hub
    repository (``hf://ORG/REPO``), a scripted expert's name or the env id of a shipped expert
    (``HalfCheetah-v5``)."""
    if hasattr(expert, "predict") and not isinstance(expert, (str, Path)):
        return expert, type(expert).__name__
    name = str(expert)
    if isinstance(expert, str) and name.startswith(HUB_PREFIX):
        model_path, description = hub_model_files(name)
        return load_expert_model(model_path, env=env), description
    if isinstance(expert, str) and name in SCRIPTED_EXPERTS:
        return SCRIPTED_EXPERTS[name](env), f"scripted:{name}"
    path = Path(name)
    if path.exists():
        return load_expert_model(path, env=env), str(path)
    looks_like_path = (isinstance(expert, Path) or os.sep in name or name.endswith((".zip", ".pkl"))
                       or name.startswith("."))
    if looks_like_path:
        raise MissingFileError(f"expert model not found: {path}")
    from sb3_cmzdril.shipped import shipped_envs, shipped_expert

    if name in shipped_envs():
        return load_expert_model(shipped_expert(name), env=env), f"shipped:{name}"
    raise UserError(
        f"unknown expert {name!r}: no such file or folder, no scripted expert and no shipped expert of that name; "
        f"scripted experts: {sorted(SCRIPTED_EXPERTS) or 'none registered'}; "
        f"shipped experts: {', '.join(shipped_envs()) or 'none'}"
    )
