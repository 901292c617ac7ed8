"""What both learners share (as sb3-contrib's ``common``): one imitation part that CMZDRIL (PPO) and
CMZDRILSAC (SAC) compose.

* :mod:`~sb3_cmzdril.common.imitation`: :class:`~sb3_cmzdril.common.imitation.ImitationLearner`, the
  mixin in front of each learner's SB3 algorithm: demonstrations, the bootstrap ensemble (built and
  fitted), the reward rule and its bounds, BC pretraining, ``pretrained``, save/load.
* :mod:`~sb3_cmzdril.common.saving`: the one format the imitation state has in a model's zip.
* :mod:`~sb3_cmzdril.common.options`: the checks of the options both take.
* :mod:`~sb3_cmzdril.common.bc`: behaviour cloning of a policy (NLL by default, or a learner's loss).
"""
