"""sb3-cmzdril: CMZ-DRIL and its baselines for stable-baselines3.

``from sb3_cmzdril import CMZDRIL`` and use it where you would use ``PPO`` (``CMZDRILSAC`` where you
would use ``SAC``); see the README.
"""
from sb3_cmzdril import envs  # noqa: F401  (registers WaypointNav-v0 with gymnasium)
from sb3_cmzdril._version import __version__ as __version__
from sb3_cmzdril.cmzdril import CMZDRIL
from sb3_cmzdril.cmzdril_sac import CMZDRILSAC
from sb3_cmzdril.data.demos import Demonstrations
from sb3_cmzdril.ensemble import BCEnsemble
from sb3_cmzdril.errors import UserError
from sb3_cmzdril.rewards import CMZReward, DisagreementReward, DRILReward

__all__ = [
    "CMZDRIL",
    "CMZDRILSAC",
    "Demonstrations",
    "BCEnsemble",
    "DisagreementReward",
    "CMZReward",
    "DRILReward",
    "UserError",
]
