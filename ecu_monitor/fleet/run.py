"""``fleet run``: every unseen log of every engine as one Dask task, then the per-engine reduction.

Dask runs the tasks: a local cluster of worker processes on this machine (one per core, one thread each:
the compiled kernels hold the GIL) unless ``scheduler`` names a running one (``tcp://HOST:8786``; its
workers need ecu-monitor installed and the logs at the same paths). Each worker is a long-lived process:
the numba kernels are compiled (or loaded from the on-disk cache, ecu_monitor/compile_cache.py, whose
folder :class:`CompileCachePlugin` sets on every worker) once per worker, at its first log.

Results come back as they finish and are written at once (fleet/store.py): a run stopped at any moment
keeps every log finished so far and the next run resumes with the others. A bad log (UserInputError) is a
failure row and the rest go on; a task that crashed (a defect, a worker lost) is a failure row too, marked
internal and retried by the next run. Then, per engine in flight order: the across-flight detector and the
ranking (fleet/engines.py), engines.parquet and report.html.
"""

from __future__ import annotations

import collections
import logging
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from distributed import WorkerPlugin

from ecu_monitor.errors import UserInputError
from ecu_monitor.fleet.engines import EngineTrend, engine_rows, engine_trend
from ecu_monitor.fleet.spec import EngineSettings, Fleet, LogJob, load_fleet
from ecu_monitor.fleet.store import FleetStore
from ecu_monitor.fleet.summary import LogSummary, engine_setup, summarise_log

__all__ = ["CompileCachePlugin", "FleetRun", "open_client", "run_fleet"]


@dataclass
class FleetRun:
    """What a run did: logs processed, skipped (seen before), failed; the engines' rows; timings."""

    processed: int = 0
    skipped: int = 0
    failed: list[tuple[str, str]] = field(default_factory=list)  # (log, reason)
    removed: int = 0
    engines: list[dict[str, Any]] = field(default_factory=list)
    trends: list[EngineTrend] = field(default_factory=list)
    wall_s: float = 0.0
    task_cpu_s: float = 0.0
    workers: int = 0
    empty_globs: list[str] = field(default_factory=list)


def _task(job: LogJob, engine: EngineSettings) -> LogSummary | str:
    """One log on a worker: its summary, or the one-line reason it cannot be read."""
    try:
        return summarise_log(job, engine)
    except UserInputError as exc:
        return str(exc)


class CompileCachePlugin(WorkerPlugin):
    """A Dask worker plugin: the ecu-monitor numba cache folder on every worker (unless it has one)."""

    name = "ecu-monitor-compile-cache"

    def setup(self, worker: Any) -> None:
        from ecu_monitor.compile_cache import use_cache_dir

        use_cache_dir()


def open_client(scheduler: str | None, workers: int | None) -> Any:
    """A Dask client of the scheduler at ``scheduler``, or of a new local cluster of ``workers`` processes
    (default: one per core); the compile-cache plugin registered."""
    from dask.distributed import Client, LocalCluster

    logging.getLogger("distributed").setLevel(logging.WARNING)  # its INFO lines would drown the progress
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise UserInputError(f"--scheduler {scheduler}: cannot reach the Dask scheduler ({exc})") from None
    else:
        count = workers or os.cpu_count() or 1
        cluster = LocalCluster(n_workers=count, threads_per_worker=1, processes=True, dashboard_address=None,
                               silence_logs=logging.ERROR)  # fmt: skip
        client = Client(cluster)
    client.register_plugin(CompileCachePlugin())
    return client


