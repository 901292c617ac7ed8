"""What a run is and whether it can start: its specification, the demo split and the checks.

:func:`plan_run` resolves a run's defaults (demo pool, number of demos and steps, output folder,
hyperparameters) into a :class:`RunSpec` and checks everything that can fail before training starts,
down to building the run's env and model once (:func:`make_training_env`, which the run itself uses
too). :func:`split_episodes` is the demo split every method of a trial shares; :func:`train_command`
is the ``sb3-cmzdril train`` line of a spec. A run executes in :mod:`sb3_cmzdril.experiments.runs`
and writes the files of :mod:`sb3_cmzdril.experiments.run_folder`.
"""
from __future__ import annotations

import dataclasses
import functools
import shlex
from pathlib import Path
from typing import Any

import numpy as np

from sb3_cmzdril.experts import check_env_id, check_seed, env_name, load_demonstrations
from sb3_cmzdril.io import PathLike

#: Methods of the paper's comparison: plain BC and the four reward modes of CMZDRIL.
METHODS: tuple[str, ...] = ("bc", "zero", "env", "dril", "cmz")
#: Hyperparameter file of the repository used when none is given (hyperparams/cmzdril.yml).
HYPERPARAMS_NAME = "cmzdril"
#: Keys of cmzdril.yml that configure the experiment rather than the model (not constructor kwargs).
EXPERIMENT_KEYS: tuple[str, ...] = ("n_demos",)
#: Training episodes per trial when neither --n-demos nor the YAML says: the paper's MuJoCo setting.
FALLBACK_N_DEMOS = 1
DEFAULT_EVAL_EPISODES = 5  # paper, Sec. IV-A.3: "We used 5 evaluation episodes for each experiment"
DEFAULT_CHECKPOINT_EVERY = 10  # PPO updates between checkpoints (~5% of an update's time each)


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """A fully resolved run (absolute paths, so it can be shipped to another process or Ray worker).

    Build it with :func:`plan_run`, which validates everything that can be checked before training.
    ``seed`` is the trial index: it seeds the networks, the training env and the demo split.
    """

    env_id: str
    method: str
    demos: str
    seed: int
    n_demos: int
    n_eval_episodes: int
    timesteps: int
    output_dir: str
    hyperparams: str
    eval_every: int = 1
    checkpoint_every: int = DEFAULT_CHECKPOINT_EVERY
    command: str | None = None

    @property
    def label(self) -> str:
        """``EnvName/method/trial<seed>``: how progress displays and reports name the run."""
        return f"{env_name(self.env_id)}/{self.method}/trial{self.seed}"


def split_episodes(n_pool: int, n_train: int, n_eval: int, seed: int) -> tuple[list[int], list[int]]:
    """Disjoint training and evaluation episode indices of a demo pool for trial ``seed``.

    ``numpy.random.default_rng(seed).permutation(n_pool)``: the first ``n_train`` train, the next
    ``n_eval`` evaluate. Every method of a trial calls this with the same arguments, hence the same data.
    """
    if n_train < 1 or n_eval < 1:
        raise ValueError(f"need at least one training and one evaluation episode, got {n_train} and {n_eval}")
    if n_train + n_eval > n_pool:
        raise ValueError(
            f"the demo pool has {n_pool} episodes but {n_train} training + {n_eval} evaluation episodes are "
            "needed; record more with `sb3-cmzdril collect-demos --episodes N` or lower --n-demos/--eval-episodes"
        )
    order = np.random.default_rng(int(seed)).permutation(int(n_pool))
    return [int(i) for i in order[:n_train]], [int(i) for i in order[n_train:n_train + n_eval]]


