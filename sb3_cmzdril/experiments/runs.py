"""One run of the paper's experiment: one env, one method, one trial seed.

A run is described by a :class:`RunSpec` (built and validated by :func:`plan_run`) and executed by
:func:`run_experiment`, which writes into its own folder::

    DIR/config.json        everything needed to reproduce it: env, method, seeds, the train/eval
                           episode indices of the demo pool (and its sha256), hyperparameters,
                           versions, the creating command and the equivalent `sb3-cmzdril train` line
    DIR/eval.csv           one row per evaluation against the held-out expert episodes
                           (ExpertEvalCallback: epoch, timesteps, return, Fréchet, action MSE, ...)
    DIR/model.zip          the latest checkpoint (written atomically every few PPO updates and at
                           the end; after done.json it is the final model; for bc the BC policy)
    DIR/vecnormalize.pkl   VecNormalize statistics beside model.zip, when the hyperparameters
                           ask for ``normalize``
    DIR/state.json         step count, wall time and the segments (start, resumes) of the run
    DIR/pretrain.csv       the NLL curve of behaviour-cloning pretraining (training and held-out steps)
    DIR/lowest_u.pt        the policy whose own training rollout had the lowest ensemble disagreement
                           (reward-free selection, sb3_cmzdril.selection), saved with each checkpoint
    DIR/final_eval.csv     the final evaluation: every pool episode not used for training, replayed by
                           the final policy ("final") and by the lowest-u one ("lowest_u"), one row
                           per (policy, episode)
    DIR/logs/progress_<T>.csv  SB3's training log of the segment that started at step T
    DIR/done.json          written last: the final summary; its presence means "finished"

Resuming: with ``done.json`` the run is skipped. With ``model.zip`` the run continues from that
checkpoint to the requested total (``learn(..., reset_num_timesteps=False)``). Evaluation rows
written after the checkpoint (by the interrupted process, for a policy that no longer exists) are
moved to ``eval.discarded.csv`` so that ``eval.csv`` describes one training trajectory; nothing is
deleted.

Methods (``METHODS``): ``bc`` (the NLL-pretrained policy, evaluated once at epoch 0) and the four
CMZDRIL reward modes ``zero``, ``env``, ``dril``, ``cmz``. Every method of a trial shares the network
seed, the env seed and the demonstration split, so their epoch-0 policies are identical.
"""
from __future__ import annotations

import contextlib
import csv
import dataclasses
import functools
import hashlib
import os
import shlex
import time
from pathlib import Path
from typing import Any, Dict, Iterator, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from sb3_cmzdril.experts import check_env_id, check_seed, env_name, load_demonstrations
from sb3_cmzdril.experts.callbacks import ProgressCallback
from sb3_cmzdril.io import (
    PathLike,
    atomic_path,
    jsonable,
    lock_output,
    read_json,
    remove_stale_temporaries,
    unlock_output,
    versions,
    write_json,
)

#: Methods of the paper's comparison: plain BC and the four reward modes of CMZDRIL.
METHODS: Tuple[str, ...] = ("bc", "zero", "env", "dril", "cmz")
#: Hyperparameter file of the repository used when none is given (hyperparams/cmzdril.yml).
HYPERPARAMS_NAME = "cmzdril"
#: Keys of cmzdril.yml that configure the experiment rather than the model (not constructor kwargs).
EXPERIMENT_KEYS: Tuple[str, ...] = ("n_demos",)
#: Training episodes per trial when neither --n-demos nor the YAML says: the paper's MuJoCo setting.
FALLBACK_N_DEMOS = 1
DEFAULT_EVAL_EPISODES = 5  # paper, Sec. IV-A.3: "We used 5 evaluation episodes for each experiment"
DEFAULT_CHECKPOINT_EVERY = 10  # PPO updates between checkpoints (~5% of an update's time each)
#: Table I averages each run over its last this-many epochs (paper, Table I caption).
TABLE_WINDOW = 100

