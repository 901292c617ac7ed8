"""Deprecated since 0.2.0: CMZDRIL lives in :mod:`sb3_cmzdril.cmzdril` (``from sb3_cmzdril import CMZDRIL``
as before); this path goes in 0.3.0."""
import warnings

warnings.warn("sb3_cmzdril.algorithm moved to sb3_cmzdril.cmzdril in 0.2.0; the old path goes in 0.3.0",
              FutureWarning, stacklevel=2)

from sb3_cmzdril.cmzdril.cmzdril import *  # noqa: E402,F403
from sb3_cmzdril.cmzdril.cmzdril import CMZDRIL, SelfCMZDRIL  # noqa: E402
from sb3_cmzdril.common.imitation import DemosLike  # noqa: E402

__all__ = ["CMZDRIL", "DemosLike", "SelfCMZDRIL"]
