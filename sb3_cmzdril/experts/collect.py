"""Recording demonstrations (``collect_demos``, the ``collect-demos`` command) and reading demo pools.

Episode ``i`` of a recording is reset with ``seed + i`` and played with deterministic expert
actions, so any episode can be replayed. A saved pool gets a ``demos`` record in the
``metadata.json`` beside it (which expert, command, seeds and returns made it). The summary table
and notes go to this module's logger (the CLI prints them).
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from sb3_cmzdril._mujoco_log import mujoco_warnings_routed
from sb3_cmzdril.console import RENDERABLE
from sb3_cmzdril.demos import Demonstrations
from sb3_cmzdril.errors import OutputExistsError, UserError
from sb3_cmzdril.experts.envs import check_env_id, check_seed
from sb3_cmzdril.experts.loading import resolve_expert
from sb3_cmzdril.io import (
    LOCK_FILE,
    PathLike,
    command_line,
    jsonable,
    lock_output,
    read_json,
    read_json_or_empty,
    unlock_output,
    versions,
    write_json,
)

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
    :param output: where to save the demonstrations (npz, written atomically), or None.
    :param verbose: log a summary table of the episodes and where they were saved (INFO).
    :param force: replace an existing ``output`` and the demos record of a ``metadata.json`` beside
        it that is not the expert's own; without it both raise FileExistsError before any episode runs.
    """
    check_env_id(env_id)
    seed = check_seed(seed)
    if isinstance(n_episodes, bool) or int(n_episodes) < 1:
        raise UserError(f"n_episodes must be >= 1, got {n_episodes}")
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
        _log_summary(demos, f"{description} on {env_id}: {demos.n_episodes} episodes, {len(demos)} steps")
    if output is not None:
        # Two collect-demos to one pool: the first to save wins, the other fails (the check above ran
        # before either had saved). The lock is the folder's, as metadata.json is.
        folder = Path(output).parent
        folder.mkdir(parents=True, exist_ok=True)
        lock = lock_output(folder, f"another process is writing demos in {folder} (lock {folder / LOCK_FILE})")
        try:
            if not force:
                _check_demos_output(Path(output), env_id, expert)
            demos.save(output)
            _record_demos_provenance(Path(output), description, env_id, demos, seed, env_kwargs)
        finally:
            unlock_output(folder, lock)
        if verbose:
            logger.info("saved %s (provenance in %s)", output, Path(output).parent / "metadata.json")
    return demos


def _check_demos_output(output: Path, env_id: str, expert: Any) -> None:
    """FileExistsError when saving to ``output`` would replace a demo pool or another pool's record.

    metadata.json beside the pool gets a ``demos`` section. That is only safe to add where the file
    has none and belongs to this very expert (train-expert's record in the expert's own folder).
    """
    if output.exists():
        raise OutputExistsError(
            f"{output} already exists ({_describe_pool(output)}); pass --force to replace it, or choose another -o"
        )
    meta_path = output.parent / "metadata.json"
    if not meta_path.is_file():
        return
    meta = read_json_or_empty(meta_path)
    recorded = meta.get("demos")
    if isinstance(recorded, dict):
        raise OutputExistsError(
            f"{meta_path} already records the demo pool {recorded.get('file')!r} of {recorded.get('expert')}; "
            f"saving {output.name} there would replace that record: pass --force, or choose another folder"
        )
    expert_folder = None
    if isinstance(expert, (str, Path)) and Path(expert).exists():
        expert_folder = Path(expert) if Path(expert).is_dir() else Path(expert).parent
    own = (expert_folder is not None and expert_folder.resolve() == output.parent.resolve()
           and meta.get("env_id") == env_id)
    if not own:
        maker = meta.get("expert") or meta.get("algo") or "something else"
        raise OutputExistsError(
            f"{meta_path} describes {maker} on {meta.get('env_id')}, "
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
    output: Path, description: str, env_id: str, demos: Demonstrations, seed: int, env_kwargs: dict[str, Any] | None
) -> None:
    """Add a ``demos`` section to the ``metadata.json`` beside the demos file (creating the file for
    a scripted expert), so a shipped pool says which expert, command and seeds made it."""
    meta_path = output.parent / "metadata.json"
    if meta_path.is_file():
        meta = read_json(meta_path)
    else:
        meta = {"env_id": env_id, "expert": description, "versions": versions()}
    returns = _episode_returns(demos)
    meta["demos"] = {
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
    if meta.get("total_timesteps") is not None:
        meta["demos"]["expert_total_timesteps"] = meta["total_timesteps"]
    write_json(meta_path, meta)