def check_method(method: str) -> str:
    """The method name, or a ValueError listing the known ones."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    return method


def default_demos_path(env_id: str, demos_dir: PathLike = "experts") -> Path:
    """``<demos_dir>/<EnvName>/demos.npz`` (where collect-demos puts an env's demo pool); for the
    default folder, the shipped pool when the working directory has none."""
    from sb3_cmzdril.shipped import local_or_shipped_demos

    return local_or_shipped_demos(env_id, demos_dir)


def default_output_dir(env_id: str, method: str, seed: int, runs_dir: PathLike = "runs") -> Path:
    """``<runs_dir>/<EnvName>/<method>/trial<seed>``: the benchmark's layout."""
    return Path(runs_dir) / env_name(env_id) / method / f"trial{int(seed)}"


def load_run_hyperparams(path: PathLike, env_id: str):
    """The env's entry of a cmzdril.yml as ``(Hyperparams, experiment settings)``.

    Experiment keys (:data:`EXPERIMENT_KEYS`) are removed from the constructor kwargs; keys this
    code does not implement (env/vec-env wrappers, callbacks, frame stacking) are refused.
    """
    from sb3_cmzdril.hyperparams import load_hyperparams

    hp = load_hyperparams(path, env_id)
    hp.check_supported(
        unsupported=("env_wrapper", "vec_env_wrapper", "callback", "frame_stack"), what="sb3-cmzdril train"
    )
    settings = {k: hp.algo_kwargs.pop(k) for k in EXPERIMENT_KEYS if k in hp.algo_kwargs}
    unknown = sorted(set(hp.algo_kwargs) - _constructor_kwargs())
    if unknown:
        # Caught here, a typo fails the whole grid at once instead of every run in its worker.
        raise ValueError(f"hyperparameters {hp.key!r} in {path}: {unknown} are not CMZDRIL/PPO arguments")
    return hp, settings


@functools.lru_cache(maxsize=1)
def _constructor_kwargs() -> frozenset:
    import inspect

    from stable_baselines3 import PPO

    from sb3_cmzdril.algorithm import CMZDRIL

    names = set(inspect.signature(CMZDRIL.__init__).parameters) | set(inspect.signature(PPO.__init__).parameters)
    return frozenset(names - {"self", "policy", "env", "_init_setup_model", "ppo_kwargs"})


@functools.lru_cache(maxsize=4)
def load_pool(path: str, mtime_ns: int):
    """A demo pool, read once per version of the file: a grid plans and checks many runs on one pool."""
    return load_demonstrations(path)


def _pool_size(path: str, mtime_ns: int) -> int:
    return load_pool(path, mtime_ns).n_episodes


def file_mtime_ns(path: PathLike) -> int:
    """The file's modification time: the version key of the cached pool and of the preflight checks."""
    return Path(path).stat().st_mtime_ns


def missing_pool_error(env_id: str, path: PathLike, alternative: str) -> FileNotFoundError:
    """The error for a demo pool that is not there: how to record one, or ``alternative`` (the option
    of the calling command that names an existing one)."""
    return FileNotFoundError(
        f"demo pool not found: {path} (record one with `sb3-cmzdril collect-demos --env {env_id} --expert ... "
        f"--episodes N -o {path}`, or {alternative})"
    )


def _positive(name: str, value: int) -> int:
    if isinstance(value, bool) or int(value) != value or int(value) < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def plan_run(
    env_id: str,
    method: str,
    seed: int,
    *,
    demos: PathLike | None = None,
    n_demos: int | None = None,
    n_eval_episodes: int = DEFAULT_EVAL_EPISODES,
    timesteps: int | None = None,
    output_dir: PathLike | None = None,
    hyperparams: PathLike | None = None,
    eval_every: int = 1,
    checkpoint_every: int = DEFAULT_CHECKPOINT_EVERY,
    command: str | None = None,
) -> RunSpec:
    """Resolve defaults and check everything that can fail before training starts.

    :param demos: the env's demo pool (default ``experts/<EnvName>/demos.npz``).
    :param n_demos: training episodes (default: ``n_demos`` of the YAML entry, else 1).
    :param timesteps: total PPO steps (default: ``n_timesteps`` of the YAML entry); unused by ``bc``.
    :param output_dir: default ``runs/<EnvName>/<method>/trial<seed>``.
    :param hyperparams: zoo-format YAML (default: the repository's ``hyperparams/cmzdril.yml``).
    :raises ValueError: unknown method or env, bad counts, a pool too small for the split.
    :raises FileNotFoundError: no demo pool or hyperparameter file.
    """
    from stable_baselines3 import PPO

    from sb3_cmzdril.algorithm import CMZDRIL
    from sb3_cmzdril.hyperparams import check_constructor_kwargs, default_hyperparams_path

    check_method(method)
    check_env_id(env_id)
    seed = check_seed(seed)
    hp_path = Path(hyperparams) if hyperparams is not None else default_hyperparams_path(HYPERPARAMS_NAME)
    hp, settings = load_run_hyperparams(hp_path, env_id)
    check_constructor_kwargs(hp, [CMZDRIL, PPO])
    n_demos = _positive("n_demos", n_demos if n_demos is not None else settings.get("n_demos", FALLBACK_N_DEMOS))
    n_eval_episodes = _positive("n_eval_episodes", n_eval_episodes)
    if method == "bc":
        timesteps = 0  # BC is the pretrained policy: no PPO steps
    else:
        timesteps = timesteps if timesteps is not None else hp.n_timesteps
        if timesteps is None:
            raise ValueError(f"no number of timesteps: pass --timesteps or set n_timesteps in {hp_path}")
        timesteps = _positive("timesteps", timesteps)
    demos_path = Path(demos) if demos is not None else default_demos_path(env_id)
    if not demos_path.is_file():
        raise missing_pool_error(env_id, demos_path, "pass the path of an existing pool with --demos")
    n_pool = _pool_size(str(demos_path.resolve()), file_mtime_ns(demos_path))
    try:
        split_episodes(n_pool, n_demos, n_eval_episodes, seed)
    except ValueError as e:
        raise ValueError(f"{demos_path}: {e}") from None
    out = Path(output_dir) if output_dir is not None else default_output_dir(env_id, method, seed)
    spec = RunSpec(
        env_id=env_id,
        method=method,
        demos=str(demos_path.resolve()),
        seed=seed,
        n_demos=n_demos,
        n_eval_episodes=n_eval_episodes,
        timesteps=int(timesteps),
        output_dir=str(out.resolve()),
        hyperparams=str(hp_path.resolve()),
        eval_every=_positive("eval_every", eval_every),
        checkpoint_every=_positive("checkpoint_every", checkpoint_every),
        command=command,
    )
    _preflight(spec, hp)
    return spec


#: Keys of the preflight checks passed in this process (a grid plans many runs that share one).
_PREFLIGHT_PASSED: set = set()


def _preflight(spec: RunSpec, hp) -> None:
    """Build the run's env and model, without training, and fit the demo pool to their spaces.

    What fails here would otherwise fail in the run after config.json is written: SB3's own checks
    (``n_steps * n_envs > 1``), env_kwargs the env does not take, a pool recorded on another env.
    """
    from sb3_cmzdril.algorithm import CMZDRIL

    key = (
        spec.env_id,
        spec.method,
        spec.hyperparams,
        file_mtime_ns(spec.hyperparams),
        spec.demos,
        file_mtime_ns(spec.demos),
    )
    if key in _PREFLIGHT_PASSED:
        return
    where = f"hyperparameters {hp.key!r} in {spec.hyperparams}"
    try:
        venv = make_training_env(spec, hp, spec.seed, None)
    except Exception as e:  # whatever the env's constructor or VecNormalize raises for bad kwargs
        raise ValueError(
            f"cannot make {spec.env_id} with the env_kwargs/normalize of {where}: {type(e).__name__}: {e}"
        ) from e
    try:
        pool = load_pool(spec.demos, key[-1])
        try:
            pool.check_spaces(venv.observation_space, venv.action_space)
        except ValueError as e:
            raise ValueError(f"demo pool {spec.demos} does not fit {spec.env_id}: {e}") from None
        kwargs = hp.model_kwargs()
        kwargs.setdefault("device", "cpu")
        try:
            CMZDRIL(
                hp.policy or "MlpPolicy",
                venv,
                demonstrations=pool,
                reward="zero" if spec.method == "bc" else spec.method,
                seed=spec.seed,
                **kwargs,
            )
        except Exception as e:  # SB3 reports bad values with asserts and TypeErrors as well as ValueErrors
            raise ValueError(
                f"{where} do not make a {spec.method} model for {spec.env_id}: {type(e).__name__}: {e}"
            ) from e
    finally:
        venv.close()
    _PREFLIGHT_PASSED.add(key)


def train_command(spec: RunSpec) -> str:
    """The ``sb3-cmzdril train`` line that performs exactly this run."""
    args = [
        "sb3-cmzdril",
        "train",
        "--env",
        spec.env_id,
        "--reward",
        spec.method,
        "--demos",
        spec.demos,
        "--n-demos",
        str(spec.n_demos),
        "--eval-episodes",
        str(spec.n_eval_episodes),
        "--seed",
        str(spec.seed),
        "--eval-every",
        str(spec.eval_every),
        "--checkpoint-every",
        str(spec.checkpoint_every),
        "--hyperparams",
        spec.hyperparams,
        "-o",
        spec.output_dir,
    ]
    if spec.method != "bc":
        args[6:6] = ["--timesteps", str(spec.timesteps)]
    return shlex.join(args)


def _normalize_kwargs(hp) -> dict[str, Any] | None:
    """VecNormalize kwargs from the zoo's ``normalize`` (True or a dict), None when off.

    As in the zoo, VecNormalize discounts rewards with the algorithm's gamma unless told otherwise.
    """
    if hp.normalize in (None, False):
        return None
    kwargs = {} if hp.normalize is True else dict(hp.normalize)
    if "gamma" in hp.algo_kwargs:
        kwargs.setdefault("gamma", hp.algo_kwargs["gamma"])
    return kwargs


def make_training_env(spec: RunSpec, hp, env_seed: int, vecnormalize_path: Path | None):
    """The training VecEnv (Monitor inside), with VecNormalize when asked (loaded from a checkpoint)."""
    from stable_baselines3.common.vec_env import VecNormalize

    from sb3_cmzdril.experts.envs import make_vec_env

    venv = make_vec_env(spec.env_id, hp.n_envs, env_seed, hp.env_kwargs)
    normalize = _normalize_kwargs(hp)
    if normalize is None:
        return venv
    if vecnormalize_path is not None and vecnormalize_path.is_file():
        return VecNormalize.load(str(vecnormalize_path), venv)
    return VecNormalize(venv, **normalize)


__all__ = [
    "DEFAULT_CHECKPOINT_EVERY",
    "DEFAULT_EVAL_EPISODES",
    "EXPERIMENT_KEYS",
    "FALLBACK_N_DEMOS",
    "HYPERPARAMS_NAME",
    "METHODS",
    "RunSpec",
    "check_method",
    "default_demos_path",
    "default_output_dir",
    "file_mtime_ns",
    "load_pool",
    "load_run_hyperparams",
    "make_training_env",
    "missing_pool_error",
    "plan_run",
    "split_episodes",
    "train_command",
]
