"""Deprecated since 0.2.0: what both learners share lives in :mod:`sb3_cmzdril.common` (the imitation
part in :mod:`sb3_cmzdril.common.imitation`, its save format in :mod:`sb3_cmzdril.common.saving`, the
checks of the options in :mod:`sb3_cmzdril.common.options`); this path goes in 0.3.0."""
import warnings

warnings.warn("sb3_cmzdril.imitation moved to sb3_cmzdril.common.imitation in 0.2.0; the old path goes in 0.3.0",
              FutureWarning, stacklevel=2)

from sb3_cmzdril.common.imitation import reward_rule, rule_bounds  # noqa: E402
from sb3_cmzdril.common.options import (  # noqa: E402
    REWARD_MODES,
    check_imitation_options,
    check_interval,
    check_whole_numbers,
)
from sb3_cmzdril.common.saving import (  # noqa: E402
    check_saved_learner,
    demo_tensors,
    demonstrations_to_go_on,
    demos_from_tensors,
    parameters_to_set,
    restored_state,
    restoring_saved_model,
    weights_brought_by_user,
)

__all__ = ["REWARD_MODES", "check_imitation_options", "check_interval", "check_saved_learner", "check_whole_numbers",
           "demo_tensors", "demonstrations_to_go_on", "demos_from_tensors", "parameters_to_set", "reward_rule",
           "restored_state", "restoring_saved_model", "rule_bounds", "weights_brought_by_user"]
