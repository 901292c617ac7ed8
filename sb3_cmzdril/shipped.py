"""Files that come with sb3-cmzdril: the experts' demo pools (``experts/<EnvId>/``) and the
rl-zoo-style hyperparameter files (``hyperparams/*.yml``).

The repository's top-level ``experts/`` and ``hyperparams/`` folders are the source of truth. A
source checkout (editable install, or ``PYTHONPATH``) reads them in place; the wheel carries copies
inside the package (``sb3_cmzdril/_shipped/``, put there by the build step in ``setup.py``), so an
installed package finds them from any working directory. Only ``pathlib`` here: the command line's
defaults and ``hyperparams`` use it without importing SB3.

The wheel carries every demo pool with its ``metadata.json``, our own experts' model zips and the
hyperparameter files (about 15 MB). Third-party experts (the RL Zoo agents behind the Walker2d-v5 and
Swimmer-v5 pools) are not redistributed: their ``metadata.json`` says where they come from.
"""
from __future__ import annotations

import functools
from pathlib import Path

from sb3_cmzdril.errors import MissingFileError
from sb3_cmzdril.io import PathLike, file_sha256

_PACKAGE = Path(__file__).resolve().parent
#: Where a wheel install holds the shipped files.
BUNDLED_DIR = _PACKAGE / "_shipped"
#: Where a source checkout holds them (the repository root).
CHECKOUT_DIR = _PACKAGE.parent


def _roots() -> list[Path]:
    # The bundled copy first: a wheel installed into a folder that happens to hold an experts/
    # directory beside site-packages must still read its own files.
    return [root for root in (BUNDLED_DIR, CHECKOUT_DIR) if (root / "hyperparams").is_dir()]


def shipped_file(*parts: str) -> Path | None:
    """The shipped file at ``parts`` (e.g. ``"experts", "Hopper-v5", "demos.npz"``), or None."""
    for root in _roots():
        path = root.joinpath(*parts)
        if path.is_file():
            return path
    return None


#: The pip constraints file of the versions the published run records were made with.
PUBLISHED_CONSTRAINTS = ("constraints", "published.txt")


def published_versions() -> dict[str, str]:
    """What the published run records were made with: distribution name -> version, from the shipped
    constraints file (``constraints/published.txt``); {} where it is not shipped."""
    path = shipped_file(*PUBLISHED_CONSTRAINTS)
    if path is None:
        return {}
    found = {}
    for line in path.read_text(encoding="utf-8").splitlines():
        name, sep, version = line.split("#", 1)[0].strip().partition("==")
        if sep:
            found[name.strip()] = version.strip()
    return found


def version_differences(used: dict[str, str]) -> list[str]:
    """``used`` (:func:`sb3_cmzdril.io.versions`' names) against :func:`published_versions`: one
    ``"mujoco 4.0.1 (published: 4.0.0)"`` for each package whose version differs (a local build tag
    such as torch's ``+cpu`` aside)."""
    differ = []
    for name, version in published_versions().items():
        mine = used.get(name.replace("-", "_"))
        if mine is not None and mine.split("+", 1)[0] != version:
            differ.append(f"{name} {mine} (published: {version})")
    return differ


def published_differences(demos_sha256: str | None, used: dict[str, str]) -> list[str]:
    """:func:`version_differences` of a run on a published demo pool (its sha256), whose numbers are then
    compared with the published records'; ``[]`` for any other pool, which has none to compare with."""
    return version_differences(used) if demos_sha256 in published_pool_digests() else []


def constraints_advice() -> str:
    """How to install what the published records were made with, naming the shipped constraints file."""
    path = shipped_file(*PUBLISHED_CONSTRAINTS)
    where = f" (in the repository; installed as {path})" if path is not None else ""
    return f"`pip install -c {'/'.join(PUBLISHED_CONSTRAINTS)}`{where} installs those versions"


@functools.lru_cache(maxsize=1)
def published_pool_digests() -> frozenset[str]:
    """The sha256 of each shipped demo pool: a run on one of them is comparable to the published records."""
    pools = (shipped_file("experts", env, "demos.npz") for env in shipped_envs())
    return frozenset(file_sha256(pool) for pool in pools if pool is not None)


