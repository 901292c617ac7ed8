"""One run of the paper's experiment: one env, one method, one trial seed.

A run is resolved once into a :class:`~sb3_cmzdril.training.spec.ResolvedRun` (every input read and
checked before a file is written, the env and model the checks build kept:
:func:`~sb3_cmzdril.training.spec.prepare_run`; a :class:`~sb3_cmzdril.training.spec.RunSpec` planned
by :func:`~sb3_cmzdril.training.spec.plan_run` for another process is resolved where it runs) and
executed here by :func:`run_experiment`, top to bottom: its
:class:`~sb3_cmzdril.training.run_folder.RunFolder` opened (the folder owns every file), the model the
checks built trained (or the checkpoint resumed), evaluated on the held-out episodes, done.json written.

Methods are entries of :data:`~sb3_cmzdril.training.methods.METHOD_REGISTRY`: the run asks its entry
(``run.method``: the learner, the reward, what it keeps), never compares names.

Resuming: with ``done.json`` the run is skipped. With ``model.zip`` the run continues from that
checkpoint to the requested total (``learn(..., reset_num_timesteps=False)``), once every file of the
checkpoint is found as state.json (written last) records it (``RunFolder.check_resumable``). Evaluation rows
written after the checkpoint (by the interrupted process, for a policy that no longer exists) are
moved to ``eval.discarded.csv`` so that ``eval.csv`` describes one training trajectory; nothing is
deleted.

Methods (``METHODS``): ``bc`` (the NLL-pretrained policy, evaluated once at epoch 0), the four
CMZDRIL reward modes ``zero``, ``env``, ``dril``, ``cmz``, and ``cmz-sac``: CMZ-DRIL's reward with the
off-policy learner CMZDRILSAC, whose epoch is ``OFFPOLICY_EPOCH_STEPS`` env steps and whose checkpoint
holds its replay buffer too (``dril-sac``, ``zero-sac`` and ``env-sac``: the same learner with the
other reward modes). Every method of a trial shares the env seed and the demonstration split;
the PPO methods share the network seed's initial weights too, so their epoch-0 policies are identical.

This module stays the public path of the planning and run-folder names that users import from it
(``plan_run``, ``RunSpec``, ``read_eval_csv``, ``window_means``, ``METHODS``, the file names, ...).
"""
from __future__ import annotations

import functools
import logging
import math
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from sb3_cmzdril.errors import MissingFileError, UserError
from sb3_cmzdril.experts import check_env_id
from sb3_cmzdril.experts.callbacks import ProgressCallback
from sb3_cmzdril.io import PathLike, portable_path
from sb3_cmzdril.training.methods import LEARNERS
from sb3_cmzdril.training.run_folder import (
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
    RunFolder,
    RunState,
    check_finished,
    discard_rows_after,
    latest_epoch,
    read_eval_csv,
    run_status,
    window_means,
)
from sb3_cmzdril.training.spec import (
    DEFAULT_CHECKPOINT_EVERY,
    DEFAULT_EVAL_EPISODES,
    EXPERIMENT_KEYS,
    FALLBACK_N_DEMOS,
    HYPERPARAMS_NAME,
    METHODS,
    OFFPOLICY_EPOCH_STEPS,
    ResolvedRun,
    RunSpec,
    build_model,
    check_method,
    default_demos_path,
    default_output_dir,
    load_run_hyperparams,
    make_training_env,
    missing_pool_error,
    plan_run,
    resolve_run,
    split_episodes,
    train_command,
)

logger = logging.getLogger(__name__)


