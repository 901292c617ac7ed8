"""Reward rules (pure numpy, with per-env state) and the VecEnvWrapper that applies one.

A rule maps the disagreement ``u`` of each env at one step (and the true env reward, for the rules
that need it) to the reward the agent trains on:

* :class:`CMZReward` (the paper): ``r_i = -alpha * (u_i - ubar_i)``, then
  ``ubar_{i+1} = ema * ubar_i + (1 - ema) * u_i``, with ``ubar_0 = u0``. ``ubar`` is kept per env of
  the VecEnv and carries across episode boundaries: the point is a long-run mean of zero, so that
  ending an episode early is not a way to escape negative reward.
* :class:`DRILReward`: ``+1`` if ``u_i <= threshold`` else ``-1`` (DRIL's clipped cost).
* :class:`ZeroReward` and :class:`EnvReward`: the paper's "no reward" and "environment reward"
  comparisons, sharing everything else with CMZ-DRIL.

:class:`DisagreementReward` computes ``u`` on the observation each env acted on (as DRIL's code
does), replaces the reward with the rule's, and keeps the true one in ``info["env_reward"]``.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Protocol, cast

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvObs, VecEnvStepReturn

from sb3_cmzdril.data.demos import Demonstrations, expert_never_terminates
from sb3_cmzdril.errors import UserError


class DisagreementModel(Protocol):
    """Anything that scores observations (and optionally actions) with a disagreement per row."""

    def disagreement(self, obs: np.ndarray, actions: np.ndarray | None = None) -> np.ndarray: ...


class RewardRule:
    """Base class: a stateless rule; subclasses with per-env state override the state methods."""

    #: the name used by ``CMZDRIL(reward=...)`` and the command line
    name = "base"
    #: the absorbing state's disagreement: the highest u this rule has scored (0 before any). It is
    #: the rule's, not its caller's, so that per-step and whole-rollout scoring share one running
    #: maximum and a saved model keeps it with the rest of the rule's state.
    absorbing_u: float = 0.0

    def __call__(self, u: np.ndarray, env_rewards: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def sequence(self, u: np.ndarray, env_rewards: np.ndarray) -> np.ndarray:
        """Rewards of T consecutive steps at once: ``u``, ``env_rewards`` and the result are
        (T, n_envs); the same as T calls of the rule, state included."""
        return (
            np.stack([self(u_t, r_t) for u_t, r_t in zip(u, env_rewards, strict=True)])
            if len(u)
            else np.zeros(u.shape, np.float32)
        )

    def absorbing(self, u_absorbing: np.ndarray, u: np.ndarray, rewards: np.ndarray) -> np.ndarray:
        """The reward each step would have had at disagreement ``u_absorbing`` (broadcast to ``u``)
        instead of its own ``u``, given ``rewards``, what the rule gave for ``u``: the per-step
        reward of the absorbing state a terminated episode enters (``CMZDRIL(absorbing=...)``)."""
        raise NotImplementedError(f"{type(self).__name__} has no absorbing-state reward")

    def replayed(self, u: np.ndarray, env_rewards: np.ndarray) -> np.ndarray:
        """Rewards of a batch of transitions replayed from a buffer (of no particular env or time):
        the rule at its current state, which this does not advance. A stateless rule gives what it
        gives any step; :class:`CMZReward` measures u against the mean of its envs' EMAs."""
        return self(u, env_rewards)

    def highest_u_so_far(self, u: np.ndarray) -> np.ndarray:
        """For the disagreements ``u`` (T, n_envs) of T consecutive steps, the highest u seen up to
        each step, that step's envs included, (T,); :attr:`absorbing_u` then holds the last."""
        seen = np.maximum.accumulate(np.maximum(u.max(axis=1), self.absorbing_u))
        self.absorbing_u = float(seen[-1])
        return seen

    def get_state(self) -> np.ndarray:
        """Per-env state as an array (empty for stateless rules), for saving with a model."""
        return np.zeros(0)

    def set_state(self, state: np.ndarray) -> None:
        """Restore what :meth:`get_state` returned."""


