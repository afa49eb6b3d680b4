"""The work-unit runner: one SIL run per unit, on a local process pool or an existing Dask cluster.

    with Runner(jobs=None, scheduler=None) as runner:      # local pool over every core
        rows = runner.run(units, desc="robustness")          # one dict per unit, in the units' order

A unit is plain data (design parameters as canonical JSON, a matrix Case, a task, plant overrides,
the simulated length), so it pickles to any worker and the same unit gives the same row anywhere:
the SIL firmware and the plant are deterministic and every random draw was made before the unit
existed (uncertainty.py).

Workers and builds: a worker process builds the SIL library once per distinct parameter set
(build_sil keeps a per-process memo, and the on-disk cache in build/ is keyed by content and written
with an atomic rename under a unique temporary name, so workers sharing a checkout never race).

Failures: a design the generator refuses, parameters a grid point makes invalid, and a plant whose
state leaves the model are result rows (refused / failed, with the reason), never a crash. A worker
that dies mid-run: the local pool is rebuilt and the units it held are resubmitted; on Dask the
scheduler reschedules them (and `retries` re-runs a unit whose task raised). Finished rows are kept
in the calling process as they arrive, so nothing finished is lost. A unit that kills its worker
MAX_ATTEMPTS times is reported (one line) instead of looping forever.
"""

from __future__ import annotations

import json
import math
import multiprocessing
import os
import signal
import socket
import threading
import time
import uuid
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, Callable, Iterable

from rodgains.errors import DesignRefused, InputError, ParamError, UserError

MAX_ATTEMPTS = 3  # a unit whose worker died this many times is reported, not retried again
DASK_RETRIES = 2  # extra attempts for a unit whose Dask task raised (a crash of the worker counts separately)
CONNECT_TIMEOUT_S = 10.0


@dataclass(frozen=True)
class Unit:
    """One SIL run: the firmware designed for `params_json`, one matrix case, one task.

    case: a rodctl.sim.matrix.Case (a Monte Carlo draw is a Case of its own: its overrides and delay);
    seconds: simulated length [s] (None: the matrix's default for the task);
    info: (name, value) pairs copied into the row (grid point, draw index, trial number);
    plant_json: the true rod's parameters as canonical JSON when they are not params_json's own
    (`rodctl robustness --plant`); the case's overrides then apply to it.
    """

    params_json: str
    case: Any
    task: str
    seconds: float | None = None
    info: tuple = ()
    plant_json: str | None = None
    key: str = field(default_factory=lambda: uuid.uuid4().hex[:12])


@lru_cache(maxsize=64)
def _params(params_json: str):
    from rodgains.params import Params, validate

    return Params(validate(json.loads(params_json)), source="work unit")


# The SIL firmware core is one global state per loaded library, so two threads of one process must
# never step it at once. Dask workers should run one thread each (--nthreads 1); with more, this lock
# keeps the rows right at the cost of running them one at a time.
_SIL_LOCK = threading.Lock()


def run_unit(unit: Unit) -> dict[str, Any]:
    """Run one unit where it lands (a pool process, a Dask worker, or here) and return its row."""
    from rodctl.sim.matrix import run_case
    from rodctl.sim.plant import SimulationError

    row: dict[str, Any] = dict(unit.info)
    row.update(case=unit.case.name, task=unit.task, refused=False, reason="")
    try:
        params = _params(unit.params_json)
        row["params_sha256"] = params.sha256()[:16]
        plant = _params(unit.plant_json) if unit.plant_json is not None else None
        if plant is not None:
            row["plant_sha256"] = plant.sha256()[:16]
        with _SIL_LOCK:
            result = run_case(params, unit.case, unit.task, seconds=unit.seconds, plant_params=plant)
        row.update(result)
    except DesignRefused as e:
        row.update(passed=False, refused=True, reason=f"design refused: {e.why}")
    except ParamError as e:
        row.update(passed=False, refused=True, reason=f"invalid parameters: {e}")
    except SimulationError as e:
        row.update(passed=False, refused=False, reason=f"simulation stopped: {e}")
    row["case"], row["task"] = unit.case.name, unit.task
    return _json_safe(row)


def _json_safe(row: dict) -> dict:
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in row.items()}


def default_jobs() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


JOBS_PER_CORE_MAX = 4  # local workers beyond this many per core only queue for the cores, each a Python process


