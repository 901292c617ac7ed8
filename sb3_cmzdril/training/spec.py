"""What a run is and whether it can start: its specification, resolved once, and every check.

:func:`prepare_run` resolves a run's defaults (demo pool, number of demos and steps, output folder,
hyperparameters) and everything the run needs, once: the hyperparameter file read and validated, the
demo pool read and split, the method's entry of the registry (:mod:`.methods`), the device and the
epoch. It refuses whatever would fail after the run folder is written, down to building the run's env
and model (:func:`build_model`), which it keeps for the run to train: a :class:`ResolvedRun`.
:func:`plan_run` is the same for a run that executes elsewhere (another process or Ray worker): it
returns the :class:`RunSpec`, plain values, which :func:`resolve_run` resolves there.
:func:`split_episodes` is the demo split every method of a trial shares; :func:`train_command` is the
``sb3-cmzdril train`` line of a spec. A run executes in :mod:`sb3_cmzdril.training.runs` and
writes the files of :mod:`sb3_cmzdril.training.run_folder`.
"""
from __future__ import annotations

import dataclasses
import datetime
import functools
import json
import math
import shlex
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from sb3_cmzdril.errors import MissingFileError, UserError
from sb3_cmzdril.experts import check_env_id, check_seed, env_name, load_demonstrations, pool_provenance
from sb3_cmzdril.hyperparams import FALLBACK_N_DEMOS, FALLBACK_POLICY
from sb3_cmzdril.io import PathLike, jsonable, portable_path
from sb3_cmzdril.training.methods import (
    HYPERPARAMS_NAME,
    METHOD_REGISTRY,
    METHODS,
    OFFPOLICY_HYPERPARAMS_NAME,
    OFFPOLICY_METHODS,
    PAPER_METHODS,
    Method,
    check_method,
    default_hyperparams_name,
    is_off_policy,
    learner_classes,
    result_policy,
)

if TYPE_CHECKING:  # heavy (torch, SB3): imported when a run is planned, not when this module is
    from sb3_cmzdril.data.demos import Demonstrations
    from sb3_cmzdril.hyperparams import Hyperparams

#: An off-policy run's epoch, in env steps: what ``eval_every``, ``checkpoint_every`` and Table I's
#: window count for it. SAC updates after every step, so its epoch is a length chosen to match a PPO
#: rollout of the shipped settings (``n_steps: 2048``, one env): both learners then evaluate, keep
#: checkpoints and average Table I over the same stretches of steps.
OFFPOLICY_EPOCH_STEPS = 2048
#: Keys of cmzdril.yml that configure the experiment rather than the model (not constructor kwargs):
#: the training episodes, (off-policy methods only) how the longest-episodes choice breaks a tie in length
#: and which episode length it prefers (the expert's, where it ends its episodes), and (PPO methods only)
#: from which fraction of the run's steps on an averaged policy is kept and evaluated, and whether the
#: longest-episodes choice is kept and evaluated too.
EXPERIMENT_KEYS: tuple[str, ...] = ("n_demos", "longest_tie_break", "episode_length", "average_from", "keep_longest")
#: Constructor arguments that the run passes itself, each with what sets it: a YAML entry that sets
#: one too would clash with it in the constructor (a TypeError once config.json is written).
RUN_SET_KEYS: dict[str, str] = {
    "seed": "--seed (the trial seed seeds the networks, the env and the split)",
    "reward": "--reward (the method)",
    "demonstrations": "--demos and --n-demos",
    "verbose": "--verbose (-v)",
}
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

    @property
    def off_policy(self) -> bool:
        """Whether the run trains CMZDRILSAC (the off-policy learner) rather than CMZDRIL (PPO)."""
        return is_off_policy(self.method)


def epoch_steps(model: Any) -> int:
    """Env steps per epoch of a built model: a PPO rollout (``n_steps * n_envs``), else
    :data:`OFFPOLICY_EPOCH_STEPS`."""
    from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

    if isinstance(model, OnPolicyAlgorithm):
        return int(model.n_steps * model.n_envs)
    return OFFPOLICY_EPOCH_STEPS


def split_episodes(n_pool: int, n_train: int, n_eval: int, seed: int) -> tuple[list[int], list[int]]:
    """Disjoint training and evaluation episode indices of a demo pool for trial ``seed``.

    ``numpy.random.default_rng(seed).permutation(n_pool)``: the first ``n_train`` train, the next
    ``n_eval`` evaluate. Every method of a trial calls this with the same arguments, hence the same data.
    """
    if n_train < 1 or n_eval < 1:
        raise UserError(f"need at least one training and one evaluation episode, got {n_train} and {n_eval}")
    if n_train + n_eval > n_pool:
        raise UserError(
            f"the demo pool has {n_pool} episodes but {n_train} training + {n_eval} evaluation episodes are "
            "needed; record more with `sb3-cmzdril collect-demos --episodes N` or lower --n-demos/--eval-episodes"
        )
    order = np.random.default_rng(int(seed)).permutation(int(n_pool))
    return [int(i) for i in order[:n_train]], [int(i) for i in order[n_train:n_train + n_eval]]