# -- one run -----------------------------------------------------------------------------------
def run_experiment(
    run: RunSpec | ResolvedRun,
    *,
    progress_bar: bool = False,
    callbacks: Sequence[Any] = (),
    verbose: int = 0,
) -> dict[str, Any]:
    """Execute (or resume, or skip) one run; returns its summary with a ``status`` entry.

    ``run`` is resolved already (:func:`~sb3_cmzdril.training.spec.prepare_run`: the ``train``
    command), or a spec planned elsewhere (a grid's worker), resolved here once
    (:func:`~sb3_cmzdril.training.spec.resolve_run`). ``status`` is ``"skipped"`` (done.json was
    there: its content is returned), ``"done"`` (the summary just written to done.json) or
    ``"stopped"`` (a callback ended training early: no done.json, the checkpoint allows resuming).
    Exceptions propagate; the last checkpoint stays. Whatever the resolution or the folder refuses
    is refused before a file is written. A new run trains the model its checks built.

    :param callbacks: extra SB3 callbacks for the PPO training (not used by ``bc``).
    """
    if not isinstance(run, ResolvedRun):
        run = resolve_run(run, keep=True, verbose=verbose)  # every input read and checked, once
    return execute_run(run, progress_bar=progress_bar, callbacks=callbacks, verbose=verbose)


def execute_run(
    run: ResolvedRun,
    *,
    progress_bar: bool = False,
    callbacks: Sequence[Any] = (),
    verbose: int = 0,
) -> dict[str, Any]:
    """:func:`run_experiment` of a run resolved already (the ``train`` command's, by
    :func:`~sb3_cmzdril.training.spec.prepare_run`): executed, resumed or skipped, the same summary."""
    try:
        return _execute(run, progress_bar=progress_bar, callbacks=list(callbacks), verbose=verbose)
    finally:
        run.built.close()  # what the run did not take: a finished run's, say


def _execute(run: ResolvedRun, *, progress_bar: bool, callbacks: list[Any], verbose: int) -> dict[str, Any]:
    folder = RunFolder(run)
    done = folder.finished()  # refuses a folder that holds someone's files or another run
    if done is not None:
        return {**done, "status": "skipped"}
    note = published_versions_note(folder.fresh_config)
    if note:
        logger.warning("%s", note)
    folder.check_resumable()
    # Read before folder.open() writes config.json: a damaged lowest_u.pt refuses with the folder untouched.
    kept = _kept_policies(run, folder, folder.resumable)
    _warn_of_device(run)
    with folder.open():  # created and locked; config.json written, or matched with the run there
        resume = folder.resumable
        model, venv, start = _resume(run, folder) if resume else _new_model(run, verbose)
        discarded = discard_rows_after(folder.eval_csv, start if resume else -1)
        state = RunState(folder.path, run.spec, start, device=str(model.device))
        tensorboard = folder.tensorboard_dir(state)
        if tensorboard is not None:
            state.data["segments"][-1]["tensorboard"] = str(tensorboard)
        model.set_logger(folder.segment_logger(start, verbose, tensorboard))
        if discarded:
            state.data["segments"][-1]["discarded_eval_rows"] = discarded
        eval_cb = _eval_callback(run, folder, verbose)
        try:
            _train(run, folder, model, state, eval_cb, kept, callbacks, start=start, resume=resume,
                   progress_bar=progress_bar)
            folder.record_rules(model.rules)  # a run that ends before its first checkpoint has them too
            finished = model.num_timesteps >= run.spec.timesteps
            final = _final_evaluation(run, folder, model, kept) if finished else None
        finally:
            eval_cb.close()
            for selector in kept.values():
                if hasattr(selector, "close"):  # the longest-episodes checks' own env
                    selector.close()
            venv.close()
            model.logger.close()  # the progress CSV and TensorBoard's events flushed
        if not finished:
            return {"status": "stopped", "num_timesteps": int(model.num_timesteps), "run_dir": str(folder.path)}
        state.write(model.num_timesteps)
        return folder.finish({**_summary(run, model, folder, state), "final_evaluation": final})


