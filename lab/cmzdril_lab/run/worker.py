"""One run of the grid as a worker executes it, whichever backend sent it: :func:`execute_run` and
the :class:`RunOutcome` it returns.

The scheduler (:mod:`.grid`) and the Ray backend (:mod:`.remote`) both import this module and
neither imports the other's internals: the local pool submits :func:`execute_run` to its processes,
the Ray task calls it in a temporary folder of its worker, and both hand back a :class:`RunOutcome`.
"""
from __future__ import annotations

import contextlib
import dataclasses
import enum
import time
import traceback
from pathlib import Path
from typing import Any

from sb3_cmzdril.io import LockHeld, atomic_write_text
from sb3_cmzdril.training.run_folder import ERROR_FILE, LOG_FILE
from sb3_cmzdril.training.runs import run_experiment
from sb3_cmzdril.training.spec import RunSpec


class RunStatus(str, enum.Enum):
    """How a run of the grid ended; the value is what summaries and benchmark.jsonl print."""

    #: finished before this invocation (done.json): nothing ran
    SKIPPED = "skipped"
    #: another process holds its folder and goes on with it
    BUSY = "busy"
    #: trained and evaluated to the end
    DONE = "done"
    #: ended early on purpose (its checkpoint resumes it)
    STOPPED = "stopped"
    #: raised; the traceback is in the run's error.txt
    FAILED = "failed"

    def __str__(self) -> str:
        return self.value


@dataclasses.dataclass(frozen=True)
class RunOutcome:
    """What became of one run: its label and folder, how it ended, how long it took, and the error
    (``"Type: message"``) of a failed run."""

    label: str
    run_dir: str
    status: RunStatus
    seconds: float = 0.0
    error: str | None = None

    @classmethod
    def of(cls, spec: RunSpec, status: RunStatus | str, seconds: float = 0.0, error: str | None = None) -> RunOutcome:
        """The outcome of ``spec``'s run; ``seconds`` kept to a tenth, as the summaries print it."""
        return cls(spec.label, spec.output_dir, RunStatus(status), round(seconds, 1), error)

    def as_dict(self) -> dict[str, Any]:
        """The outcome as JSON data: ``{"label", "run_dir", "status", "seconds", "error"}``."""
        return {
            "label": self.label,
            "run_dir": self.run_dir,
            "status": self.status.value,
            "seconds": self.seconds,
            "error": self.error,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RunOutcome:
        """The inverse of :meth:`as_dict`."""
        return cls(data["label"], data["run_dir"], RunStatus(data["status"]), data["seconds"], data["error"])


def init_worker() -> None:
    """One torch thread per run: two single-threaded runs beat one two-threaded run on our machines.

    MuJoCo's warnings go to the run's log.txt, minus known noise, instead of MUJOCO_LOG.TXT in the
    working directory (see :mod:`sb3_cmzdril._mujoco_log`).
    """
    import torch

    from sb3_cmzdril._mujoco_log import route_mujoco_warnings

    torch.set_num_threads(1)
    route_mujoco_warnings()


def write_error(spec: RunSpec, text: str) -> None:
    """Leave ``text`` (a traceback) in the run's error.txt, under a line saying which run failed when."""
    out = Path(spec.output_dir)
    header = f"{time.strftime('%Y-%m-%dT%H:%M:%S%z')} {spec.label} failed\n{spec}\n\n"
    atomic_write_text(out / ERROR_FILE, header + text)


def execute_run(spec: RunSpec) -> RunOutcome:
    """Worker entry point of both backends: one run, its output in ``<run>/log.txt``, never raising
    for a failed run (the traceback goes to ``<run>/error.txt``; the outcome says ``failed``)."""
    init_worker()
    t0 = time.time()
    out = Path(spec.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    try:
        with (
            open(out / LOG_FILE, "a", encoding="utf-8") as log,
            contextlib.redirect_stdout(log),
            contextlib.redirect_stderr(log),
        ):
            print(f"=== {time.strftime('%Y-%m-%d %H:%M:%S')} {spec.label}", flush=True)
            result = run_experiment(spec)
            print(f"=== {result['status']} after {time.time() - t0:.0f} s", flush=True)
    except LockHeld:  # another process took the folder since run_grid looked: its run, not a failure
        return RunOutcome.of(spec, RunStatus.BUSY, time.time() - t0)
    except Exception as e:  # any failure is this run's alone: record it and let the grid go on
        write_error(spec, traceback.format_exc())
        return RunOutcome.of(spec, RunStatus.FAILED, time.time() - t0, f"{type(e).__name__}: {e}")
    return RunOutcome.of(spec, result["status"], time.time() - t0)


__all__ = ["RunOutcome", "RunStatus", "execute_run", "init_worker", "write_error"]
