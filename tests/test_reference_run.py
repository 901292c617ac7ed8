"""The published reference run reproduces exactly: ``results/reference/`` holds a short CMZ-DRIL run
made by the command its ``config.json`` records (``train_command``); rerun into a temporary folder, it
must write the same ``eval.csv`` and ``final_eval.csv``, byte for byte.

It fails when a change of the code changes the numbers a published command gives. Then either the
change is a mistake, or the published runs need to be made again: rerun the commands in
``results/reference/README.md`` (and say in the changelog that the numbers changed).
"""
from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
import torch

REPO = Path(__file__).resolve().parent.parent
REFERENCE = REPO / "results" / "reference" / "WaypointNav-v0" / "cmz" / "trial0"
#: The files compared byte for byte: the per-epoch evaluation and the final evaluation.
COMPARED = ("eval.csv", "final_eval.csv")


def rerun_command(config: dict, output: Path) -> list[str]:
    """The run's recorded ``train_command`` with its output folder replaced by ``output``, run with
    this interpreter (``python -m sb3_cmzdril``) and without a progress bar."""
    argv = shlex.split(config["train_command"])
    assert argv[0] == "sb3-cmzdril" and argv[1] == "train", argv
    i = argv.index("-o")
    argv[i + 1] = str(output)
    return [sys.executable, "-m", "sb3_cmzdril", *argv[1:], "--no-progress", "--threads", "1"]


def test_rerun_command_replaces_only_the_output_folder(tmp_path):
    config = {"train_command": "sb3-cmzdril train --env E --reward cmz --seed 3 -o results/x/trial3"}
    assert rerun_command(config, tmp_path)[3:] == ["train", "--env", "E", "--reward", "cmz", "--seed", "3", "-o",
                                                   str(tmp_path), "--no-progress", "--threads", "1"]


@pytest.mark.slow
def test_published_reference_run_reproduces_byte_for_byte(tmp_path):
    config = json.loads((REFERENCE / "config.json").read_text(encoding="utf-8"))
    made_with = config["versions"]["torch"]
    if made_with != torch.__version__:  # another build's kernels round differently (CI pins the same)
        pytest.skip(f"the reference was made with torch {made_with}, this is {torch.__version__}")
    output = tmp_path / "trial0"
    # Threads pinned to one: torch's and BLAS's parallel reductions may sum in another order. On the
    # CPU, as the reference was made: a GPU's kernels sum in another order too.
    env = dict(os.environ, PYTHONPATH=str(REPO), OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", CUDA_VISIBLE_DEVICES="")
    result = subprocess.run(rerun_command(config, output), cwd=REPO, env=env, capture_output=True, text=True,
                            timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    for name in COMPARED:
        assert (output / name).read_bytes() == (REFERENCE / name).read_bytes(), name