def default_demos_path(env_id: str, demos_dir: PathLike = "experts") -> Path:
    """``<demos_dir>/<EnvName>/demos.npz`` (where collect-demos puts an env's demo pool); for the
    default folder, the shipped pool when the working directory has none."""
    from sb3_cmzdril.shipped import local_or_shipped_demos

    return local_or_shipped_demos(env_id, demos_dir)


def default_output_dir(env_id: str, method: str, seed: int, runs_dir: PathLike = "runs") -> Path:
    """``<runs_dir>/<EnvName>/<method>/trial<seed>``: the benchmark's layout."""
    return Path(runs_dir) / env_name(env_id) / method / f"trial{int(seed)}"


def load_run_hyperparams(path: PathLike, env_id: str, method: str = "cmz") -> tuple[Hyperparams, dict[str, Any]]:
    """The env's entry of a cmzdril.yml (cmzdril_sac.yml for an off-policy ``method``) as
    ``(Hyperparams, experiment settings)``, read and validated once.

    Experiment keys (:data:`EXPERIMENT_KEYS`) are removed from the constructor kwargs; keys this
    code does not implement (env/vec-env wrappers, callbacks, frame stacking) are refused, and so are
    keys the method's learner (:meth:`~.methods.Learner.classes`) does not take and values of a type
    its constructor's annotations rule out.
    """
    from sb3_cmzdril.hyperparams import check_constructor_kwargs, load_hyperparams

    learner = Method.of(method).learner
    hp = load_hyperparams(Path(path), env_id, method)
    unknown_methods = [name for name in hp.per_method_names if name not in METHOD_REGISTRY]
    if unknown_methods:
        raise UserError(f"hyperparameters {hp.key!r} in {path}: per_method names unknown methods "
                        f"{unknown_methods}; choose from {', '.join(METHODS)}")
    hp.check_supported(
        unsupported=("env_wrapper", "vec_env_wrapper", "callback", "frame_stack"), what="sb3-cmzdril train"
    )
    run_set = [k for k in RUN_SET_KEYS if k in hp.algo_kwargs]
    if run_set:
        raise UserError(f"hyperparameters {hp.key!r} in {path}: {run_set[0]} is set by the run, with "
                        f"{RUN_SET_KEYS[run_set[0]]}, not by the YAML; remove it from the entry")
    settings = {k: hp.algo_kwargs.pop(k) for k in EXPERIMENT_KEYS if k in hp.algo_kwargs}
    for key in ("longest_tie_break", "episode_length"):
        if key not in settings:
            continue
        # selection.py imports torch: only read where the entry sets one of its keys.
        from sb3_cmzdril.selection import EPISODE_LENGTHS, TIE_BREAKS

        allowed = TIE_BREAKS if key == "longest_tie_break" else EPISODE_LENGTHS
        if not learner.off_policy:
            raise UserError(f"hyperparameters {hp.key!r} in {path}: {key} applies only to the off-policy "
                            f"methods {list(OFFPOLICY_METHODS)} (their longest-episodes choice), not to {method!r}")
        if settings[key] not in allowed:
            raise UserError(f"hyperparameters {hp.key!r} in {path}: {key} must be one of "
                            f"{list(allowed)}, got {settings[key]!r}")
    average_from = settings.get("average_from")
    if average_from is not None:
        # bc has no updates to average and ignores it, as it ignores the reward's keys.
        if learner.off_policy:
            raise UserError(f"hyperparameters {hp.key!r} in {path}: average_from applies only to the PPO methods "
                            f"(it averages the policy after each rollout's update), not to {method!r}")
        fraction = not isinstance(average_from, bool) and isinstance(average_from, (int, float))
        if not fraction or not 0 <= average_from < 1:
            raise UserError(f"hyperparameters {hp.key!r} in {path}: average_from must be a fraction of the run's "
                            f"steps in [0, 1) or null, got {average_from!r}")
    keep_longest = settings.get("keep_longest")
    if keep_longest is not None:
        if not isinstance(keep_longest, bool):
            raise UserError(f"hyperparameters {hp.key!r} in {path}: keep_longest must be true or false, "
                            f"got {keep_longest!r}")
        if learner.off_policy:
            raise UserError(f"hyperparameters {hp.key!r} in {path}: keep_longest applies only to the PPO methods; "
                            f"{method!r} always keeps the longest-episodes choice (its result)")
    # Caught here, a typo or a wrong type fails the whole grid at once instead of every run in its worker.
    check_constructor_kwargs(hp, list(learner.classes()))
    return hp, settings


