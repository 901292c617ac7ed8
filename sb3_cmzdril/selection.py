"""Reward-free selection of a policy during training, without the true reward.

Fine-tuning can drift away from a near-expert behaviour-cloned start, or find the expert's behaviour
and lose it again, and the true reward is not available to an imitation learner to notice it. Two
signals are:

* :class:`LowestDisagreementPolicy` (for :class:`~sb3_cmzdril.cmzdril.CMZDRIL`): the ensemble's
  disagreement is low where the expert's data is dense. It watches the mean disagreement ``u`` of each
  training rollout (``CMZDRIL.rollout_disagreement``, computed by the rollout scorer for every reward
  mode) and keeps a copy of the policy that collected the rollout with the lowest one. Rollout ``k``
  is collected by the policy after ``k`` updates, so epoch ``k`` here is the same policy that the
  per-epoch evaluation calls epoch ``k``; epoch 0 is the behaviour-cloned start.
* :class:`LongestEpisodesPolicy` (any SB3 algorithm, meant for the off-policy
  :class:`~sb3_cmzdril.cmzdril_sac.CMZDRILSAC`): on a task that ends an episode when the agent fails (a
  fall), an expert's episodes run to the time limit. Every ``check_every`` steps it plays the policy
  deterministically from a fixed set of starts and keeps the policy whose episodes lasted longest,
  the latest on a tie (``tie_break="latest"``), or on a tie the one whose episodes' states the
  ensemble disagrees on least (``tie_break="lowest_u"``, for a model with an ensemble). It reads
  termination and the ensemble, never reward; on a task without failure terminations every check
  ties, and ``"latest"`` keeps the last policy. Where the expert itself ends its episodes (it reaches
  a goal before the time limit: BipedalWalker, MountainCar), a longer episode is no better one:
  ``episode_length="expert"`` keeps the check whose episodes last as long as the demonstrations'.

A third policy is made rather than chosen: :class:`AveragedPolicy` (for an on-policy learner such as
:class:`~sb3_cmzdril.cmzdril.CMZDRIL`) averages the policy weights after each update over the last
part of training, as stochastic weight averaging does (Izmailov et al., 2018; for deep RL, Nikishin et
al., 2018), so that the policy a run ends with depends less on where its last update happened to land.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, cast

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_cmzdril.data.demos import expert_never_terminates
from sb3_cmzdril.errors import UserError
from sb3_cmzdril.io import PathLike, atomic_path

#: How :class:`LongestEpisodesPolicy` chooses between checks whose episodes lasted equally long.
TIE_BREAKS: tuple[str, ...] = ("latest", "lowest_u")
#: Which episode length :class:`LongestEpisodesPolicy` prefers: the longest, or the expert's.
EPISODE_LENGTHS: tuple[str, ...] = ("longest", "expert")


def kept_check(history: Sequence[tuple[int, float, float]], tie_break: str = "latest",
               target_length: float | None = None) -> int:
    """The index in ``history`` of the check :class:`LongestEpisodesPolicy` keeps: the longest mean
    episode, or with a ``target_length`` the mean episode closest to it; among equally good ones the
    latest, or with ``tie_break="lowest_u"`` the lowest mean disagreement (the later on an exact tie,
    or where u is NaN).

    :param history: (training steps, mean episode length, mean disagreement) of each check, in order,
        as :attr:`LongestEpisodesPolicy.history` holds them.
    :raises UserError: an empty history or an unknown ``tie_break``.
    """
    if tie_break not in TIE_BREAKS:
        raise UserError(f"tie_break must be one of {list(TIE_BREAKS)}, got {tie_break!r}")
    if not history:
        raise UserError("no checks to choose from")
    best, best_length, best_u = 0, -float("inf"), float("nan")
    for index, (_, episode_length, u) in enumerate(history):
        length = episode_length if target_length is None else -abs(episode_length - target_length)
        tied_and_better = length == best_length and (tie_break == "latest" or not u > best_u)
        if length > best_length or tied_and_better:
            best, best_length, best_u = index, length, u
    return best


class _KeptWeights(BaseCallback):
    """What the selectors share: a CPU copy of the chosen policy's weights, loading it back, and
    saving the choice for a resumed run."""

    #: what :meth:`load` calls the file when it cannot read it
    _file_kind = "kept-policy"

    def __init__(self, verbose: int = 0) -> None:
        super().__init__(verbose)
        self.best_state: dict[str, th.Tensor] | None = None

    def _keep(self) -> None:
        # On the CPU: a copy per improvement should not hold accelerator memory.
        self.best_state = {k: v.detach().to("cpu", copy=True) for k, v in self.model.policy.state_dict().items()}

    def _on_step(self) -> bool:
        return True

    def apply(self, model: Any) -> None:
        """Load the kept weights into ``model.policy``."""
        if self.best_state is None:
            raise RuntimeError("no policy has been scored yet: nothing to select")
        model.policy.load_state_dict(self.best_state)

    def _choice(self) -> dict[str, Any]:
        """Besides the weights, what :meth:`save` writes: tensors (or dicts of them) only, so that
        loading needs no pickle."""
        raise NotImplementedError

    def kept(self) -> dict[str, Any]:
        """Which policy is kept and why, as JSON-ready numbers and lists (for a run's summary)."""
        raise NotImplementedError

    def _restore(self, blob: Mapping[str, Any]) -> None:
        """Take back what :meth:`_choice` gave; a KeyError or ValueError when the file lacks it."""
        raise NotImplementedError

    def save(self, path: PathLike) -> None:
        """Write the choice (weights and what led to them) atomically; nothing is written before a choice exists."""
        if self.best_state is None:
            return
        with atomic_path(path, suffix=".pt") as tmp:
            th.save({"state_dict": self.best_state, **self._choice()}, tmp)

    def load(self, path: PathLike) -> bool:
        """Restore a choice written by :meth:`save`, so that a resumed run continues the same search;
        False when there is no such file, a UserError naming it when it is damaged."""
        if not Path(path).is_file():
            return False
        try:
            blob = th.load(path, map_location="cpu", weights_only=True)
            state = blob["state_dict"]
            if not isinstance(state, dict):
                raise TypeError(f"state_dict is a {type(state).__name__}")
            self._restore(blob)
        except Exception as e:  # torch raises RuntimeError, OSError (errno 22), pickle errors... for damage
            raise UserError(
                f"{path} is truncated or not a {self._file_kind} file ({type(e).__name__}: {e}); delete it to "
                "resume without the earlier choice"
            ) from None
        self.best_state = state
        return True


class LowestDisagreementPolicy(_KeptWeights):
    """Keep the policy weights of the training rollout with the lowest mean disagreement.

    Use with :class:`~sb3_cmzdril.cmzdril.CMZDRIL` (any reward mode). After ``learn()``,
    :meth:`apply` loads the kept weights into a model; :meth:`save`/:meth:`load` persist the choice
    so a resumed run continues the same search.
    """

    _file_kind = "lowest-u policy"

    def __init__(self, verbose: int = 0) -> None:
        super().__init__(verbose)
        self.best_u = float("inf")
        self.best_epoch: int | None = None
        self._epoch = 0

    def _on_rollout_start(self) -> None:
        # The callback is for CMZDRIL (a PPO): on-policy, n_steps per env in each rollout.
        model = cast(OnPolicyAlgorithm, self.model)
        self._epoch = int(model.num_timesteps // (model.n_steps * model.n_envs))

    def _on_rollout_end(self) -> None:
        u = getattr(self.model, "rollout_disagreement", None)
        if u is None or not np.isfinite(u) or u >= self.best_u:
            return
        self.best_u, self.best_epoch = float(u), self._epoch
        self._keep()
        if self.verbose >= 1:
            print(f"[lowest u] epoch {self._epoch}: rollout disagreement {u:.4g}")

    def _choice(self) -> dict[str, th.Tensor]:
        return {"epoch": th.tensor(self.best_epoch), "u": th.tensor(self.best_u)}

    def kept(self) -> dict[str, float]:
        """The kept policy's epoch and its rollout's mean disagreement."""
        return {"epoch": int(self.best_epoch if self.best_epoch is not None else -1), "rollout_u": self.best_u}

    def _restore(self, blob: Mapping[str, th.Tensor]) -> None:
        self.best_epoch, self.best_u = int(blob["epoch"]), float(blob["u"])


class LongestEpisodesPolicy(_KeptWeights):
    """Keep the policy whose deterministic episodes from fixed starts last longest (on a tie, the
    latest or the one with the lowest disagreement).

    The policy is checked when training starts (the behaviour-cloned start), every ``check_every``
    steps and when training ends. Each check plays ``n_episodes`` episodes with
    ``predict(deterministic=True)`` on its own env, reset with ``seed`` before each check so that every
    check starts from the same states: the comparison between checks is paired. The episodes are not
    training data; they cost CPU time and env steps (:attr:`env_steps`) beside the training's.

    When the model has an ensemble (``model.ensemble.disagreement(obs, actions)``, as
    :class:`~sb3_cmzdril.cmzdril_sac.CMZDRILSAC`), each check also records the mean disagreement ``u`` over
    its episodes' states and the actions played there. Where every episode reaches the time limit
    (HalfCheetah's always do) length cannot tell a policy that runs from one that has stalled;
    ``tie_break="lowest_u"`` then prefers the policy whose states the ensemble knows best, the
    signal :class:`LowestDisagreementPolicy` uses. An exact tie in ``u`` too keeps the later policy.

    Length means failure only where the expert runs to the time limit. Where its demonstrations end
    earlier (its success ends the episode), a check that lasts longer reached the goal later or not at
    all: ``episode_length="expert"`` (the default with ``tie_break="lowest_u"``) then keeps the check
    whose mean episode length is closest to the mean length of the model's demonstrations
    (``model.demonstrations``), :attr:`target_length`, set when training starts. Where every
    demonstration lasts the env's time limit it keeps the longest, as ``"longest"`` does.

    After ``learn()``, :meth:`apply` loads the kept weights into a model. :meth:`save`/:meth:`load`
    persist the choice with the checks so far, so that a resumed run (``learn(...,
    reset_num_timesteps=False)`` after loading the model) neither repeats nor forgets a check.

    :param eval_env: env id (made with ``env_kwargs``) or a gymnasium Env with the observation and
        action spaces of the training env, without reward wrappers (the reward is not read).
    :param check_every: training steps between checks.
    :param n_episodes: episodes per check.
    :param seed: the reset seed of each check's first episode.
    :param env_kwargs: keyword arguments of ``gym.make`` when ``eval_env`` is an id.
    :param verbose: 1 prints each check.
    :param tie_break: ``"latest"`` or ``"lowest_u"`` (:data:`TIE_BREAKS`).
    :param episode_length: ``"longest"`` or ``"expert"`` (:data:`EPISODE_LENGTHS`, above); None:
        ``"expert"`` with ``tie_break="lowest_u"``, ``"longest"`` with ``"latest"``.
    """

    _file_kind = "longest-episodes policy"

    def __init__(
        self,
        eval_env: str | gym.Env,
        check_every: int = 10_000,
        n_episodes: int = 5,
        seed: int = 0,
        env_kwargs: Mapping[str, Any] | None = None,
        verbose: int = 0,
        tie_break: str = "latest",
        episode_length: str | None = None,
    ) -> None:
        super().__init__(verbose)
        for name, value in (("check_every", check_every), ("n_episodes", n_episodes)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise UserError(f"{name} must be a positive integer, got {value!r}")
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
            raise UserError(f"seed must be an integer, got {seed!r}")
        if tie_break not in TIE_BREAKS:
            raise UserError(f"tie_break must be one of {list(TIE_BREAKS)}, got {tie_break!r}")
        if episode_length is None:
            episode_length = "expert" if tie_break == "lowest_u" else "longest"
        if episode_length not in EPISODE_LENGTHS:
            raise UserError(f"episode_length must be one of {list(EPISODE_LENGTHS)}, got {episode_length!r}")
        if isinstance(eval_env, str):
            eval_env = gym.make(eval_env, **dict(env_kwargs or {}))
        elif env_kwargs:
            raise UserError("env_kwargs applies only to an env id; the env given is made already")
        self.check_every, self.n_episodes, self.seed = int(check_every), int(n_episodes), int(seed)
        self.tie_break, self.episode_length = tie_break, episode_length
        #: the mean episode length a check is kept for coming closest to; None: the longest is kept
        #: (``episode_length="expert"`` sets it when training starts, where the expert ends its episodes)
        self.target_length: float | None = None
        self.eval_env = DummyVecEnv([lambda: Monitor(eval_env)])
        self.best_length = -float("inf")
        self.best_timesteps: int | None = None
        #: the kept check's mean disagreement (NaN without an ensemble)
        self.best_u = float("nan")
        #: (training steps, mean episode length, mean disagreement or NaN) of every check
        self.history: list[tuple[int, float, float]] = []
        #: env steps the checks' episodes took
        self.env_steps = 0
        self._next_check = 0

    def _on_training_start(self) -> None:
        if self.tie_break == "lowest_u" and self._ensemble() is None:
            raise UserError(
                f"tie_break='lowest_u' needs a model with an ensemble; {type(self.model).__name__} has none"
            )
        if self.episode_length == "expert":
            demonstrations = getattr(self.model, "demonstrations", None)
            if demonstrations is None:
                raise UserError(f"episode_length='expert' reads the model's demonstrations; "
                                f"{type(self.model).__name__} has none")
            # Where the expert runs to the time limit no check lasts longer than it: the longest is the
            # closest, and keeping the longest says so without a float comparison.
            if not expert_never_terminates(demonstrations, self.eval_env):
                self.target_length = float(np.mean(demonstrations.episode_lengths))
        self._next_check = int(self.model.num_timesteps)
        self._check()

    def _ensemble(self) -> Any:
        ensemble = getattr(self.model, "ensemble", None)
        return ensemble if callable(getattr(ensemble, "disagreement", None)) else None

    def _on_step(self) -> bool:
        if self.model.num_timesteps >= self._next_check:
            self._check()
        return True

    def _on_training_end(self) -> None:
        self._check()

    def _check(self) -> None:
        timesteps = int(self.model.num_timesteps)
        self._next_check = timesteps + self.check_every
        # The end of one learn() and the start of the next (reset_num_timesteps=False) are one policy.
        if self.history and self.history[-1][0] == timesteps:
            return
        self.eval_env.seed(self.seed)
        ensemble = self._ensemble()
        played: tuple[list[Any], list[np.ndarray]] = ([], [])

        def record(local_vars: dict[str, Any], _globals: dict[str, Any]) -> None:
            # Called once per step of the single env, with the observation acted on and the action played.
            played[0].append(local_vars["observations"])
            played[1].append(np.asarray(local_vars["actions"]))

        _, lengths = evaluate_policy(self.model, self.eval_env, n_eval_episodes=self.n_episodes, deterministic=True,
                                     return_episode_rewards=True, callback=record if ensemble is not None else None)
        length = float(np.mean(lengths))
        self.env_steps += int(np.sum(lengths))
        u = float(np.mean(ensemble.disagreement(_stacked(played[0]), np.concatenate(played[1])))) \
            if ensemble is not None and played[0] else float("nan")
        self.history.append((timesteps, length, u))
        if kept_check(self.history, self.tie_break, self.target_length) == len(self.history) - 1:
            self.best_length, self.best_timesteps, self.best_u = length, timesteps, u
            self._keep()
        if self.verbose >= 1:
            print(f"[longest episodes] {timesteps} steps: mean episode length {length:.1f}, u {u:.4g} "
                  f"(kept: {self.best_timesteps} steps, {self.best_length:.1f})")

    def _choice(self) -> dict[str, th.Tensor]:
        return {
            "history": th.tensor(self.history, dtype=th.float64).reshape(-1, 3),
            "best_length": th.tensor(self.best_length, dtype=th.float64),
            "best_u": th.tensor(self.best_u, dtype=th.float64),
            "best_timesteps": th.tensor(self.best_timesteps, dtype=th.int64),
            "env_steps": th.tensor(self.env_steps, dtype=th.int64),
        }

    def kept(self) -> dict[str, Any]:
        """The kept policy's training steps, its checks' mean episode length and disagreement (NaN
        without an ensemble), the checks' env steps, and every check as ``[steps, mean length, mean
        u]`` (what :func:`kept_check` chooses from: the run's record of the other tie break's choice),
        and the target length (None: the longest)."""
        steps = -1 if self.best_timesteps is None else self.best_timesteps
        return {"timesteps": int(steps), "mean_length": self.best_length, "mean_u": self.best_u,
                "env_steps": int(self.env_steps), "checks": [list(check) for check in self.history],
                "target_length": self.target_length}

    def _restore(self, blob: Mapping[str, th.Tensor]) -> None:
        # Everything is read before anything is set: a file that lacks a part changes nothing. Files
        # written before u was recorded have two columns of history and no best_u: u is NaN there.
        rows = [[*row, float("nan")][:3] for row in blob["history"].tolist()]
        restored = ([(int(steps), float(length), float(u)) for steps, length, u in rows],
                    float(blob["best_length"]), int(blob["best_timesteps"]), int(blob["env_steps"]),
                    float(blob["best_u"]) if "best_u" in blob else float("nan"))
        self.history, self.best_length, self.best_timesteps, self.env_steps, self.best_u = restored

    def close(self) -> None:
        """Close the checks' env."""
        self.eval_env.close()


def _stacked(observations: list[Any]) -> Any:
    """One batch of per-step VecEnv observations (arrays, or dicts of arrays for a Dict space)."""
    if isinstance(observations[0], dict):
        return {k: np.concatenate([o[k] for o in observations]) for k in observations[0]}
    return np.concatenate(observations)


class AveragedPolicy(_KeptWeights):
    """The uniform average of the policy's weights after every update from ``start_timesteps`` on.

    For an on-policy learner (a rollout per update, as :class:`~sb3_cmzdril.cmzdril.CMZDRIL`): the
    weights are added at the start of each rollout whose policy has trained for at least
    ``start_timesteps`` steps, and once more when training ends (the last update's weights). Every
    floating-point tensor of the policy's state is averaged (in float64, cast back); the rest are
    the latest. :meth:`save`/:meth:`load` persist the running sum, so that a resumed run
    (``learn(..., reset_num_timesteps=False)`` after loading the model) adds each policy once.

    :param start_timesteps: the first training step count whose policy is averaged (0: the
        behaviour-cloned start too).
    """

    _file_kind = "policy-average"

    def __init__(self, start_timesteps: int, verbose: int = 0) -> None:
        super().__init__(verbose)
        if isinstance(start_timesteps, bool) or not isinstance(start_timesteps, (int, np.integer)) \
                or start_timesteps < 0:
            raise UserError(f"start_timesteps must be a non-negative integer, got {start_timesteps!r}")
        self.start_timesteps = int(start_timesteps)
        self.count = 0
        #: training steps of the first and the last policy averaged (-1 before the first)
        self.first_timesteps = self.last_timesteps = -1
        self._sum: dict[str, th.Tensor] = {}

    def _on_training_start(self) -> None:
        if not isinstance(self.model, OnPolicyAlgorithm):
            raise UserError(f"AveragedPolicy averages after each rollout's update: it needs an on-policy learner, "
                            f"not {type(self.model).__name__}")

    def _on_rollout_start(self) -> None:
        self._add()

    def _on_training_end(self) -> None:
        self._add()

    def _add(self) -> None:
        timesteps = int(self.model.num_timesteps)
        # A resumed run's first rollout starts from the step its checkpoint already added.
        if timesteps < self.start_timesteps or timesteps <= self.last_timesteps:
            return
        state = self.model.policy.state_dict()
        for k, v in state.items():
            if v.is_floating_point():
                v64 = v.detach().to("cpu", th.float64)
                self._sum[k] = v64.clone() if k not in self._sum else self._sum[k].add_(v64)
        self.count += 1
        self.first_timesteps = timesteps if self.first_timesteps < 0 else self.first_timesteps
        self.last_timesteps = timesteps
        self.best_state = {
            k: (self._sum[k] / self.count).to(v.dtype) if k in self._sum else v.detach().to("cpu", copy=True)
            for k, v in state.items()
        }
        if self.verbose >= 1:
            print(f"[averaged] {timesteps} steps: {self.count} policies averaged")

    def _choice(self) -> dict[str, Any]:
        return {
            "sum": self._sum,
            "count": th.tensor(self.count),
            "first_timesteps": th.tensor(self.first_timesteps),
            "last_timesteps": th.tensor(self.last_timesteps),
        }

    def kept(self) -> dict[str, float]:
        """How many policies were averaged, and the training steps of the first and the last."""
        return {"n_averaged": self.count, "first_timesteps": self.first_timesteps,
                "last_timesteps": self.last_timesteps}

    def _restore(self, blob: Mapping[str, Any]) -> None:
        total = blob["sum"]
        if not isinstance(total, dict):
            raise TypeError(f"sum is a {type(total).__name__}")
        self._sum, self.count = dict(total), int(blob["count"])
        self.first_timesteps, self.last_timesteps = int(blob["first_timesteps"]), int(blob["last_timesteps"])


__all__ = ["TIE_BREAKS", "AveragedPolicy", "LongestEpisodesPolicy", "LowestDisagreementPolicy", "kept_check"]
