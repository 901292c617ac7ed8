"""The trial grid's progress display: runs done / total, which are running, and each event.

On a terminal a rich progress bar with one line per running run; elsewhere (nohup, CI, a notebook
log) one plain line per event with the grid's status, and a heartbeat line while nothing happens.
:func:`~cmzdril_lab.run.grid.run_grid` drives it.
"""
from __future__ import annotations

import collections
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from cmzdril_lab.run.worker import RunOutcome, RunStatus
from sb3_cmzdril.io import LOCK_FILE
from sb3_cmzdril.training.run_folder import ERROR_FILE, latest_epoch
from sb3_cmzdril.training.spec import RunSpec


class GridProgress:
    """Runs done / total and which are running (with their latest evaluated epoch).

    A rich progress bar on a terminal; otherwise (nohup, CI, a notebook log) one line per event and
    a heartbeat line every ``heartbeat_s`` seconds.
    """

    def __init__(self, total: int, enabled: bool = True, heartbeat_s: float = 300.0) -> None:
        self.total = total
        self.enabled = enabled
        self.heartbeat_s = heartbeat_s
        self.counts: collections.Counter = collections.Counter()
        self.running: dict[str, RunSpec] = {}
        self._progress = None
        self._task: Any = None  #: rich's TaskID of the bar, once there is one
        self._last_line = time.time()
        if enabled and sys.stderr.isatty():
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
            from rich.text import Text

            display = self

            class _Progress(Progress):
                """The bar, then one line per running run (a long list would squeeze the bar to nothing)."""

                def get_renderables(self):
                    yield self.make_tasks_table(self.tasks)
                    for line in display._running_lines():
                        yield Text(f"  running: {line}", overflow="ellipsis", no_wrap=True)

            self._progress = _Progress(
                TextColumn("runs"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                TextColumn("{task.description}"), transient=False,
            )
            self._progress.start()
            self._task = self._progress.add_task("", total=total)

    @property
    def finished_count(self) -> int:
        return sum(self.counts.values())

    def _running_lines(self) -> list[str]:
        lines = []
        for label, spec in self.running.items():
            epoch = latest_epoch(spec.output_dir)
            lines.append(label if epoch is None else f"{label} (epoch {epoch})")
        return lines

    def _counts_text(self) -> str:
        return ", ".join(f"{n} {k}" for k, n in sorted(self.counts.items()))

    def _status_text(self) -> str:
        counts = self._counts_text()
        running = ", ".join(self._running_lines()) or "-"
        return f"{self.finished_count}/{self.total} finished{', ' + counts if counts else ''}; running: {running}"

    def _line(self, event: str) -> None:
        self._last_line = time.time()
        if self._progress is not None:
            self._progress.console.print(f"[{time.strftime('%H:%M:%S')}] {event}")
            self.refresh()
        elif self.enabled:
            print(f"[{time.strftime('%H:%M:%S')}] {event} | {self._status_text()}", flush=True)

    def started(self, spec: RunSpec) -> None:
        self.running[spec.label] = spec
        self._line(f"started {spec.label}")

    def skipped(self, specs: Sequence[RunSpec]) -> None:
        """Runs finished before this invocation: one line for all of them."""
        if specs:
            self.counts["skipped"] += len(specs)
            self._line(f"{len(specs)} runs already finished (done.json), skipped")

    def finished(self, spec: RunSpec, outcome: RunOutcome) -> None:
        self.running.pop(spec.label, None)
        self.counts[outcome.status.value] += 1
        if outcome.status is RunStatus.BUSY:
            self._line(f"skipped {spec.label}: another process is running it ({Path(spec.output_dir) / LOCK_FILE})")
            return
        detail = f": {outcome.error} (see {Path(spec.output_dir) / ERROR_FILE})" if outcome.error else ""
        took = f" in {outcome.seconds:.0f} s" if outcome.seconds else ""
        self._line(f"{outcome.status.value} {spec.label}{took}{detail}")

    def refresh(self) -> None:
        if self._progress is not None and self._task is not None:
            self._progress.update(self._task, completed=self.finished_count, description=self._counts_text())
        elif self.enabled and time.time() - self._last_line >= self.heartbeat_s:
            self._line("still working")

    def close(self) -> None:
        if self._progress is not None:
            self.refresh()
            self._progress.stop()
            self._progress = None


__all__ = ["GridProgress"]
