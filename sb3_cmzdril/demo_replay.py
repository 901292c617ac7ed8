"""Deprecated since 0.2.0: the demo-mixing replay buffer lives in
:mod:`sb3_cmzdril.cmzdril_sac.demo_replay`; this path goes in 0.3.0 (models saved with it load as before:
``load()`` reads the old path a zip names without a warning)."""
import warnings

warnings.warn("sb3_cmzdril.demo_replay moved to sb3_cmzdril.cmzdril_sac.demo_replay in 0.2.0; the old path "
              "goes in 0.3.0", FutureWarning, stacklevel=2)

from sb3_cmzdril.cmzdril_sac.demo_replay import *  # noqa: E402,F403
from sb3_cmzdril.cmzdril_sac.demo_replay import DemoReplayBuffer, DemoTransitions, Relabel  # noqa: E402

__all__ = ["DemoReplayBuffer", "DemoTransitions", "Relabel"]
