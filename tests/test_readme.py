"""Every ```python block of README.md runs as written, from an empty folder, so the README cannot drift
from the code. Only the training lengths shrink: ``.learn(300_000`` becomes ``.learn(64``.

``python tests/test_readme.py DIR`` writes the blocks as they are run here (``DIR/readme_<i>.py``):
CI runs them with the installed wheel (.ci/wheel_smoke.sh).
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
README = REPO / "README.md"
_BLOCK = re.compile(r"^```python\n(.*?)^```", re.S | re.M)
#: A step count given to learn(): the first positional argument or total_timesteps=.
_LEARN = re.compile(r"(\.learn\(\s*(?:total_timesteps\s*=\s*)?)\d[\d_]*")
#: Below one PPO rollout: learn() still collects one rollout and makes one update.
TINY_STEPS = 64


def readme_blocks(text: str | None = None) -> list[str]:
    """The README's Python blocks with every ``learn`` step count replaced by :data:`TINY_STEPS`."""
    text = README.read_text(encoding="utf-8") if text is None else text
    return [_LEARN.sub(rf"\g<1>{TINY_STEPS}", block) for block in _BLOCK.findall(text)]


def write_blocks(folder: Path) -> list[Path]:
    """Write the blocks as ``folder/readme_<i>.py``; their paths."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, block in enumerate(readme_blocks()):
        path = folder / f"readme_{i}.py"
        path.write_text(block, encoding="utf-8")
        paths.append(path)
    return paths


def test_training_lengths_shrink_and_nothing_else_changes():
    text = "```python\nm.learn(300_000, progress_bar=True)\nm.learn(total_timesteps=5000)\nx = 300_000\n```\n"
    assert readme_blocks(text) == [f"m.learn({TINY_STEPS}, progress_bar=True)\nm.learn(total_timesteps={TINY_STEPS})\n"
                                   "x = 300_000\n"]
    assert len(readme_blocks()) >= 2


#: The README's commands, verbatim: the main job, the test suite (the one CI runs) and the docs build.
COMMANDS = (
    'python3 -m pip install torch==2.13.0 && python3 -m pip install -e ".[experiments]" && sb3-cmzdril train '
    "--env HalfCheetah-v5 --reward cmz --timesteps 300000 --eval-every 5",
    'python3 -m pip install torch==2.13.0 && python3 -m pip install -e ".[test]" && python3 -m pytest -n auto',
    'python3 -m pip install -e ".[docs]" && python3 -m mkdocs build --strict',
)


@pytest.mark.parametrize("command", COMMANDS)
def test_readme_shows_its_commands_verbatim(command):
    assert f"\n    {command}\n" in README.read_text(encoding="utf-8")


def test_readme_fits_on_a_screen_or_three():
    assert len(README.read_text(encoding="utf-8").splitlines()) <= 150


@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(readme_blocks())))
def test_readme_block_runs_from_an_empty_folder(index, tmp_path):
    (script,) = [p for p in write_blocks(tmp_path / "blocks") if p.name == f"readme_{index}.py"]
    empty = tmp_path / "cwd"
    empty.mkdir()
    env = dict(os.environ, PYTHONPATH=str(REPO), OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    result = subprocess.run(
        [sys.executable, str(script)], cwd=empty, env=env, capture_output=True, text=True, timeout=900
    )
    assert result.returncode == 0, f"README block {index} failed:\n{script.read_text()}\n{result.stderr[-3000:]}"


if __name__ == "__main__":
    for written in write_blocks(Path(sys.argv[1])):
        print(written)