class CMZReward(RewardRule):
    """Continuous mean-zero reward ``r_i = -alpha * (u_i - ubar_i)`` with a per-env EMA ``ubar``.

    :param alpha: reward scale (> 0); the paper uses 10.
    :param ema: EMA factor ``g`` in (0, 1); the paper uses 0.99.
    :param u0: initial ``ubar`` of every env; the paper uses 0.
    :param u_max: clip ``u`` at this value before the reward and the EMA (None, the paper: no clip).
        Linear in ``u``, the reward lets a few far-off states (a cheetah on its back) outweigh many
        ordinary ones in PPO's normalised advantages; clipped, every state beyond ``u_max`` costs the
        same, as in DRIL's reward, and the states below it keep their graded reward.
    """

    name = "cmz"

    def __init__(self, alpha: float = 10.0, ema: float = 0.99, u0: float = 0.0, u_max: float | None = None) -> None:
        if not (np.isfinite(alpha) and alpha > 0):
            raise UserError(f"alpha must be > 0 and finite, got {alpha}")
        if not 0.0 < ema < 1.0:
            raise UserError(f"ema must lie in (0, 1), got {ema}")
        if not np.isfinite(u0):
            raise UserError(f"u0 must be finite, got {u0}")
        if u_max is not None and not (np.isfinite(u_max) and u_max > 0):
            raise UserError(f"u_max must be finite and > 0, or None, got {u_max}")
        self.alpha = float(alpha)
        self.ema = float(ema)
        self.u0 = float(u0)
        self.u_max = None if u_max is None else float(u_max)
        self.ubar: np.ndarray | None = None

    def _clipped(self, u: np.ndarray) -> np.ndarray:
        u = np.asarray(u, dtype=np.float64)
        return u if self.u_max is None else np.minimum(u, self.u_max)

    def __call__(self, u: np.ndarray, env_rewards: np.ndarray) -> np.ndarray:
        u = self._clipped(u)
        if self.ubar is None or self.ubar.shape != u.shape:
            if self.ubar is not None:
                raise ValueError(f"CMZReward holds EMA state for {self.ubar.size} envs but got {u.size} disagreements")
            self.ubar = np.full(u.shape, self.u0, dtype=np.float64)
        reward = u - self.ubar
        reward *= -self.alpha
        self.ubar *= self.ema
        self.ubar += (1.0 - self.ema) * u
        return reward.astype(np.float32)

    def sequence(self, u: np.ndarray, env_rewards: np.ndarray) -> np.ndarray:
        # The EMA is a first-order linear filter, y_t = g*y_{t-1} + (1-g)*u_{t-1} with y_0 = ubar:
        # scipy runs it over all steps and envs at once and hands back the state after the last step.
        from scipy.signal import lfilter

        u = self._clipped(u)
        if len(u) == 0:
            return np.zeros(u.shape, np.float32)
        if self.ubar is None:
            self.ubar = np.full(u.shape[1:], self.u0, dtype=np.float64)
        elif self.ubar.shape != u.shape[1:]:
            raise ValueError(
                f"CMZReward holds EMA state for {self.ubar.size} envs but got {u.shape[1:]} disagreements per step"
            )
        ubar, final = lfilter([0.0, 1.0 - self.ema], [1.0, -self.ema], u, axis=0, zi=self.ubar[None])
        self.ubar = final[0]
        return (-self.alpha * (u - ubar)).astype(np.float32)

    def replayed(self, u: np.ndarray, env_rewards: np.ndarray) -> np.ndarray:
        # An off-policy learner replays transitions long after their step: the reward is measured
        # against where the agent's disagreement stands now, so it stays about mean-zero on the
        # agent's current behaviour (and positive on states more expert-like than that).
        ubar = self.u0 if self.ubar is None else float(self.ubar.mean())
        return (-self.alpha * (self._clipped(u) - ubar)).astype(np.float32)

    def absorbing(self, u_absorbing: np.ndarray, u: np.ndarray, rewards: np.ndarray) -> np.ndarray:
        # rewards = -alpha (u - ubar), so -alpha (u_absorbing - ubar) needs no ubar of its own.
        return (rewards - self.alpha * (self._clipped(u_absorbing) - self._clipped(u))).astype(np.float32)

    def get_state(self) -> np.ndarray:
        return np.zeros(0) if self.ubar is None else self.ubar.copy()

    def set_state(self, state: np.ndarray) -> None:
        state = np.asarray(state, dtype=np.float64).reshape(-1)
        self.ubar = state.copy() if state.size else None

    def __repr__(self) -> str:
        clip = "" if self.u_max is None else f", u_max={self.u_max:.6g}"
        return f"CMZReward(alpha={self.alpha}, ema={self.ema}, u0={self.u0}{clip})"


