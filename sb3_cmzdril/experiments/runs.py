"""One run of the paper's experiment: one env, one method, one trial seed.

A run is described by a :class:`~sb3_cmzdril.experiments.spec.RunSpec` (built and validated by
:func:`~sb3_cmzdril.experiments.spec.plan_run`) and executed here by :func:`run_experiment`, which
writes into its own folder (the files: :mod:`sb3_cmzdril.experiments.run_folder`).

Resuming: with ``done.json`` the run is skipped. With ``model.zip`` the run continues from that
checkpoint to the requested total (``learn(..., reset_num_timesteps=False)``). Evaluation rows
written after the checkpoint (by the interrupted process, for a policy that no longer exists) are
moved to ``eval.discarded.csv`` so that ``eval.csv`` describes one training trajectory; nothing is
deleted.

Methods (``METHODS``): ``bc`` (the NLL-pretrained policy, evaluated once at epoch 0) and the four
CMZDRIL reward modes ``zero``, ``env``, ``dril``, ``cmz``. Every method of a trial shares the network
seed, the env seed and the demonstration split, so their epoch-0 policies are identical.

This module stays the public path of the planning and run-folder names that users import from it
(``plan_run``, ``RunSpec``, ``read_eval_csv``, ``window_means``, ``METHODS``, the file names, ...).
"""
from __future__ import annotations

import contextlib
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from sb3_cmzdril.experiments.run_folder import (
    CONFIG_FILE,
    DISCARDED_CSV,
    DONE_FILE,
    ERROR_FILE,
    EVAL_CSV,
    FINAL_EVAL_COLUMNS,
    FINAL_EVAL_CSV,
    LOG_FILE,
    LOWEST_U_FILE,
    LOWEST_U_MODEL,
    MODEL_FILE,
    PRETRAIN_CSV,
    STATE_FILE,
    TABLE_WINDOW,
    VECNORMALIZE_FILE,
    RunState,
    check_finished,
    check_or_write_config,
    discard_rows_after,
    latest_epoch,
    locked,
    read_eval_csv,
    run_config,
    run_status,
    window_means,
    write_pretrain_csv,
)
from sb3_cmzdril.experiments.spec import (
    DEFAULT_CHECKPOINT_EVERY,
    DEFAULT_EVAL_EPISODES,
    EXPERIMENT_KEYS,
    FALLBACK_N_DEMOS,
    HYPERPARAMS_NAME,
    METHODS,
    RunSpec,
    check_method,
    default_demos_path,
    default_output_dir,
    load_run_hyperparams,
    make_training_env,
    missing_pool_error,
    plan_run,
    split_episodes,
    train_command,
)
from sb3_cmzdril.experts import check_env_id
from sb3_cmzdril.experts.callbacks import ProgressCallback
from sb3_cmzdril.io import PathLike, atomic_path, deferred_signals, remove_stale_temporaries, write_json


# -- one run -----------------------------------------------------------------------------------
def run_experiment(
    spec: RunSpec,
    *,
    progress_bar: bool = False,
    callbacks: Sequence[Any] = (),
    verbose: int = 0,
) -> dict[str, Any]:
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
    with locked(out):
        remove_stale_temporaries(out)
        return _run_locked(spec, out, progress_bar, list(callbacks), verbose)


def _run_locked(spec: RunSpec, out: Path, progress_bar: bool, callbacks: list[Any], verbose: int) -> dict[str, Any]:
    from sb3_cmzdril.algorithm import CMZDRIL
    from sb3_cmzdril.demos import Demonstrations
    from sb3_cmzdril.metrics import ExpertEvalCallback
    from sb3_cmzdril.selection import LowestDisagreementPolicy

    pool = Demonstrations.load(spec.demos)
    train_idx, eval_idx = split_episodes(pool.n_episodes, spec.n_demos, spec.n_eval_episodes, spec.seed)
    hp, _ = load_run_hyperparams(spec.hyperparams, spec.env_id)
    config = check_or_write_config(out, run_config(spec, hp, train_idx, eval_idx, pool))

    model_path, vecnorm_path, csv_path = out / MODEL_FILE, out / VECNORMALIZE_FILE, out / EVAL_CSV
    resume = spec.method != "bc" and model_path.is_file()
    kwargs = hp.model_kwargs()
    kwargs.setdefault("device", "cpu")  # small MLPs: the CPU beats a GPU's launch overheads
    if resume:
        venv = make_training_env(spec, hp, spec.seed, vecnorm_path)
        try:
            model = CMZDRIL.load(model_path, env=venv, device=kwargs["device"])
        except Exception as e:  # a zip is written atomically, so this is a foreign or damaged file
            venv.close()
            raise ValueError(f"cannot resume from {model_path}: {type(e).__name__}: {e}") from e
        start = int(model.num_timesteps)
        # Seeds of a resumed segment (networks' sampling and the env, which set_random_seed also
        # seeds) are offset by its start, so it does not replay the first segment's noise.
        model.set_random_seed(spec.seed + start)
        discarded = discard_rows_after(csv_path, start)
    else:
        start = 0
        venv = make_training_env(spec, hp, spec.seed, None)
        if spec.method == "bc":
            # The ensemble is not used by BC; one epoch (the minimum) instead of hundreds. It is fitted
            # after the policy's NLL pretraining, so the BC policy equals the other methods' epoch 0.
            kwargs["ensemble_epochs"] = 1
        reward = "zero" if spec.method == "bc" else spec.method
        model = CMZDRIL(
            hp.policy or "MlpPolicy", venv, demonstrations=pool.select(train_idx), reward=reward, seed=spec.seed,
            verbose=verbose, **kwargs,
        )
        discarded = discard_rows_after(csv_path, -1)  # rows of an attempt that died before its first checkpoint
    model.set_logger(_segment_logger(out, start, verbose))
    state = RunState(out, spec, start)
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
        # The checkpoint's files belong together: Ctrl-C or SIGTERM waits until all are written.
        with deferred_signals():
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
            write_pretrain_csv(out / PRETRAIN_CSV, model.pretrain_history)
        else:
            checkpoint_cb = _checkpoint_callback_class()(save, spec.checkpoint_every)
            progress_cb = ProgressCallback(spec.timesteps, show=progress_bar)
            model.learn(
                max(spec.timesteps - start, 0),
                callback=[eval_cb, selector, checkpoint_cb, progress_cb, *callbacks],
                reset_num_timesteps=not resume,
            )
            if not resume:
                write_pretrain_csv(out / PRETRAIN_CSV, model.pretrain_history)
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


