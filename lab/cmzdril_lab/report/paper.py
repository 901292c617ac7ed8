"""The paper's numbers and names: reference values copied from the paper, kept apart from anything
this code measures. They enter a report only through ``references`` and are printed in their own,
labelled tables or columns: never mixed with measured numbers.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Mapping

from cmzdril_lab.report.formatting import fmt_mean_std, md_table
from cmzdril_lab.report.records import METHOD_LABELS, METHOD_ORDER, env_key


@dataclasses.dataclass(frozen=True)
class ReferenceTable:
    """Numbers reported elsewhere, keyed ``env -> method -> (mean, std)``, shown in their own table."""

    title: str
    note: str
    values: Mapping[str, Mapping[str, tuple[float, float]]]

    @property
    def name(self) -> str:
        """The title without its parenthesised remark, lower-cased first letter ("the paper's Table I")."""
        name = self.title.split(" (")[0]
        return name[:1].lower() + name[1:]


#: The paper's Table I: mean (std) reward over the last 100 training epochs, 5 trials, one demo
#: episode for the MuJoCo envs (v1, mujoco-py) and five for PyUXV. Our envs stand in for theirs.
PAPER_TABLE_I = ReferenceTable(
    title="The paper's Table I (reported numbers, copied from the paper, not produced by this code)",
    note=(
        "Mean (std) reward over the last 100 training epochs. The paper's envs: PyUXV (our stand-in: "
        "WaypointNav-v0), MuJoCo Half Cheetah and Hopper version 1 (we run -v5); DRIL was not tested on PyUXV."
    ),
    values={
        "WaypointNav-v0": {"bc": (-52.6, 45.0), "cmz": (-34.8, 29.4)},
        "HalfCheetah-v5": {"bc": (708.0, 162.0), "dril": (277.0, 60.9), "cmz": (1690.0, 360.0)},
        "Hopper-v5": {"bc": (704.0, 248.0), "dril": (244.0, 23.0), "cmz": (1140.0, 514.0)},
    },
)

#: What the paper calls the envs we stand in for.
PAPER_ENV_NAMES: dict[str, str] = {
    "WaypointNav-v0": "PyUXV",
    "HalfCheetah-v5": "Half Cheetah v1",
    "Hopper-v5": "Hopper v1",
}


def reference_markdown(reference: ReferenceTable, heading: str = "###") -> str:
    """A reference table in the paper's layout (methods as rows, envs as columns), with title (a ``heading``)
    and note."""
    envs = sorted(reference.values, key=env_key)
    methods = [m for m in METHOD_ORDER if any(m in reference.values[e] for e in envs)]
    body = ([METHOD_LABELS[m], *(fmt_mean_std(*reference.values[e][m]) if m in reference.values[e] else "—"
                                 for e in envs)] for m in methods)
    return f"{heading} {reference.title}\n\n{reference.note}\n\n{md_table(['Method', *envs], body)}\n"


__all__ = ["ReferenceTable", "PAPER_TABLE_I", "PAPER_ENV_NAMES", "reference_markdown"]