def published_versions_note(config: Mapping[str, Any]) -> str | None:
    """A line saying that a run's packages differ from those the published records were made with, where
    it trains on a published demo pool (``config``: its config.json's content): its numbers then need not
    repeat theirs; None where nothing differs or there is nothing published to compare with."""
    from sb3_cmzdril.shipped import constraints_advice, published_differences

    differ = published_differences(config["demos_sha256"], config["versions"])
    if not differ:
        return None
    return (f"note: {', '.join(differ)}: the published records were made with other versions, so this run's "
            f"numbers may differ from theirs; {constraints_advice()}")


def _warn_of_device(run: ResolvedRun) -> None:
    """A warning line where the model will not run on the device its hyperparameters ask for (SB3 falls
    back to the CPU without a word where CUDA is missing); config.json and state.json record the one used."""
    asked = str(run.model_kwargs()["device"])
    if asked != "auto" and asked.split(":")[0] != run.device.split(":")[0]:
        logger.warning("hyperparameters %r in %s ask for device %r, which this machine does not have: the run uses "
                       "%r (recorded in config.json)", run.hp.key, run.spec.hyperparams, asked, run.device)


def _new_model(run: ResolvedRun, verbose: int) -> tuple[Any, Any, int]:
    """(model, its training env, 0): the fresh model the run's checks built, else one built now."""
    venv, model = run.built.take() or build_model(run, verbose)
    return model, venv, 0


def _resume(run: ResolvedRun, folder: RunFolder) -> tuple[Any, Any, int]:
    """(model, its training env, its step count): the run's checkpoint, to train on from where it stopped,
    in the envs the run's checks made where they made them."""
    built = run.built.take()  # the checks' model is new: the checkpoint's replaces it
    venv = make_training_env(run.spec, run.hp, run.spec.seed, folder.vecnormalize, built[0] if built else None)
    source = folder.model
    try:
        model = run.learner.load(source, env=venv, device=run.model_kwargs()["device"])
        if run.method.off_policy:
            source = folder.replay_buffer
            model.load_replay_buffer(source)
    except Exception as e:  # files are written atomically, so this is a foreign or damaged one
        venv.close()
        raise UserError(f"cannot resume from {source}: {type(e).__name__}: {e}") from e
    start = int(model.num_timesteps)
    # Seeds of a resumed segment (networks' sampling and the env, which set_random_seed also
    # seeds) are offset by its start, so it does not replay the first segment's noise.
    model.set_random_seed(run.spec.seed + start)
    return model, venv, start


#: The longest-episodes checks (an off-policy run's, or a PPO run's with ``keep_longest``): episodes per
#: check, and the first reset seed of trial 0's (trial t: + 100 t); no pool episode of the shipped pools
#: starts from these seeds.
LONGEST_CHECK_EPISODES, LONGEST_CHECK_SEED = 5, 100_000


def _kept_policies(run: ResolvedRun, folder: RunFolder, resume: bool) -> dict[str, Any]:
    """The policies a run keeps beside its last weights (final_eval.csv's name -> selector), continued
    from the checkpoint's: its learner's reward-free choice (:attr:`~.methods.Learner.kept`), the
    lowest-disagreement rollout's policy for CMZDRIL or the policy with the longest episodes for
    CMZDRILSAC, whose rollouts are single steps; for CMZDRIL with ``keep_longest`` in the
    hyperparameters, the longest-episodes choice beside its own; and, with ``average_from``, the average
    of the policies after every update from that fraction of the run's steps on. The longest-episodes
    checks come every ``eval_every`` epochs."""
    from sb3_cmzdril.selection import AveragedPolicy, LowestDisagreementPolicy

    choices: dict[str, Callable[[], Any]] = {
        "lowest_u": LowestDisagreementPolicy, "longest": functools.partial(_longest_policy, run, run.epoch),
    }
    kept: dict[str, Any] = {run.method.learner.kept: choices[run.method.learner.kept]()}
    trains = not run.method.pretrain_only
    if trains and run.settings.get("keep_longest"):  # PPO methods only (spec.py refuses cmz-sac)
        kept["longest"] = choices["longest"]()
    average_from = run.settings.get("average_from")
    if average_from is not None and trains:
        kept["averaged"] = AveragedPolicy(math.ceil(average_from * run.spec.timesteps))
    if resume:
        for name, selector in kept.items():
            selector.load(folder.kept_file(name))
    return kept


