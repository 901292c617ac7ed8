"""The paper's trial grid (envs x methods x trials), run by a local process pool or by Ray.

Trial ``t`` draws its training and evaluation episodes from the env's demo pool with
``numpy.random.default_rng(t)`` (:func:`~sb3_cmzdril.training.spec.split_episodes`) and uses ``t``
as network and env seed, so every method of a trial sees the same data and starts from the same
BC-pretrained policy (the paper: "The same training and evaluation data were used for BC, DRIL, and
CMZ-DRIL"). Runs go to ``RUNS_DIR/<EnvName>/<method>/trial<t>/`` (layout: :mod:`.run_folder`).

Both backends execute :func:`~.worker.execute_run` one run per worker (one CPU and one torch thread each):

* ``local``: a ``ProcessPoolExecutor`` with the ``spawn`` context (no forked torch/OpenMP state);
* ``ray``: the same function as a ``ray.remote(num_cpus=1)`` task, on ``ray.init(address=...)`` or
  a local instance (an already initialised Ray is used as it is). Ray is optional:
  ``pip install 'sb3-cmzdril[ray]'``. No shared filesystem is needed: the task carries the demo pool,
  the hyperparameters and a partial run's files, and the run folder comes back (:mod:`.remote`).

At most ``workers`` runs are in flight at a time (so "running" in the progress display is exact).
Finished runs (done.json) are skipped without starting a worker, interrupted ones continue from their
checkpoint, and a failed run leaves its traceback in ``<run>/error.txt`` without stopping the others.
A run whose folder another process holds (a second benchmark on the same runs folder) is skipped as
``busy``: that process goes on with it, and a later invocation finds it finished or resumes it.

Local workers die with the process that started them, however it ends (SIGKILL included): an orphan
would go on training and hold its run's lock. On Linux the kernel sends them SIGKILL
(``PR_SET_PDEATHSIG``); everywhere a watchdog thread ends a worker whose parent is gone. An
interrupted grid (Ctrl-C, SIGTERM) ends its running workers before it returns; their checkpoints
are atomic, so the next invocation resumes them. A local Ray instance the Ray backend starts dies
with it too: a watchdog process (``_ray_watchdog.py``, Linux) ends what Ray would leave running.
"""
from __future__ import annotations

import collections
import concurrent.futures
import contextlib
import ctypes
import json
import multiprocessing
import os
import signal
import subprocess
import sys
import threading
import time
import traceback
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from cmzdril_lab.run.progress import GridProgress
from cmzdril_lab.run.worker import RunOutcome, RunStatus, execute_run, init_worker, write_error
from sb3_cmzdril.errors import UserError
from sb3_cmzdril.experts import check_env_id, env_name
from sb3_cmzdril.io import LockHeld, PathLike, lock_output, unlock_output
from sb3_cmzdril.training.run_folder import ERROR_FILE, check_finished
from sb3_cmzdril.training.spec import (
    DEFAULT_CHECKPOINT_EVERY,
    DEFAULT_EVAL_EPISODES,
    PAPER_METHODS,
    Method,
    RunSpec,
    default_demos_path,
    default_output_dir,
    missing_pool_error,
    plan_run,
)

BACKENDS = ("local", "ray")
#: One line per benchmark invocation in RUNS_DIR (command, grid, outcome): the runs' history.
BENCHMARK_LOG = "benchmark.jsonl"


def parse_list(text: str | Sequence[str]) -> list[str]:
    """``"a,b, c"`` (or a list) -> ``["a", "b", "c"]``, duplicates removed, order kept."""
    items = text.split(",") if isinstance(text, str) else list(text)
    return list(dict.fromkeys(i.strip() for i in items if i.strip()))


