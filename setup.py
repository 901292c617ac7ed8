"""Build step: the wheel carries the repository's shipped files (``sb3_cmzdril/shipped.py`` finds them).

``experts/`` and ``hyperparams/`` stay top-level folders of the repository (the source of truth, what
the README and the commands name); building a wheel copies the files users need from any folder into
``sb3_cmzdril/_shipped/`` inside the package. Everything else about the build is in pyproject.toml.
"""
from __future__ import annotations

from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

#: Top-level folder -> the files of it that the wheel carries: demo pools with their records (each
#: pool's NAME.json, and the folder's metadata.json) and our SAC experts' zips (the wheel stays under
#: 15 MB); third-party experts are not in the repository at all.
SHIPPED = {
    "experts": ("*/demos.npz", "*/*.json", "*/model.zip"),
    "hyperparams": ("*.yml",),
    "constraints": ("published.txt",),
}


class BuildPyWithShippedFiles(build_py):
    """``build_py`` that also copies :data:`SHIPPED` into the package's ``_shipped/`` folder."""

    def run(self) -> None:
        super().run()
        # An editable install imports the checkout itself, which already has the folders.
        if getattr(self, "editable_mode", False):
            return
        root = Path(__file__).resolve().parent
        for folder, patterns in SHIPPED.items():
            files = sorted({path for pattern in patterns for path in (root / folder).glob(pattern)})
            if not files:
                raise FileNotFoundError(f"building a wheel needs {folder}/ with {', '.join(patterns)}")
            for source in files:
                target = Path(self.build_lib, "sb3_cmzdril", "_shipped", source.relative_to(root))
                self.mkpath(str(target.parent))
                self.copy_file(str(source), str(target))


setup(cmdclass={"build_py": BuildPyWithShippedFiles})
