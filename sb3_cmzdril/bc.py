"""Deprecated since 0.2.0: behaviour cloning lives in :mod:`sb3_cmzdril.common.bc`; this path goes in
0.3.0."""
import warnings

warnings.warn("sb3_cmzdril.bc moved to sb3_cmzdril.common.bc in 0.2.0; the old path goes in 0.3.0",
              FutureWarning, stacklevel=2)

from sb3_cmzdril.common.bc import *  # noqa: E402,F403
from sb3_cmzdril.common.bc import (  # noqa: E402
    BehaviourCloner,
    EarlyStopping,
    ObsTransform,
    StepLoss,
    TensorObs,
    nll_loss,
)

__all__ = ["BehaviourCloner", "EarlyStopping", "ObsTransform", "StepLoss", "TensorObs", "nll_loss"]