def plan_grid(
    env_ids: str | Sequence[str],
    methods: str | Sequence[str] = PAPER_METHODS,
    trials: int | Sequence[int] = 5,
    runs_dir: PathLike = "runs",
    *,
    timesteps: int | None = None,
    n_demos: int | None = None,
    n_eval_episodes: int = DEFAULT_EVAL_EPISODES,
    eval_every: int = 1,
    checkpoint_every: int = DEFAULT_CHECKPOINT_EVERY,
    demos_dir: PathLike = "experts",
    hyperparams: PathLike | None = None,
    offpolicy_hyperparams: PathLike | None = None,
    command: str | None = None,
) -> list[RunSpec]:
    """Every run of the grid, validated before anything starts (unknown env or method, missing or
    too small demo pool, bad counts raise here).

    :param trials: a number T (trials 0..T-1) or the trial indices themselves.
    :param n_demos: training episodes per trial (default: the YAML's per-env ``n_demos``: 1 for the
        MuJoCo envs, 5 for WaypointNav, as in the paper).
    :param demos_dir: demo pools are ``<demos_dir>/<EnvName>/demos.npz``.
    :param hyperparams: the PPO methods' YAML (default: the shipped cmzdril.yml, the package's defaults).
    :param offpolicy_hyperparams: the off-policy methods' (``cmz-sac``) YAML (default: the shipped
        cmzdril_sac.yml), as the zoo keeps one file per algorithm.
    Order: trial, then env, then method, so that whole trials finish first.
    """
    envs = parse_list(env_ids)
    names = parse_list(methods)
    if not envs:
        raise UserError("no environment given")
    if not names:
        raise UserError("no method given")
    chosen = [Method.of(name) for name in names]
    for option, path, learner, readers in (
        ("--hyperparams", hyperparams, "PPO", [m.name for m in chosen if not m.off_policy]),
        ("--sac-hyperparams", offpolicy_hyperparams, "off-policy", [m.name for m in chosen if m.off_policy]),
    ):
        if path is not None and not readers:
            raise UserError(f"{option} {path} is read by the {learner} methods only and --methods has none "
                            f"({', '.join(names)}); pass it as "
                            f"{'--sac-hyperparams' if option == '--hyperparams' else '--hyperparams'}")
    for env_id in envs:
        check_env_id(env_id)
        pool = default_demos_path(env_id, demos_dir)
        if not pool.is_file():
            raise missing_pool_error(
                env_id, pool, f"pass --demos-dir DIR, a folder holding {env_name(env_id)}/demos.npz"
            )
    indices = list(range(int(trials))) if isinstance(trials, int) else [int(t) for t in trials]
    if not indices:
        raise UserError(f"need at least one trial, got {trials!r}")
    specs = [
        plan_run(
            env_id,
            method.name,
            trial,
            demos=default_demos_path(env_id, demos_dir),
            n_demos=n_demos,
            n_eval_episodes=n_eval_episodes,
            timesteps=timesteps,
            output_dir=default_output_dir(env_id, method.name, trial, runs_dir),
            hyperparams=offpolicy_hyperparams if method.off_policy else hyperparams,
            eval_every=eval_every,
            checkpoint_every=checkpoint_every,
            command=command,
        )
        for trial in indices
        for env_id in envs
        for method in chosen
    ]
    check_shared_splits(specs)
    return specs


def check_shared_splits(specs: Sequence[RunSpec]) -> None:
    """A trial's methods train and are evaluated on the same episodes of the pool: the split depends on
    the trial seed, the pool, ``n_demos`` and ``n_eval_episodes``, so settings that give one method of
    a trial other values (a ``per_method`` ``n_demos``) are refused, naming them."""
    splits: dict[tuple[str, int], dict[tuple, list[str]]] = {}
    for spec in specs:
        split = (spec.demos, spec.n_demos, spec.n_eval_episodes)
        splits.setdefault((spec.env_id, spec.seed), {}).setdefault(split, []).append(spec.method)
    for (env_id, seed), by_split in splits.items():
        if len(by_split) > 1:
            parts = "; ".join(f"{', '.join(methods)}: {n} training / {m} held-out episodes of {pool}"
                              for (pool, n, m), methods in by_split.items())
            raise UserError(f"{env_id} trial {seed}: the methods would split the demo pool differently ({parts}); "
                            "a trial's methods must share one split (n_demos and n_eval_episodes per env, "
                            "not per method)")


# -- the worker side -------------------------------------------------------------------------------
#: prctl option: the signal the kernel sends a process when its parent ends (linux/prctl.h).
_PR_SET_PDEATHSIG = 1
#: How often the watchdog looks for the parent (seconds).
_WATCHDOG_PERIOD_S = 0.5


def _init_pool_worker(parent_pid: int) -> None:
    """A local pool's worker: it ends when ``parent_pid``, the grid's process, does
    (:func:`die_with_parent`), and runs as every worker runs (:func:`.worker.init_worker`)."""
    die_with_parent(parent_pid)
    init_worker()