@functools.lru_cache(maxsize=4)
def load_pool(path: str, mtime_ns: int):
    """A demo pool, read once per version of the file: a grid plans and checks many runs on one pool."""
    return load_demonstrations(path)


def file_mtime_ns(path: PathLike) -> int:
    """The file's modification time: the version key of the cached pool and of the preflight checks."""
    return Path(path).stat().st_mtime_ns


def missing_pool_error(env_id: str, path: PathLike, alternative: str) -> MissingFileError:
    """The error for a demo pool that is not there: how to record one, or ``alternative`` (the option
    of the calling command that names an existing one)."""
    return MissingFileError(
        f"demo pool not found: {path} (record one with `sb3-cmzdril collect-demos --env {env_id} --expert ... "
        f"--episodes N -o {path}`, or {alternative})"
    )


def _positive_int(name: str, value: int) -> int:
    """``value`` as an int when it is a whole number >= 1 (3.0 passes, "3", 2.5, true and inf do not)."""
    try:
        whole = not isinstance(value, bool) and int(value) == value
    except (TypeError, ValueError, OverflowError):  # a string, None, inf or nan: not a count
        whole = False
    if not whole or int(value) < 1:
        raise UserError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def prepare_run(
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
    verbose: int = 0,
    keep: bool = True,
) -> ResolvedRun:
    """Resolve defaults and everything the run needs, once, and check everything that can fail before
    training starts; the run to hand to :func:`~sb3_cmzdril.training.runs.run_experiment`.

    :param demos: the env's demo pool (default ``experts/<EnvName>/demos.npz``).
    :param n_demos: training episodes (default: ``n_demos`` of the YAML entry, else 1).
    :param timesteps: total PPO steps (default: ``n_timesteps`` of the YAML entry); unused by ``bc``.
    :param output_dir: default ``runs/<EnvName>/<method>/trial<seed>``.
    :param hyperparams: zoo-format YAML (default: the repository's ``hyperparams/cmzdril.yml``,
        ``hyperparams/cmzdril_sac.yml`` for an off-policy method).
    :param verbose: the SB3 verbosity of the model the checks build.
    :param keep: keep that env and model in the run (:attr:`ResolvedRun.built`) for it to train;
        without, they are closed.
    :raises ValueError: unknown method or env, bad counts, a pool too small for the split, anything
        :func:`resolve_run` refuses.
    :raises FileNotFoundError: no demo pool or hyperparameter file.
    """
    from sb3_cmzdril.shipped import local_or_shipped_demos, shipped_hyperparams

    chosen = Method.of(method)
    check_env_id(env_id)
    seed = check_seed(seed)
    # where neither file is named, the shipped ones (the pool is found to be there after the hyperparameters)
    hp_path = Path(hyperparams) if hyperparams is not None else shipped_hyperparams(chosen.learner.hyperparams_name)
    demos_path = Path(demos) if demos is not None else local_or_shipped_demos(env_id)
    hp, settings = load_run_hyperparams(hp_path, env_id, method)
    n_demos = _positive_int("n_demos", n_demos if n_demos is not None else settings.get("n_demos", FALLBACK_N_DEMOS))
    n_eval_episodes = _positive_int("n_eval_episodes", n_eval_episodes)
    if chosen.pretrain_only:
        timesteps = 0  # BC is the pretrained policy: no PPO steps
    else:
        timesteps = timesteps if timesteps is not None else hp.n_timesteps
        if timesteps is None:
            raise UserError(f"no number of timesteps: pass --timesteps or set n_timesteps in {hp_path}")
        timesteps = _positive_int("timesteps", timesteps)
    if not demos_path.is_file():
        raise missing_pool_error(env_id, demos_path, "pass the path of an existing pool with --demos")
    if output_dir is not None and not str(output_dir).strip():
        # Path("") is the current folder: a run would land among whatever files are there.
        raise UserError(f"output_dir is empty ({str(output_dir)!r}); name the run folder")
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
        eval_every=_positive_int("eval_every", eval_every),
        checkpoint_every=_positive_int("checkpoint_every", checkpoint_every),
        command=command,
    )
    # everything else that can fail before training, the pool's fit included
    return _resolved(spec, hp, settings, check=True, keep=keep, verbose=verbose)


def plan_run(env_id: str, method: str, seed: int, **options: Any) -> RunSpec:
    """:func:`prepare_run`'s checks (``options``: its keyword arguments) for a run that executes
    elsewhere (a grid's worker): its :class:`RunSpec`, which
    :func:`~sb3_cmzdril.training.runs.run_experiment` resolves there."""
    return prepare_run(env_id, method, seed, **options, keep=False).spec