def _env_folder(env_id: str) -> str:
    # The folder of ``sb3_cmzdril:WaypointNav-v0`` is ``WaypointNav-v0``.
    return str(env_id).rsplit(":", 1)[-1]


def shipped_envs() -> list[str]:
    """The env ids that have a shipped demo pool, sorted."""
    found: set[str] = set()
    for root in _roots():
        found.update(p.parent.name for p in (root / "experts").glob("*/demos.npz"))
    return sorted(found)


def shipped_demos(env_id: str) -> Path:
    """The shipped demo pool of ``env_id`` (``experts/<EnvId>/demos.npz``).

    >>> Demonstrations.load(shipped_demos("HalfCheetah-v5"))  # doctest: +SKIP

    :raises FileNotFoundError: no pool ships for that env; the message lists the envs that have one.
    """
    path = shipped_file("experts", _env_folder(env_id), "demos.npz")
    if path is None:
        raise MissingFileError(
            f"no shipped demo pool for {env_id!r}; shipped pools: {', '.join(shipped_envs()) or 'none'} "
            "(record your own with `sb3-cmzdril collect-demos`)"
        )
    return path


def shipped_expert(env_id: str) -> Path:
    """The shipped expert model of ``env_id`` (``experts/<EnvId>/model.zip``).

    :raises FileNotFoundError: the env's expert is not a model file here: a third-party agent (its
        ``metadata.json`` names the repository, path and commit to get it from), a scripted expert,
        or no shipped expert at all.
    """
    folder = _env_folder(env_id)
    path = shipped_file("experts", folder, "model.zip")
    if path is not None:
        return path
    metadata = shipped_file("experts", folder, "metadata.json")
    if metadata is None:
        raise MissingFileError(f"no shipped expert for {env_id!r}; shipped experts: {', '.join(shipped_envs())}")
    import json

    meta = json.loads(metadata.read_text(encoding="utf-8"))
    source = meta.get("source")
    if isinstance(source, dict):
        raise MissingFileError(
            f"the expert of {folder} is not shipped (a third-party agent): get {source.get('path')} from "
            f"{source.get('repository')} (commit {source.get('commit')})"
        )
    raise MissingFileError(f"the expert of {folder} is not a model file: it is {meta.get('expert')}")


def shipped_hyperparams(name: str) -> Path:
    """The shipped hyperparameter file ``hyperparams/<name>.yml``.

    :raises FileNotFoundError: no such file; the message lists the shipped ones.
    """
    path = shipped_file("hyperparams", f"{name}.yml")
    if path is None:
        names = sorted({p.stem for root in _roots() for p in (root / "hyperparams").glob("*.yml")})
        raise MissingFileError(
            f"no shipped hyperparameter file {name}.yml (shipped: {', '.join(names) or 'none'}); "
            "pass one explicitly with --hyperparams / hyperparams_path="
        )
    return path


def local_or_shipped_demos(env_id: str, demos_dir: PathLike = "experts") -> Path:
    """``<demos_dir>/<EnvId>/demos.npz`` if it exists (a pool the user recorded), else the shipped pool.

    Only the default folder ``experts`` falls back to the shipped pool: a folder the user names is
    meant, and a pool missing from it must be reported, not replaced. Without either the local path
    is returned, so the caller's error names where the pool was expected.
    """
    local = Path(demos_dir) / _env_folder(env_id) / "demos.npz"
    if local.is_file() or Path(demos_dir) != Path("experts"):
        return local
    shipped = shipped_file("experts", _env_folder(env_id), "demos.npz")
    return shipped if shipped is not None else local


__all__ = [
    "BUNDLED_DIR",
    "CHECKOUT_DIR",
    "PUBLISHED_CONSTRAINTS",
    "constraints_advice",
    "local_or_shipped_demos",
    "published_differences",
    "published_pool_digests",
    "published_versions",
    "shipped_demos",
    "shipped_envs",
    "shipped_expert",
    "shipped_file",
    "shipped_hyperparams",
    "version_differences",
]
