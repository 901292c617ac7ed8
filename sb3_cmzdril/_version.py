"""The package's version, the one place it is written: ``pyproject.toml`` reads it from here
without importing the package, and every layer (the provenance records of :mod:`sb3_cmzdril.io`
among them) imports it from here rather than from the package's public face above them."""

__version__ = "0.3.0.dev0"