CONFIG_FILE = "config.json"
DONE_FILE = "done.json"
STATE_FILE = "state.json"
MODEL_FILE = "model.zip"
VECNORMALIZE_FILE = "vecnormalize.pkl"
EVAL_CSV = "eval.csv"
FINAL_EVAL_CSV = "final_eval.csv"
FINAL_EVAL_COLUMNS = ("policy", "episode", "seed", "return", "length", "frechet", "action_mse", "expert_return")
PRETRAIN_CSV = "pretrain.csv"
LOWEST_U_FILE = "lowest_u.pt"
LOWEST_U_MODEL = "model_lowest_u.zip"
DISCARDED_CSV = "eval.discarded.csv"
ERROR_FILE = "error.txt"
LOG_FILE = "log.txt"

#: config.json entries that must agree before a run folder is resumed (the rest may change, e.g.
#: the requested number of steps or how often to evaluate).
_IDENTITY_KEYS = ("env_id", "method", "seed", "train_episodes", "eval_episodes", "demos_sha256", "hyperparams_values")
#: config.json entries a resume may change.
_SETTING_KEYS = ("timesteps", "eval_every", "checkpoint_every", "train_command")


# -- specification -----------------------------------------------------------------------------
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
    command: Optional[str] = None

    @property
    def label(self) -> str:
        """``EnvName/method/trial<seed>``: how progress displays and reports name the run."""
        return f"{env_name(self.env_id)}/{self.method}/trial{self.seed}"


def split_episodes(n_pool: int, n_train: int, n_eval: int, seed: int) -> Tuple[List[int], List[int]]:
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
    """``<demos_dir>/<EnvName>/demos.npz``: where collect-demos puts an env's demo pool."""
    return Path(demos_dir) / env_name(env_id) / "demos.npz"


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
    hp.check_supported(unsupported=("env_wrapper", "vec_env_wrapper", "callback", "frame_stack"), what="sb3-cmzdril train")
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
def _load_pool(path: str, mtime_ns: int):
    """A demo pool, read once per version of the file: a grid plans and checks many runs on one pool."""
    return load_demonstrations(path)


def _pool_size(path: str, mtime_ns: int) -> int:
    return _load_pool(path, mtime_ns).n_episodes


def _mtime_ns(path: PathLike) -> int:
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
    demos: Optional[PathLike] = None,
    n_demos: Optional[int] = None,
    n_eval_episodes: int = DEFAULT_EVAL_EPISODES,
    timesteps: Optional[int] = None,
    output_dir: Optional[PathLike] = None,
    hyperparams: Optional[PathLike] = None,
    eval_every: int = 1,
    checkpoint_every: int = DEFAULT_CHECKPOINT_EVERY,
    command: Optional[str] = None,
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
    n_pool = _pool_size(str(demos_path.resolve()), _mtime_ns(demos_path))
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

    key = (spec.env_id, spec.method, spec.hyperparams, _mtime_ns(spec.hyperparams), spec.demos, _mtime_ns(spec.demos))
    if key in _PREFLIGHT_PASSED:
        return
    where = f"hyperparameters {hp.key!r} in {spec.hyperparams}"
    try:
        venv = _make_training_env(spec, hp, spec.seed, None)
    except Exception as e:  # whatever the env's constructor or VecNormalize raises for bad kwargs
        raise ValueError(f"cannot make {spec.env_id} with the env_kwargs/normalize of {where}: {type(e).__name__}: {e}") from e
    try:
        pool = _load_pool(spec.demos, key[-1])
        try:
            pool.check_spaces(venv.observation_space, venv.action_space)
        except ValueError as e:
            raise ValueError(f"demo pool {spec.demos} does not fit {spec.env_id}: {e}") from None
        kwargs = hp.model_kwargs()
        kwargs.setdefault("device", "cpu")
        try:
            CMZDRIL(hp.policy or "MlpPolicy", venv, demonstrations=pool, reward="zero" if spec.method == "bc" else spec.method,
                    seed=spec.seed, **kwargs)
        except Exception as e:  # SB3 reports bad values with asserts and TypeErrors as well as ValueErrors
            raise ValueError(f"{where} do not make a {spec.method} model for {spec.env_id}: {type(e).__name__}: {e}") from e
    finally:
        venv.close()
    _PREFLIGHT_PASSED.add(key)