def check_jobs(jobs: int | None) -> None:
    """--jobs: None (every core) or 1 to JOBS_PER_CORE_MAX per core; a command checks it before work that cannot
    be undone."""
    if jobs is not None and jobs < 1:
        raise InputError(f"--jobs {jobs}: must be >= 1")
    cores = default_jobs()
    if jobs is not None and jobs > JOBS_PER_CORE_MAX * cores:
        raise InputError(f"--jobs {jobs}: at most {JOBS_PER_CORE_MAX * cores} local worker processes on these {cores} "
                         f"cores; --scheduler ADDRESS runs on a Dask cluster")


class Runner:
    """Runs units on a local process pool (default: every core) or on the Dask cluster at `scheduler`."""

    def __init__(self, jobs: int | None = None, scheduler: str | None = None, progress: bool = True):
        check_jobs(jobs)
        self.scheduler = scheduler
        self.progress = progress
        self.jobs = jobs or default_jobs()
        self._pool: ProcessPoolExecutor | None = None
        self._client = None
        if scheduler:
            self._client = connect(scheduler)
            self.jobs = max(1, sum(w.get("nthreads", 1) for w in self._client.scheduler_info()["workers"].values()))

    # -- lifetime -------------------------------------------------------------------------------
    def __enter__(self) -> "Runner":
        return self

    def __exit__(self, exc_type, *exc) -> None:
        self.close(abandon=exc_type is not None)

    def close(self, abandon: bool = False) -> None:
        """Stop the pool: wait for its workers, or with `abandon` (Ctrl-C, an error) stop them now."""
        if self._pool is not None:
            if abandon:
                self._abandon_pool()
            else:
                self._pool.shutdown(wait=True, cancel_futures=True)
                self._pool = None
        if self._client is not None:
            self._client.close()
            self._client = None

    @property
    def where(self) -> str:
        if self._client is not None:
            return f"Dask cluster {self.scheduler} ({self.jobs} worker threads)"
        return f"local process pool ({self.jobs} workers)"

    def local_worker_pids(self) -> list[int]:
        """Process ids of the local pool's workers (empty before the first run, or on Dask)."""
        if self._pool is None:
            return []
        return sorted(p.pid for p in list(getattr(self._pool, "_processes", {}).values()) if p.pid)

    def _abandon_pool(self) -> None:
        """Stop the local pool without waiting. Its workers ignore Ctrl-C (_pool_worker_init), and a
        pool left to wind down while the interpreter exits can hold that exit up (its manager thread
        is joined at exit), so they are terminated: a run holds nothing to save, and every finished
        row is already in this process."""
        for proc in list(getattr(self._pool, "_processes", {}).values()):
            proc.terminate()
        self._pool.shutdown(wait=False, cancel_futures=True)
        self._pool = None

    # -- running ----------------------------------------------------------------------------------
    def run(self, units: Iterable[Unit], *, desc: str = "runs", on_row: Callable[[Unit, dict], None] | None = None,
            show: bool | None = None) -> list[dict]:
        """Every unit's row, in the units' order. on_row(unit, row) is called as each one finishes;
        show: a progress bar (default: the Runner's `progress`)."""
        units = list(units)
        rows: list[dict | None] = [None] * len(units)
        bar = _bar(len(units), desc, self.progress if show is None else show)
        try:
            def done(i: int, row: dict) -> None:
                rows[i] = row
                if on_row is not None:
                    on_row(units[i], row)
                if bar is not None:
                    bar.update(1)

            if self._client is not None:
                self._run_dask(units, done)
            else:
                self._run_local(units, done)
        finally:
            if bar is not None:
                bar.close()
        return rows  # type: ignore[return-value]

    def _new_pool(self) -> ProcessPoolExecutor:
        # spawn: workers start clean (no copied threads or locks from this process) on every platform
        return ProcessPoolExecutor(max_workers=self.jobs, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_pool_worker_init)

    def _run_local(self, units: list[Unit], done: Callable[[int, dict], None]) -> None:
        attempts = [0] * len(units)
        todo = dispatch_order(units)[::-1]  # a stack: pop() takes the longest first
        window = 4 * self.jobs
        while todo:
            if self._pool is None:
                self._pool = self._new_pool()
            running: dict = {}
            try:
                while todo or running:
                    while todo and len(running) < window:
                        i = todo.pop()
                        running[self._pool.submit(run_unit, units[i])] = i
                    finished, _ = wait(running, return_when=FIRST_COMPLETED)
                    for f in finished:
                        row = f.result()  # raises BrokenProcessPool with f still counted as running
                        done(running.pop(f), row)
            except BrokenProcessPool:
                # A worker died (killed, out of memory): rows already in are kept; what it and its
                # siblings held goes back on the stack on a fresh pool.
                self._pool.shutdown(wait=False, cancel_futures=True)
                self._pool = None
                lost = sorted(running.values())
                for i in lost:
                    attempts[i] += 1
                    if attempts[i] >= MAX_ATTEMPTS:
                        raise UserError(f"a pool worker died {MAX_ATTEMPTS} times running {_describe(units[i])}")
                todo.extend(lost[::-1])
            except BaseException:
                self._abandon_pool()
                raise

    def _run_dask(self, units: list[Unit], done: Callable[[int, dict], None]) -> None:
        from distributed import as_completed

        client = self._client
        batch = uuid.uuid4().hex[:8]
        futures = {}
        window = max(64, 8 * self.jobs)
        todo = dispatch_order(units)[::-1]

        def submit(i: int):
            f = client.submit(run_unit, units[i], key=f"rodctl-{batch}-{i}", retries=DASK_RETRIES, pure=False)
            futures[f.key] = (f, i)
            return f

        first = [submit(todo.pop()) for _ in range(min(window, len(todo)))]
        try:
            ac = as_completed(first, loop=client.loop)
            for f in ac:
                _, i = futures.pop(f.key)
                try:
                    row = f.result()
                except Exception as e:  # KilledWorker, or the task's own error after its retries
                    raise UserError(f"Dask run of {_describe(units[i])} failed: {type(e).__name__}: "
                                    f"{(str(e).splitlines() or [''])[0]}") from None
                f.release()
                done(i, row)
                if todo:
                    ac.add(submit(todo.pop()))
        except BaseException:
            client.cancel([f for f, _ in futures.values()])
            raise