class BuiltModel:
    """The training env and fresh model that a run's checks built (:func:`build_model`), for the run to
    train instead of building its own: taken once; what is not taken is closed. Empty where the checks
    built none (this process passed them before) or were not asked to keep them."""

    def __init__(self, venv: Any = None, model: Any = None) -> None:
        self._parts: tuple[Any, Any] | None = None if venv is None else (venv, model)

    def take(self) -> tuple[Any, Any] | None:
        """(env, model), the first time; None after, or where there are none."""
        parts, self._parts = self._parts, None
        return parts

    def close(self) -> None:
        """Close the env unless it was taken."""
        parts = self.take()
        if parts is not None:
            parts[0].close()


@dataclasses.dataclass(frozen=True)
class ResolvedRun:
    """A run with every input read and checked, once: what :func:`~sb3_cmzdril.training.runs.run_experiment`
    trains and evaluates, and what its config.json records. Build it with :func:`prepare_run` or
    :func:`resolve_run`."""

    spec: RunSpec
    method: Method  #: the registry's entry for ``spec.method``
    learner: Any  #: the class that trains it: CMZDRIL or CMZDRILSAC (:meth:`~.methods.Learner.classes`)
    hp: Hyperparams
    pool: Demonstrations  #: the whole demo pool; the run trains on ``train_idx`` and evaluates on the rest
    train_idx: tuple[int, ...]
    eval_idx: tuple[int, ...]  #: the episodes of the evaluation every ``eval_every`` epochs
    #: the YAML entry's experiment keys (:data:`EXPERIMENT_KEYS`) that it sets
    settings: Mapping[str, Any]
    #: the device the model runs on: the asked one (``device`` of the YAML, else the CPU) as SB3 resolves
    #: it, which falls back to the CPU, silently, where CUDA is asked for but missing
    device: str
    #: env steps per epoch: a PPO rollout (``n_steps * n_envs``), or :data:`OFFPOLICY_EPOCH_STEPS`
    epoch: int
    #: the env and model the checks built, for the run to train (:func:`prepare_run`'s ``keep``)
    built: BuiltModel = dataclasses.field(default_factory=BuiltModel, compare=False, repr=False)

    @property
    def held_out(self) -> list[int]:
        """Every pool episode not used for training: the final evaluation replays them all."""
        return [i for i in range(self.pool.n_episodes) if i not in set(self.train_idx)]

    @property
    def reward(self) -> str:
        """The learner's reward mode (:attr:`Method.reward`): BC is CMZDRIL's pretrained policy, trained
        with no reward at all."""
        return self.method.reward

    def model_kwargs(self) -> dict[str, Any]:
        """The model's constructor kwargs: the YAML's, on the CPU unless it says otherwise."""
        return _model_kwargs(self.hp, self.method)

    def constructor_arguments(self) -> dict[str, Any]:
        """Every argument the learner's constructor takes, as this run gives it: the constructor's
        default where neither the YAML nor the run sets one (all but the env, the demonstrations and
        the console's verbosity). config.json records it, so that a run says every value it used."""
        import inspect

        skipped = {"self", "env", "demonstrations", "verbose", "_init_setup_model"}
        values = {name: p.default for name, p in inspect.signature(self.learner).parameters.items()
                  if name not in skipped}
        values.update(policy=self.hp.policy or FALLBACK_POLICY, reward=self.reward, seed=self.spec.seed,
                      **self.model_kwargs())
        return values


def _model_kwargs(hp: Hyperparams, method: Method) -> dict[str, Any]:
    kwargs = hp.model_kwargs()
    kwargs.setdefault("device", "cpu")  # small MLPs: the CPU beats a GPU's launch overheads
    if method.pretrain_only:
        # The ensemble is not used by BC; one epoch (the minimum) instead of hundreds. It is fitted
        # after the policy's NLL pretraining, so the BC policy equals the other methods' epoch 0.
        kwargs["ensemble_epochs"] = 1
    return kwargs


def _release(version: str) -> tuple[int, ...]:
    """``"0.3.0.dev0"`` -> ``(0, 3, 0)``: a version's leading numbers, so that a development version
    counts as the release it leads to."""
    numbers = []
    for part in version.split("."):
        if not part.isdigit():
            break
        numbers.append(int(part))
    return tuple(numbers)


def record_version(config: Mapping[str, Any]) -> str | None:
    """The sb3-cmzdril version that made the run of ``config`` (config.json's ``versions``), None where
    the record does not say."""
    versions = config.get("versions")
    found = versions.get("sb3_cmzdril") if isinstance(versions, Mapping) else None
    return found if isinstance(found, str) else None


def record_made(config: Mapping[str, Any]) -> dict[str, str | None]:
    """When and by which version the run of ``config`` was made: the ``version`` and ``created_at``
    arguments of :func:`learner_defaults` and :func:`effective_values` (None where it does not say)."""
    created = config.get("created_at")
    return {"version": record_version(config), "created_at": created if isinstance(created, str) else None}


