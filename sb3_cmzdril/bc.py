"""Behaviour cloning of an SB3 ActorCriticPolicy by negative log-likelihood (NLL) of expert actions.

Used twice by CMZ-DRIL (paper, Alg. 1): to pretrain the policy before RL, and for one epoch on the
demonstrations after every PPO update, so that the policy keeps choosing the expert's actions where
the expert data is dense. BC has its own Adam optimiser: sharing PPO's would mix the moment estimates
of two different losses.
"""
from __future__ import annotations

from typing import Callable, List, Optional

import numpy as np
import torch as th
from stable_baselines3.common.policies import ActorCriticPolicy

from sb3_cmzdril.demos import Demonstrations

ObsTransform = Callable[[np.ndarray], np.ndarray]


class BehaviourCloner:
    """NLL behaviour cloning of ``policy`` on ``demos``.

    The optimiser exists from construction on (so a saved model can restore its state); the demos
    are given with :meth:`set_demonstrations`, already checked against the policy's spaces.

    :param policy: the SB3 policy to train (its action distribution is used, not its value head).
    :param batch_size: minibatch size.
    :param learning_rate: Adam step size of the BC optimiser.
    :param max_grad_norm: gradient clipping, as in PPO.
    :param seed: seeds the minibatch order.
    """

    def __init__(
        self,
        policy: ActorCriticPolicy,
        batch_size: int = 64,
        learning_rate: float = 1e-3,
        max_grad_norm: float = 0.5,
        seed: Optional[int] = None,
    ) -> None:
        if batch_size < 1:
            raise ValueError(f"bc batch_size must be >= 1, got {batch_size}")
        if learning_rate <= 0:
            raise ValueError(f"bc learning_rate must be > 0, got {learning_rate}")
        self.policy = policy
        self.batch_size = int(batch_size)
        self.max_grad_norm = float(max_grad_norm)
        self.optimizer = th.optim.Adam(policy.parameters(), lr=learning_rate)
        self.rng = np.random.default_rng(seed)
        self.demos: Optional[Demonstrations] = None

    def set_demonstrations(self, demos: Demonstrations) -> None:
        self.demos = demos
        self._raw_obs = demos.observations
        dtype = th.long if demos.actions.dtype.kind in "iu" else th.float32
        self._actions = th.as_tensor(demos.actions, dtype=dtype, device=self.policy.device)

    def nll(self, obs_transform: Optional[ObsTransform] = None) -> float:
        """Mean NLL of the expert actions under the current policy (no update)."""
        obs = self._observations(obs_transform)
        with th.no_grad():
            return float(-self.policy.get_distribution(obs).log_prob(self._actions).mean())

    def epoch(self, obs_transform: Optional[ObsTransform] = None) -> float:
        """One pass over the demos in shuffled minibatches; returns the mean NLL over the pass."""
        obs = self._observations(obs_transform)
        self.policy.set_training_mode(True)
        n = len(obs)
        order = th.as_tensor(self.rng.permutation(n), device=self.policy.device)
        total = 0.0
        for start in range(0, n, self.batch_size):
            idx = order[start : start + self.batch_size]
            loss = -self.policy.get_distribution(obs[idx]).log_prob(self._actions[idx]).mean()
            self.optimizer.zero_grad(set_to_none=True)
            loss.backward()
            th.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
            self.optimizer.step()
            total += float(loss.detach()) * len(idx)
        self.policy.set_training_mode(False)
        return total / n

    def train(self, n_epochs: int, obs_transform: Optional[ObsTransform] = None, progress_bar: bool = False) -> List[float]:
        """``n_epochs`` epochs; returns the mean NLL of each."""
        epochs = range(int(n_epochs))
        if progress_bar:
            from tqdm.auto import tqdm

            epochs = tqdm(epochs, desc="BC pretraining", leave=False)
        return [self.epoch(obs_transform) for _ in epochs]

    def _observations(self, obs_transform: Optional[ObsTransform]) -> th.Tensor:
        if self.demos is None:
            raise RuntimeError("BehaviourCloner has no demonstrations: call set_demonstrations() first")
        # VecNormalize statistics move during training, so demo observations are normalised afresh.
        obs = self._raw_obs if obs_transform is None else obs_transform(self._raw_obs)
        return th.as_tensor(np.asarray(obs, dtype=np.float32), device=self.policy.device)