def train_command(spec: RunSpec) -> str:
    """The ``sb3-cmzdril train`` line that performs exactly this run."""
    args = [
        "sb3-cmzdril", "train", "--env", spec.env_id, "--reward", spec.method, "--demos", spec.demos,
        "--n-demos", str(spec.n_demos), "--eval-episodes", str(spec.n_eval_episodes), "--seed", str(spec.seed),
        "--eval-every", str(spec.eval_every), "--checkpoint-every", str(spec.checkpoint_every),
        "--hyperparams", spec.hyperparams, "-o", spec.output_dir,
    ]
    if spec.method != "bc":
        args[6:6] = ["--timesteps", str(spec.timesteps)]
    return shlex.join(args)


# -- eval.csv ------------------------------------------------------------------------------------
def read_eval_csv(path: PathLike) -> Dict[str, np.ndarray]:
    """eval.csv as columns (float arrays, rows sorted by epoch; first row per epoch kept).

    Rows cut short by a killed process (wrong field count, unparsable numbers) are skipped.
    """
    from sb3_cmzdril.metrics import ExpertEvalCallback

    columns = ExpertEvalCallback.CSV_COLUMNS
    rows: Dict[int, List[float]] = {}
    path = Path(path)
    if path.is_file():
        with open(path, newline="") as f:
            for row in csv.DictReader(f):
                try:
                    values = [float(row[c]) for c in columns]
                except (TypeError, ValueError, KeyError):
                    continue
                rows.setdefault(int(values[0]), values)
    ordered = [rows[e] for e in sorted(rows)]
    table = np.asarray(ordered, dtype=np.float64).reshape(len(ordered), len(columns))
    return {c: table[:, i] for i, c in enumerate(columns)}


def window_means(columns: Mapping[str, np.ndarray], window: int = TABLE_WINDOW) -> Dict[str, float]:
    """Each metric averaged over the evaluations of the last ``window`` epochs (all, if fewer).

    "Last 100 epochs" counts epochs, not rows: rows with ``epoch > last_epoch - window``.
    """
    epochs = columns["epoch"]
    if epochs.size == 0:
        return {"return": float("nan"), "frechet": float("nan"), "action_mse": float("nan"), "n_rows": 0,
                "first_epoch": -1, "last_epoch": -1}
    keep = epochs > epochs[-1] - window
    return {
        "return": float(np.mean(columns["return_mean"][keep])),
        "frechet": float(np.mean(columns["frechet_mean"][keep])),
        "action_mse": float(np.mean(columns["action_mse"][keep])),
        "n_rows": int(keep.sum()),
        "first_epoch": int(epochs[keep][0]),
        "last_epoch": int(epochs[-1]),
    }


def _discard_rows_after(csv_path: Path, timesteps: int) -> int:
    """Move eval rows with ``timesteps`` beyond the checkpoint to eval.discarded.csv; returns how many.

    They were evaluated by a process that died after the checkpoint: the policy they describe is
    gone, and the resumed run evaluates those epochs again.
    """
    if not csv_path.is_file():
        return 0
    lines = csv_path.read_text().splitlines()
    if not lines:
        return 0
    header, keep, moved = lines[0], [lines[0]], []
    n_fields = len(header.split(","))
    for line in lines[1:]:
        fields = line.split(",")
        try:
            later = len(fields) != n_fields or int(fields[1]) > timesteps
        except ValueError:
            later = True
        # A row cut short by the kill counts as later: it is moved out of the way with its text kept.
        (moved if later else keep).append(line)
    if not moved:
        return 0
    discarded = csv_path.with_name(DISCARDED_CSV)
    with open(discarded, "a") as f:
        if discarded.stat().st_size == 0:
            f.write(header + "\n")
        f.write("".join(f"{line}\n" for line in moved))
        f.flush()
        os.fsync(f.fileno())  # the rows are safe in the discard file before they leave eval.csv
    with atomic_path(csv_path) as tmp:
        tmp.write_text("".join(f"{line}\n" for line in keep))
    return len(moved)


# -- building blocks --------------------------------------------------------------------------------
def _sha256(path: PathLike) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _normalize_kwargs(hp) -> Optional[Dict[str, Any]]:
    """VecNormalize kwargs from the zoo's ``normalize`` (True or a dict), None when off.

    As in the zoo, VecNormalize discounts rewards with the algorithm's gamma unless told otherwise.
    """
    if hp.normalize in (None, False):
        return None
    kwargs = {} if hp.normalize is True else dict(hp.normalize)
    if "gamma" in hp.algo_kwargs:
        kwargs.setdefault("gamma", hp.algo_kwargs["gamma"])
    return kwargs