def _moment(stamp: str) -> datetime.datetime:
    """A record's ``created_at`` (``2026-11-21T07:31:25+0000``, the offset with or without a colon)."""
    return datetime.datetime.strptime(stamp, "%Y-%m-%dT%H:%M:%S%z")


def learner_defaults(method: str, version: str | None = None, created_at: str | None = None) -> dict[str, Any]:
    """What a run of ``method`` gets for a hyperparameter its entry leaves out, as config.json stores
    values: the learner's constructor defaults, the fallback policy and number of demos, one env. With
    ``version`` (and ``created_at``), those of that sb3-cmzdril version (the learner's ``defaults_before``)
    at that time (its ``options_added``): what a record it made ran with."""
    import inspect

    learner = Method.of(method).learner.classes()[0]
    defaults = {name: p.default for name, p in inspect.signature(learner).parameters.items()
                if p.default is not inspect.Parameter.empty}
    defaults.update(policy=FALLBACK_POLICY, n_demos=FALLBACK_N_DEMOS, n_envs=1,
                    policy_kwargs=learner.default_policy_kwargs)
    # the newest change first, so that the oldest one still ahead of the record wins
    if version is not None:
        for changed_in, before in sorted(learner.defaults_before.items(), key=lambda kv: _release(kv[0]),
                                         reverse=True):
            if _release(version) < _release(changed_in):
                defaults.update(before)
    if created_at is not None:
        for added_at, before in sorted(learner.options_added.items(), key=lambda kv: _moment(kv[0]), reverse=True):
            if _moment(created_at) < _moment(added_at):
                defaults.update(before)
    return json.loads(json.dumps(jsonable(defaults)))


def effective_values(values: Mapping[str, Any], method: str, version: str | None = None,
                     created_at: str | None = None) -> dict[str, Any]:
    """A hyperparameter entry's ``values`` (as config.json stores them) as this version's YAML would
    state them: without those that say what the run does anyway (:func:`learner_defaults`), and with a
    default of ``version`` at ``created_at`` (when a record was made) that this version's defaults
    changed. Two entries with the same effective values make the same run (the shipped YAML states no
    default, the records of older runs state every one)."""
    from sb3_cmzdril.hyperparams import safe_eval

    current = learner_defaults(method)
    then = learner_defaults(method, version, created_at) if (version, created_at) != (None, None) else current
    given = dict(values)
    if isinstance(given.get("policy_kwargs"), str):  # the YAML's expression: compared as what it makes
        given["policy_kwargs"] = jsonable(safe_eval(given["policy_kwargs"]))
    stated = {k: values[k] for k, v in given.items() if k not in current or current[k] != v}
    implied = {k: v for k, v in then.items() if k not in given and current.get(k) != v}
    return {**implied, **stated}


def _device(asked: Any) -> str:
    from stable_baselines3.common.utils import get_device

    try:
        return str(get_device(asked))
    except (RuntimeError, TypeError, ValueError):  # not a device at all: the preflight's model refuses it
        return str(asked)


def _epoch(hp: Hyperparams, method: Method, learner: Any, kwargs: Mapping[str, Any]) -> int:
    """Env steps per epoch (:func:`epoch_steps` of the model the run builds, before it is built): the
    rollout length of the YAML, else the learner's default, times the envs; an off-policy epoch's length."""
    if method.off_policy:
        return OFFPOLICY_EPOCH_STEPS
    import inspect

    n_steps = kwargs.get("n_steps", inspect.signature(learner).parameters["n_steps"].default)
    return int(n_steps) * hp.n_envs


def resolve_run(spec: RunSpec, *, check: bool = True, keep: bool = False, verbose: int = 0) -> ResolvedRun:
    """``spec`` resolved where it executes: its hyperparameters read and validated, its demo pool read
    and split, once.

    With ``check`` (the default), also refuse everything that would otherwise fail after the run
    folder is written: held-out episodes without a reset seed to replay them from, an env or model
    the hyperparameters cannot build, a pool recorded on another env, values the constructors accept
    but training cannot use. With ``keep``, the env and model those checks build (``verbose``: the
    model's SB3 verbosity) stay in the run for it to train.

    :raises ValueError: naming the file and the value at fault.
    """
    hp, settings = load_run_hyperparams(spec.hyperparams, spec.env_id, spec.method)
    return _resolved(spec, hp, settings, check=check, keep=keep, verbose=verbose)


