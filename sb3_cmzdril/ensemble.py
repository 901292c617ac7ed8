"""BCEnsemble: a bootstrap ensemble of behaviour-cloning policies held as one batched network.

The E members share one set of tensors per layer (weights ``[E, out, in]``, biases ``[E, out]``), so a
forward pass for all members is one ``baddbmm`` per layer. Each member is fitted on its own bootstrap
resample of the demonstration steps (drawn once, as DRIL does), from its own random initialisation;
the spread of the members' predictions is the disagreement ``u``.

Inputs are built as SB3 builds a policy's (:mod:`sb3_cmzdril.data.spaces`): Box parts as floats
(standardised with the demos' mean and std), Discrete / MultiDiscrete parts one-hot, MultiBinary as
0/1, a Dict key by key, concatenated into one flat vector. Image parts (uint8 Boxes, scaled by 1/255)
go through a CNN trunk shared by all members (as DRIL's ``PolicyEnsembleCNN``: one trunk, batched
heads), whose features join the flat vector; the members' heads stay one batched forward.

Scoring happens once per environment step inside the reward wrapper, or once per rollout from the
buffer. For flat inputs on small batches, where torch's per-operator overhead dominates, inference
runs on cached numpy copies of the weights with preallocated buffers (see :meth:`BCEnsemble.disagreement`);
larger batches and images use torch.

Disagreement forms (``disagreement=``), per action space:

* ``"std"`` (default, CMZ-DRIL's "ensemble standard deviation"):

  - Box (any shape, flattened): mean over action dimensions of the standard deviation (population,
    ddof=0) across members of their predicted actions, clipped to the action bounds;
  - Discrete (any ``start``): standard deviation across members of the probability each assigns to
    the agent's action (needs the actions; without them, the mean over all actions);
  - MultiDiscrete: the Discrete form for each component, summed over the components;
  - MultiBinary: standard deviation across members of the probability of each bit, summed over the
    bits (the probability of the agent's bit, ``p`` or ``1 - p``, has the same spread, so no actions
    are needed).

* ``"std_unclipped"`` (Box only): the ``"std"`` form on the members' outputs as they are, not
  clipped to the action bounds. Where the expert's actions often sit on a bound (LunarLander's
  heuristic lander fires its main engine at full or not at all), members trained on those
  clipped targets extrapolate past the bound off the expert's states, and clipped they agree
  exactly: u is 0, the lowest there is, where they know least.

* ``"auto"``: ``"std_unclipped"`` where at least :data:`AUTO_UNCLIPPED_SHARE` of the entries of the
  demonstrations' actions lie on a bound of a Box action space, ``"std"`` otherwise (chosen by
  :meth:`BCEnsemble.fit` and kept in the state dict). A clipped or saturating expert (a heuristic,
  a deterministic policy whose output the env clips) holds a bound; a squashed Gaussian (SAC's
  tanh) comes close but lands on it only where float32 rounds tanh to 1, so it takes ``"std"``.

* ``"quadratic"`` (DRIL's original form): Box: ``a^T Cov a`` with the agent's clipped action ``a``
  and the covariance across members of their predicted actions; the categorical and binary spaces
  use the variance across members of the same probabilities (the square of each component's "std"
  form, summed), as DRIL's Atari code does.
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

from sb3_cmzdril.data.demos import Demonstrations
from sb3_cmzdril.data.spaces import (
    ObsEncoder,
    Observations,
    actions_as_indices,
    categorical_starts,
    check_action_space,
    indices_as_actions,
    shape_of,
    space_from_config,
    space_to_config,
    take,
)
from sb3_cmzdril.errors import MissingFileError, UserError
from sb3_cmzdril.io import PathLike, atomic_path
from sb3_cmzdril.policies import observation_statistics

DISAGREEMENT_FORMS = ("std", "quadratic", "std_unclipped", "auto")
#: ``disagreement="auto"`` takes the unclipped form from this share of action entries on a bound up: enough
#: for the members to learn to push past the bound, and far above what float32's rounding of a tanh
#: gives a SAC expert (benchmarks/studies/bound_share.py: one episode of the clipping experts at hand holds
#: 0.5-57%, the SAC and TQC experts' pools none).
AUTO_UNCLIPPED_SHARE = 0.01
# Up to this batch size numpy (no dispatch overhead) is faster; above it torch's batched matmul
# is (numpy's float32 matmul ran at ~1 GFLOP/s here: 40 ms per layer for 2048 observations,
# against 2.5 ms for torch.bmm).
_NUMPY_MAX_BATCH = 32
# Rows per torch forward when scoring many image observations: bounds the trunk's activations.
_TORCH_CHUNK = 4096


class ImageTrunk(nn.Module):
    """SB3's NatureCNN (conv 32x8/4, 64x4/2, 64x3/1, then a linear layer) for images of at least
    36 pixels a side; smaller images get two 3x3 stride-2 convolutions, which fit any size."""

    def __init__(self, shape: tuple[int, int, int], features_dim: int) -> None:
        super().__init__()
        channels, height, width = shape
        if min(height, width) >= 36:
            layers: list[nn.Module] = [
                nn.Conv2d(channels, 32, 8, stride=4), nn.ReLU(),
                nn.Conv2d(32, 64, 4, stride=2), nn.ReLU(),
                nn.Conv2d(64, 64, 3, stride=1), nn.ReLU(),
            ]  # fmt: skip
        else:
            layers = [
                nn.Conv2d(channels, 16, 3, stride=2, padding=1), nn.ReLU(),
                nn.Conv2d(16, 32, 3, stride=2, padding=1), nn.ReLU(),
            ]  # fmt: skip
        self.cnn = nn.Sequential(*layers, nn.Flatten())
        with th.no_grad():
            n_flat = int(self.cnn(th.zeros(1, channels, height, width)).shape[1])
        self.linear = nn.Sequential(nn.Linear(n_flat, features_dim), nn.ReLU())
        self.features_dim = int(features_dim)

    def forward(self, images: th.Tensor) -> th.Tensor:
        """(..., C, H, W) in [0, 1] -> (..., features_dim)."""
        lead = images.shape[:-3]
        out = self.linear(self.cnn(images.reshape(-1, *images.shape[-3:])))
        return out.reshape(*lead, self.features_dim)


class BCEnsemble(nn.Module):
    """E behaviour-cloning policies fitted on bootstrap resamples of the demonstrations.

    :param observation_space: any observation space PPO takes (Box of any shape, images, Discrete,
        MultiDiscrete, MultiBinary, Dict of those).
    :param action_space: Box (any shape), Discrete (any start), MultiDiscrete or MultiBinary.
    :param n_members: ensemble size E (DRIL and the paper use 5).
    :param hidden_sizes: hidden layer widths (ReLU) of each member's head. DRIL used 512 units; 64x64
        keeps per-step scoring cheap (see the README's performance section) and fits 1,000 demo steps.
    :param disagreement: ``"std"``, ``"quadratic"``, ``"std_unclipped"`` or ``"auto"`` (see the module
        docstring); :attr:`disagreement_form` is the form in use.
    :param seed: seeds initialisation, bootstrap draws and minibatch order.
    :param image_features: output width of the shared CNN trunk of each image part.
    """

    obs_mean: th.Tensor
    obs_std: th.Tensor
    action_low: th.Tensor
    action_high: th.Tensor
    fitted: th.Tensor
    unclipped: th.Tensor  # registered only for disagreement="auto"

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        n_members: int = 5,
        hidden_sizes: Sequence[int] = (64, 64),
        disagreement: str = "std",
        seed: int = 0,
        image_features: int = 128,
    ) -> None:
        super().__init__()
        encoder = ObsEncoder(observation_space)
        check_action_space(action_space)
        if int(n_members) < 2:
            raise UserError(f"an ensemble needs at least 2 members to disagree; got n_members={n_members}")
        if disagreement not in DISAGREEMENT_FORMS:
            raise UserError(f"disagreement must be one of {DISAGREEMENT_FORMS}, got {disagreement!r}")
        if disagreement == "std_unclipped" and not isinstance(action_space, spaces.Box):
            raise UserError(f"disagreement='std_unclipped' needs Box actions (it leaves the members' actions "
                            f"unclipped), got {type(action_space).__name__}; use 'std'")
        hidden_sizes = tuple(int(h) for h in hidden_sizes)
        if any(h < 1 for h in hidden_sizes):
            raise UserError(f"hidden sizes must be positive, got {hidden_sizes}")
        self.observation_space = observation_space
        self.action_space = action_space
        self.encoder = encoder
        self.n_members = int(n_members)
        self.hidden_sizes = hidden_sizes
        self.requested_disagreement = disagreement
        #: the form in use: the one asked for, or the one "auto" resolves to ("std" until fitted)
        self.disagreement_form = "std" if disagreement == "auto" else disagreement
        self.seed = int(seed)
        self.image_features = int(image_features)
        #: "box", "categorical" (Discrete, MultiDiscrete) or "binary" (MultiBinary)
        self.action_kind = (
            "box" if isinstance(action_space, spaces.Box)
            else "binary" if isinstance(action_space, spaces.MultiBinary)
            else "categorical"
        )  # fmt: skip
        self.discrete = self.action_kind == "categorical"
        self.action_shape = shape_of(action_space)
        #: the categorical components' sizes (Discrete: one; MultiDiscrete: nvec; otherwise none)
        self.segments: list[int] = []
        self._starts = np.zeros(0, np.int64)
        if isinstance(action_space, (spaces.Discrete, spaces.MultiDiscrete)):
            nvec = [action_space.n] if isinstance(action_space, spaces.Discrete) else action_space.nvec
            self.segments = [int(n) for n in np.asarray(nvec).reshape(-1)]
            self._starts = categorical_starts(action_space)
        self.out_dim = sum(self.segments) if self.segments else int(np.prod(self.action_shape))
        self.obs_dim = encoder.flat_dim

        gen = th.Generator().manual_seed(self.seed)
        with th.random.fork_rng(devices=[]):
            th.manual_seed(self.seed)  # the trunks' default initialisation, reproducibly
            self.trunks = nn.ModuleList(
                [ImageTrunk(encoder.image_shape(p), self.image_features) for p in encoder.image_parts]
            )
        sizes = [encoder.flat_dim + self.image_features * len(self.trunks), *hidden_sizes, self.out_dim]
        self.weights = nn.ParameterList()
        self.biases = nn.ParameterList()
        for fan_in, fan_out in zip(sizes[:-1], sizes[1:], strict=True):
            # nn.Linear's default initialisation, drawn independently for every member.
            bound = 1.0 / math.sqrt(fan_in)
            self.weights.append(nn.Parameter((th.rand(self.n_members, fan_out, fan_in, generator=gen) * 2 - 1) * bound))
            self.biases.append(nn.Parameter((th.rand(self.n_members, fan_out, generator=gen) * 2 - 1) * bound))
        self.register_buffer("obs_mean", th.zeros(self.obs_dim))
        self.register_buffer("obs_std", th.ones(self.obs_dim))
        if isinstance(action_space, spaces.Box):
            low = np.asarray(action_space.low, np.float32).reshape(-1)
            high = np.asarray(action_space.high, np.float32).reshape(-1)
        else:
            low, high = np.zeros(1, np.float32), np.zeros(1, np.float32)
        # Copies: as_tensor would share memory with the space's own bounds, and loading a state dict
        # (set_parameters) would then rewrite the env's action space.
        self.register_buffer("action_low", th.tensor(low))
        self.register_buffer("action_high", th.tensor(high))
        # A float flag, not a bool: SB3's set_parameters and its users treat every saved tensor as numeric.
        self.register_buffer("fitted", th.zeros(()))
        if disagreement == "auto":
            # What "auto" chose, in the state dict so that a loaded ensemble scores as it was fitted.
            self.register_buffer("unclipped", th.zeros(()))
        self.train_loss_: np.ndarray | None = None
        self._np_cache: dict[str, Any] | None = None

    @property
    def is_fitted(self) -> bool:
        return float(self.fitted) != 0.0

    # -- torch forward (fitting) -------------------------------------------------------------
    def forward(self, obs: th.Tensor, images: Sequence[th.Tensor] = ()) -> th.Tensor:
        """Raw outputs of every member: ``obs`` the flat encoding, (E, B, obs_dim) or (B, obs_dim),
        ``images`` one (E, B, C, H, W) or (B, C, H, W) tensor per image part -> (E, B, out_dim)."""
        h = (obs - self.obs_mean) / self.obs_std
        if len(self.trunks):
            h = th.cat([h, *(trunk(img) for trunk, img in zip(self.trunks, images, strict=True))], dim=-1)
        if h.dim() == 2:
            h = h.unsqueeze(0).expand(self.n_members, -1, -1)
        last = len(self.weights) - 1
        for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            h = th.baddbmm(b.unsqueeze(1), h, w.transpose(1, 2))
            if i < last:
                h = th.relu(h)
        return h

    def _loss(self, out: th.Tensor, targets: th.Tensor) -> th.Tensor:
        """Each member's loss, (E,): MSE (Box), cross-entropy summed over components (categorical),
        binary cross-entropy (MultiBinary)."""
        if self.action_kind == "box":
            return ((out - targets) ** 2).mean(dim=(1, 2))
        if self.action_kind == "binary":
            return nn.functional.binary_cross_entropy_with_logits(out, targets, reduction="none").mean(dim=(1, 2))
        total = out.new_zeros(self.n_members)
        for j, logits in enumerate(th.split(out, self.segments, dim=2)):
            ce = nn.functional.cross_entropy(
                logits.reshape(-1, logits.shape[-1]), targets[..., j].reshape(-1), reduction="none"
            )
            total = total + ce.view(self.n_members, -1).mean(1)
        return total

    def fit(
        self,
        demos: Demonstrations,
        n_epochs: int = 200,
        batch_size: int = 64,
        learning_rate: float = 1e-3,
        progress_bar: bool = False,
    ) -> BCEnsemble:
        """Fit every member on its own bootstrap resample of the demo steps (see :meth:`_loss`).
        Returns ``self``; ``train_loss_`` holds each member's loss over the last epoch."""
        demos = demos.check_spaces(self.observation_space, self.action_space)
        if n_epochs < 1 or batch_size < 1 or learning_rate <= 0:
            raise UserError(
                "need n_epochs >= 1, batch_size >= 1, learning_rate > 0; "
                f"got {n_epochs}, {batch_size}, {learning_rate}"
            )
        device = self.obs_mean.device  # fit where the module lives (SB3's device="auto" may be CUDA)
        batch = self.encoder.batch(demos.observations)
        flat = self.encoder.flat(batch)
        mean, std = observation_statistics(flat)
        # Only Box columns are standardised; one-hot and binary columns stay as SB3 feeds them.
        box = self.encoder.box_columns
        mean, std = np.where(box, mean, 0.0), np.where(box, std, 1.0)
        with th.no_grad():
            self.obs_mean.copy_(th.as_tensor(mean))
            self.obs_std.copy_(th.as_tensor(std))
        obs = th.as_tensor(flat, device=device)
        images = [th.as_tensor(img, device=device) for img in self.encoder.images(batch)]
        targets = self._targets(demos.actions, device)

        rng = np.random.default_rng(self.seed)
        n = len(demos)
        # One fixed bootstrap resample per member: rows of indices into the demo steps.
        boot = rng.integers(0, n, size=(self.n_members, n))
        members = np.arange(self.n_members)[:, None]
        optimizer = th.optim.Adam(self.parameters(), lr=learning_rate)
        epochs: Any = range(n_epochs)
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
                per_member = self._loss(self(obs[idx], [img[idx] for img in images]), targets[idx])
                optimizer.zero_grad(set_to_none=True)
                # Members are independent (the shared trunk learns from all), so summing their losses
                # trains each head on its own loss.
                per_member.sum().backward()
                optimizer.step()
                epoch_loss += per_member.detach().cpu().numpy() * idx.shape[1]
        self.eval()
        self.train_loss_ = epoch_loss / n
        return self.mark_fitted(demos.actions)

    def mark_fitted(self, actions: np.ndarray | None) -> BCEnsemble:
        """Mark the members' current weights as fitted (``fit`` does, and so does a caller that loaded
        them by hand). ``disagreement="auto"`` then takes its form from ``actions``, the training
        demonstrations' actions; None keeps the form it has (a loaded state dict's)."""
        with th.no_grad():
            self.fitted.fill_(1.0)
            if self.requested_disagreement == "auto" and actions is not None:
                chosen = auto_disagreement_form(actions, self.action_space)
                self.unclipped.fill_(float(chosen == "std_unclipped"))
        self._resolve_auto()
        self._np_cache = None
        return self

    def mark_unfitted(self) -> BCEnsemble:
        """Forget the fit: the members keep their weights, and whoever needs a fitted ensemble
        (disagreement, a learner's pretraining) fits it again."""
        with th.no_grad():
            self.fitted.fill_(0.0)
        self._np_cache = None
        return self

    def _resolve_auto(self) -> None:
        if self.requested_disagreement == "auto":
            self.disagreement_form = "std_unclipped" if float(self.unclipped) != 0.0 else "std"

    def _targets(self, actions: np.ndarray, device: th.device) -> th.Tensor:
        if self.action_kind == "categorical":
            idx = actions_as_indices(actions, self.action_space).reshape(len(actions), -1)
            return th.as_tensor(idx, dtype=th.long, device=device)
        targets = th.as_tensor(actions_as_indices(actions, self.action_space), device=device)
        if self.action_kind == "box":
            targets = th.max(th.min(targets, self.action_high), self.action_low)
        return targets

    # -- inference (scoring) -----------------------------------------------------------------
    def _numpy_params(self) -> dict[str, Any]:
        if self._np_cache is None:
            if not self.is_fitted:
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

    def member_outputs(self, obs: Observations, clip: bool = True) -> np.ndarray:
        """Each member's output on a batch (or a single observation): (E, B, out_dim) actions clipped
        to the bounds (Box, flattened; as they are with ``clip=False``), probabilities of each
        component's actions (Discrete, MultiDiscrete) or of each bit (MultiBinary). The returned
        array may be a reused buffer: copy it to keep it."""
        p = self._numpy_params()
        batch = self.encoder.batch(obs)
        x = self.encoder.flat(batch)
        if len(x) > _NUMPY_MAX_BATCH or len(self.trunks):
            return self._torch_outputs(x, self.encoder.images(batch), clip)
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
        if self.action_kind == "categorical":
            start = 0
            for n in self.segments:
                seg = h[..., start : start + n]
                np.subtract(seg, seg.max(axis=2, keepdims=True), out=seg)
                np.exp(seg, out=seg)
                np.divide(seg, seg.sum(axis=2, keepdims=True), out=seg)
                start += n
        elif self.action_kind == "binary":
            np.negative(h, out=h)
            np.exp(h, out=h)
            np.add(h, 1.0, out=h)
            np.reciprocal(h, out=h)
        elif clip:
            np.minimum(h, p["high"], out=h)
            np.maximum(h, p["low"], out=h)
        return h

    def _torch_outputs(self, x: np.ndarray, images: list[np.ndarray], clip: bool = True) -> np.ndarray:
        device = self.obs_mean.device
        chunks = []
        with th.inference_mode():
            for start in range(0, max(len(x), 1), _TORCH_CHUNK):
                rows = slice(start, start + _TORCH_CHUNK)
                imgs = [th.as_tensor(img[rows], device=device) for img in images]
                out = self(th.as_tensor(x[rows], device=device), imgs)
                if self.action_kind == "categorical":
                    out = th.cat([th.softmax(seg, dim=2) for seg in th.split(out, self.segments, dim=2)], dim=2)
                elif self.action_kind == "binary":
                    out = th.sigmoid(out)
                elif clip:
                    out = th.max(th.min(out, self.action_high), self.action_low)
                chunks.append(out.cpu().numpy())
        return chunks[0] if len(chunks) == 1 else np.concatenate(chunks, axis=1)

    def predict(self, obs: Observations) -> np.ndarray:
        """The ensemble's action for each observation, shaped as the action space's samples (batched):
        the mean action (Box, clipped), each component's most probable action (Discrete,
        MultiDiscrete, start included), each bit's more probable value (MultiBinary)."""
        out = self.member_outputs(obs).mean(axis=0)
        if self.action_kind == "categorical":
            idx = np.stack([seg.argmax(axis=1) for seg in np.split(out, np.cumsum(self.segments)[:-1], axis=1)], 1)
            return indices_as_actions(idx, self.action_space)
        if self.action_kind == "binary":
            return (out > 0.5).astype(self.action_space.dtype).reshape((len(out), *self.action_shape))
        return out.reshape((len(out), *self.action_shape))

    @property
    def needs_actions(self) -> bool:
        """Whether :meth:`disagreement` uses the agent's actions."""
        if self.action_kind == "box":
            return self.disagreement_form == "quadratic"
        return self.action_kind == "categorical"

    def disagreement(self, obs: Observations, actions: np.ndarray | None = None) -> np.ndarray:
        """Disagreement ``u`` for each observation, (B,) float64 (see the module docstring).
        ``actions`` are the space's own (Discrete/MultiDiscrete: with their ``start``)."""
        out = self.member_outputs(obs, clip=self.disagreement_form != "std_unclipped")
        batch = out.shape[1]
        if self.action_kind == "categorical":
            return self._categorical_disagreement(out, actions)
        if self.action_kind == "binary":
            spread = out.var(axis=0) if self.disagreement_form == "quadratic" else out.std(axis=0)
            return spread.sum(axis=1).astype(np.float64)
        # Deviations from member 0 (a shifted variance): exactly 0 when the members agree, where
        # deviations from the float32 mean would leave rounding noise.
        dev = out[1:] - out[0]
        if self.disagreement_form != "quadratic":
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

    def _categorical_disagreement(self, out: np.ndarray, actions: np.ndarray | None) -> np.ndarray:
        batch = out.shape[1]
        u = np.zeros(batch, np.float64)
        if actions is not None:
            idx = actions_as_indices(np.asarray(actions).reshape(batch, -1), self.action_space).reshape(batch, -1)
            if idx.shape[1] != len(self.segments):
                raise ValueError(f"actions have {idx.shape[1]} components, the action space {len(self.segments)}")
            high = np.asarray(self.segments) - 1
            if idx.min() < 0 or np.any(idx.max(axis=0) > high):
                ranges = [f"[{lo}, {lo + hi}]" for lo, hi in zip(self._starts, high, strict=True)]
                raise ValueError(f"discrete actions must lie in {', '.join(ranges)}")
        start = 0
        for j, n in enumerate(self.segments):
            seg = out[:, :, start : start + n]
            start += n
            if actions is None:
                spread = seg.std(axis=0).mean(axis=1)
            else:
                spread = seg[:, np.arange(batch), idx[:, j]].std(axis=0)
            u += spread * spread if self.disagreement_form == "quadratic" else spread
        return u

    # -- persistence ---------------------------------------------------------------------------
    def load_state_dict(self, state_dict: Any, strict: bool = True, assign: bool = False) -> Any:
        # torch 2.0 (the floor pyproject.toml declares) has no `assign`: pass it on only when asked for.
        options = {"assign": True} if assign else {}
        result = super().load_state_dict(state_dict, strict=strict, **options)
        self._np_cache = None
        self._resolve_auto()
        return result

    def _config(self) -> dict[str, Any]:
        return {
            "observation_space": space_to_config(self.observation_space),
            "action_space": space_to_config(self.action_space),
            "n_members": self.n_members,
            "hidden_sizes": list(self.hidden_sizes),
            "disagreement": self.requested_disagreement,
            "seed": self.seed,
            "image_features": self.image_features,
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
            raise MissingFileError(f"ensemble file not found: {path}")
        try:
            blob = th.load(path, map_location="cpu", weights_only=True)
            cfg = blob["config"]
            obs_space, act_space = _config_spaces(cfg)
        except Exception as e:  # torch raises several types for a damaged file
            raise UserError(f"ensemble file {path} is corrupt or not a BCEnsemble file: {e}") from e
        ens = cls(
            obs_space,
            act_space,
            cfg["n_members"],
            cfg["hidden_sizes"],
            cfg["disagreement"],
            cfg["seed"],
            cfg.get("image_features", 128),
        )
        ens.load_state_dict(blob["state_dict"])
        return ens

    def extra_repr(self) -> str:
        return (
            f"n_members={self.n_members}, hidden_sizes={self.hidden_sizes}, obs_dim={self.obs_dim}, "
            f"images={len(self.trunks)}, out_dim={self.out_dim}, actions={self.action_kind!r}, "
            f"disagreement={self.requested_disagreement!r}"
            + (f" (-> {self.disagreement_form!r})" if self.requested_disagreement == "auto" else "")
        )


def share_on_bound(actions: np.ndarray, action_space: spaces.Space) -> float:
    """The share of the entries of ``actions`` that sit exactly on a bound of a Box ``action_space`` (0 for
    any other space, and for no actions): what ``disagreement="auto"`` reads."""
    if not isinstance(action_space, spaces.Box) or not len(actions):
        return 0.0
    # Exactly on it, in float32: a clipping expert lands there; a tanh-squashed one only where float32
    # rounds tanh to 1. An unbounded side (inf) is never met.
    a = np.asarray(actions, np.float32).reshape(len(actions), -1)
    low = np.asarray(action_space.low, np.float32).reshape(-1)
    high = np.asarray(action_space.high, np.float32).reshape(-1)
    return float(np.mean((a == low) | (a == high)))


def auto_disagreement_form(actions: np.ndarray, action_space: spaces.Space) -> str:
    """The form ``disagreement="auto"`` takes for demonstrations with these ``actions``."""
    return "std_unclipped" if share_on_bound(actions, action_space) >= AUTO_UNCLIPPED_SHARE else "std"


def _config_spaces(cfg: dict[str, Any]) -> tuple[spaces.Space, spaces.Space]:
    if "observation_space" in cfg:
        return space_from_config(cfg["observation_space"]), space_from_config(cfg["action_space"])
    # Files from before Dict and multi-discrete support: a Box observation, Box or Discrete actions.
    obs_space = spaces.Box(
        np.asarray(cfg["obs_low"], np.float32).reshape(cfg["obs_shape"]),
        np.asarray(cfg["obs_high"], np.float32).reshape(cfg["obs_shape"]),
    )
    if cfg["discrete_n"]:
        return obs_space, spaces.Discrete(cfg["discrete_n"])
    act_space = spaces.Box(
        np.asarray(cfg["act_low"], np.float32).reshape(cfg["act_shape"]),
        np.asarray(cfg["act_high"], np.float32).reshape(cfg["act_shape"]),
    )
    return obs_space, act_space


def disagreement_on_demos(ensemble: Any, demos: Demonstrations) -> np.ndarray:
    """u at every demonstration step, with the expert's own actions, (N,) float64."""
    return np.concatenate(
        [
            ensemble.disagreement(take(demos.observations, slice(i, i + 4096)), demos.actions[i : i + 4096])
            for i in range(0, len(demos), 4096)
        ]
    )


def quantile_of_disagreement(ensemble: Any, demos: Demonstrations, q: float) -> float:
    """The q-quantile of u over the demonstration steps, with the expert's own actions."""
    if not 0.0 < q <= 1.0:
        raise UserError(f"quantile q must lie in (0, 1], got {q}")
    return float(np.quantile(disagreement_on_demos(ensemble, demos), q))