def _final_evaluation(spec: RunSpec, model, pool, train_idx: list[int], hp, selector, out: Path) -> dict[str, Any]:
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
    results: dict[str, Any] = {"episodes": episodes}
    rows = [",".join(FINAL_EVAL_COLUMNS)]
    final_state = {k: v.detach().clone() for k, v in model.policy.state_dict().items()}
    try:
        for name, source in policies.items():
            if source is not None:
                source.apply(model)
                with atomic_path(out / LOWEST_U_MODEL, suffix=".zip") as tmp:
                    model.save(tmp)
            ev = evaluate_against_expert(
                model, spec.env_id, held_out, env_kwargs=hp.env_kwargs, start_mismatch="ignore"
            )
            summary = ev.summary()
            if source is not None:
                summary.update(epoch=int(source.best_epoch), rollout_u=float(source.best_u))
            results[name] = summary
            for j, episode in enumerate(episodes):
                rows.append(
                    ",".join(
                        str(v)
                        for v in (
                            name,
                            episode,
                            int(ev.seeds[j]),
                            f"{ev.returns[j]:.6g}",
                            int(ev.lengths[j]),
                            f"{ev.frechet[j]:.6g}",
                            f"{ev.episode_action_mse[j]:.6g}",
                            f"{ev.expert_returns[j]:.6g}",
                        )
                    )
                )
    finally:
        model.policy.load_state_dict(final_state)
    with atomic_path(out / FINAL_EVAL_CSV) as tmp:
        tmp.write_text("\n".join(rows) + "\n")
    return results


def _summary(spec: RunSpec, model, config: Mapping[str, Any], state: RunState, csv_path: Path) -> dict[str, Any]:
    columns = read_eval_csv(csv_path)
    integral = ("epoch", "timesteps", "n_episodes")
    last = (
        {c: (int(v[-1]) if c in integral else float(v[-1])) for c, v in columns.items()}
        if columns["epoch"].size
        else {}
    )
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
    env_kwargs: Mapping[str, Any] | None = None,
    vecnormalize: PathLike | None = None,
) -> tuple[Any, Any | None]:
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
        raise ValueError(
            f"VecNormalize statistics {vecnormalize} are damaged or not VecNormalize's: {type(e).__name__}: {e}"
        ) from None
    stats.training = False
    return model, stats.normalize_obs


# -- building blocks --------------------------------------------------------------------------------
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


# The names under which the tests reach these helpers, from before they moved to run_folder.
_config = run_config
_discard_rows_after = discard_rows_after

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
    "load_evaluation_model",
    "load_run_hyperparams",
    "missing_pool_error",
    # Settings and file names, defined in spec and run_folder, importable from here as before.
    "DEFAULT_CHECKPOINT_EVERY",
    "DEFAULT_EVAL_EPISODES",
    "EXPERIMENT_KEYS",
    "FALLBACK_N_DEMOS",
    "HYPERPARAMS_NAME",
    "TABLE_WINDOW",
    "CONFIG_FILE",
    "DISCARDED_CSV",
    "DONE_FILE",
    "ERROR_FILE",
    "EVAL_CSV",
    "FINAL_EVAL_COLUMNS",
    "FINAL_EVAL_CSV",
    "LOG_FILE",
    "LOWEST_U_FILE",
    "LOWEST_U_MODEL",
    "MODEL_FILE",
    "PRETRAIN_CSV",
    "STATE_FILE",
    "VECNORMALIZE_FILE",
]