def _resolved(spec: RunSpec, hp: Hyperparams, settings: dict[str, Any], *, check: bool, keep: bool,
              verbose: int) -> ResolvedRun:
    """The run of ``spec`` with its hyperparameters read: the pool read and split, the settings that
    follow from them resolved, and (``check``) every check before training passed."""
    pool = load_pool(spec.demos, file_mtime_ns(spec.demos))
    try:
        train_idx, eval_idx = split_episodes(pool.n_episodes, spec.n_demos, spec.n_eval_episodes, spec.seed)
    except ValueError as e:
        raise UserError(f"{spec.demos}: {e}") from None
    method = Method.of(spec.method)
    learner, _ = method.learner.classes()
    kwargs = _model_kwargs(hp, method)
    run = ResolvedRun(spec, method, learner, hp, pool, tuple(train_idx), tuple(eval_idx), settings,
                      device=_device(kwargs["device"]), epoch=_epoch(hp, method, learner, kwargs))
    if not check:
        return run
    _check_reset_seeds(run)
    _check_pool_env_kwargs(run)
    built = _preflight(run, verbose)
    if not keep:
        built.close()
        return run
    return dataclasses.replace(run, built=built)


def _env_own_kwargs(kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """``kwargs`` without gym.make's own keywords (``max_episode_steps``, ``disable_env_checker``): they
    wrap the env, a shorter time limit for a quick run say, and leave its dynamics and rewards alone."""
    import inspect

    import gymnasium as gym

    wrapping = set(inspect.signature(gym.make).parameters) - {"id", "kwargs"}
    return {k: v for k, v in kwargs.items() if k not in wrapping}


def _check_pool_env_kwargs(run: ResolvedRun) -> None:
    """Evaluation replays the pool's episodes in the run's env: one made with other env_kwargs than the
    pool's expert saw would score the policy against episodes of another env."""
    recorded = pool_provenance(run.spec.demos).get("env_kwargs")
    if not isinstance(recorded, dict):  # a pool with no record of how it was made: nothing to hold the entry to
        return
    recorded = _env_own_kwargs(recorded)
    configured = _env_own_kwargs(jsonable(run.hp.env_kwargs or {}))
    if recorded != configured:
        raise UserError(
            f"demo pool {run.spec.demos} was recorded with env_kwargs {recorded}, but hyperparameters "
            f"{run.hp.key!r} in {run.spec.hyperparams} make the env with {configured}: give the entry the pool's "
            "env_kwargs (each evaluation replays the pool's episodes in the run's env)"
        )


def _check_reset_seeds(run: ResolvedRun) -> None:
    """Evaluation replays each held-out episode from its recorded reset seed: one without cannot be."""
    from sb3_cmzdril.data.demos import UNKNOWN_SEED

    unknown = [i for i in run.held_out if int(run.pool.seeds[i]) == UNKNOWN_SEED]
    if unknown:
        raise UserError(
            f"demo pool {run.spec.demos}: episodes {unknown}, held out for evaluation, have no recorded reset seed, "
            "so they cannot be replayed from the expert's start; record the pool with seeds "
            "(`sb3-cmzdril collect-demos` does)"
        )


#: Keys of the preflight checks passed in this process (a grid plans many runs that share one).
_PREFLIGHT_PASSED: set = set()


def _preflight(run: ResolvedRun, verbose: int) -> BuiltModel:
    """Build the run's env and model (:func:`build_model`), without training, and fit the demo pool to
    their spaces; the env and model built (none where this process passed the same checks before).

    What fails here would otherwise fail in the run after config.json is written: SB3's own checks
    (``n_steps * n_envs > 1``), env_kwargs the env does not take, a pool recorded on another env,
    values only training would trip over (:func:`_check_values`).
    """
    spec = run.spec
    key = (
        spec.env_id,
        spec.method,
        spec.hyperparams,
        file_mtime_ns(spec.hyperparams),
        spec.demos,
        file_mtime_ns(spec.demos),
    )
    if key in _PREFLIGHT_PASSED:
        return BuiltModel()
    venv = _training_env(run)
    try:
        try:
            run.pool.check_spaces(venv.observation_space, venv.action_space)
        except ValueError as e:
            raise UserError(f"demo pool {spec.demos} does not fit {spec.env_id}: {e}") from None
        _check_episode_lengths(run)
        _check_starts(run)
        model = _model(run, venv, verbose)
        _check_values(model, _where(run))
    except BaseException:
        venv.close()
        raise
    _PREFLIGHT_PASSED.add(key)
    return BuiltModel(venv, model)


def build_model(run: ResolvedRun, verbose: int = 0) -> tuple[Any, Any]:
    """(the run's training env, its fresh model on the run's training episodes; ``verbose``: SB3's
    verbosity), refused with a UserError naming the hyperparameters where they cannot be made."""
    venv = _training_env(run)
    try:
        return venv, _model(run, venv, verbose)
    except BaseException:
        venv.close()
        raise


def _where(run: ResolvedRun) -> str:
    return f"hyperparameters {run.hp.key!r} in {run.spec.hyperparams}"


def _training_env(run: ResolvedRun) -> Any:
    """:func:`make_training_env` for a new run, refused with a UserError naming what the YAML gives the env."""
    spec = run.spec
    configured = [k for k in ("env_kwargs", "normalize") if getattr(run.hp, k) not in (None, False, {})]
    try:
        return make_training_env(spec, run.hp, spec.seed, None)
    except (TypeError, ValueError, AssertionError) as e:
        if not configured:  # the YAML passes nothing to the env: the env's own failure, traceback and all
            raise
        # how envs and VecNormalize refuse a keyword or a value; anything else is the env's own bug
        raise UserError(
            f"cannot make {spec.env_id} with the {'/'.join(configured)} of {_where(run)}: {type(e).__name__}: {e}"
        ) from e


def _model(run: ResolvedRun, venv: Any, verbose: int) -> Any:
    """The run's fresh model on ``venv`` and the run's training episodes."""
    spec = run.spec
    try:
        return run.learner(
            run.hp.policy or FALLBACK_POLICY, venv, demonstrations=run.pool.select(run.train_idx), reward=run.reward,
            seed=spec.seed, verbose=verbose, **run.model_kwargs(),
        )
    except Exception as e:  # SB3 reports bad values with asserts and TypeErrors as well as ValueErrors
        raise UserError(
            f"{_where(run)} do not make a {spec.method} model for {spec.env_id}: {type(e).__name__}: {e}"
        ) from e


def _own_step_limit(env: Any) -> int | None:
    """The step limit an env keeps itself (an int ``max_steps`` or ``max_episode_steps`` of the
    unwrapped env, as WaypointNav-v0's ``max_steps`` option), the smallest where both are set; None
    where it has none. gym.make's TimeLimit (``max_episode_steps``) is not the env's own: it wraps it."""
    limits = [getattr(env.unwrapped, name, None) for name in ("max_steps", "max_episode_steps")]
    found = [int(v) for v in limits if isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v > 0]
    return min(found) if found else None


def _check_episode_lengths(run: ResolvedRun) -> None:
    """UserError when a pool episode lasts longer than the step limit the env keeps itself, made with
    the entry's env_kwargs: the expert's env let it run on, so the run's env is another one (a pool
    without a sound record of its env_kwargs is held to them this way). gym.make's ``max_episode_steps``
    is left out, as :func:`_check_pool_env_kwargs` leaves it: a time limit wrapped around the same env,
    shorter than the pool's episodes, is how a quick run is made."""
    from sb3_cmzdril.metrics.evaluation import make_env

    spec = run.spec
    own = _env_own_kwargs(run.hp.env_kwargs or {})
    env = make_env(spec.env_id, own)
    try:
        limit = _own_step_limit(env)
    finally:
        env.close()
    lengths = np.asarray(run.pool.episode_lengths)
    longer = [int(i) for i in np.flatnonzero(lengths > limit)] if limit is not None else []
    if longer:
        shown = ", ".join(map(str, longer[:5])) + (", ..." if len(longer) > 5 else "")
        longest = int(lengths[longer].max())
        raise UserError(
            f"demo pool {spec.demos}: {len(longer)} episode(s) ({shown}) last up to {longest} steps, "
            f"longer than the {limit}-step limit of {spec.env_id} made with env_kwargs {own} (hyperparameters "
            f"{run.hp.key!r} in {spec.hyperparams}): the pool was recorded with other env_kwargs; give the entry the "
            "pool's (a shorter time limit over the same env is gym.make's max_episode_steps)"
        )


def _check_starts(run: ResolvedRun) -> None:
    """UserError unless every held-out episode's recorded reset seed reproduces its first observation.

    The evaluations replay the held-out episodes from their seeds (every ``eval_every`` epochs the
    ``eval_idx`` ones, at the end all of them); a pool recorded on another env with the same spaces,
    or whose seeds do not reproduce its starts, would compare the agent with an expert that started
    elsewhere. One reset per episode tells, before any file is written; the message names each one.
    """
    from sb3_cmzdril.data.demos import UNKNOWN_SEED
    from sb3_cmzdril.metrics.evaluation import make_env, same_observation

    spec = run.spec
    episodes = [i for i in run.held_out if int(run.pool.seeds[i]) != UNKNOWN_SEED]
    if not episodes:
        return
    env = make_env(spec.env_id, run.hp.env_kwargs)
    try:
        differing = [i for i in episodes if not same_observation(env.reset(seed=int(run.pool.seeds[i]))[0],
                                                                 run.pool.episode(i)["observations"])]
    finally:
        env.close()
    if differing:
        plural = len(differing) > 1
        more = ", ..." if len(differing) > 10 else ""
        shown = ", ".join(map(str, differing[:10])) + more
        seeds = ", ".join(str(int(run.pool.seeds[i])) for i in differing[:10]) + more
        raise UserError(
            f"demo pool {spec.demos} was not recorded on {spec.env_id} with these env_kwargs: resetting its "
            f"episode{'s' if plural else ''} {shown} (of {len(episodes)} held out) with {'their' if plural else 'its'} "
            f"seed{'s' if plural else ''} {seeds} does not give the episode's first observation; pass the pool of "
            f"{spec.env_id} (or the env and env_kwargs it was recorded on)"
        )


def _at_least_one(value: float) -> bool:
    return value >= 1


def _positive(value: float) -> bool:
    return math.isfinite(value) and value > 0


def _non_negative(value: float) -> bool:
    return math.isfinite(value) and value >= 0


def _fraction(value: float) -> bool:
    return 0 <= value <= 1


#: Values the constructors (SB3's PPO, CMZDRIL) accept but training cannot use: each would fail, or
#: train on nan, only once the run folder is written (``n_epochs: 0`` ends in an UnboundLocalError
#: inside PPO.train). Attribute of the built model, the condition, and the condition in words; a
#: schedule is checked at the start of training (a linear one ends at 0 by design), and None (off)
#: is always accepted.
_VALUE_CHECKS: tuple[tuple[str, Callable[[float], bool], str], ...] = (
    ("n_epochs", _at_least_one, ">= 1"),
    ("batch_size", _at_least_one, ">= 1"),
    ("ensemble_epochs", _at_least_one, ">= 1"),
    ("ensemble_batch_size", _at_least_one, ">= 1"),
    ("bc_batch_size", _at_least_one, ">= 1"),
    ("learning_rate", _positive, "finite and > 0"),
    ("ensemble_learning_rate", _positive, "finite and > 0"),
    ("bc_learning_rate", _positive, "finite and > 0"),
    ("clip_range", _positive, "finite and > 0"),
    ("clip_range_vf", _positive, "finite and > 0"),
    ("target_kl", _positive, "finite and > 0"),
    ("max_grad_norm", _positive, "finite and > 0"),
    ("vf_coef", _non_negative, "finite and >= 0"),
    ("ent_coef", math.isfinite, "finite"),
    ("gamma", _fraction, "in [0, 1]"),
    ("gae_lambda", _fraction, "in [0, 1]"),
)


def _check_values(model: Any, where: str) -> None:
    """ValueError naming the first hyperparameter of ``model`` that training cannot use."""
    for name, ok, rule in _VALUE_CHECKS:
        value = getattr(model, name, None)
        if value is None or isinstance(value, str):  # SAC's ent_coef "auto...": checked by SAC itself
            continue
        start = float(value(1.0)) if callable(value) else float(value)
        if not ok(start):
            raise UserError(f"{where}: {name} must be {rule}, got {start!r}")


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
        portable_path(spec.demos),
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
        portable_path(spec.hyperparams),
        "-o",
        portable_path(spec.output_dir),
    ]
    if not Method.of(spec.method).pretrain_only:
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