def _longest_policy(run: ResolvedRun, epoch: int) -> Any:
    """The run's longest-episodes choice, checked every ``eval_every`` epochs of ``epoch`` env steps."""
    from sb3_cmzdril.selection import LongestEpisodesPolicy

    return LongestEpisodesPolicy(
        run.spec.env_id, check_every=run.spec.eval_every * epoch, n_episodes=LONGEST_CHECK_EPISODES,
        seed=LONGEST_CHECK_SEED + 100 * run.spec.seed, env_kwargs=run.hp.env_kwargs,
        tie_break=run.settings.get("longest_tie_break", "latest"), episode_length=run.settings.get("episode_length"),
    )


def _eval_callback(run: ResolvedRun, folder: RunFolder, verbose: int) -> Any:
    """eval.csv's rows: the policy against the held-out expert episodes every ``eval_every`` epochs."""
    from sb3_cmzdril.metrics import ExpertEvalCallback

    return ExpertEvalCallback(
        run.spec.env_id, run.pool.select(run.eval_idx), eval_every=run.spec.eval_every, csv_path=folder.eval_csv,
        env_kwargs=run.hp.env_kwargs, verbose=verbose,
        # an off-policy epoch is a length of steps; a PPO one its rollout, which the callback reads off the model
        steps_per_epoch=run.epoch if run.method.off_policy else None,
    )


def _train(
    run: ResolvedRun, folder: RunFolder, model: Any, state: RunState, eval_cb: Any, kept: dict[str, Any],
    callbacks: list[Any], *, start: int, resume: bool, progress_bar: bool,
) -> None:
    """Pretrain (BC to convergence, the ensemble fit), then PPO or SAC from step ``start`` to the run's
    ``timesteps``, checkpointing into the folder; BC stops after pretraining."""
    spec = run.spec
    # Pretraining takes seconds to minutes: show it.
    model.pretrain(progress_bar=progress_bar)
    # Written now, not after PPO: a run stopped before its first segment ends must still have it. A
    # resumed model carries its history in the checkpoint, for a folder whose pretrain.csv is missing.
    if model.pretrain_history and (not resume or not folder.has_pretrain()):
        folder.write_pretrain(model.pretrain_history)
    if run.method.pretrain_only:
        # learn(0): pretraining, then the callback's end-of-training evaluation at epoch 0.
        model.learn(0, callback=[eval_cb])
        folder.checkpoint(model, {}, state)  # the BC policy itself, for `sb3-cmzdril evaluate`
        return
    checkpoint_cb = _checkpoint_callback_class()(
        lambda m: folder.checkpoint(m, kept, state), spec.checkpoint_every, run.epoch
    )
    progress_cb = ProgressCallback(spec.timesteps, show=progress_bar)
    model.learn(
        max(spec.timesteps - start, 0),
        # The kept policies before the checkpoint: a checkpoint at a rollout's start holds what they took there.
        callback=[eval_cb, *kept.values(), checkpoint_cb, progress_cb, *callbacks],
        reset_num_timesteps=not resume,
    )