def _make_training_env(spec: RunSpec, hp, env_seed: int, vecnormalize_path: Optional[Path]):
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


def _segment_logger(out: Path, start: int, verbose: int):
    """SB3 logger writing this segment's progress CSV (a resumed run must not overwrite the last one)."""
    import sys

    from stable_baselines3.common.logger import CSVOutputFormat, HumanOutputFormat, Logger

    (out / "logs").mkdir(exist_ok=True)
    formats = [CSVOutputFormat(str(out / "logs" / f"progress_{start}.csv"))]
    if verbose >= 1:
        formats.append(HumanOutputFormat(sys.stdout))
    return Logger(folder=None, output_formats=formats)


def _checkpoint_callback_class():
    from stable_baselines3.common.callbacks import BaseCallback

    class CheckpointCallback(BaseCallback):
        """model.zip (and VecNormalize stats) every ``every`` PPO updates and at the end, then state.json.

        It saves at the start of a rollout, after the ExpertEvalCallback listed before it has
        evaluated the same policy, so an eval row and the checkpoint at that step always agree.
        """

        def __init__(self, save: Any, every: int) -> None:
            super().__init__()
            self.save = save
            self.every = int(every)
            self._last = -1

        def _on_rollout_start(self) -> None:
            epoch = self.model.num_timesteps // (self.model.n_steps * self.model.n_envs)
            if epoch > 0 and epoch % self.every == 0:
                self._save()

        def _on_step(self) -> bool:
            return True

        def _on_training_end(self) -> None:
            self._save()

        def _save(self) -> None:
            if self.model.num_timesteps != self._last:
                self.save(self.model)
                self._last = self.model.num_timesteps

    return CheckpointCallback


class _RunState:
    """state.json: step count, wall time across segments, and how each segment started."""

    def __init__(self, out: Path, spec: RunSpec, start_steps: int) -> None:
        self.path = out / STATE_FILE
        self.data: Dict[str, Any] = {"num_timesteps": 0, "wall_time_s": 0.0, "segments": []}
        if self.path.is_file() and start_steps > 0:
            self.data.update(read_json(self.path))
        self._base_wall = float(self.data.get("wall_time_s", 0.0))
        self._t0 = time.time()
        self.data["segments"].append({
            "started_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "from_timesteps": int(start_steps),
            "command": spec.command,
        })

    def wall_time(self) -> float:
        return self._base_wall + (time.time() - self._t0)

    def write(self, num_timesteps: int) -> None:
        self.data.update(num_timesteps=int(num_timesteps), wall_time_s=round(self.wall_time(), 2))
        write_json(self.path, self.data)