def die_with_parent(parent_pid: int) -> None:
    """End this process as soon as ``parent_pid`` (its parent) is gone, however the parent ended.

    Linux: the kernel sends SIGKILL when the parent exits (``prctl(PR_SET_PDEATHSIG)``, through
    ctypes). Everywhere: a daemon thread checks ``os.getppid()``, which changes to a reaper's pid
    once the parent is gone, and ends the process. Both, because the first is immediate but
    Linux-only, and the second also covers a parent that died before the first was set up.
    """
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    if os.getppid() != parent_pid:
        os._exit(1)  # the parent ended before we were set up

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(_WATCHDOG_PERIOD_S)
        os._exit(1)

    threading.Thread(target=watch, name="sb3-cmzdril-parent-watchdog", daemon=True).start()


def held_elsewhere(output_dir: PathLike) -> bool:
    """Whether another process holds the run folder's lock (is running that run) right now."""
    out = Path(output_dir)
    if not out.is_dir():
        return False
    try:
        handle = lock_output(out)
    except LockHeld:
        return True
    unlock_output(out, handle)
    return False


# -- backends --------------------------------------------------------------------------------------
class _LocalBackend:
    """A spawn-context process pool, rebuilt if a worker dies (BrokenProcessPool); its workers die
    with this process (:func:`die_with_parent`)."""

    def __init__(self, workers: int) -> None:
        self.workers = workers
        self.context = multiprocessing.get_context("spawn")
        self.pool = self._new_pool()

    def _new_pool(self) -> concurrent.futures.ProcessPoolExecutor:
        return concurrent.futures.ProcessPoolExecutor(
            max_workers=self.workers, mp_context=self.context, initializer=_init_pool_worker, initargs=(os.getpid(),)
        )

    def submit(self, spec: RunSpec) -> concurrent.futures.Future:
        try:
            return self.pool.submit(execute_run, spec)
        except concurrent.futures.process.BrokenProcessPool:
            self.pool.shutdown(wait=False, cancel_futures=True)
            self.pool = self._new_pool()
            return self.pool.submit(execute_run, spec)

    def wait(self, handles: list[Any], timeout: float) -> list[Any]:
        done, _ = concurrent.futures.wait(handles, timeout=timeout, return_when=concurrent.futures.FIRST_COMPLETED)
        return list(done)

    def result(self, handle: concurrent.futures.Future) -> RunOutcome:
        return handle.result()

    def close(self, interrupted: bool = False) -> None:
        """Shut the pool down; interrupted, end the running workers too (shutdown only cancels the
        queued runs, and a worker left running would hold its run's lock)."""
        workers = list((getattr(self.pool, "_processes", None) or {}).values()) if interrupted else []
        # shutdown() forgets the pool's manager thread; kept here to be joined below.
        manager = getattr(self.pool, "_executor_manager_thread", None) if interrupted else None
        for process in workers:
            with contextlib.suppress(OSError, ValueError):
                process.terminate()
        self.pool.shutdown(wait=not interrupted, cancel_futures=interrupted)
        for process in workers:
            with contextlib.suppress(OSError, ValueError, AssertionError):
                process.join(timeout=5)
                if process.is_alive():
                    process.kill()
        if manager is not None:
            # The manager thread closes its wakeup pipe once it sees the ended workers. At interpreter
            # exit concurrent.futures writes to every live pool's pipe without the pool's lock (CPython
            # 3.11-3.13 here), so a thread still closing it then races the exit: "OSError: [Errno 9] Bad
            # file descriptor", printed after the command's last line. Joined, the pipe is closed first.
            manager.join(timeout=10)