def _final_evaluation(run: ResolvedRun, folder: RunFolder, model: Any, kept: dict[str, Any]) -> dict[str, Any]:
    """Replay every pool episode not used for training with the final policy and, for the RL
    methods, the kept ones (the reward-free choice: lowest u, or longest episodes; the averaged
    policy where asked); write final_eval.csv (one row per policy and episode) and each kept policy's
    model zip; return the summaries for done.json.

    Five episodes per evaluation cannot tell methods apart on HalfCheetah (one BC policy scored 188
    on one machine and 242 on another); the whole rest of the pool can.
    """
    from sb3_cmzdril.metrics import evaluate_against_expert

    episodes = run.held_out
    held_out = run.pool.select(episodes)
    policies: dict[str, Any] = {"final": None}
    if not run.method.pretrain_only:
        policies.update((name, selector) for name, selector in kept.items() if selector.best_state is not None)
    results: dict[str, Any] = {"episodes": episodes}
    rows = []
    final_state = {k: v.detach().clone() for k, v in model.policy.state_dict().items()}
    try:
        for name, source in policies.items():
            if source is not None:
                source.apply(model)
                folder.save_kept_model(model, name)
            ev = evaluate_against_expert(
                model, run.spec.env_id, held_out, env_kwargs=run.hp.env_kwargs, start_mismatch="ignore"
            )
            summary = ev.summary()
            if source is not None:
                summary.update(source.kept())
                if "timesteps" in summary:  # a choice by steps gets the epoch the tables show too
                    summary["epoch"] = eval_epoch(int(summary["timesteps"]), run.epoch)
            results[name] = summary
            rows += final_eval_rows(name, episodes, ev)
    finally:
        model.policy.load_state_dict(final_state)
    folder.write_final_evaluation(rows)
    return results


