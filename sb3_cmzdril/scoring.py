"""Deprecated since 0.2.0: CMZDRIL's rollout scoring lives in :mod:`sb3_cmzdril.cmzdril.scoring`, what
both learners use of it in :mod:`sb3_cmzdril.common.imitation`; this path goes in 0.3.0."""
import warnings

warnings.warn("sb3_cmzdril.scoring moved to sb3_cmzdril.cmzdril.scoring in 0.2.0; the old path goes in 0.3.0",
              FutureWarning, stacklevel=2)

from sb3_cmzdril.cmzdril.scoring import *  # noqa: E402,F403
from sb3_cmzdril.cmzdril.scoring import RolloutRecord, RolloutScores, score_rollout  # noqa: E402
from sb3_cmzdril.common.imitation import buffer_actions, disagreement_where_ended  # noqa: E402

__all__ = ["RolloutRecord", "RolloutScores", "buffer_actions", "disagreement_where_ended", "score_rollout"]
