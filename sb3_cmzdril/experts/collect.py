"""Recording demonstrations (``collect_demos``, the ``collect-demos`` command) and reading demo pools.

Episode ``i`` of a recording is reset with ``seed + i`` and played with deterministic expert
actions, so any episode can be replayed. A saved pool ``DIR/NAME.npz`` keeps its provenance (which
expert, command, seeds and returns made it) in ``DIR/NAME.json`` beside it, so a folder can hold
several pools. Pools recorded before that keep it as the ``demos`` section of ``DIR/metadata.json``
(the shipped experts' folders); :func:`pool_provenance` reads either. The summary table and notes go
to this module's logger (the CLI prints them).
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from sb3_cmzdril._mujoco_log import mujoco_warnings_routed
from sb3_cmzdril.console import RENDERABLE
from sb3_cmzdril.data.demos import Demonstrations
from sb3_cmzdril.errors import OutputExistsError, UserError
from sb3_cmzdril.experts.envs import check_env_id, check_seed
from sb3_cmzdril.experts.loading import expert_files, resolve_expert
from sb3_cmzdril.io import (
    LOCK_FILE,
    PathLike,
    command_line,
    jsonable,
    lock_output,
    read_json_or_empty,
    remove_stale_temporaries,
    same_file,
    unlock_output,
    versions,
    write_json,
)
from sb3_cmzdril.metrics.evaluation import make_env

logger = logging.getLogger(__name__)


def load_demonstrations(path: PathLike) -> Demonstrations:
    """:meth:`Demonstrations.load` with every kind of damaged file turned into a ValueError.

    A compressed npz whose deflate stream is damaged (rather than its CRC) fails inside zlib with
    ``zlib.error``, which names neither the file nor the problem.
    """
    import zlib

    try:
        return Demonstrations.load(path)
    except zlib.error as e:
        raise UserError(f"demo file {path} is corrupt: {e}") from e


def run_episode(expert: Any, env: gym.Env, seed: int) -> dict[str, Any]:
    """One episode with deterministic expert actions, reset with ``seed``."""
    obs, _ = env.reset(seed=int(seed))
    observations, actions, rewards = [], [], []
    done = False
    step_action: int | np.ndarray
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


def _episode_returns(demos: Demonstrations) -> np.ndarray:
    returns = demos.episode_returns
    if returns is None:  # run_episode records every reward; only a caller's own pool can lack them
        raise UserError("the demonstrations hold no rewards, so there are no returns to report")
    return returns


def _log_summary(demos: Demonstrations, title: str) -> None:
    """Log a table of the episodes (seed, return, length) and their mean.

    The message is the plain-text table; where rich is installed the record also carries the rich
    table (attribute :data:`RENDERABLE`), which the CLI prints in its place.
    """
    returns = _episode_returns(demos)
    rows = [(i, int(demos.seeds[i]), float(returns[i]), int(demos.episode_lengths[i])) for i in range(demos.n_episodes)]
    mean, std = float(np.mean(returns)), float(np.std(returns))
    mean_len = float(np.mean(demos.episode_lengths))
    lines = [title, f"{'episode':>8} {'seed':>8} {'return':>12} {'length':>8}"]
    lines += [f"{i:>8} {s:>8} {r:>12.2f} {n:>8}" for i, s, r, n in rows]
    lines.append(f"{'mean':>8} {'':>8} {mean:>12.2f} {mean_len:>8.1f}  (std {std:.2f})")
    extra = {}
    try:
        from rich.table import Table
    except ImportError:  # rich comes with the experiments extra; the plain table stands alone
        pass
    else:
        table = Table(title=title)
        for col in ("episode", "seed", "return", "length"):
            table.add_column(col, justify="right")
        for i, s, r, n in rows:
            table.add_row(str(i), str(s), f"{r:.2f}", str(n))
        table.add_section()
        table.add_row("mean", "", f"{mean:.2f} +/- {std:.2f}", f"{mean_len:.1f}")
        extra[RENDERABLE] = table
    logger.info("%s", "\n".join(lines), extra=extra)


#: The record of an expert's folder (train-expert's), which older pools also kept their provenance in.
FOLDER_METADATA = "metadata.json"


def provenance_path(pool: PathLike) -> Path:
    """Where the provenance of the pool ``DIR/NAME.npz`` is written: ``DIR/NAME.json``."""
    return Path(pool).with_suffix(".json")


def pool_provenance(pool: PathLike) -> dict[str, Any]:
    """The provenance record of a demo pool (expert, env, seeds, returns, command), ``{}`` if none.

    Read from ``NAME.json`` beside the pool, else from the ``demos`` section of the ``metadata.json``
    beside it when that section names this file (the layout of pools recorded before each pool had
    its own record, e.g. the shipped ``experts/<EnvId>/demos.npz``).
    """
    pool = Path(pool)
    own = provenance_path(pool)
    if own.is_file() and own.name != FOLDER_METADATA:
        record = read_json_or_empty(own).get("demos")
        if isinstance(record, dict):
            return record
    legacy = read_json_or_empty(pool.parent / FOLDER_METADATA).get("demos")
    if isinstance(legacy, dict) and legacy.get("file", pool.name) == pool.name:
        return legacy
    return {}


@mujoco_warnings_routed()  # the expert steps MuJoCo: its warnings go to stderr, not MUJOCO_LOG.TXT
def collect_demos(
    expert: str | PathLike | Any,
    env_id: str,
    n_episodes: int,
    seed: int = 0,
    output: PathLike | None = None,
    env_kwargs: dict[str, Any] | None = None,
    verbose: bool = True,
    force: bool = False,
) -> Demonstrations:
    """Record ``n_episodes`` deterministic expert episodes; episode ``i`` is reset with ``seed + i``.

    :param expert: a path to an SB3 zip (any algorithm), a folder holding ``model.zip``, a
        registered scripted-expert name, or an object with ``predict``.
    :param output: where to save the demonstrations, ``NAME.npz`` (written atomically; its record
        goes to ``NAME.json``), or None. Neither may be one of the expert's own files.
    :param verbose: log a summary table of the episodes and where they were saved (INFO).
    :param force: replace an existing ``output`` and the record ``NAME.json`` beside it; without it
        either raises FileExistsError before any episode runs.
    :raises UserError: ``output`` does not end in ``.npz``, or it or its record would replace one of
        the expert's files or the folder's ``metadata.json`` (also with ``force``).
    """
    check_env_id(env_id)
    seed = check_seed(seed)
    if isinstance(n_episodes, bool) or int(n_episodes) < 1:
        raise UserError(f"n_episodes must be >= 1, got {n_episodes}")
    check_seed(seed + int(n_episodes) - 1)
    if output is not None:
        _check_demos_output(Path(output), force, expert)
    env = make_env(env_id, env_kwargs)  # kwargs the env does not take: one line, before any file
    try:
        policy, description = resolve_expert(expert, env)
        episodes = [run_episode(policy, env, seed + i) for i in range(int(n_episodes))]
    finally:
        env.close()
    demos = Demonstrations.from_episodes(episodes)
    if verbose:
        _log_summary(demos, f"{description} on {env_id}: {demos.n_episodes} episodes, {len(demos)} steps")
    if output is not None:
        # Two collect-demos to one pool: the first to save wins, the other fails (the check above ran
        # before either had saved). The lock is the folder's, as the folder's record is.
        folder = Path(output).parent
        folder.mkdir(parents=True, exist_ok=True)
        lock = lock_output(folder, f"another process is writing demos in {folder} (lock {folder / LOCK_FILE})")
        try:
            _check_demos_output(Path(output), force, expert)
            remove_stale_temporaries(folder)  # an earlier collect-demos killed while saving (kill -9)
            demos.save(output)
            _record_demos_provenance(Path(output), expert, description, env_id, demos, seed, env_kwargs)
        finally:
            unlock_output(folder, lock)
        if verbose:
            logger.info("saved %s (provenance in %s)", output, provenance_path(output))
    return demos


def _check_demos_output(output: Path, force: bool, expert: Any = None) -> None:
    """Refuse, before any episode runs, an ``output`` that is no ``.npz`` (its record ``NAME.json``
    could be the pool itself), or whose pool or record would be one of the ``expert``'s files or the
    folder's ``metadata.json`` (ValueError, with ``force`` too), and without ``force`` one that
    would replace a pool or a file beside it (FileExistsError)."""
    if output.suffix.lower() != ".npz":
        raise UserError(
            f"demo pool {output} must end in .npz: the pool is written as NAME.npz and its provenance as "
            "NAME.json beside it"
        )
    record = provenance_path(output)
    for what, path in (("the pool", output), ("the pool's provenance", record)):
        source = next((f for f in expert_files(expert) if same_file(path, f)), None)
        if source is not None:
            raise UserError(f"{what} {path} would replace the expert's file {source}; choose another -o")
    if record.name == FOLDER_METADATA:
        raise UserError(
            f"a pool named {output.name} would keep its provenance in {record}, the expert folder's own record; "
            "choose another name"
        )
    if force:
        return
    if output.exists():
        raise OutputExistsError(
            f"{output} already exists ({_describe_pool(output)}); pass --force to replace it, or choose another -o"
        )
    if record.exists():
        raise OutputExistsError(
            f"{record} already exists (the pool's provenance would be written there) and {output.name} does not; "
            "pass --force to replace it, or choose another -o"
        )


def _describe_pool(path: Path) -> str:
    """``"a demo pool of N episodes"`` when the file reads as one, else ``"not a readable demo pool"``."""
    try:
        with np.load(path, allow_pickle=False) as data:
            return f"a demo pool of {len(data['episode_lengths'])} episodes"
    except Exception:  # any damage: the file is still there and still not ours to replace
        return "not a readable demo pool"


def _expert_record(expert: Any) -> dict[str, Any]:
    """train-expert's ``metadata.json`` of an expert given as its folder or its zip ({} otherwise)."""
    if not isinstance(expert, (str, Path)) or not Path(expert).exists():
        return {}
    folder = Path(expert) if Path(expert).is_dir() else Path(expert).parent
    return read_json_or_empty(folder / FOLDER_METADATA)