class _RayBackend:
    """:func:`~.worker.execute_run` as Ray tasks with one CPU each (:mod:`.remote`); starts (and
    stops) a local Ray if none is up."""

    def __init__(self, workers: int, address: str | None) -> None:
        try:
            import ray
        except ImportError as e:
            from sb3_cmzdril.extras import MissingExtraError

            raise MissingExtraError(
                "the Ray backend needs the optional 'ray' package: pip install 'sb3-cmzdril[ray]' "
                "(or use --backend local)"
            ) from e
        self.ray = ray
        self.owned = not ray.is_initialized()
        self.watchdog: subprocess.Popen[bytes] | None = None
        if self.owned:
            if address:
                ray.init(address=address)
            else:
                # Started first, so that it records Ray's processes from the moment they exist.
                self.watchdog = start_ray_watchdog()
                ray.init(num_cpus=workers, include_dashboard=False)
        from cmzdril_lab.run.remote import RemoteRuns

        self.runs = RemoteRuns(ray)

    def submit(self, spec: RunSpec) -> Any:
        return self.runs.submit(spec)

    def wait(self, handles: list[Any], timeout: float) -> list[Any]:
        ready, _ = self.ray.wait(handles, num_returns=1, timeout=timeout)
        return ready

    def result(self, handle: Any) -> RunOutcome:
        return self.runs.result(handle)

    def close(self, interrupted: bool = False) -> None:
        if self.owned:
            self.ray.shutdown()
        if self.watchdog is not None:
            stop_ray_watchdog(self.watchdog)
            self.watchdog = None


def start_ray_watchdog() -> subprocess.Popen[bytes] | None:
    """Start the watchdog that ends the local Ray instance this process is about to start when this
    process dies, SIGKILL included (``_ray_watchdog.py``: Ray's agents would otherwise outlive it by
    about a minute); None where there is no ``/proc`` to find the instance's processes in.

    Its standard input is a pipe only this process holds open: the kernel closes it when this process
    ends, however it ends, and the watchdog reads end of file.
    """
    if not Path("/proc/self/stat").is_file():
        return None
    script = Path(__file__).with_name("_ray_watchdog.py")
    return subprocess.Popen(
        [sys.executable, str(script), str(os.getpid())],
        stdin=subprocess.PIPE,
        # Its own session: a signal to this process's group (a terminal's Ctrl-C, kill -- -PGID) must
        # leave it alive to clean up after the group.
        start_new_session=True,
    )


def stop_ray_watchdog(watchdog: subprocess.Popen[bytes]) -> None:
    """Tell the watchdog that Ray was shut down here (nothing to end) and wait for it."""
    with contextlib.suppress(OSError):  # it is gone already: nothing to stop
        if watchdog.stdin is not None:
            watchdog.stdin.write(b"stop\n")
            watchdog.stdin.close()
    try:
        watchdog.wait(timeout=10)
    except subprocess.TimeoutExpired:
        watchdog.kill()
        watchdog.wait()


def _backend(name: str, workers: int, ray_address: str | None) -> _LocalBackend | _RayBackend:
    if name == "local":
        if ray_address:
            raise UserError("--ray-address needs --backend ray")
        return _LocalBackend(workers)
    if name == "ray":
        return _RayBackend(workers, ray_address)
    raise UserError(f"unknown backend {name!r}; choose from {', '.join(BACKENDS)}")


# -- the grid ---------------------------------------------------------------------------------------
def run_grid(
    specs: Sequence[RunSpec],
    workers: int = 1,
    backend: str = "local",
    ray_address: str | None = None,
    progress: bool = True,
) -> list[RunOutcome]:
    """Execute the runs, ``workers`` at a time; returns one outcome per spec, in spec order.

    Each :class:`~.worker.RunOutcome` has a status: ``skipped`` (done before), ``busy`` (another
    process holds its folder: it goes on with it), ``done``, ``stopped`` or ``failed``. An
    interruption (KeyboardInterrupt, SIGTERM's exception) ends the running workers before it
    propagates.
    """
    if backend not in BACKENDS:
        raise UserError(f"unknown backend {backend!r}; choose from {', '.join(BACKENDS)}")
    if isinstance(workers, bool) or int(workers) < 1:
        raise UserError(f"workers must be >= 1, got {workers!r}")
    workers = int(workers)
    labels = [s.output_dir for s in specs]
    if len(set(labels)) != len(labels):
        raise UserError("two runs of the grid share an output folder")
    outcomes: dict[str, RunOutcome] = {}
    todo: collections.deque = collections.deque()
    skipped = []
    for spec in specs:
        # Raises for a finished folder of another run, or one finished short of the steps asked:
        # before anything starts, rather than counting foreign numbers as this grid's.
        if check_finished(spec) is not None:
            outcomes[spec.output_dir] = RunOutcome.of(spec, RunStatus.SKIPPED)
            skipped.append(spec)
        else:
            todo.append(spec)
    display = GridProgress(len(specs), enabled=progress)
    display.skipped(skipped)
    runner: _LocalBackend | _RayBackend | None = None  # started with the first run that needs it
    interrupted = True
    try:
        running: dict[Any, RunSpec] = {}
        while todo or running:
            while todo and len(running) < workers:
                spec = todo.popleft()
                if held_elsewhere(spec.output_dir):
                    outcomes[spec.output_dir] = RunOutcome.of(spec, RunStatus.BUSY)
                    display.finished(spec, outcomes[spec.output_dir])
                    continue
                runner = runner or _backend(backend, workers, ray_address)
                running[runner.submit(spec)] = spec
                display.started(spec)
            if runner is None or not running:
                continue
            for handle in runner.wait(list(running), timeout=1.0):
                spec = running.pop(handle)
                try:
                    outcome = runner.result(handle)
                except Exception as e:  # the worker itself died (killed, out of memory, Ray task error)
                    write_error(spec, "".join(traceback.format_exception(type(e), e, e.__traceback__)))
                    outcome = RunOutcome.of(spec, RunStatus.FAILED, 0.0, f"{type(e).__name__}: {e}")
                outcomes[spec.output_dir] = outcome
                display.finished(spec, outcome)
            display.refresh()
        interrupted = False
    finally:
        if runner is not None:
            runner.close(interrupted=interrupted)
        display.close()
    return [outcomes[s.output_dir] for s in specs]


