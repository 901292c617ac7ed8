"""Deprecated since 0.2.0: the paper's experiment left the library.

One run of ``train`` is :mod:`sb3_cmzdril.training`; the trial grid and the report are the lab's
(``cmzdril_lab.run``, ``cmzdril_lab.report``; ``pip install -e lab/`` in a clone of the repository).
The old import paths keep working, with one FutureWarning, until 0.3.0: each resolves to the module
that now holds it. The lab is looked up by name only when an old path asks for it.
"""
from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import warnings
from types import ModuleType
from typing import Any

#: Old module path -> where it lives now (longest prefix wins).
MOVED = {
    "sb3_cmzdril.experiments.run.spec": "sb3_cmzdril.training.spec",
    "sb3_cmzdril.experiments.run.run_folder": "sb3_cmzdril.training.run_folder",
    "sb3_cmzdril.experiments.run.runs": "sb3_cmzdril.training.runs",
    "sb3_cmzdril.experiments.run": "cmzdril_lab.run",
    "sb3_cmzdril.experiments.report": "cmzdril_lab.report",
}
#: The names this package exported -> the module that holds them now.
_NAMES = {
    "METHODS": "sb3_cmzdril.training.spec",
    "RunSpec": "sb3_cmzdril.training.spec",
    "plan_run": "sb3_cmzdril.training.spec",
    "run_experiment": "sb3_cmzdril.training.runs",
    "plan_grid": "cmzdril_lab.run.grid",
    "run_grid": "cmzdril_lab.run.grid",
    "benchmark": "cmzdril_lab.run.grid",
    "write_report": "cmzdril_lab.report",
    "run": "cmzdril_lab",
    "report": "cmzdril_lab",
}


def new_name(old: str) -> str | None:
    """Where the module ``old`` (a path under ``sb3_cmzdril.experiments``) lives now."""
    for prefix in sorted(MOVED, key=len, reverse=True):
        if old == prefix or old.startswith(prefix + "."):
            return MOVED[prefix] + old[len(prefix):]
    return None


def _warn(old: str, new: str) -> None:
    warnings.warn(f"{old} moved to {new} in sb3-cmzdril 0.2.0; the old path goes in 0.3.0",
                  FutureWarning, stacklevel=3)


class _MovedModules(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Resolves an old module path to the module that holds it now (the same module object)."""

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> importlib.machinery.ModuleSpec | None:
        if new_name(fullname) is None:
            return None
        return importlib.machinery.ModuleSpec(fullname, self)

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        new = new_name(spec.name)
        assert new is not None
        _warn(spec.name, new)
        try:
            return importlib.import_module(new)
        except ModuleNotFoundError as error:
            if error.name != "cmzdril_lab":
                raise
            if any(old.startswith(spec.name + ".") for old in MOVED):  # a parent of library modules
                package = ModuleType(spec.name)
                package.__path__ = []
                return package
            raise ModuleNotFoundError(
                f"{spec.name} moved to the lab ({new}), which is not installed: pip install -e lab/ in a clone "
                "of the sb3-cmzdril repository", name=new) from None

    def exec_module(self, module: ModuleType) -> None:
        """Nothing to run: the module is already imported under its new name."""


if not any(isinstance(finder, _MovedModules) for finder in sys.meta_path):
    sys.meta_path.insert(0, _MovedModules())


def __getattr__(name: str) -> Any:
    if name not in _NAMES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    _warn(f"{__name__}.{name}", f"{_NAMES[name]}.{name}")
    return getattr(importlib.import_module(_NAMES[name]), name)