def _record_demos_provenance(
    output: Path,
    expert: Any,
    description: str,
    env_id: str,
    demos: Demonstrations,
    seed: int,
    env_kwargs: dict[str, Any] | None,
) -> None:
    """Write the pool's provenance to ``NAME.json`` beside it, so a pool says which expert, command
    and seeds made it wherever it is kept, and drop a ``metadata.json`` record of an earlier pool
    of the same name, which the new pool replaced."""
    returns = _episode_returns(demos)
    record: dict[str, Any] = {
        "file": output.name,
        "expert": description,
        "env_id": env_id,
        "env_kwargs": jsonable(env_kwargs or {}),
        "episodes": demos.n_episodes,
        "steps": len(demos),
        "seeds": [int(seed), int(seed) + demos.n_episodes - 1],
        "mean_return": float(np.mean(returns)),
        "std_return": float(np.std(returns)),
        "mean_length": float(np.mean(demos.episode_lengths)),
        "command": command_line(),
    }
    # The step count of one of our experts, which further training changes: the pool came from this one.
    total = _expert_record(expert).get("total_timesteps")
    if total is not None:
        record["expert_total_timesteps"] = total
    write_json(provenance_path(output), {"demos": record, "versions": versions()})
    folder_meta = output.parent / FOLDER_METADATA
    if folder_meta.is_file():
        meta = read_json_or_empty(folder_meta)
        stale = meta.get("demos")
        if isinstance(stale, dict) and stale.get("file") == output.name:
            del meta["demos"]
            write_json(folder_meta, meta)
