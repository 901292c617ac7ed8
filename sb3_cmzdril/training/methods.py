"""The methods a run can use, each once: which learner trains it, with which reward, and what follows.

:data:`METHOD_REGISTRY` maps each method name to its :class:`Method`; every place that acts on a
method asks its entry (``Method.of(name)``) instead of comparing names. A method is a learner
(:data:`PPO_LEARNER`: CMZDRIL; :data:`SAC_LEARNER`: the off-policy CMZDRILSAC) with a reward mode; what
belongs to the learner (its hyperparameter file, the policy it hands back, the reward-free choice it
keeps) is said once, in its :class:`Learner`. The tuples and helpers below (:data:`METHODS`,
:func:`is_off_policy`, :func:`result_policy`, ...) are views of the registry.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

from sb3_cmzdril.errors import UserError

if TYPE_CHECKING:  # heavy (torch, SB3): imported when a learner is asked for, not when this module is
    from stable_baselines3.common.base_class import BaseAlgorithm

#: Hyperparameter file of the repository used when none is given (hyperparams/cmzdril.yml).
HYPERPARAMS_NAME = "cmzdril"
#: The same for the off-policy methods (hyperparams/cmzdril_sac.yml).
OFFPOLICY_HYPERPARAMS_NAME = "cmzdril_sac"


@dataclasses.dataclass(frozen=True)
class Learner:
    """What a learner brings to every method it trains."""

    name: str  #: "ppo" (CMZDRIL) or "sac" (CMZDRILSAC)
    off_policy: bool  #: whether it learns from a replay buffer (an epoch is then a length of steps)
    hyperparams_name: str  #: the shipped hyperparams/<name>.yml its methods read when none is given
    #: the final-evaluation policy its methods hand back as their result: "longest" for the off-policy
    #: learner, whose last weights can fall in a run's last steps after walking for most of it (the
    #: policy whose deterministic episodes from fixed starts lasted longest, chosen without the env
    #: reward), "final" (the last weights) for CMZDRIL
    result_policy: str
    #: final_eval.csv's name of the reward-free choice a run keeps beside its last weights: the policy
    #: whose own training rollout had the lowest disagreement (CMZDRIL), or whose episodes lasted longest
    #: (CMZDRILSAC, whose rollouts are single steps)
    kept: str

    def classes(self) -> tuple[Any, type[BaseAlgorithm]]:
        """(the learner's class, the SB3 algorithm it extends): its constructor's arguments are the
        union of both. The learner is Any: CMZDRIL and CMZDRILSAC share their imitation interface but
        differ beyond what a common type would say."""
        if self.off_policy:
            from stable_baselines3 import SAC

            from sb3_cmzdril import CMZDRILSAC

            return CMZDRILSAC, SAC
        from stable_baselines3 import PPO

        from sb3_cmzdril import CMZDRIL

        return CMZDRIL, PPO


PPO_LEARNER = Learner("ppo", off_policy=False, hyperparams_name=HYPERPARAMS_NAME, result_policy="final",
                      kept="lowest_u")
SAC_LEARNER = Learner("sac", off_policy=True, hyperparams_name=OFFPOLICY_HYPERPARAMS_NAME, result_policy="longest",
                      kept="longest")


@dataclasses.dataclass(frozen=True)
class Method:
    """One method: a learner trained with a reward mode (``reward``, the learner's ``reward=``)."""

    name: str
    learner: Learner
    reward: str  #: "cmz", "dril", "zero" (none) or "env"
    paper: bool = True  #: in the paper's comparison: what a grid runs when no method is named
    #: BC: the learner's pretrained policy alone (no reward, no RL steps, no checkpoint to go on from)
    pretrain_only: bool = False

    @classmethod
    def of(cls, name: str) -> Method:
        """The registry's entry for ``name``; a UserError listing the known ones otherwise."""
        try:
            return METHOD_REGISTRY[name]
        except (KeyError, TypeError):
            raise UserError(f"unknown method {name!r}; choose from {', '.join(METHODS)}") from None

    @property
    def off_policy(self) -> bool:
        """Whether its learner is the off-policy one (:attr:`Learner.off_policy`): asked in many places."""
        return self.learner.off_policy

    @property
    def recorded_reward(self) -> str:
        """config.json's ``reward``: the method, or that BC has none."""
        return "none (BC: pretrained policy only)" if self.pretrain_only else self.name


#: Every method, in the order the command line lists them: plain BC and the four reward modes of
#: CMZDRIL (PPO), the paper's comparison; then the off-policy learner CMZDRILSAC with each reward mode,
#: named ``<reward>-sac``: ``cmz-sac`` is the package's off-policy method, the others its comparisons.
METHOD_REGISTRY: Mapping[str, Method] = MappingProxyType({m.name: m for m in (
    Method("bc", PPO_LEARNER, "zero", pretrain_only=True),
    Method("zero", PPO_LEARNER, "zero"),
    Method("env", PPO_LEARNER, "env"),
    Method("dril", PPO_LEARNER, "dril"),
    Method("cmz", PPO_LEARNER, "cmz"),
    Method("cmz-sac", SAC_LEARNER, "cmz", paper=False),
    Method("dril-sac", SAC_LEARNER, "dril", paper=False),
    Method("zero-sac", SAC_LEARNER, "zero", paper=False),
    Method("env-sac", SAC_LEARNER, "env", paper=False),
)})
#: The learners, CMZDRIL first.
LEARNERS: tuple[Learner, ...] = tuple(dict.fromkeys(m.learner for m in METHOD_REGISTRY.values()))

# -- views of the registry --------------------------------------------------------------------------
#: Methods of the paper's comparison, then the off-policy ones (:data:`OFFPOLICY_METHODS`).
METHODS: tuple[str, ...] = tuple(METHOD_REGISTRY)
#: Methods trained by CMZDRILSAC, each with the reward mode it names before ``-sac``.
OFFPOLICY_METHODS: tuple[str, ...] = tuple(m.name for m in METHOD_REGISTRY.values() if m.off_policy)
#: The paper's comparison: what a grid runs when no method is named.
PAPER_METHODS: tuple[str, ...] = tuple(m.name for m in METHOD_REGISTRY.values() if m.paper)


def check_method(method: str) -> str:
    """The method name, or a UserError listing the known ones."""
    return Method.of(method).name


def is_off_policy(method: str) -> bool:
    """Whether ``method`` is trained by CMZDRILSAC (:data:`OFFPOLICY_METHODS`)."""
    return method in METHOD_REGISTRY and METHOD_REGISTRY[method].off_policy


def _learner(method: str) -> Learner:
    """``method``'s learner; CMZDRIL's for a name the registry does not hold (a record's, say)."""
    return METHOD_REGISTRY[method].learner if method in METHOD_REGISTRY else PPO_LEARNER


def result_policy(method: str) -> str:
    """The final-evaluation policy ``method`` hands back as its result (:attr:`Learner.result_policy`)."""
    return _learner(method).result_policy


def learner_classes(method: str) -> tuple[Any, type[BaseAlgorithm]]:
    """(the method's learner class, the SB3 algorithm it extends): :meth:`Learner.classes`."""
    return _learner(method).classes()


def default_hyperparams_name(method: str) -> str:
    """The shipped hyperparameter file a method reads when none is given: cmzdril.yml (PPO), cmzdril_sac.yml."""
    return _learner(method).hyperparams_name


__all__ = [
    "HYPERPARAMS_NAME",
    "LEARNERS",
    "METHODS",
    "METHOD_REGISTRY",
    "OFFPOLICY_HYPERPARAMS_NAME",
    "OFFPOLICY_METHODS",
    "PAPER_METHODS",
    "PPO_LEARNER",
    "SAC_LEARNER",
    "Learner",
    "Method",
    "check_method",
    "default_hyperparams_name",
    "is_off_policy",
    "learner_classes",
    "result_policy",
]
