"""Deprecated after 0.2.0: this module lives in :mod:`sb3_cmzdril.data.demos` (``from sb3_cmzdril import
Demonstrations`` as before); this path goes in 0.4.0."""
import warnings

warnings.warn("sb3_cmzdril.demos moved to sb3_cmzdril.data.demos after 0.2.0; the old path goes in 0.4.0",
              FutureWarning, stacklevel=2)

from sb3_cmzdril.data.demos import *  # noqa: E402,F403