def eval_epoch(timesteps: int, steps_per_epoch: int) -> int:
    """The epoch eval.csv gives the policy after ``timesteps`` steps: each epoch's first step is that
    epoch's row, and a run that ends inside an epoch evaluates that epoch's end as the epoch it was in
    (:class:`~sb3_cmzdril.metrics.ExpertEvalCallback`), hence the count rounded up."""
    return -(-int(timesteps) // int(steps_per_epoch)) if timesteps >= 0 else int(timesteps)


def final_eval_rows(policy: str, episodes: Sequence[int], ev: Any) -> list[str]:
    """final_eval.csv's lines (columns ``FINAL_EVAL_COLUMNS``) for one policy's
    :class:`~sb3_cmzdril.metrics.evaluation.ExpertEvaluation` of the pool ``episodes``."""
    return [
        ",".join(
            str(v)
            for v in (
                policy,
                episode,
                int(ev.seeds[j]),
                f"{ev.returns[j]:.6g}",
                int(ev.lengths[j]),
                f"{ev.frechet[j]:.6g}",
                f"{ev.episode_action_mse[j]:.6g}",
                f"{ev.expert_returns[j]:.6g}",
            )
        )
        for j, episode in enumerate(episodes)
    ]


def _summary(run: ResolvedRun, model: Any, folder: RunFolder, state: RunState) -> dict[str, Any]:
    spec = run.spec
    columns = read_eval_csv(folder.eval_csv)
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
        "train_episodes": folder.config["train_episodes"],
        "eval_episodes": folder.config["eval_episodes"],
        "num_timesteps": int(model.num_timesteps),
        "requested_timesteps": spec.timesteps,
        "epochs": int(model.num_timesteps // run.epoch),
        "n_evaluations": int(columns["epoch"].size),
        "last_evaluation": last,
        # What Table I takes from this run (the report recomputes it from eval.csv).
        "final_window": {"window_epochs": TABLE_WINDOW, **window_means(columns)},
        "pretrain": dict(model.pretrain_info),
        "dril_threshold": model.dril_threshold,
        # what each "auto" setting was decided to be, and why (the learner's rules)
        "rules": dict(model.rules),
        "wall_time_s": round(state.wall_time(), 2),
        "cpu_time_s": round(state.cpu_time(), 2),
        "segments": len(state.data["segments"]),
        # the CPU models its segments ran on (state.json has each segment's), for cpu_time_s's sake
        "cpus": sorted({str(seg["machine"]["cpu"]) for seg in state.data["segments"] if "machine" in seg}),
        "finished_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "run_dir": portable_path(spec.output_dir),
    }


def load_evaluation_model(
    path: PathLike,
    env_id: str,
    env_kwargs: Mapping[str, Any] | None = None,
    vecnormalize: PathLike | None = None,
) -> tuple[Any, Any | None]:
    """``(model, observation transform or None)`` for :func:`~sb3_cmzdril.metrics.evaluate_against_expert`.

    A CMZDRIL or CMZDRILSAC zip, else any SB3 model (an expert, a plain PPO). With ``vecnormalize``
    (statistics saved beside a run's model.zip) the transform normalises observations as the policy saw them.
    """
    from sb3_cmzdril.experts import load_expert_model

    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"model file not found: {path}")
    model = None
    for learner in (learned.classes()[0] for learned in LEARNERS):
        try:
            model = learner.load(path, device="cpu")
            break
        except Exception:  # not this learner's zip: the next one's, or some other SB3 algorithm's
            continue
    if model is None:  # load_expert_model identifies the SB3 algorithm
        model = load_expert_model(path)
    _check_model_fits_env(model, path, env_id, env_kwargs)
    if vecnormalize is None:
        if getattr(model, "vecnormalize_obs", False):
            raise UserError(
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
        raise UserError(
            f"VecNormalize statistics {vecnormalize} are damaged or not VecNormalize's: {type(e).__name__}: {e}"
        ) from None
    stats.training = False
    return model, stats.normalize_obs


def _describe_space(space: Any) -> str:
    """A space as the mismatch message shows it: its kind and shape (Discrete: its n)."""
    from gymnasium import spaces

    if isinstance(space, spaces.Discrete):
        return f"Discrete({int(space.n)})"
    return f"{type(space).__name__} of shape {tuple(space.shape) if space.shape is not None else ()}"


def _check_model_fits_env(model: Any, path: Path, env_id: str, env_kwargs: Mapping[str, Any] | None) -> None:
    """UserError naming the model file when it was trained on other spaces than ``env_id`` has.

    Checked before anything else is compared with the model (a demo pool, VecNormalize statistics),
    so that the message blames the model and the env, not whatever is compared next.
    """
    from sb3_cmzdril.metrics.evaluation import make_env

    env = make_env(env_id, env_kwargs)
    try:
        wanted = {"observation": env.observation_space, "action": env.action_space}
    finally:
        env.close()
    for what, space in wanted.items():
        trained = getattr(model, f"{what}_space", None)
        if trained is None:  # a scripted expert has no spaces of its own
            continue
        if type(trained) is not type(space) or _describe_space(trained) != _describe_space(space):
            raise UserError(
                f"{path} was trained on another environment: its {what} space is {_describe_space(trained)}, "
                f"{env_id}'s is {_describe_space(space)}; pass the --env it was trained on"
            )


# -- building blocks --------------------------------------------------------------------------------
def _checkpoint_callback_class():
    from stable_baselines3.common.callbacks import BaseCallback

    class CheckpointCallback(BaseCallback):
        """model.zip (and VecNormalize stats) every ``every`` PPO updates and at the end, then state.json.

        It saves at the start of a rollout, after the ExpertEvalCallback listed before it has
        evaluated the same policy, so an eval row and the checkpoint at that step always agree. An
        off-policy epoch spans many rollouts: the first of it saves.
        """

        def __init__(self, save: Any, every: int, steps_per_update: int) -> None:
            super().__init__()
            self.save = save
            self.every = int(every)
            self.steps_per_update = int(steps_per_update)
            self._last = -1
            self._last_epoch = -1

        def _on_training_start(self) -> None:
            # A resumed run starts at its checkpoint's epoch: that one is saved already.
            self._last_epoch = self.model.num_timesteps // self.steps_per_update

        def _on_rollout_start(self) -> None:
            epoch = self.model.num_timesteps // self.steps_per_update
            if epoch > 0 and epoch % self.every == 0 and epoch != self._last_epoch:
                self._last_epoch = epoch
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
_discard_rows_after = discard_rows_after

__all__ = [
    "METHODS",
    "RunSpec",
    "plan_run",
    "run_experiment",
    "execute_run",
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
    "OFFPOLICY_EPOCH_STEPS",
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
