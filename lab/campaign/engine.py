"""The campaign engine: units as Dask tasks on a local or remote cluster, results as they finish.

:class:`ClusterOptions` says where to run: a fresh ``LocalCluster`` (processes, one thread each,
one worker per core unless ``workers`` says otherwise), an existing scheduler's address
(``tcp://HOST:PORT``) or its scheduler file. :class:`Engine` connects (an unreachable scheduler is
a :class:`~lab.campaign.spec.CampaignError` before anything is submitted), submits units with
unique keys (Dask would otherwise share the result of two identical calls), and hands back each
unit's row as it finishes.

Failure handling, so a campaign never sticks:

- a flight over its ``timeout_s`` stops itself (the in-process watchdog, or the SITL processes
  killed) and comes back "timed out";
- a task that still has not come back twice its limit plus ``grace`` seconds after a worker took
  it (a hang outside the flight loop; the worker may hold one task queued behind the one it
  flies) is cancelled, recorded "timed out", and its worker restarted (through its nanny);
- a worker that dies (killed, out of memory, a crash in native code) makes its task "error";
  Dask retries it on another worker once before giving up (``allowed-failures`` of a local
  cluster; an external scheduler keeps its own setting).

Batches: in-process units go to the workers a few at a time, one task flying a batch of them one
after another (:func:`fly_batch`; each flight the same as alone, so the rows are the same), so
Dask's cost per task (a scheduler round trip, the worker idle in between: a few ms, a fifth of a
compiled 20 s flight) is paid per batch. A batch is at most :data:`MAX_BATCH_TICKS` control ticks,
and small enough that every worker gets about four (the last ones keep all workers busy); SITL
units go one per task. A batch that fails as a whole (its worker died, it hung, its task raised)
is not a result: its units are flown again one per task, where the rules above apply to each.
"""

from __future__ import annotations

import logging
import math
import os
import time
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lab.campaign.spec import CampaignError
from lab.campaign.units import Unit

#: a unit's task: the unit in, its result row out.
UnitTask = Callable[[Unit], dict[str, Any]]

#: a batch is at most this many control ticks (some 0.3 s compiled; 20 flights of 20 s at 500 Hz).
MAX_BATCH_TICKS = 200_000
#: batches per worker the units are cut into (at least), so the last ones keep every worker busy.
BATCHES_PER_WORKER = 4


def fly_batch(task: UnitTask, units: Sequence[Unit]) -> list[dict[str, Any]]:
    """(Runs on a worker.) The rows of ``units``, flown one after another by ``task``."""
    return [task(u) for u in units]


def batches(units: Sequence[Unit], workers: int, *, max_ticks: int = MAX_BATCH_TICKS) -> list[list[Unit]]:
    """``units`` cut into consecutive batches (order kept): in-process units at most ``max_ticks``
    control ticks a batch (a swarm's: every vehicle's) and about :data:`BATCHES_PER_WORKER` batches per worker; each SITL unit
    (two processes of its own) alone."""
    inproc = sum(1 for u in units if not u.sitl)
    size = max(1, math.ceil(inproc / (BATCHES_PER_WORKER * max(1, workers))))
    out: list[list[Unit]] = []
    cur: list[Unit] = []
    ticks = 0
    for u in units:
        if u.sitl:
            if cur:
                out.append(cur)
                cur, ticks = [], 0
            out.append([u])
            continue
        n = u.scenario.n_ticks * u.scenario.count  # a swarm unit flies every vehicle's ticks
        if cur and (len(cur) >= size or ticks + n > max_ticks):
            out.append(cur)
            cur, ticks = [], 0
        cur.append(u)
        ticks += n
    if cur:
        out.append(cur)
    return out


@dataclass(frozen=True)
class ClusterOptions:
    """Where units run: ``address`` (``tcp://HOST:PORT``) or ``scheduler_file`` of an existing
    Dask scheduler, else a ``LocalCluster`` of ``workers`` processes (default: the cores)."""

    workers: int | None = None
    address: str | None = None
    scheduler_file: Path | None = None
    #: seconds to wait for an existing scheduler.
    connect_timeout_s: float = 10.0

    def __post_init__(self) -> None:
        if self.workers is not None and self.workers < 1:
            raise CampaignError(f"--workers must be >= 1, got {self.workers}")
        if self.address is not None and self.scheduler_file is not None:
            raise CampaignError("give either --cluster or --scheduler-file, not both")
        if self.address is not None and not self.address.strip():
            raise CampaignError("--cluster needs a scheduler address such as tcp://127.0.0.1:8786")
        if self.scheduler_file is not None and not self.scheduler_file.is_file():
            raise CampaignError(f"--scheduler-file {self.scheduler_file}: no such file")

    @property
    def local(self) -> bool:
        return self.address is None and self.scheduler_file is None