class DRILReward(RewardRule):
    """DRIL's reward: ``+1`` where ``u <= threshold``, ``-1`` elsewhere."""

    name = "dril"

    def __init__(self, threshold: float) -> None:
        if not np.isfinite(threshold):
            raise UserError(f"threshold must be finite, got {threshold}")
        self.threshold = float(threshold)

    @classmethod
    def from_quantile(cls, ensemble: Any, demos: Demonstrations, q: float = 0.98) -> DRILReward:
        """Threshold = the q-quantile of u over the demonstrations, with the expert's actions."""
        from sb3_cmzdril.ensemble import quantile_of_disagreement

        return cls(quantile_of_disagreement(ensemble, demos, q))

    def __call__(self, u: np.ndarray, env_rewards: np.ndarray) -> np.ndarray:
        return np.where(u <= self.threshold, 1.0, -1.0).astype(np.float32)

    sequence = __call__  # stateless and elementwise

    def absorbing(self, u_absorbing: np.ndarray, u: np.ndarray, rewards: np.ndarray) -> np.ndarray:
        return self(np.broadcast_to(u_absorbing, np.shape(u)), rewards)

    def __repr__(self) -> str:
        return f"DRILReward(threshold={self.threshold:.6g})"


class ZeroReward(RewardRule):
    """Reward 0 everywhere: PPO then only regularises the BC epochs (the paper's "no reward")."""

    name = "zero"

    def __call__(self, u: np.ndarray, env_rewards: np.ndarray) -> np.ndarray:
        return np.zeros(u.shape, dtype=np.float32)

    sequence = __call__

    def absorbing(self, u_absorbing: np.ndarray, u: np.ndarray, rewards: np.ndarray) -> np.ndarray:
        return np.zeros(np.shape(u), dtype=np.float32)


class EnvReward(RewardRule):
    """The true environment reward (the paper's upper bound)."""

    name = "env"

    def __call__(self, u: np.ndarray, env_rewards: np.ndarray) -> np.ndarray:
        return np.asarray(env_rewards, dtype=np.float32)

    sequence = __call__


def terminations(dones: np.ndarray, infos: Sequence[dict]) -> np.ndarray:
    """Which envs' episodes ended by termination at this step: done, and not cut by a time limit. An env
    the VecEnv gives no info dict for (a custom VecEnv may return ``[]``, as PPO tolerates) is read as not
    truncated."""
    done = np.asarray(dones, dtype=bool)
    truncated = np.array([i < len(infos) and bool(infos[i].get("TimeLimit.truncated", False))
                          for i in range(len(done))], dtype=bool)
    return done & ~truncated


def with_absorbing_state(
    rule: RewardRule, rewards: np.ndarray, u: np.ndarray, terminated: np.ndarray, u_absorbing: np.ndarray, gamma: float
) -> np.ndarray:
    """``rewards`` with each terminating step's reward raised by the discounted value of staying
    forever in an absorbing state of disagreement ``u_absorbing`` (broadcast to ``u``: the highest u
    seen up to that step): ``gamma / (1 - gamma)`` times the rule's reward there (``rule.absorbing``).

    A disagreement reward says nothing about an episode's end: under a mean-zero reward, dying is
    worth about as much as living on. Where the expert never terminates (Walker2d and Hopper: it
    walks until the time limit), termination is the least expert-like outcome, and an absorbing
    state (as in DAC, Kostrikov et al. 2019) at the highest disagreement seen scores it so.
    """
    if not terminated.any() or gamma >= 1.0:
        return rewards
    out = np.array(rewards, dtype=np.float32, copy=True)
    u_absorbing = np.broadcast_to(u_absorbing, np.shape(u))[terminated]
    out[terminated] += gamma / (1.0 - gamma) * rule.absorbing(u_absorbing, u[terminated], out[terminated])
    return out