def make_training_env(spec: RunSpec, hp, env_seed: int, vecnormalize_path: Path | None, venv: Any = None):
    """The training VecEnv (Monitor inside), with VecNormalize when asked (loaded from a checkpoint);
    ``venv``: one made so before, whose envs are used again instead of new ones."""
    from stable_baselines3.common.vec_env import VecNormalize

    from sb3_cmzdril.experts.envs import make_vec_env

    if venv is None:
        venv = make_vec_env(spec.env_id, hp.n_envs, env_seed, hp.env_kwargs)
    elif isinstance(venv, VecNormalize):
        venv = venv.venv  # the envs beneath the statistics, which come from vecnormalize_path or anew
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
    "FALLBACK_POLICY",
    "effective_values",
    "learner_defaults",
    "record_made",
    "record_version",
    "HYPERPARAMS_NAME",
    "METHODS",
    "METHOD_REGISTRY",
    "OFFPOLICY_EPOCH_STEPS",
    "OFFPOLICY_HYPERPARAMS_NAME",
    "OFFPOLICY_METHODS",
    "PAPER_METHODS",
    "RUN_SET_KEYS",
    "BuiltModel",
    "Method",
    "ResolvedRun",
    "RunSpec",
    "build_model",
    "check_method",
    "default_demos_path",
    "default_hyperparams_name",
    "default_output_dir",
    "epoch_steps",
    "file_mtime_ns",
    "is_off_policy",
    "learner_classes",
    "load_pool",
    "load_run_hyperparams",
    "make_training_env",
    "missing_pool_error",
    "plan_run",
    "prepare_run",
    "resolve_run",
    "result_policy",
    "split_episodes",
    "train_command",
]
