"""CMZDRILSAC: SB3's SAC with CMZ-DRIL's imitation part, off-policy
(:mod:`sb3_cmzdril.cmzdril_sac.cmzdril_sac`), and its replay buffer that mixes the demonstrations into
every batch (:mod:`sb3_cmzdril.cmzdril_sac.demo_replay`)."""
from sb3_cmzdril.cmzdril_sac.cmzdril_sac import CMZDRILSAC

__all__ = ["CMZDRILSAC"]