def _config(spec: RunSpec, hp, train_idx: List[int], eval_idx: List[int], pool) -> Dict[str, Any]:
    return {
        "env_id": spec.env_id,
        "env_name": env_name(spec.env_id),
        "method": spec.method,
        "reward": "none (BC: pretrained policy only)" if spec.method == "bc" else spec.method,
        "seed": spec.seed,
        "network_seed": spec.seed,
        "env_seed": spec.seed,
        "demos": spec.demos,
        "demos_sha256": _sha256(spec.demos),
        "pool_episodes": int(pool.n_episodes),
        "split": "numpy.random.default_rng(seed).permutation(pool_episodes): first n_demos train, next n_eval_episodes evaluate",
        "n_demos": spec.n_demos,
        "n_eval_episodes": spec.n_eval_episodes,
        "train_episodes": train_idx,
        "eval_episodes": eval_idx,
        "train_episode_seeds": [int(pool.seeds[i]) for i in train_idx],
        "eval_episode_seeds": [int(pool.seeds[i]) for i in eval_idx],
        "timesteps": spec.timesteps,
        "eval_every": spec.eval_every,
        "checkpoint_every": spec.checkpoint_every,
        "hyperparams_file": spec.hyperparams,
        "hyperparams_key": hp.key,
        "hyperparams_values": hp.raw,
        "model_kwargs": hp.model_kwargs(),
        "env_kwargs": hp.env_kwargs,
        "versions": versions(),
        "command": spec.command,
        "train_command": train_command(spec),
        "cwd": os.getcwd(),
        "created_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


def _as_stored(config: Mapping[str, Any]) -> Dict[str, Any]:
    """``config`` as config.json stores it, to compare like with like."""
    import json

    return json.loads(json.dumps(jsonable(dict(config))))


def _check_same_run(out: Path, saved: Mapping[str, Any], fresh: Mapping[str, Any], what: str = "a different run") -> None:
    """ValueError naming each identity entry in which the folder's run and the asked one differ."""
    differing = [k for k in _IDENTITY_KEYS if k in saved and saved.get(k) != fresh.get(k)]
    if differing:
        raise ValueError(
            f"{out} holds {what} ({', '.join(f'{k}: {saved.get(k)!r} there, {fresh.get(k)!r} now' for k in differing)}); "
            "use another output folder or delete that one"
        )


def _check_or_write_config(out: Path, config: Dict[str, Any]) -> Dict[str, Any]:
    """Write config.json for a new run; for an existing one, refuse to mix two different runs.

    A config.json with nothing trained beside it (an attempt that failed or was stopped before its
    first checkpoint) is replaced: it must not block the corrected command.
    """
    path = out / CONFIG_FILE
    fresh = _as_stored(config)
    trained = (out / MODEL_FILE).is_file() or (out / DONE_FILE).is_file()
    if not path.is_file() or not trained:
        write_json(path, config)
        return config
    saved = read_json(path)
    _check_same_run(out, saved, fresh)
    # A resume may ask for more steps or another cadence: config.json follows, so that its
    # train_command reproduces what the run became (state.json keeps each segment's command).
    changed = {k: fresh[k] for k in _SETTING_KEYS if saved.get(k) != fresh.get(k)}
    if changed:
        saved.update(changed)
        write_json(path, saved)
    return saved


@contextlib.contextmanager
def _locked(out: Path) -> Iterator[None]:
    """One process per run folder: a second one fails at once instead of corrupting the first."""
    try:
        lock = lock_output(out)
    except ValueError:
        raise ValueError(f"another process is already running in {out} (lock {out / '.lock'})") from None
    try:
        yield
    finally:
        unlock_output(out, lock)


# -- one run -----------------------------------------------------------------------------------
def run_experiment(
    spec: RunSpec,
    *,
    progress_bar: bool = False,
    callbacks: Sequence[Any] = (),
    verbose: int = 0,
) -> Dict[str, Any]:
    """Execute (or resume, or skip) one run; returns its summary with a ``status`` entry.

    ``status`` is ``"skipped"`` (done.json was there: its content is returned), ``"done"`` (the
    summary just written to done.json) or ``"stopped"`` (a callback ended training early: no
    done.json, the checkpoint allows resuming). Exceptions propagate; the last checkpoint stays.

    :param callbacks: extra SB3 callbacks for the PPO training (not used by ``bc``).
    """
    out = Path(spec.output_dir)
    done = check_finished(spec)
    if done is not None:
        return {**done, "status": "skipped"}
    out.mkdir(parents=True, exist_ok=True)
    with _locked(out):
        remove_stale_temporaries(out)
        return _run_locked(spec, out, progress_bar, list(callbacks), verbose)


def check_finished(spec: RunSpec) -> Optional[Dict[str, Any]]:
    """done.json's summary when ``spec.output_dir`` holds this run finished, None when it is not finished.

    :raises ValueError: the folder holds a finished run of something else (another method, seed,
        split, demo pool or hyperparameters), whose numbers must not pass for this run's; or this
        run, finished with fewer steps than ``spec.timesteps`` asks for.
    """
    out = Path(spec.output_dir)
    done_path = out / DONE_FILE
    if not done_path.is_file():
        return None
    done = read_json(done_path)
    # done.json repeats the first identity entries, for a folder whose config.json went missing.
    saved = read_json(out / CONFIG_FILE) if (out / CONFIG_FILE).is_file() else done
    hp, _ = load_run_hyperparams(spec.hyperparams, spec.env_id)
    pool = _load_pool(spec.demos, _mtime_ns(spec.demos))
    train_idx, eval_idx = split_episodes(pool.n_episodes, spec.n_demos, spec.n_eval_episodes, spec.seed)
    _check_same_run(out, saved, _as_stored(_config(spec, hp, train_idx, eval_idx, pool)), "a different, finished run")
    steps = int(done.get("num_timesteps", 0))
    if spec.timesteps > steps:
        raise ValueError(
            f"{out} is finished at {steps} steps (done.json), fewer than the {spec.timesteps} asked; to train it "
            f"further, delete {done_path} and run the command again (it continues from {MODEL_FILE}), or use "
            "another output folder"
        )
    return done


def _run_locked(spec: RunSpec, out: Path, progress_bar: bool, callbacks: List[Any], verbose: int) -> Dict[str, Any]:
    from sb3_cmzdril.algorithm import CMZDRIL
    from sb3_cmzdril.demos import Demonstrations
    from sb3_cmzdril.metrics import ExpertEvalCallback
    from sb3_cmzdril.selection import LowestDisagreementPolicy

    pool = Demonstrations.load(spec.demos)
    train_idx, eval_idx = split_episodes(pool.n_episodes, spec.n_demos, spec.n_eval_episodes, spec.seed)
    hp, _ = load_run_hyperparams(spec.hyperparams, spec.env_id)
    config = _check_or_write_config(out, _config(spec, hp, train_idx, eval_idx, pool))

    model_path, vecnorm_path, csv_path = out / MODEL_FILE, out / VECNORMALIZE_FILE, out / EVAL_CSV
    resume = spec.method != "bc" and model_path.is_file()
    kwargs = hp.model_kwargs()
    kwargs.setdefault("device", "cpu")  # small MLPs: the CPU beats a GPU's launch overheads
    if resume:
        venv = _make_training_env(spec, hp, spec.seed, vecnorm_path)
        try:
            model = CMZDRIL.load(model_path, env=venv, device=kwargs["device"])
        except Exception as e:  # a zip is written atomically, so this is a foreign or damaged file
            venv.close()
            raise ValueError(f"cannot resume from {model_path}: {type(e).__name__}: {e}") from e
        start = int(model.num_timesteps)
        # Seeds of a resumed segment (networks' sampling and the env, which set_random_seed also
        # seeds) are offset by its start, so it does not replay the first segment's noise.
        model.set_random_seed(spec.seed + start)
        discarded = _discard_rows_after(csv_path, start)
    else:
        start = 0
        venv = _make_training_env(spec, hp, spec.seed, None)
        if spec.method == "bc":
            # The ensemble is not used by BC; one epoch (the minimum) instead of hundreds. It is fitted
            # after the policy's NLL pretraining, so the BC policy equals the other methods' epoch 0.
            kwargs["ensemble_epochs"] = 1
        reward = "zero" if spec.method == "bc" else spec.method
        model = CMZDRIL(
            hp.policy or "MlpPolicy", venv, demonstrations=pool.select(train_idx), reward=reward, seed=spec.seed,
            verbose=verbose, **kwargs,
        )
        discarded = _discard_rows_after(csv_path, -1)  # rows of an attempt that died before its first checkpoint
    model.set_logger(_segment_logger(out, start, verbose))
    state = _RunState(out, spec, start)
    if discarded:
        state.data["segments"][-1]["discarded_eval_rows"] = discarded

    eval_cb = ExpertEvalCallback(
        spec.env_id, pool.select(eval_idx), eval_every=spec.eval_every, csv_path=csv_path, env_kwargs=hp.env_kwargs,
        verbose=verbose,
    )
    selector = LowestDisagreementPolicy()
    if resume:
        selector.load(out / LOWEST_U_FILE)

    def save(m) -> None:
        vec_normalize = m.get_vec_normalize_env()
        if vec_normalize is not None:
            with atomic_path(vecnorm_path, suffix=".pkl") as tmp:
                vec_normalize.save(str(tmp))
        with atomic_path(model_path, suffix=".zip") as tmp:
            m.save(tmp)
        selector.save(out / LOWEST_U_FILE)  # with the checkpoint, so a resume continues the same search
        state.write(m.num_timesteps)

    try:
        # Pretraining (BC to convergence, the ensemble fit) takes seconds to minutes: show it.
        model.pretrain(progress_bar=progress_bar)
        if spec.method == "bc":
            # learn(0): pretraining, then the callback's end-of-training evaluation at epoch 0.
            model.learn(0, callback=[eval_cb])
            save(model)  # the BC policy itself, for `sb3-cmzdril evaluate` and later inspection
            _write_pretrain_csv(out / PRETRAIN_CSV, model.pretrain_history)
        else:
            checkpoint_cb = _checkpoint_callback_class()(save, spec.checkpoint_every)
            progress_cb = ProgressCallback(spec.timesteps, show=progress_bar)
            model.learn(
                max(spec.timesteps - start, 0),
                callback=[eval_cb, selector, checkpoint_cb, progress_cb, *callbacks],
                reset_num_timesteps=not resume,
            )
            if not resume:
                _write_pretrain_csv(out / PRETRAIN_CSV, model.pretrain_history)
        if model.num_timesteps >= spec.timesteps:
            final = _final_evaluation(spec, model, pool, train_idx, hp, selector, out)
    finally:
        eval_cb.close()
        venv.close()

    if model.num_timesteps < spec.timesteps:
        return {"status": "stopped", "num_timesteps": int(model.num_timesteps), "run_dir": str(out)}
    state.write(model.num_timesteps)
    summary = _summary(spec, model, config, state, csv_path)
    summary["final_evaluation"] = final
    write_json(out / DONE_FILE, summary)
    with contextlib.suppress(FileNotFoundError):
        (out / ERROR_FILE).unlink()  # an earlier attempt's failure is history once the run is done
    return summary


def _write_pretrain_csv(path: Path, history: Mapping[str, Sequence[float]]) -> None:
    """pretrain.csv: epoch, training NLL, held-out NLL (epoch 0: before training, held-out only)."""
    train, validation = list(history.get("train_nll", [])), list(history.get("validation_nll", []))
    n = max(len(train) + (1 if validation else 0), len(validation))
    lines = ["epoch,train_nll,validation_nll"]
    offset = 1 if validation else 0  # validation_nll[0] is measured before the first epoch
    for epoch in range(n):
        t = train[epoch - offset] if 0 <= epoch - offset < len(train) else float("nan")
        v = validation[epoch] if epoch < len(validation) else float("nan")
        lines.append(f"{epoch + 1 - offset},{t:.6g},{v:.6g}")
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n")


def _final_evaluation(spec: RunSpec, model, pool, train_idx: List[int], hp, selector, out: Path) -> Dict[str, Any]:
    """Replay every pool episode not used for training with the final policy and, for the RL
    methods, the lowest-u one; write final_eval.csv (one row per policy and episode) and
    model_lowest_u.zip; return the summaries for done.json.

    Five episodes per evaluation cannot tell methods apart on HalfCheetah (one BC policy scored 188
    on one machine and 242 on another); the whole rest of the pool can.
    """
    from sb3_cmzdril.metrics import evaluate_against_expert

    episodes = [i for i in range(pool.n_episodes) if i not in set(train_idx)]
    held_out = pool.select(episodes)
    policies = {"final": None}
    if spec.method != "bc" and selector.best_state is not None:
        policies["lowest_u"] = selector
    results: Dict[str, Any] = {"episodes": episodes}
    rows = [",".join(FINAL_EVAL_COLUMNS)]
    final_state = {k: v.detach().clone() for k, v in model.policy.state_dict().items()}
    try:
        for name, source in policies.items():
            if source is not None:
                source.apply(model)
                with atomic_path(out / LOWEST_U_MODEL, suffix=".zip") as tmp:
                    model.save(tmp)
            ev = evaluate_against_expert(model, spec.env_id, held_out, env_kwargs=hp.env_kwargs, start_mismatch="ignore")
            summary = ev.summary()
            if source is not None:
                summary.update(epoch=int(source.best_epoch), rollout_u=float(source.best_u))
            results[name] = summary
            for j, episode in enumerate(episodes):
                rows.append(",".join(str(v) for v in (
                    name, episode, int(ev.seeds[j]), f"{ev.returns[j]:.6g}", int(ev.lengths[j]), f"{ev.frechet[j]:.6g}",
                    f"{ev.episode_action_mse[j]:.6g}", f"{ev.expert_returns[j]:.6g}",
                )))
    finally:
        model.policy.load_state_dict(final_state)
    with atomic_path(out / FINAL_EVAL_CSV) as tmp:
        tmp.write_text("\n".join(rows) + "\n")
    return results


def _summary(spec: RunSpec, model, config: Mapping[str, Any], state: _RunState, csv_path: Path) -> Dict[str, Any]:
    columns = read_eval_csv(csv_path)
    integral = ("epoch", "timesteps", "n_episodes")
    last = {c: (int(v[-1]) if c in integral else float(v[-1])) for c, v in columns.items()} if columns["epoch"].size else {}
    return {
        "status": "done",
        "env_id": spec.env_id,
        "method": spec.method,
        "seed": spec.seed,
        "train_episodes": config["train_episodes"],
        "eval_episodes": config["eval_episodes"],
        "num_timesteps": int(model.num_timesteps),
        "requested_timesteps": spec.timesteps,
        "epochs": int(model.num_timesteps // (model.n_steps * model.n_envs)),
        "n_evaluations": int(columns["epoch"].size),
        "last_evaluation": last,
        # What Table I takes from this run (the report recomputes it from eval.csv).
        "final_window": {"window_epochs": TABLE_WINDOW, **window_means(columns)},
        "pretrain": dict(model.pretrain_info),
        "dril_threshold": model.dril_threshold,
        "wall_time_s": round(state.wall_time(), 2),
        "segments": len(state.data["segments"]),
        "finished_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "run_dir": spec.output_dir,
    }


def load_evaluation_model(
    path: PathLike,
    env_id: str,
    env_kwargs: Optional[Mapping[str, Any]] = None,
    vecnormalize: Optional[PathLike] = None,
) -> Tuple[Any, Optional[Any]]:
    """``(model, observation transform or None)`` for :func:`~sb3_cmzdril.metrics.evaluate_against_expert`.

    A CMZDRIL zip, else any SB3 model (an expert, a plain PPO). With ``vecnormalize`` (statistics
    saved beside a run's model.zip) the transform normalises observations as the policy saw them.
    """
    from sb3_cmzdril.algorithm import CMZDRIL
    from sb3_cmzdril.experts import load_expert_model

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"model file not found: {path}")
    try:
        model = CMZDRIL.load(path, device="cpu")
    except Exception:  # not a CMZDRIL zip: some other SB3 algorithm's, which load_expert_model identifies
        model = load_expert_model(path)
    if vecnormalize is None:
        if getattr(model, "vecnormalize_obs", False):
            raise ValueError(
                f"{path} was trained on VecNormalize'd observations: pass its statistics (the vecnormalize.pkl "
                "saved beside it) with --vecnormalize; without them its actions would be silently wrong"
            )
        return model, None
    import gymnasium as gym
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    venv = DummyVecEnv([lambda: gym.make(env_id, **dict(env_kwargs or {}))])
    try:
        stats = VecNormalize.load(str(vecnormalize), venv)
    except Exception as e:  # pickle raises many types for a damaged or foreign file
        venv.close()
        raise ValueError(f"VecNormalize statistics {vecnormalize} are damaged or not VecNormalize's: {type(e).__name__}: {e}") from None
    stats.training = False
    return model, stats.normalize_obs


def run_status(output_dir: PathLike) -> str:
    """``"done"``, ``"failed"`` (error.txt, no done.json), ``"partial"`` (a checkpoint) or ``"new"``."""
    out = Path(output_dir)
    if (out / DONE_FILE).is_file():
        return "done"
    if (out / ERROR_FILE).is_file():
        return "failed"
    if (out / MODEL_FILE).is_file():
        return "partial"
    return "new"


def latest_epoch(output_dir: PathLike) -> Optional[int]:
    """The epoch of the last row of a run's eval.csv (cheap: reads the file's tail), or None."""
    path = Path(output_dir) / EVAL_CSV
    try:
        with open(path, "rb") as f:
            f.seek(0, os.SEEK_END)
            f.seek(max(0, f.tell() - 1024))
            tail = f.read().decode("utf-8", "replace").strip().splitlines()
        return int(tail[-1].split(",")[0]) if tail else None
    except (OSError, ValueError, IndexError):
        return None


__all__ = [
    "METHODS",
    "RunSpec",
    "plan_run",
    "run_experiment",
    "split_episodes",
    "read_eval_csv",
    "window_means",
    "train_command",
    "default_demos_path",
    "default_output_dir",
    "check_env_id",
    "check_method",
    "check_finished",
    "run_status",
    "latest_epoch",
]
