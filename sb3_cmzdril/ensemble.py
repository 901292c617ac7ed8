"""BCEnsemble: a bootstrap ensemble of behaviour-cloning MLPs held as one batched network.

The E members share one set of tensors per layer (weights ``[E, out, in]``, biases ``[E, out]``), so a
forward pass for all members is one ``baddbmm`` per layer during fitting. Each member is fitted on its
own bootstrap resample of the demonstration steps (drawn once, as DRIL does), from its own random
initialisation; the spread of the members' predictions is the disagreement ``u``.

Scoring happens once per environment step inside the reward wrapper, usually on a batch of one
observation, where torch's per-operator overhead dominates. Inference therefore runs on cached numpy
copies of the weights with preallocated buffers (see :meth:`BCEnsemble.disagreement`); torch is used
only to fit.

Disagreement forms (``disagreement=``):

* ``"std"`` (default, CMZ-DRIL's "ensemble standard deviation"): Box: mean over action dimensions of
  the standard deviation (population, ddof=0) across members of their predicted actions, clipped to
  the action bounds; Discrete: standard deviation across members of the probability each assigns to
  the agent's action (needs the actions; without them, the mean over all actions).
* ``"quadratic"`` (DRIL's original form): ``a^T Cov a`` with the agent's clipped action ``a`` and the
  covariance across members of their predicted actions (Box only; Discrete uses the same
  probability-variance as DRIL's Atari code, i.e. the square of the "std" form).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from torch import nn

from sb3_cmzdril.demos import Demonstrations
from sb3_cmzdril.io import PathLike, atomic_path
from sb3_cmzdril.policies import observation_statistics

DISAGREEMENT_FORMS = ("std", "quadratic")
# Up to this batch size numpy (no dispatch overhead) is faster; above it torch's batched matmul
# is (numpy's float32 matmul ran at ~1 GFLOP/s here: 40 ms per layer for 2048 observations,
# against 2.5 ms for torch.bmm).
_NUMPY_MAX_BATCH = 32


class BCEnsemble(nn.Module):
    """E behaviour-cloning MLPs fitted on bootstrap resamples of the demonstrations.

    :param observation_space: Box observation space.
    :param action_space: Box or Discrete action space.
    :param n_members: ensemble size E (DRIL and the paper use 5).
    :param hidden_sizes: hidden layer widths (ReLU). DRIL used 512 units; 64x64 keeps per-step
        scoring cheap (see the README's performance section) and fits 1,000 demo steps easily.
    :param disagreement: ``"std"`` or ``"quadratic"`` (see module docstring).
    :param seed: seeds initialisation, bootstrap draws and minibatch order.
    """

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        n_members: int = 5,
        hidden_sizes: Sequence[int] = (64, 64),
        disagreement: str = "std",
        seed: int = 0,
    ) -> None:
        super().__init__()
        if not isinstance(observation_space, spaces.Box):
            raise ValueError(f"BCEnsemble needs a Box observation space, got {observation_space}")
        if not isinstance(action_space, (spaces.Box, spaces.Discrete)):
            raise ValueError(f"BCEnsemble supports Box and Discrete action spaces, got {action_space}")
        if int(n_members) < 2:
            raise ValueError(f"an ensemble needs at least 2 members to disagree; got n_members={n_members}")
        if disagreement not in DISAGREEMENT_FORMS:
            raise ValueError(f"disagreement must be one of {DISAGREEMENT_FORMS}, got {disagreement!r}")
        hidden_sizes = tuple(int(h) for h in hidden_sizes)
        if any(h < 1 for h in hidden_sizes):
            raise ValueError(f"hidden sizes must be positive, got {hidden_sizes}")
        self.observation_space = observation_space
        self.action_space = action_space
        self.n_members = int(n_members)
        self.hidden_sizes = hidden_sizes
        self.disagreement_form = disagreement
        self.seed = int(seed)
        self.discrete = isinstance(action_space, spaces.Discrete)
        self.obs_shape = tuple(observation_space.shape)
        self.obs_dim = int(np.prod(self.obs_shape))
        self.out_dim = int(action_space.n) if self.discrete else int(np.prod(action_space.shape))

        gen = th.Generator().manual_seed(self.seed)
        sizes = [self.obs_dim, *hidden_sizes, self.out_dim]
        self.weights = nn.ParameterList()
        self.biases = nn.ParameterList()
        for fan_in, fan_out in zip(sizes[:-1], sizes[1:], strict=True):
            # nn.Linear's default initialisation, drawn independently for every member.
            bound = 1.0 / math.sqrt(fan_in)
            self.weights.append(nn.Parameter((th.rand(self.n_members, fan_out, fan_in, generator=gen) * 2 - 1) * bound))
            self.biases.append(nn.Parameter((th.rand(self.n_members, fan_out, generator=gen) * 2 - 1) * bound))
        self.register_buffer("obs_mean", th.zeros(self.obs_dim))
        self.register_buffer("obs_std", th.ones(self.obs_dim))
        if self.discrete:
            low, high = np.zeros(1, np.float32), np.zeros(1, np.float32)
        else:
            low = np.asarray(action_space.low, np.float32).reshape(-1)
            high = np.asarray(action_space.high, np.float32).reshape(-1)
        self.register_buffer("action_low", th.as_tensor(low))
        self.register_buffer("action_high", th.as_tensor(high))
        self.register_buffer("fitted", th.zeros((), dtype=th.bool))
        self.train_loss_: np.ndarray | None = None
        self._np_cache: dict[str, Any] | None = None

    # -- torch forward (fitting) -------------------------------------------------------------
    def forward(self, obs: th.Tensor) -> th.Tensor:
        """Raw outputs for every member: ``obs`` (E, B, obs_dim) or (B, obs_dim) -> (E, B, out_dim)."""
        if obs.dim() == 2:
            obs = obs.unsqueeze(0).expand(self.n_members, -1, -1)
        h = (obs - self.obs_mean) / self.obs_std
        last = len(self.weights) - 1
        for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            h = th.baddbmm(b.unsqueeze(1), h, w.transpose(1, 2))
            if i < last:
                h = th.relu(h)
        return h

    def fit(
        self,
        demos: Demonstrations,
        n_epochs: int = 200,
        batch_size: int = 64,
        learning_rate: float = 1e-3,
        progress_bar: bool = False,
    ) -> BCEnsemble:
        """Fit every member on its own bootstrap resample of the demo steps (MSE on clipped actions
        for Box, cross-entropy for Discrete). Returns ``self``; ``train_loss_`` holds each member's
        loss over the last epoch."""
        demos = demos.check_spaces(self.observation_space, self.action_space)
        if n_epochs < 1 or batch_size < 1 or learning_rate <= 0:
            raise ValueError(
                "need n_epochs >= 1, batch_size >= 1, learning_rate > 0; "
                f"got {n_epochs}, {batch_size}, {learning_rate}"
            )
        device = self.obs_mean.device  # fit where the module lives (SB3's device="auto" may be CUDA)
        mean, std = observation_statistics(demos.observations)
        with th.no_grad():
            self.obs_mean.copy_(th.as_tensor(mean))
            self.obs_std.copy_(th.as_tensor(std))
        obs = th.as_tensor(demos.observations.reshape(len(demos), -1), dtype=th.float32, device=device)
        if self.discrete:
            targets = th.as_tensor(demos.actions, dtype=th.long, device=device)
        else:
            targets = th.as_tensor(demos.actions.reshape(len(demos), -1), dtype=th.float32, device=device)
            targets = th.max(th.min(targets, self.action_high), self.action_low)

        rng = np.random.default_rng(self.seed)
        n = len(demos)
        # One fixed bootstrap resample per member: rows of indices into the demo steps.
        boot = rng.integers(0, n, size=(self.n_members, n))
        members = np.arange(self.n_members)[:, None]
        optimizer = th.optim.Adam(self.parameters(), lr=learning_rate)
        epochs = range(n_epochs)
        if progress_bar:
            from sb3_cmzdril.extras import require_extra

            epochs = require_extra("tqdm.auto", "experiments", "progress_bar=True").tqdm(
                epochs, desc="fit ensemble", leave=False
            )
        self.train()
        epoch_loss = np.zeros(self.n_members)
        for _ in epochs:
            order = boot[members, rng.permuted(np.tile(np.arange(n), (self.n_members, 1)), axis=1)]
            epoch_loss[:] = 0.0
            for start in range(0, n, batch_size):
                idx = th.as_tensor(order[:, start : start + batch_size], device=device)
                out = self(obs[idx])
                if self.discrete:
                    per_member = (
                        nn.functional.cross_entropy(
                            out.reshape(-1, self.out_dim), targets[idx].reshape(-1), reduction="none"
                        )
                        .view(self.n_members, -1)
                        .mean(1)
                    )
                else:
                    per_member = ((out - targets[idx]) ** 2).mean(dim=(1, 2))
                optimizer.zero_grad(set_to_none=True)
                # Members are independent, so summing their losses trains each on its own loss.
                per_member.sum().backward()
                optimizer.step()
                epoch_loss += per_member.detach().cpu().numpy() * idx.shape[1]
        self.eval()
        self.train_loss_ = epoch_loss / n
        with th.no_grad():
            self.fitted.fill_(True)
        self._np_cache = None
        return self

    # -- numpy inference (scoring) -----------------------------------------------------------
    def _numpy_params(self) -> dict[str, Any]:
        if self._np_cache is None:
            if not bool(self.fitted):
                raise RuntimeError("BCEnsemble is not fitted: call fit(demonstrations) first")
            self._np_cache = {
                # [E, in, out] so that h @ W needs no transpose per call.
                "W": [w.detach().cpu().numpy().transpose(0, 2, 1).copy() for w in self.weights],
                "b": [b.detach().cpu().numpy()[:, None, :].copy() for b in self.biases],
                "mean": self.obs_mean.cpu().numpy().copy(),
                "inv_std": (1.0 / self.obs_std.cpu().numpy()).astype(np.float32),
                "low": self.action_low.cpu().numpy().copy(),
                "high": self.action_high.cpu().numpy().copy(),
                "bufs": {},
            }
        return self._np_cache

    def _check_obs(self, obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs, dtype=np.float32)
        if obs.shape == self.obs_shape:
            obs = obs[None]
        if obs.shape[1:] != self.obs_shape:
            raise ValueError(f"observations of shape {obs.shape[1:]} do not match the ensemble's {self.obs_shape}")
        if not np.isfinite(obs).all():
            raise ValueError("observations contain NaN or inf")
        return obs.reshape(len(obs), self.obs_dim)

    def member_outputs(self, obs: np.ndarray) -> np.ndarray:
        """Each member's output on a batch: (E, B, act_dim) clipped actions for Box, (E, B, n)
        probabilities for Discrete. The returned array may be a reused buffer: copy it to keep it."""
        p = self._numpy_params()
        x = self._check_obs(obs)
        if len(x) > _NUMPY_MAX_BATCH:
            return self._torch_outputs(x)
        bufs = p["bufs"].get(len(x))
        if bufs is None:
            sizes = [*self.hidden_sizes, self.out_dim]
            bufs = [np.empty((self.n_members, len(x), s), np.float32) for s in sizes]
            bufs.append(np.empty((len(x), self.obs_dim), np.float32))
            p["bufs"] = {len(x): bufs}  # one batch size at a time: rollouts use a fixed n_envs
        h = bufs[-1]
        np.subtract(x, p["mean"], out=h)
        np.multiply(h, p["inv_std"], out=h)
        last = len(p["W"]) - 1
        for i, (w, b) in enumerate(zip(p["W"], p["b"], strict=True)):
            out = bufs[i]
            np.matmul(h, w, out=out)
            np.add(out, b, out=out)
            if i < last:
                np.maximum(out, 0.0, out=out)
            h = out
        if self.discrete:
            np.subtract(h, h.max(axis=2, keepdims=True), out=h)
            np.exp(h, out=h)
            np.divide(h, h.sum(axis=2, keepdims=True), out=h)
        else:
            np.minimum(h, p["high"], out=h)
            np.maximum(h, p["low"], out=h)
        return h

    def _torch_outputs(self, x: np.ndarray) -> np.ndarray:
        with th.inference_mode():
            out = self(th.as_tensor(x, device=self.obs_mean.device))
            if self.discrete:
                out = th.softmax(out, dim=2)
            else:
                out = th.max(th.min(out, self.action_high), self.action_low)
            return out.cpu().numpy()

    def predict(self, obs: np.ndarray) -> np.ndarray:
        """The ensemble's mean action (Box, clipped) or most probable action (Discrete), (B, ...)."""
        out = self.member_outputs(obs).mean(axis=0)
        if self.discrete:
            return out.argmax(axis=1)
        return out.reshape((len(out),) + tuple(self.action_space.shape))

    @property
    def needs_actions(self) -> bool:
        """Whether :meth:`disagreement` uses the agent's actions."""
        return self.discrete or self.disagreement_form == "quadratic"

    def disagreement(self, obs: np.ndarray, actions: np.ndarray | None = None) -> np.ndarray:
        """Disagreement ``u`` for each observation, (B,) float64 (see the module docstring)."""
        out = self.member_outputs(obs)
        batch = out.shape[1]
        if self.discrete:
            if actions is None:
                return out.std(axis=0).mean(axis=1).astype(np.float64)
            a = np.asarray(actions).reshape(-1).astype(np.int64)
            if a.shape[0] != batch:
                raise ValueError(f"{a.shape[0]} actions given for {batch} observations")
            if a.min() < 0 or a.max() >= self.out_dim:
                raise ValueError(f"discrete actions must lie in [0, {self.out_dim - 1}]")
            probs = out[:, np.arange(batch), a]  # (E, B)
            u = probs.std(axis=0).astype(np.float64)
            return u * u if self.disagreement_form == "quadratic" else u
        # Deviations from member 0 (a shifted variance): exactly 0 when the members agree, where
        # deviations from the float32 mean would leave rounding noise.
        dev = out[1:] - out[0]
        if self.disagreement_form == "std":
            mean_dev = np.add.reduce(dev, axis=0)
            mean_dev /= self.n_members
            var = np.add.reduce(dev * dev, axis=0)
            var /= self.n_members
            var -= mean_dev * mean_dev
            np.maximum(var, 0.0, out=var)
            np.sqrt(var, out=var)
            return np.add.reduce(var, axis=1).astype(np.float64) / self.out_dim
        if actions is None:
            raise ValueError("the 'quadratic' disagreement needs the agent's actions")
        a = np.asarray(actions, dtype=np.float32).reshape(batch, -1)
        if a.shape[1] != self.out_dim:
            raise ValueError(f"actions have {a.shape[1]} dimensions, the action space {self.out_dim}")
        p = self._numpy_params()
        a = np.clip(a, p["low"], p["high"])
        dev = dev.astype(np.float64)
        proj = np.einsum("eba,ba->eb", dev, a)  # (d_e . a) for members 1..E-1; member 0 contributes 0
        mean_proj = proj.sum(axis=0) / self.n_members
        return np.maximum((proj * proj).sum(axis=0) / self.n_members - mean_proj * mean_proj, 0.0)

    # -- persistence ---------------------------------------------------------------------------
    def load_state_dict(self, state_dict: Any, strict: bool = True, assign: bool = False) -> Any:
        result = super().load_state_dict(state_dict, strict=strict, assign=assign)
        self._np_cache = None
        return result

    def _config(self) -> dict[str, Any]:
        act = self.action_space
        return {
            "obs_shape": list(self.obs_shape),
            "obs_low": np.asarray(self.observation_space.low, np.float64).reshape(-1).tolist(),
            "obs_high": np.asarray(self.observation_space.high, np.float64).reshape(-1).tolist(),
            "discrete_n": int(act.n) if self.discrete else 0,
            "act_shape": [] if self.discrete else list(act.shape),
            "act_low": [] if self.discrete else np.asarray(act.low, np.float64).reshape(-1).tolist(),
            "act_high": [] if self.discrete else np.asarray(act.high, np.float64).reshape(-1).tolist(),
            "n_members": self.n_members,
            "hidden_sizes": list(self.hidden_sizes),
            "disagreement": self.disagreement_form,
            "seed": self.seed,
        }

    def save(self, path: PathLike) -> None:
        """Save configuration and weights (torch file, written atomically)."""
        with atomic_path(path) as tmp:
            th.save({"config": self._config(), "state_dict": self.state_dict()}, tmp)

    @classmethod
    def load(cls, path: PathLike) -> BCEnsemble:
        """Load an ensemble written by :meth:`save`."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"ensemble file not found: {path}")
        try:
            blob = th.load(path, map_location="cpu", weights_only=True)
            cfg = blob["config"]
        except Exception as e:  # torch raises several types for a damaged file
            raise ValueError(f"ensemble file {path} is corrupt or not a BCEnsemble file: {e}") from e
        obs_space = spaces.Box(
            np.asarray(cfg["obs_low"], np.float32).reshape(cfg["obs_shape"]),
            np.asarray(cfg["obs_high"], np.float32).reshape(cfg["obs_shape"]),
        )
        if cfg["discrete_n"]:
            act_space: spaces.Space = spaces.Discrete(cfg["discrete_n"])
        else:
            act_space = spaces.Box(
                np.asarray(cfg["act_low"], np.float32).reshape(cfg["act_shape"]),
                np.asarray(cfg["act_high"], np.float32).reshape(cfg["act_shape"]),
            )
        ens = cls(obs_space, act_space, cfg["n_members"], cfg["hidden_sizes"], cfg["disagreement"], cfg["seed"])
        ens.load_state_dict(blob["state_dict"])
        return ens

    def extra_repr(self) -> str:
        return (
            f"n_members={self.n_members}, hidden_sizes={self.hidden_sizes}, obs_dim={self.obs_dim}, "
            f"out_dim={self.out_dim}, discrete={self.discrete}, disagreement={self.disagreement_form!r}"
        )


def quantile_of_disagreement(ensemble: Any, demos: Demonstrations, q: float) -> float:
    """The q-quantile of u over the demonstration steps, with the expert's own actions."""
    if not 0.0 < q <= 1.0:
        raise ValueError(f"quantile q must lie in (0, 1], got {q}")
    u = np.concatenate(
        [
            ensemble.disagreement(demos.observations[i : i + 4096], demos.actions[i : i + 4096])
            for i in range(0, len(demos), 4096)
        ]
    )
    return float(np.quantile(u, q))
