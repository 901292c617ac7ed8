"""Deprecated since 0.2.0: CMZDRILSAC lives in :mod:`sb3_cmzdril.cmzdril_sac` (``from sb3_cmzdril import
CMZDRILSAC`` as before); this path goes in 0.3.0."""
import warnings

warnings.warn("sb3_cmzdril.sac moved to sb3_cmzdril.cmzdril_sac in 0.2.0; the old path goes in 0.3.0",
              FutureWarning, stacklevel=2)

from sb3_cmzdril.cmzdril_sac.cmzdril_sac import *  # noqa: E402,F403
from sb3_cmzdril.cmzdril_sac.cmzdril_sac import CMZDRILSAC, ScaledActionMSE  # noqa: E402

__all__ = ["CMZDRILSAC", "ScaledActionMSE"]
