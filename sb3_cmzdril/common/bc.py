"""Behaviour cloning of an SB3 policy, by negative log-likelihood (NLL) of expert actions by default.

Used twice by CMZ-DRIL (paper, Alg. 1): to pretrain the policy before RL, and for one epoch on the
demonstrations after every PPO update, so that the policy keeps choosing the expert's actions where
the expert data is dense. BC has its own Adam optimiser: sharing PPO's would mix the moment estimates
of two different losses.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy

from sb3_cmzdril.data.demos import Demonstrations
from sb3_cmzdril.data.spaces import actions_as_indices
from sb3_cmzdril.errors import UserError

ObsTransform = Callable[[Any], Any]
TensorObs = th.Tensor | dict[str, th.Tensor]
#: (policy, observations, expert actions) -> the loss of each step, (batch,)
StepLoss = Callable[[Any, TensorObs, th.Tensor], th.Tensor]


#: ``bc_epochs_per_update="auto"`` keeps the NLL epochs only where the clone's NLL on the held-out demo steps, per
#: action entry in units of half its bounds' range (:func:`nll_per_action_entry`), is below this: the clone
#: predicts the expert's held-out actions closely (chosen across tasks: docs/one_default.md)
AUTO_EPOCHS_NLL = -1.0


def nll_per_action_entry(nll: float, space: spaces.Space) -> float | None:
    """A Gaussian policy's NLL of a step's action (``nll``) per entry of a Box action space, each bounded entry
    measured in units of half its bounds' range: scaling an action by ``h`` shifts its NLL by ``log h``, so one
    threshold reads alike on any Box. None for other spaces and where ``nll`` is not a number."""
    if not isinstance(space, spaces.Box) or not np.isfinite(nll):
        return None
    half = (space.high.astype(np.float64) - space.low.astype(np.float64)).ravel() / 2
    finite = np.isfinite(half) & (half > 0)
    return float(nll / half.size - np.log(np.where(finite, half, 1.0)).mean())


def nll_loss(policy: Any, obs: TensorObs, actions: th.Tensor) -> th.Tensor:
    """The NLL of each expert action under an SB3 policy's action distribution."""
    return -policy.get_distribution(obs).log_prob(actions)