class DisagreementReward(VecEnvWrapper):
    """Replace a VecEnv's reward with a rule of the ensemble's disagreement.

    Works with any SB3 algorithm and any VecEnv (Dummy or Subproc). Put it *below* VecNormalize so
    the ensemble sees raw observations (``CMZDRIL`` does this itself). Each step's ``infos[i]`` gets
    ``"env_reward"`` (the reward the env returned) and ``"disagreement"`` (u_i).

    :param venv: the environments to wrap (Box observations).
    :param ensemble: anything with ``disagreement(obs, actions) -> (n_envs,)``, e.g. a fitted
        :class:`~sb3_cmzdril.ensemble.BCEnsemble`. ``needs_actions`` on it (default True) says
        whether to pass the actions.
    :param rule: the reward rule, e.g. ``CMZReward()``.
    :param absorbing_gamma: give each terminating step the discounted value (with this discount) of
        an absorbing state at the highest u seen so far (:func:`with_absorbing_state`); None: off.
    :param terminal_disagreement: with ``absorbing_gamma``, the absorbing state's u for an episode
        that terminated: this function of the observations the episodes ended in (a batch, from
        ``infos[i]["terminal_observation"]``) instead of the highest u seen (None). ``CMZDRIL``
        passes it for ``absorbing_score="terminal"``.

    Put it above any Monitor/VecMonitor so they record the true return (``CMZDRIL`` does; by default
    it does not use this wrapper at all but scores whole rollouts, see :mod:`sb3_cmzdril.cmzdril.scoring`).
    """

    def __init__(
        self,
        venv: VecEnv,
        ensemble: DisagreementModel,
        rule: RewardRule,
        absorbing_gamma: float | None = None,
        terminal_disagreement: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> None:
        super().__init__(venv)
        if not hasattr(ensemble, "disagreement"):
            raise TypeError(f"ensemble must have a disagreement(obs, actions) method; got {type(ensemble).__name__}")
        if not isinstance(rule, RewardRule):
            raise TypeError(f"rule must be a RewardRule (CMZReward, DRILReward, ...); got {type(rule).__name__}")
        self.ensemble = ensemble
        self.rule = rule
        self.absorbing_gamma = absorbing_gamma
        self.terminal_disagreement = terminal_disagreement
        self._pass_actions = bool(getattr(ensemble, "needs_actions", True))
        self._last_obs: VecEnvObs | None = None
        self._actions: np.ndarray | None = None
        self._sum_u = self._sum_reward = 0.0
        self._count = 0

    def reset(self) -> VecEnvObs:
        obs = self.venv.reset()
        self._last_obs = obs
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions
        self.venv.step_async(actions)

    def step_wait(self) -> VecEnvStepReturn:
        if self._last_obs is None:
            raise RuntimeError("DisagreementReward.step_wait() before reset(): the acted-on observation is unknown")
        obs, env_rewards, dones, infos = self.venv.step_wait()
        # The wrapper is for Box observation spaces (see the class docstring), whose VecEnvs return arrays.
        acted_on = cast(np.ndarray, self._last_obs)
        u = self.ensemble.disagreement(acted_on, self._actions if self._pass_actions else None)
        rewards = self.rule(u, env_rewards)
        if self.absorbing_gamma is not None:
            self.rule.highest_u_so_far(np.reshape(u, (1, -1)))
            terminated = terminations(dones, infos)
            u_absorbing = np.full(np.shape(u), self.rule.absorbing_u)
            if self.terminal_disagreement is not None and terminated.any():
                ended_in = np.stack([infos[i]["terminal_observation"] for i in np.flatnonzero(terminated)])
                u_absorbing[terminated] = self.terminal_disagreement(ended_in)
            rewards = with_absorbing_state(self.rule, rewards, u, terminated, u_absorbing, self.absorbing_gamma)
        for info, r_env, u_i in zip(infos, env_rewards.tolist(), u.tolist(), strict=True):
            info["env_reward"] = r_env
            info["disagreement"] = u_i
        # After an auto-reset, obs holds the new episode's first observation: the next one acted on.
        self._last_obs = obs
        self._sum_u += float(np.add.reduce(u))
        self._sum_reward += float(np.add.reduce(rewards))
        self._count += u.size
        return obs, rewards, dones, infos

    @property
    def absorbing_u(self) -> float:
        """The absorbing state's disagreement, the highest u scored so far (kept by the rule)."""
        return self.rule.absorbing_u

    def pop_stats(self) -> dict[str, float]:
        """Mean u and mean shaped reward since the last call (empty dict if no step was taken)."""
        count, self._count = self._count, 0
        total_u, total_r = self._sum_u, self._sum_reward
        self._sum_u = self._sum_reward = 0.0
        if count == 0:
            return {}
        return {"disagreement_mean": total_u / count, "shaped_reward_mean": total_r / count}


def make_rule(name: str, **kwargs: Any) -> RewardRule:
    """Build a rule from its name: ``cmz`` (alpha, ema, u0, u_max), ``dril`` (threshold), ``zero``, ``env``."""
    rules: dict[str, Any] = {r.name: r for r in (CMZReward, DRILReward, ZeroReward, EnvReward)}
    if name not in rules:
        raise UserError(f"unknown reward {name!r}; choose one of {sorted(rules)}")
    return rules[name](**kwargs)


__all__: list[str] = [
    "RewardRule",
    "CMZReward",
    "DRILReward",
    "ZeroReward",
    "EnvReward",
    "DisagreementReward",
    "expert_never_terminates",
    "make_rule",
    "terminations",
    "with_absorbing_state",
]
