"""The published reference run reproduces exactly: ``results/reference/`` holds a short CMZ-DRIL run
made by the command its ``config.json`` records (``train_command``); rerun into a temporary folder, it
must write the same ``eval.csv`` and ``final_eval.csv``, byte for byte on the kind of CPU it was made
on, and to a relative tolerance of :data:`RTOL` on any other.

It fails when a change of the code changes the numbers a published command gives. Then either the
change is a mistake, or the published runs need to be made again: rerun the commands in
``results/reference/README.md`` (and say in the changelog that the numbers changed).
"""
from __future__ import annotations

import csv
import json
import os
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from sb3_cmzdril.io import cpu_model

REPO = Path(__file__).resolve().parent.parent
REFERENCE = REPO / "results" / "reference" / "WaypointNav-v0" / "cmz" / "trial0"
#: The files compared: the per-epoch evaluation and the final evaluation.
COMPARED = ("eval.csv", "final_eval.csv")
#: The CPU the reference was made on (its records predate state.json's machine entry): CI on this kind of
#: machine rebuilt it byte for byte.
REFERENCE_CPU = "AMD EPYC"
#: On another CPU, MKL's and oneDNN's kernels take other paths and round otherwise: on an Intel Xeon with
#: AVX-512 the first evaluation's return moves in its 8th digit and the final evaluation's in its 6th, and
#: neither ATEN_CPU_CAPABILITY, MKL_CBWR, MKL_ENABLE_INSTRUCTIONS, DNNL_MAX_CPU_ISA, OPENBLAS_CORETYPE nor
#: NPY_DISABLE_CPU_FEATURES brought back the bytes. There every number must agree to this relative
#: tolerance, twenty times the drift seen; a change of the code that changes what the run computes moves
#: the numbers far more.
RTOL = 1e-4


def read_rows(path: Path) -> list[list[str]]:
    with path.open(newline="", encoding="utf-8") as f:
        return list(csv.reader(f))


def assert_same_numbers(rerun: Path, reference: Path) -> None:
    """``rerun`` has ``reference``'s header, rows and text cells, and its numbers to :data:`RTOL`."""
    got, want = read_rows(rerun), read_rows(reference)
    assert got[0] == want[0] and len(got) == len(want), rerun.name
    for row, expected in zip(got[1:], want[1:], strict=True):
        for cell, wanted in zip(row, expected, strict=True):
            try:
                value, target = float(cell), float(wanted)
            except ValueError:
                assert cell == wanted, (rerun.name, row)
                continue
            assert np.isclose(value, target, rtol=RTOL, atol=0.0), (rerun.name, cell, wanted)


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
        if cpu_model().startswith(REFERENCE_CPU):
            assert (output / name).read_bytes() == (REFERENCE / name).read_bytes(), name
        else:
            assert_same_numbers(output / name, REFERENCE / name)


def test_the_tolerance_on_another_cpu_still_catches_a_changed_number(tmp_path):
    reference = REFERENCE / "eval.csv"
    rows = read_rows(reference)
    rows[2][2] = repr(float(rows[2][2]) * (1 + 1e-6))  # the drift of another CPU's kernels: accepted
    (tmp_path / "eval.csv").write_text("\n".join(",".join(r) for r in rows) + "\n", encoding="utf-8")
    assert_same_numbers(tmp_path / "eval.csv", reference)
    rows[3][2] = repr(float(rows[3][2]) * (1 + 1e-3))  # a return off in its 4th digit: refused
    (tmp_path / "eval.csv").write_text("\n".join(",".join(r) for r in rows) + "\n", encoding="utf-8")
    with pytest.raises(AssertionError):
        assert_same_numbers(tmp_path / "eval.csv", reference)