class BehaviourCloner:
    """Behaviour cloning of ``policy`` on ``demos`` (NLL unless another ``loss`` is given).

    The optimiser exists from construction on (so a saved model can restore its state); the demos
    are given with :meth:`set_demonstrations`, already checked against the policy's spaces.

    :param policy: the SB3 policy to train (its action distribution is used, not its value head).
    :param batch_size: minibatch size.
    :param learning_rate: Adam step size of the BC optimiser.
    :param max_grad_norm: gradient clipping, as in PPO.
    :param seed: seeds the minibatch order.
    :param loss: the per-step loss (:data:`StepLoss`); :func:`nll_loss` by default. Where this
        module's names say NLL, they mean this loss.
    """

    def __init__(
        self,
        policy: BasePolicy,
        batch_size: int = 64,
        learning_rate: float = 1e-3,
        max_grad_norm: float = 0.5,
        seed: int | None = None,
        loss: StepLoss = nll_loss,
    ) -> None:
        if batch_size < 1:
            raise UserError(f"bc batch_size must be >= 1, got {batch_size}")
        if learning_rate <= 0:
            raise UserError(f"bc learning_rate must be > 0, got {learning_rate}")
        self.policy = policy
        self.loss = loss
        self.batch_size = int(batch_size)
        self.max_grad_norm = float(max_grad_norm)
        self.optimizer = th.optim.Adam(policy.parameters(), lr=learning_rate)
        self.rng = np.random.default_rng(seed)
        self.demos: Demonstrations | None = None

    def set_demonstrations(self, demos: Demonstrations) -> None:
        """The demos to clone, already checked against the policy's spaces (``check_spaces``)."""
        self.demos = demos
        self._raw_obs = demos.observations
        space = self.policy.action_space
        # As SB3's distributions take them: 0-based indices (a Discrete start is subtracted), flat floats.
        actions = actions_as_indices(demos.actions, space)
        dtype = th.long if isinstance(space, (spaces.Discrete, spaces.MultiDiscrete)) else th.float32
        self._actions = th.as_tensor(actions, dtype=dtype, device=self.policy.device)

    def nll(self, obs_transform: ObsTransform | None = None, indices: np.ndarray | None = None) -> float:
        """Mean NLL of the expert actions (of the steps ``indices``, default all) under the current
        policy (no update)."""
        obs = self._observations(obs_transform)
        actions = self._actions
        if indices is not None:
            idx = th.as_tensor(np.asarray(indices), device=self.policy.device)
            obs, actions = _rows(obs, idx), actions[idx]
        with th.no_grad():
            return float(self.loss(self.policy, obs, actions).mean())

    def epoch(
        self, obs_transform: ObsTransform | None = None, indices: np.ndarray | None = None, fraction: float = 1.0
    ) -> float:
        """One pass over the demos (or the steps ``indices``) in shuffled minibatches; returns the
        mean NLL over the pass. ``fraction`` < 1: a pass over that share of them (at least one step),
        drawn at random without replacement."""
        obs = self._observations(obs_transform)
        rows = np.arange(len(self._actions)) if indices is None else np.asarray(indices)
        self.policy.set_training_mode(True)
        shuffled = self.rng.permutation(rows)[: max(1, math.ceil(fraction * len(rows)))]
        order = th.as_tensor(shuffled, device=self.policy.device)
        total = 0.0
        for start in range(0, len(order), self.batch_size):
            idx = order[start : start + self.batch_size]
            total += self._update(obs, idx) * len(idx)
        self.policy.set_training_mode(False)
        return total / len(order)

    def sample_loss(self, obs_transform: ObsTransform | None = None) -> th.Tensor:
        """The mean loss of a minibatch of demo steps drawn at random, with its graph, for a learner
        that adds it to a loss of its own (an off-policy actor's) instead of stepping this optimiser."""
        obs = self._observations(obs_transform)
        idx = th.as_tensor(self.rng.integers(0, len(self._actions), size=self.batch_size), device=self.policy.device)
        return self.loss(self.policy, _rows(obs, idx), self._actions[idx]).mean()

    def _update(self, obs: TensorObs, idx: th.Tensor) -> float:
        """One optimiser step on the demo steps ``idx``; their mean loss before it."""
        loss = self.loss(self.policy, _rows(obs, idx), self._actions[idx]).mean()
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        th.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
        self.optimizer.step()
        return float(loss.detach())

    def train(
        self, n_epochs: int, obs_transform: ObsTransform | None = None, progress_bar: bool = False
    ) -> list[float]:
        """``n_epochs`` epochs on all demo steps; returns the mean NLL of each."""
        return [self.epoch(obs_transform) for _ in _epochs(int(n_epochs), progress_bar, "BC")]

    def train_early_stopping(
        self,
        max_epochs: int,
        validation_fraction: float = 0.2,
        patience: int = 20,
        obs_transform: ObsTransform | None = None,
        progress_bar: bool = False,
        on_epoch: Callable[[int, float, float], None] | None = None,
        refit: bool = False,
    ) -> EarlyStopping:
        """Train on a random ``1 - validation_fraction`` of the demo steps until the NLL of the
        held-out steps has not improved for ``patience`` epochs (or ``max_epochs``), then restore the
        weights of the best held-out epoch, as DRIL's code does with its train/test split.

        ``validation_fraction=0`` trains ``max_epochs`` on every step (no early stopping).
        ``on_epoch(epoch, train_nll, validation_nll)`` is called after each epoch (for logging).
        ``refit=True``: the split only chooses the number of epochs; the policy then starts again
        from its weights before training and learns that many epochs on every demo step. With one
        demonstration the held-out steps are neighbours of training steps on the same trajectory, so
        they measure interpolation rather than generalisation, and holding them out costs the clone
        a fifth of its only episode (see :attr:`EarlyStopping.refit_epochs`).
        """
        if not 0.0 <= validation_fraction < 1.0:
            raise UserError(f"validation_fraction must lie in [0, 1), got {validation_fraction}")
        if int(max_epochs) < 0 or int(patience) < 1:
            raise UserError(f"need max_epochs >= 0 and patience >= 1, got {max_epochs} and {patience}")
        self._observations(obs_transform)  # refuses a cloner without demonstrations
        n = len(self._actions)
        n_val = int(round(validation_fraction * n))
        result = EarlyStopping()
        if n_val == 0 or n_val == n:
            result.train_nll = self.train(max_epochs, obs_transform, progress_bar)
            result.best_epoch = result.epochs = len(result.train_nll)
            return result
        order = self.rng.permutation(n)
        val_idx, train_idx = order[:n_val], order[n_val:]
        initial = _snapshot(self.policy) if refit else None
        best = (self.nll(obs_transform, val_idx), _snapshot(self.policy))
        result.validation_nll.append(best[0])
        bar = _epochs(int(max_epochs), progress_bar, "BC pretraining")
        for epoch in bar:
            result.train_nll.append(self.epoch(obs_transform, train_idx))
            val = self.nll(obs_transform, val_idx)
            result.validation_nll.append(val)
            result.epochs = epoch + 1
            if on_epoch is not None:
                on_epoch(epoch + 1, result.train_nll[-1], val)
            if val < best[0]:
                best = (val, _snapshot(self.policy))
                result.best_epoch = epoch + 1
            elif epoch + 1 - result.best_epoch >= patience:
                break
        self.policy.load_state_dict(best[1])
        # Adam's moments belong to the discarded epochs' trajectory; the later BC epochs start afresh.
        self.optimizer.state.clear()
        if initial is not None and result.best_epoch > 0:
            self.policy.load_state_dict(initial)
            result.refit_nll = self.train(result.best_epoch, obs_transform, progress_bar)
            result.refit_epochs = result.best_epoch
            self.optimizer.state.clear()
        return result

    def _observations(self, obs_transform: ObsTransform | None) -> TensorObs:
        if self.demos is None:
            raise RuntimeError("BehaviourCloner has no demonstrations: call set_demonstrations() first")
        # VecNormalize statistics move during training, so demo observations are normalised afresh.
        obs = self._raw_obs if obs_transform is None else obs_transform(self._raw_obs)
        if isinstance(obs, dict):
            return {k: _tensor(v, self.policy.device) for k, v in obs.items()}
        return _tensor(obs, self.policy.device)