def run_fleet(
    fleet_path: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    say: Callable[[str], None] | None = None,
    client: Any = None,
) -> FleetRun:
    """Run the fleet (module docstring); ``say`` gets the progress lines. ``client``: a Dask client to use
    (else :func:`open_client`, closed at the end)."""
    started = time.perf_counter()
    say = say or _stderr
    fleet = load_fleet(fleet_path)
    store = FleetStore(out)
    jobs, empty = fleet.jobs()
    store.prepare([fleet.source, *(j.path for j in jobs)])
    run = FleetRun(empty_globs=empty)
    done = store.done_keys() | store.failed_keys(internal=False)
    todo = [j for j in jobs if j.key not in done]
    unique: dict[str, LogJob] = {}
    for job in todo:
        unique.setdefault(job.key, job)
    run.skipped = len(jobs) - len(todo)
    say(f"fleet {fleet.source}: {len(fleet.engines)} engines, {len(jobs)} logs, {len(unique)} to process"
        f" ({run.skipped} seen before)")  # fmt: skip
    if unique:
        own = client is None
        client = client or open_client(scheduler, workers)
        try:
            run.workers = len(client.scheduler_info()["workers"])
            _process(client, fleet, list(unique.values()), store, run, say)
        finally:
            if own:
                cluster = client.cluster
                client.close()
                if cluster is not None:
                    cluster.close()
    run.removed = store.remove_stale({j.key for j in jobs})
    run.trends, run.engines = reduce_fleet(fleet, store)
    from ecu_monitor.fleet.report import write_report

    write_report(store, fleet, run.engines, run.trends)
    run.wall_s = time.perf_counter() - started
    return run


def _process(client: Any, fleet: Fleet, jobs: list[LogJob], store: FleetStore, run: FleetRun,
             say: Callable[[str], None]) -> None:  # fmt: skip
    """Submit one task per log and write each result as it comes; progress lines."""
    from dask.distributed import as_completed

    futures = {client.submit(_task, job, fleet.engine(job.serial), key=f"fleet-log-{job.key}", pure=False): job
               for job in jobs}  # fmt: skip
    started = time.perf_counter()
    last_said = -1e9
    for finished, future in enumerate(as_completed(futures), start=1):
        job = futures[future]
        if future.status == "error":
            exc = future.exception()
            reason = f"internal error: {type(exc).__name__}: {exc}".splitlines()[0]
            store.write_failure(job.serial, job.name, job.key, reason, internal=True)
            run.failed.append((job.name, reason))
        else:
            result = future.result()
            if isinstance(result, str):
                store.write_failure(job.serial, job.name, job.key, result, internal=False)
                run.failed.append((job.name, result))
            else:
                store.write_log(job.serial, job.key, result.flights, result.events)
                run.processed += 1
                run.task_cpu_s += result.cpu_s
        future.release()
        now = time.perf_counter()
        if now - last_said >= 2.0 or finished == len(jobs):
            elapsed = now - started
            left = elapsed / finished * (len(jobs) - finished)
            say(f"fleet: {finished}/{len(jobs)} logs done, {len(run.failed)} failed, {elapsed:.0f} s elapsed,"
                f" about {left:.0f} s left")  # fmt: skip
            last_said = now


def reduce_fleet(fleet: Fleet, store: FleetStore) -> tuple[list[EngineTrend], list[dict[str, Any]]]:
    """Per engine: its flights in order and the across-flight detector; engines.parquet written, ranked."""
    flights = collections.defaultdict(list)
    for row in store.table("flights").to_pylist():
        flights[row["serial"]].append(row)
    events = collections.defaultdict(list)
    for row in store.table("events").to_pylist():
        events[row["serial"]].append(row)
    failures = collections.Counter(row["serial"] for row in store.table("failures").to_pylist())
    trends = []
    baseline = {}
    for engine in fleet.engines:
        config, _ = engine_setup(engine)
        trends.append(engine_trend(engine.serial, flights[engine.serial], config.wear, config.wear_reference))
        baseline[engine.serial] = config.wear.baseline_flights
    overhaul = {e.serial: (e.tbo_hours, e.overhaul_hours) for e in fleet.engines}
    rows = engine_rows(trends, events, failures, overhaul, baseline)
    store.write_engines(rows)
    return trends, rows


def _stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)