def _estimated_cost(unit: Unit) -> float:
    """Relative cost of a run: simulated seconds x plant edges (the plant dominates a run)."""
    from rodctl.sim.matrix import DEFAULT_SECONDS

    seconds = unit.seconds or DEFAULT_SECONDS.get(unit.task, 10.0)
    edges = None
    for o in unit.case.plant_overrides:
        if o.replace(" ", "").startswith("plant.edges="):
            edges = o.split("=", 1)[1]
    if edges is None:
        edges = json.loads(unit.plant_json or unit.params_json).get("plant", {}).get("edges", 20)
    try:
        return seconds * float(edges)
    except ValueError:
        return seconds * 20.0


def dispatch_order(units: list[Unit]) -> list[int]:
    """Indices, longest run first, so the last runs to finish are short ones and no worker idles at the end
    waiting for one long run (rows still come back in the units' order)."""
    return sorted(range(len(units)), key=lambda i: -_estimated_cost(units[i]))


def _pool_worker_init() -> None:
    # Ctrl-C reaches the whole process group: the parent stops the pool (Runner._abandon_pool), so the
    # workers leave that to it instead of each printing a traceback.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # A parent killed outright (SIGTERM, SIGKILL) cannot stop its pool: the workers notice the orphaning.
    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(0)

    threading.Thread(target=watch, name="rodctl-parent-watch", daemon=True).start()


def _describe(unit: Unit) -> str:
    extra = ", ".join(f"{k}={v}" for k, v in unit.info)
    return f"case {unit.case.name}/{unit.task}" + (f" ({extra})" if extra else "")


def connect(address: str):
    """A Dask client for the scheduler at `address`, or a one-line error (exit 2)."""
    try:
        from distributed import Client
    except ImportError:
        raise UserError("--scheduler needs dask.distributed: pip install 'dask[distributed]'") from None
    if "://" not in address:
        address = "tcp://" + address
    _probe(address)
    try:
        return Client(address, timeout=CONNECT_TIMEOUT_S, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as e:
        first = (str(e).splitlines() or [type(e).__name__])[0]
        raise InputError(f"--scheduler {address}: cannot reach the Dask scheduler ({first})") from None


def _probe(address: str) -> None:
    """Fail at once on a refused or unresolvable tcp:// address instead of after the client's timeout."""
    scheme, _, rest = address.partition("://")
    if scheme != "tcp":
        return
    host, _, port = rest.rpartition(":")
    if not host or not port.isdigit():
        raise InputError(f"--scheduler {address}: expected tcp://HOST:PORT")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as e:
        raise InputError(f"--scheduler {address}: cannot reach the Dask scheduler ({e.strerror or e})") from None


def _bar(total: int, desc: str, enabled: bool):
    if not enabled:
        return None
    from rodctl.progress import bar

    return bar(total=total, desc=desc, unit="run")