def _dashboard_available() -> bool:
    try:
        import bokeh  # noqa: F401
    except ImportError:
        return False
    return True


def _error_row(unit: Unit, status: str, message: str) -> dict[str, Any]:
    return {"unit": unit.index, "group": unit.group, "controller": unit.controller, "seed_index": unit.seed_index, "seed": unit.seed,
            "status": status, "message": message, "wall_s": 0.0, "sim_s": 0.0, **dict(unit.values)}  # fmt: skip


def _executing_keys(dask_worker: Any) -> list[str]:
    """(Runs on a worker.) The keys of the tasks it is executing."""
    return [str(ts.key) for ts in dask_worker.state.executing]


#: a unit whose task comes back lost (no result, no error of its own: a worker died) is flown again
#: this many times before it is recorded as an error.
MAX_LOST_RETRIES = 3


def _timeout_s(what: Unit | list[Unit]) -> float:
    """The wall-clock limit of a task: its unit's, or the sum of its batch's."""
    return sum(u.timeout_s for u in what) if isinstance(what, list) else what.timeout_s


class Engine:
    """A connection to a Dask cluster that flies units (a context manager: leaving it closes the
    client and a local cluster it started)."""

    def __init__(self, options: ClusterOptions, *, task: UnitTask | None = None, grace_s: float = 30.0, tag: str = "unit",
                 batch: bool = True) -> None:  # fmt: skip
        self.options = options
        #: fly in-process units in batches (:func:`batches`); False: one unit per task.
        self.batch = batch
        if task is None:
            from lab.campaign.flight import fly_row

            task = fly_row
        self.task = task
        self.grace_s = grace_s
        self.tag = f"{tag}-{uuid.uuid4().hex[:8]}"
        self.client: Any = None
        self.cluster: Any = None
        #: what each task in flight flies: one unit, or a batch of them (a list).
        self._pending: dict[Any, Unit | list[Unit]] = {}
        #: times each unit (by index) was flown again after a worker died with it: see :meth:`poll`.
        self._again: dict[int, int] = {}
        self._started: dict[str, float] = {}
        self._last_check = 0.0
        self._ac: Any = None

    # -- connection --------------------------------------------------------------------------------
    def __enter__(self) -> Engine:
        try:
            import dask
            from distributed import Client, LocalCluster, as_completed
        except ImportError as exc:
            raise CampaignError(f"campaigns run on Dask, which is not installed ({exc.name}): pip install 'dask[distributed]'") from None

        o = self.options
        if o.local:
            n = o.workers or os.cpu_count() or 1
            # saturation 1.0: a worker holds only the unit it flies (the rest wait on the scheduler), so a worker
            # that dies or hangs takes no queued unit with it
            with dask.config.set({"distributed.scheduler.allowed-failures": 1, "distributed.scheduler.worker-saturation": 1.0,
                                  "distributed.worker.profile.enabled": False}):  # the sampling profiler costs the flight 1/4 of its speed
                self.cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, silence_logs=logging.ERROR,
                                            dashboard_address=":0")  # fmt: skip
                self.client = Client(self.cluster)
            self._ac = as_completed()
            return self
        where = o.address if o.address is not None else f"scheduler file {o.scheduler_file}"
        try:
            if o.address is not None:
                self.client = Client(o.address, timeout=o.connect_timeout_s)
            else:
                self.client = Client(scheduler_file=str(o.scheduler_file), timeout=o.connect_timeout_s)
        except (OSError, TimeoutError, ValueError) as exc:
            raise CampaignError(f"cannot reach the Dask scheduler at {where}: {exc or type(exc).__name__}") from None
        self._ac = as_completed()
        return self

    def __exit__(self, *exc: object) -> None:
        for f in list(self._pending):
            f.cancel()
        self._pending.clear()
        if self.client is not None:
            try:
                self.client.close(timeout=10)
            except Exception:  # closing after Ctrl-C or a lost scheduler must not hide the first error
                pass
        if self.cluster is not None:
            try:
                self.cluster.close(timeout=10)
            except Exception:
                pass

    @property
    def n_workers(self) -> int:
        return max(1, len(self.client.scheduler_info(n_workers=-1).get("workers", {})))

    def wait_for_workers(self, n: int = 1, timeout_s: float = 60.0) -> None:
        try:
            self.client.wait_for_workers(n, timeout=timeout_s)
        except TimeoutError:
            raise CampaignError(f"the scheduler has no worker after {timeout_s:g} s (start `dask worker SCHEDULER` on a machine)") from None

    @property
    def dashboard(self) -> str | None:
        if self.options.local and not _dashboard_available():
            return None
        try:
            link = self.client.dashboard_link
        except Exception:
            return None
        return link or None

    @property
    def where(self) -> str:
        if self.options.local:
            return f"local cluster, {self.n_workers} worker processes"
        return f"Dask scheduler {self.client.scheduler.address}, {self.n_workers} workers"

    # -- units ---------------------------------------------------------------------------------------
    def batches(self, units: Sequence[Unit]) -> list[list[Unit]]:
        """How :meth:`submit` cuts ``units`` into tasks (one unit each without ``batch``)."""
        if not self.batch:
            return [[u] for u in units]
        workers = (self.options.workers or os.cpu_count() or 1) if self.options.local else self.n_workers
        return batches(units, workers)

    def submit(self, units: Sequence[Unit]) -> None:
        """Queue ``units``, in batches (:meth:`batches`); unique task keys: the engine's tag and
        the (first) unit index."""
        for b in self.batches(units):
            if len(b) == 1:
                self._submit(b[0], f"{self.tag}-{b[0].index}")
            else:
                fut = self.client.submit(fly_batch, self.task, b, key=f"{self.tag}-batch-{b[0].index}-{len(b)}", pure=False)
                self._pending[fut] = b
                self._ac.add(fut)

    def _submit(self, unit: Unit, key: str) -> None:
        fut = self.client.submit(self.task, unit, key=key, pure=False)
        self._pending[fut] = unit
        self._ac.add(fut)

    @property
    def pending(self) -> int:
        """Units not finished yet."""
        return sum(len(v) if isinstance(v, list) else 1 for v in self._pending.values())

    def poll(self, timeout_s: float = 1.0) -> list[tuple[Unit, dict[str, Any]]]:
        """The units finished within ``timeout_s`` (possibly none), with their rows. Workers never
        wait for this: every submitted unit is queued on the scheduler."""
        if not self._pending:
            return []
        deadline = time.monotonic() + timeout_s
        done: list[Any] = []
        while True:
            done = [f for f in self._ac.next_batch(block=False) if f in self._pending]
            if done or time.monotonic() >= deadline:
                break
            time.sleep(0.02)
        out: list[tuple[Unit, dict[str, Any]]] = []
        for fut in done:
            unit = self._pending.pop(fut)
            self._started.pop(fut.key, None)
            if isinstance(unit, list):
                out += self._batch_rows(fut, unit)
                continue
            died = self._worker_died(fut)
            tries = self._again.get(unit.index, 0)
            if died and tries < (1 if died == "killed" else MAX_LOST_RETRIES):
                # Dask counts a worker's death against every task the scheduler had given that worker,
                # not only the one it was flying: a unit queued there can be "killed" twice, or lost,
                # without having flown. It is flown again; only a unit whose worker dies with it again
                # is an error (a lost one, after MAX_LOST_RETRIES).
                self._again[unit.index] = tries + 1
                self._submit(unit, f"{self.tag}-{unit.index}-again{tries + 1}")
                continue
            out.append((unit, self._row_of(fut, unit)))
        out += self._overdue()
        return out

    def _batch_rows(self, fut: Any, units: list[Unit]) -> list[tuple[Unit, dict[str, Any]]]:
        """A finished batch's rows; a batch that failed as a whole has its units flown again one per task."""
        rows: Any = None
        if fut.status == "finished":
            try:
                rows = fut.result()
            except Exception:
                rows = None
        if isinstance(rows, list) and len(rows) == len(units):
            return [(u, dict(r)) for u, r in zip(units, rows)]
        for u in units:
            self._submit(u, f"{self.tag}-{u.index}-alone")
        return []

    @staticmethod
    def _worker_died(fut: Any) -> str:
        """"killed": the unit's worker died with it (KilledWorker); "lost": its task came back
        without a result or an error of its own (lost with a dying worker); "": neither."""
        from distributed import KilledWorker

        if fut.status in ("finished", "cancelled"):
            return ""
        if fut.status != "error":
            return "lost"
        try:
            problem = fut.exception()
        except Exception:
            return ""
        if isinstance(problem, KilledWorker):
            return "killed"
        return "lost" if problem is None else ""

    def _row_of(self, fut: Any, unit: Unit) -> dict[str, Any]:
        from distributed import KilledWorker

        if fut.status == "finished":
            try:
                return dict(fut.result())
            except Exception as exc:
                return _error_row(unit, "error", f"{type(exc).__name__}: {exc}")
        if fut.status == "cancelled":
            return _error_row(unit, "error", "the task was cancelled (its worker or the scheduler went away)")
        problem: BaseException | None
        try:
            problem = fut.exception()
        except Exception as e:
            problem = e
        if isinstance(problem, KilledWorker):
            return _error_row(unit, "error", "its worker died while flying it (killed, out of memory or crashed), again when flown once more")
        if problem is None:
            return _error_row(unit, "error", f"its task was lost with a dying worker {MAX_LOST_RETRIES + 1} times, never flown to its end")
        return _error_row(unit, "error", f"{type(problem).__name__}: {problem}")

    def _overdue(self) -> list[tuple[Unit, dict[str, Any]]]:
        """Cancel tasks running past their limit plus the grace; restart their workers."""
        now = time.monotonic()
        if now - self._last_check < 1.0 or not self._pending:
            return []
        self._last_check = now
        try:
            processing = self.client.processing()
        except Exception:
            return []
        by_key = {f.key: f for f in self._pending}
        running: dict[str, str] = {}
        for worker, keys in processing.items():
            for k in keys:
                running[k] = worker
                self._started.setdefault(k, now)
        for k in [k for k in self._started if k not in running]:  # back in the queue (a worker restarted): not started
            del self._started[k]
        over = [k for k, t0 in self._started.items() if k in by_key and k in running
                and now - t0 > 2.0 * _timeout_s(self._pending[by_key[k]]) + self.grace_s]  # fmt: skip
        out: list[tuple[Unit, dict[str, Any]]] = []
        restart: set[str] = set()
        if over:
            executing = self._executing(sorted({running[k] for k in over}))
            for k in over:
                if k not in executing:  # queued on its worker behind another task: not started yet
                    self._started[k] = now
                    continue
                fut = by_key[k]
                unit = self._pending.pop(fut)
                self._started.pop(k, None)
                fut.cancel()
                restart.add(running[k])
                if isinstance(unit, list):  # a batch that hangs: its units flown again one per task
                    for u in unit:
                        self._submit(u, f"{self.tag}-{u.index}-alone")
                    continue
                out.append((unit, _error_row(unit, "timed out", f"no result {2.0 * unit.timeout_s + self.grace_s:g} s after its worker took it"
                                             " (a hang): cancelled, the worker restarted")))  # fmt: skip
        if restart:
            for k in [k for k, w in running.items() if w in restart]:
                self._started.pop(k, None)
            try:
                self.client.restart_workers(list(restart), timeout=60)
            except Exception as exc:  # a worker without a nanny cannot be restarted from here
                logging.getLogger(__name__).warning("could not restart worker(s) %s: %s", ", ".join(sorted(restart)), exc)
        return out

    def _executing(self, workers: Sequence[str]) -> set[str]:
        """The task keys these workers are executing now (their event loop answers while a task hangs)."""
        try:
            found = self.client.run(_executing_keys, workers=list(workers), on_error="return")
        except Exception:
            return set()
        return {k for keys in found.values() if isinstance(keys, list) for k in keys}

    def run(self, units: Sequence[Unit], on_row: Callable[[Unit, dict[str, Any]], None]) -> None:
        """Fly every unit; ``on_row`` gets each one's row as it finishes (in finishing order)."""
        self.submit(units)
        while self._pending:
            for unit, row in self.poll(1.0):
                on_row(unit, row)
