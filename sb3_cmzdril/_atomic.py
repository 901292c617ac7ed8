"""Moved to :mod:`sb3_cmzdril.io`; kept only until the last modules importing it are switched."""
from sb3_cmzdril.io import PathLike, atomic_path, atomic_write_text  # noqa: F401
