"""rl-zoo3 plugin: train CMZDRIL with the zoo's own ``train`` entry point and flags.

``python -m sb3_cmzdril.zoo --env HalfCheetah-v5 -n 300000`` is rl-zoo3's ``train.py`` with
``cmzdril`` registered (``--algo`` defaults to ``cmzdril``, ``--conf-file`` to the shipped
``hyperparams/cmzdril.yml``); every other flag is the zoo's. In a script, :func:`register` does the
registration: ``rl_zoo3.ALGOS["cmzdril"]``.

The class the zoo builds is :class:`ZooCMZDRIL`, a :class:`~sb3_cmzdril.CMZDRIL` that also takes
what a zoo YAML holds besides constructor arguments: ``n_demos`` (train on the first ``n_demos``
episodes of the demonstrations; one when it is left out, as for ``sb3-cmzdril train``), no
``demonstrations`` at all (the shipped pool
``experts/<EnvId>/demos.npz``, looked up in the working directory, then among the shipped pools) and an
entry's ``per_method`` block, whose ``cmz`` settings it takes (the zoo trains CMZ-DRIL).
Its saved models load with ``CMZDRIL.load`` as well. Needs the ``zoo`` extra.
"""
from __future__ import annotations

import argparse
import importlib
import numbers
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sb3_cmzdril.cmzdril import CMZDRIL
from sb3_cmzdril.common.imitation import DemosLike
from sb3_cmzdril.data.demos import Demonstrations, as_demonstrations
from sb3_cmzdril.errors import MissingFileError, UserError
from sb3_cmzdril.extras import require_extra
from sb3_cmzdril.hyperparams import (
    FALLBACK_N_DEMOS,
    FALLBACK_POLICY,
    PER_METHOD_KEY,
    SPECIAL_KEYS,
    resolve_per_method,
    split_hyperparams,
)

ALGO = "cmzdril"
#: The method of a grid the zoo's CMZDRIL is: whose settings it takes from an entry's ``per_method`` block.
METHOD = "cmz"
#: Where ``collect-demos`` puts an env's demo pool, relative to the working directory.
DEMOS_DIR = Path("experts")
#: rl-zoo3 modules that hold an ``ALGOS`` table (all the same dict in rl-zoo3 2.x, but updated one
#: by one so a release that copies it still sees cmzdril).
_ZOO_MODULES = ("rl_zoo3", "rl_zoo3.utils", "rl_zoo3.exp_manager", "rl_zoo3.train")


def env_id_of(env: Any) -> str:
    """The registered id (without ``module:`` prefix) of an env id, a gymnasium env or a VecEnv."""
    if isinstance(env, str):
        return env.rsplit(":", 1)[-1]
    spec = env.get_attr("spec", [0])[0] if hasattr(env, "get_attr") else getattr(env, "spec", None)
    if spec is None:
        raise UserError(
            f"cannot tell which environment {type(env).__name__} is (it has no gymnasium spec), so there is no "
            "default demo pool: give `demonstrations: path/to/demos.npz` in the hyperparameters"
        )
    return spec.id


def default_demos_path(env: Any) -> Path:
    """``experts/<EnvId>/demos.npz`` in the working directory, else the shipped pool of that env."""
    from sb3_cmzdril.shipped import local_or_shipped_demos

    path = local_or_shipped_demos(env_id_of(env), DEMOS_DIR)
    if not path.is_file():
        raise MissingFileError(
            f"no demonstrations given and no demo pool at {path} or shipped with sb3-cmzdril: record one with "
            "`sb3-cmzdril collect-demos`, or give `demonstrations: path/to/demos.npz` in the hyperparameters "
            "(or -params demonstrations:\"'path'\")"
        )
    return path


def method_settings(per_method: Any) -> dict[str, Any]:
    """The constructor arguments an entry's ``per_method`` block gives CMZ-DRIL (:data:`METHOD`), with the
    schedules and expressions read as the zoo reads the entry's own. A key the zoo handles itself
    (``normalize``, ``n_envs``, ``policy_kwargs``...) is refused: the zoo has used the entry's already."""
    if per_method is None:
        return {}
    settings, _ = resolve_per_method({PER_METHOD_KEY: per_method}, METHOD, "the zoo's hyperparameters")
    special = [key for key in SPECIAL_KEYS if key in settings]
    if special:
        raise UserError(f"the zoo's hyperparameters: {PER_METHOD_KEY}.{METHOD} sets {special}, which the zoo reads "
                        "only at the entry's top level")
    return split_hyperparams(settings, key=f"{PER_METHOD_KEY}.{METHOD}").algo_kwargs


def first_episodes(demos: Demonstrations, n_demos: int | None) -> Demonstrations:
    """The first ``n_demos`` episodes (all of them for None)."""
    if n_demos is None:
        return demos
    if isinstance(n_demos, bool) or not isinstance(n_demos, numbers.Integral) or not 1 <= n_demos <= demos.n_episodes:
        raise UserError(f"n_demos must be an integer in [1, {demos.n_episodes}] (episodes available), got {n_demos!r}")
    return demos if n_demos == demos.n_episodes else demos.select(range(n_demos))