def _tensor(array: np.ndarray, device: th.device) -> th.Tensor:
    # Floats as float32; integers (images, discrete observations) as they are: SB3's preprocess_obs
    # scales and one-hot encodes them inside the policy.
    array = np.asarray(array)
    return th.as_tensor(array.astype(np.float32, copy=False) if array.dtype.kind == "f" else array, device=device)


def _rows(obs: TensorObs, idx: th.Tensor) -> TensorObs:
    return {k: v[idx] for k, v in obs.items()} if isinstance(obs, dict) else obs[idx]


@dataclasses.dataclass
class EarlyStopping:
    """What :meth:`BehaviourCloner.train_early_stopping` did: per-epoch NLLs (``validation_nll[0]``
    is before the first epoch), the epoch whose weights were kept, and the epochs run."""

    train_nll: list[float] = dataclasses.field(default_factory=list)
    validation_nll: list[float] = dataclasses.field(default_factory=list)
    best_epoch: int = 0
    epochs: int = 0
    #: with ``refit``: the epochs trained afresh on every demo step (the best epoch), and their NLLs
    refit_epochs: int = 0
    refit_nll: list[float] = dataclasses.field(default_factory=list)


def _snapshot(module: th.nn.Module) -> dict[str, th.Tensor]:
    return {k: v.detach().clone() for k, v in module.state_dict().items()}


def _epochs(n: int, progress_bar: bool, desc: str) -> Iterable[int]:
    if not progress_bar:
        return range(n)
    from sb3_cmzdril.extras import require_extra

    return require_extra("tqdm.auto", "experiments", "progress_bar=True").tqdm(range(n), desc=desc, leave=False)


__all__ = ["BehaviourCloner", "EarlyStopping", "ObsTransform", "StepLoss", "TensorObs", "nll_loss"]