def benchmark(
    env_ids: str | Sequence[str],
    methods: str | Sequence[str] = PAPER_METHODS,
    trials: int | Sequence[int] = 5,
    runs_dir: PathLike = "runs",
    *,
    workers: int = 1,
    backend: str = "local",
    ray_address: str | None = None,
    progress: bool = True,
    command: str | None = None,
    **plan_kwargs: Any,
) -> list[RunOutcome]:
    """:func:`plan_grid` + :func:`run_grid`, and a line in ``RUNS_DIR/benchmark.jsonl`` recording
    the command, the grid and the outcome of this invocation. ``plan_kwargs`` go to :func:`plan_grid`."""
    if backend not in BACKENDS:  # before planning: a typo should not wait for the pool checks
        raise UserError(f"unknown backend {backend!r}; choose from {', '.join(BACKENDS)}")
    specs = plan_grid(env_ids, methods, trials, runs_dir, command=command, **plan_kwargs)
    started = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    t0 = time.time()
    outcomes = run_grid(specs, workers=workers, backend=backend, ray_address=ray_address, progress=progress)
    counts = collections.Counter(o.status.value for o in outcomes)
    record = {
        "started_at": started,
        "wall_time_s": round(time.time() - t0, 1),
        "command": command,
        "envs": parse_list(env_ids),
        "methods": parse_list(methods),
        "trials": sorted({s.seed for s in specs}),
        "workers": workers,
        "backend": backend,
        "outcome": dict(counts),
        "failed": [o.label for o in outcomes if o.status is RunStatus.FAILED],
    }
    log = Path(runs_dir) / BENCHMARK_LOG
    log.parent.mkdir(parents=True, exist_ok=True)
    with open(log, "a", encoding="utf-8") as f:
        f.write(json.dumps(record) + "\n")
    return outcomes


def summarize_outcomes(outcomes: Iterable[RunOutcome]) -> str:
    """One line: how many runs ended how, and which failed (with their error files)."""
    outcomes = list(outcomes)
    counts = collections.Counter(o.status.value for o in outcomes)
    text = f"{len(outcomes)} runs: " + ", ".join(f"{n} {k}" for k, n in sorted(counts.items()))
    busy = [o for o in outcomes if o.status is RunStatus.BUSY]
    if busy:
        waiting = ", ".join(o.label for o in busy)
        text += f"\n{RunStatus.BUSY.value} (another process is running them; run this again once it ends): {waiting}"
    failed = [o for o in outcomes if o.status is RunStatus.FAILED]
    if failed:
        text += "\nfailed:\n" + "\n".join(
            f"  {o.label}: {o.error} ({Path(o.run_dir) / ERROR_FILE})" for o in failed
        )
    return text


__all__ = [
    "BACKENDS",
    "die_with_parent",
    "held_elsewhere",
    "plan_grid",
    "run_grid",
    "benchmark",
    "parse_list",
    "summarize_outcomes",
    "GridProgress",
]