class ZooCMZDRIL(CMZDRIL):
    """:class:`~sb3_cmzdril.CMZDRIL` as rl-zoo3 constructs it from a hyperparameter YAML.

    :param policy: as for CMZDRIL; a YAML that names none gets what ``sb3-cmzdril train`` gets.
    :param env: as for CMZDRIL (a keyword here, as the zoo passes it).
    :param demonstrations: as for CMZDRIL; None means the env's shipped pool
        (:func:`default_demos_path`).
    :param n_demos: train on the first ``n_demos`` episodes (None: all); a YAML without it gets what
        ``sb3-cmzdril train`` gets.
    :param kwargs: CMZDRIL's (and PPO's) arguments.
    """

    def __init__(
        self,
        policy: Any = FALLBACK_POLICY,
        env: Any = None,
        demonstrations: DemosLike = None,
        n_demos: int | None = FALLBACK_N_DEMOS,
        per_method: dict[str, Any] | None = None,
        **kwargs: Any,
    ) -> None:
        kwargs.update(method_settings(per_method))
        # load() builds the object with _init_setup_model=False and then restores the saved demos.
        if kwargs.get("_init_setup_model", True):
            if env is None:
                raise TypeError("ZooCMZDRIL needs an env")
            if demonstrations is None:
                demonstrations = default_demos_path(env)
            demonstrations = first_episodes(as_demonstrations(demonstrations), n_demos)
        self.n_demos = n_demos
        super().__init__(policy, env, demonstrations=demonstrations, **kwargs)

    @classmethod
    def load(
        cls,
        path: Any,
        env: Any = None,
        device: Any = "auto",
        custom_objects: dict | None = None,
        print_system_info: bool = False,
        force_reset: bool = True,
        demonstrations: DemosLike = None,
        n_demos: int | None = FALLBACK_N_DEMOS,
        per_method: dict[str, Any] | None = None,
        **kwargs: Any,
    ) -> ZooCMZDRIL:
        """CMZDRIL's load; the zoo's ``-i agent.zip`` passes the YAML's keys, so ``n_demos`` applies to
        ``demonstrations`` when those are given (otherwise the saved demos are kept), and ``per_method``'s
        ``cmz`` settings to the loaded model as the entry's own do."""
        kwargs.update(method_settings(per_method))
        if demonstrations is not None:
            demonstrations = first_episodes(as_demonstrations(demonstrations), n_demos)
        return super().load(
            path, env=env, device=device, custom_objects=custom_objects, print_system_info=print_system_info,
            force_reset=force_reset, demonstrations=demonstrations, **kwargs,
        )


def register(name: str = ALGO) -> type[ZooCMZDRIL]:
    """Add :class:`ZooCMZDRIL` to rl-zoo3's algorithm table(s) under ``name``; idempotent."""
    require_extra("rl_zoo3", "zoo", feature="sb3_cmzdril.zoo")
    for module_name in _ZOO_MODULES:
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as e:
            if e.name != module_name:  # an rl-zoo3 module that exists but cannot import: say so
                raise
            continue
        table = getattr(module, "ALGOS", None)
        if isinstance(table, dict):
            table[name] = ZooCMZDRIL
    return ZooCMZDRIL


def zoo_argv(argv: Sequence[str]) -> list[str]:
    """The zoo's arguments with ``--algo cmzdril`` and our ``--conf-file`` added when absent."""
    argv = list(argv)
    # The zoo's own spellings (argparse also accepts unambiguous prefixes and --flag=value).
    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("--algo")
    parser.add_argument("-conf", "--conf-file")
    known, _ = parser.parse_known_args(argv)
    if known.algo is None:
        argv = ["--algo", ALGO, *argv]
    if (known.algo or ALGO) == ALGO and known.conf_file is None:
        from sb3_cmzdril.hyperparams import default_hyperparams_path

        conf = default_hyperparams_path(ALGO)
        argv += ["--conf-file", str(conf)]
    return argv


def main(argv: Sequence[str] | None = None) -> None:
    """Run rl-zoo3's ``train`` with cmzdril registered (``argv`` defaults to ``sys.argv[1:]``)."""
    register()
    from rl_zoo3.train import train

    args = zoo_argv(sys.argv[1:] if argv is None else argv)
    # The zoo's train() parses sys.argv itself; the program name keeps its usage line right.
    saved = sys.argv
    sys.argv = ["python -m sb3_cmzdril.zoo", *args]
    try:
        train()
    finally:
        sys.argv = saved


if __name__ == "__main__":
    # Run the importable module's main, so the registered class is sb3_cmzdril.zoo.ZooCMZDRIL and
    # not a second copy defined in __main__.
    from sb3_cmzdril.zoo import main as _main

    _main()
