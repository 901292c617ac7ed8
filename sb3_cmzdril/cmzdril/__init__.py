"""CMZDRIL: SB3's PPO with CMZ-DRIL's imitation part (:mod:`sb3_cmzdril.cmzdril.cmzdril`), and the rollout
scoring it alone uses (:mod:`sb3_cmzdril.cmzdril.scoring`)."""
from sb3_cmzdril.cmzdril.cmzdril import CMZDRIL

__all__ = ["CMZDRIL"]
