"""Reward-free selection of a policy: the one whose own rollout the ensemble disagreed on least.

PPO fine-tuning can drift away from a near-expert behaviour-cloned start, and the true reward is not
available to an imitation learner to notice it. The ensemble's disagreement is: it is low where the
expert's data is dense. :class:`LowestDisagreementPolicy` watches the mean disagreement ``u`` of each
training rollout (``CMZDRIL.rollout_disagreement``, computed by the rollout scorer for every reward
mode) and keeps a copy of the policy that collected the rollout with the lowest one. Rollout ``k`` is
collected by the policy after ``k`` updates, so epoch ``k`` here is the same policy that the per-epoch
evaluation calls epoch ``k``; epoch 0 is the behaviour-cloned start.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, cast

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

from sb3_cmzdril.errors import UserError
from sb3_cmzdril.io import PathLike, atomic_path


class LowestDisagreementPolicy(BaseCallback):
    """Keep the policy weights of the training rollout with the lowest mean disagreement.

    Use with :class:`~sb3_cmzdril.algorithm.CMZDRIL` (any reward mode). After ``learn()``,
    :meth:`apply` loads the kept weights into a model; :meth:`save`/:meth:`load` persist the choice
    so a resumed run continues the same search.
    """

    def __init__(self, verbose: int = 0) -> None:
        super().__init__(verbose)
        self.best_u = float("inf")
        self.best_epoch: int | None = None
        self.best_state: dict[str, th.Tensor] | None = None
        self._epoch = 0

    def _on_rollout_start(self) -> None:
        # The callback is for CMZDRIL (a PPO): on-policy, n_steps per env in each rollout.
        model = cast(OnPolicyAlgorithm, self.model)
        self._epoch = int(model.num_timesteps // (model.n_steps * model.n_envs))

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        u = getattr(self.model, "rollout_disagreement", None)
        if u is None or not np.isfinite(u) or u >= self.best_u:
            return
        self.best_u, self.best_epoch = float(u), self._epoch
        # On the CPU: a copy per improvement should not hold accelerator memory.
        self.best_state = {k: v.detach().to("cpu", copy=True) for k, v in self.model.policy.state_dict().items()}
        if self.verbose >= 1:
            print(f"[lowest u] epoch {self._epoch}: rollout disagreement {u:.4g}")

    def apply(self, model: Any) -> None:
        """Load the kept weights into ``model.policy``."""
        if self.best_state is None:
            raise RuntimeError("no rollout has been scored yet: nothing to select")
        model.policy.load_state_dict(self.best_state)

    def save(self, path: PathLike) -> None:
        """Write the choice (weights, epoch, u) atomically; nothing is written before a choice exists."""
        if self.best_state is None:
            return
        blob = {"state_dict": self.best_state, "epoch": th.tensor(self.best_epoch), "u": th.tensor(self.best_u)}
        with atomic_path(path, suffix=".pt") as tmp:
            th.save(blob, tmp)

    def load(self, path: PathLike) -> bool:
        """Restore a choice written by :meth:`save`; False when there is no such file, a ValueError
        naming it when it is damaged."""
        if not Path(path).is_file():
            return False
        try:
            blob = th.load(path, map_location="cpu", weights_only=True)
            state, epoch, u = blob["state_dict"], int(blob["epoch"]), float(blob["u"])
            if not isinstance(state, dict):
                raise TypeError(f"state_dict is a {type(state).__name__}")
        except Exception as e:  # torch raises RuntimeError, OSError (errno 22), pickle errors... for damage
            raise UserError(
                f"{path} is truncated or not a lowest-u policy file ({type(e).__name__}: {e}); delete it to "
                "resume without the earlier choice"
            ) from None
        self.best_state, self.best_epoch, self.best_u = state, epoch, u
        return True


__all__ = ["LowestDisagreementPolicy"]
