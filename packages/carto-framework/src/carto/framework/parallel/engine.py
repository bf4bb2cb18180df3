"""The tile engine: runs a stage's tile tasks in this process, on worker processes of a local
``dask.distributed`` cluster, or on an existing cluster, with a progress bar, retries and a
record of the tasks that failed.

A task is an argument-less callable (a ``functools.partial`` of a module-level function over
paths, windows and settings), so it pickles and runs on any worker that sees the files; the
large arrays that a stage's tasks share (sensors' tables, a DEM) travel once, not in every task
(:mod:`~carto.framework.parallel.task_packing`). A task
that raises is retried (:data:`RETRIES` times); one that still fails gives a
:class:`TaskFailure` in its place, and the stage goes on: the caller decides what a missing
tile means (the DEM marks it nodata and the command fails with the cause). An interruption
(Ctrl-C, SIGTERM) is never retried.

:func:`open_engine` makes the engine of a command: ``workers=1`` runs in this process,
``workers=N`` starts a ``LocalCluster`` of ``N`` single-threaded worker processes (when a
stage first has more than one task; a single task runs in this process, on all its threads), and
``scheduler="tcp://host:8786"`` connects to a running cluster (``dask scheduler`` and
``dask worker`` on the machines, or ``dask-jobqueue`` on SLURM/PBS; the workers need Carto
installed and the input and output folders mounted at the same paths). Several commands run
in one process (``carto demo``) share one engine inside :func:`shared_engine`: their worker
processes start, import and load their compiled kernels once.
"""

from __future__ import annotations

import contextlib
import contextvars
import logging
import os
import sys
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import attrs

from carto.framework.errors import UsageError
from carto.framework.parallel.process_memory import release_free_memory
from carto.framework.parallel.progress import stage_bar

__all__ = [
    "RETRIES",
    "TaskFailure",
    "TileEngine",
    "default_workers",
    "open_engine",
    "shared_engine",
]

RETRIES = 1
"""How many times a failed task is run again before it is recorded as failed."""

GDAL_CACHE_MB = 256
"""GDAL's raster block cache per process, MB, unless ``GDAL_CACHEMAX`` is set: GDAL's default
(5 % of the RAM) lets each process keep up to 1.2 GB of blocks of a 24 GB machine, so the
memory of a run would grow with the rasters it reads and writes up to that size; a tile
reads and writes windows of a few tens of MB."""


def bound_gdal_cache() -> None:
    """Bound GDAL's block cache of this process and of the workers it starts
    (:data:`GDAL_CACHE_MB`) unless the user set ``GDAL_CACHEMAX``. Takes effect where GDAL
    has not read a raster yet (the CLI calls it first)."""
    os.environ.setdefault("GDAL_CACHEMAX", str(GDAL_CACHE_MB))


_WORKER_ENV = {  # one thread per worker process: the processes are the parallelism
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "NUMBA_NUM_THREADS": "1",
}


@attrs.frozen
class TaskFailure:
    """A task that failed after its retries: its key (e.g. ``"tile 3,4"``) and the cause
    (one line: the exception's type and message)."""

    key: str
    cause: str

    def __str__(self) -> str:
        return f"{self.key}: {self.cause}"


def _cause(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__


WORKERS_PER_CORE = 4
"""Most local worker processes per core (``--workers``): tile tasks are compute bound, more
processes than that only share the cores while each holds its tiles' memory."""


def default_workers() -> int:
    """All the cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def _run_here(task: Callable[[], Any], retries: int) -> Any:
    for attempt in range(retries + 1):
        try:
            return task()
        except Exception as exc:  # noqa: BLE001 (a task's failure is recorded, not raised)
            if attempt == retries:
                return exc
    return None  # pragma: no cover


@attrs.define(eq=False)
class TileEngine:
    """Runs lists of tasks (see the module docstring).

    Attributes:
        workers: the number of tasks that run at once.
        client: a ``distributed.Client`` (``None``: tasks run in this process).
        description: what runs the tasks, for reports (``"this process"``,
            ``"LocalCluster of 2 processes"``, ``"cluster tcp://..."``).
        quiet: no progress bars.
        connect: makes the client when a stage first has more than one task (a local
            cluster is started only when there is work to share; a stage of one task runs
            in this process, on all its threads).
    """

    workers: int = 1
    client: Any = None
    description: str = "this process"
    quiet: bool = False
    connect: Callable[[], Any] | None = None
    disconnect: Callable[[], None] | None = None

    def release(self) -> None:
        """Stop the local cluster this engine started, so that its worker processes give
        their memory back while the command goes on in this process (the bundle adjustment
        after the tie points); a later stage starts it again. A shared engine
        (:func:`shared_engine`) has no ``disconnect``: it keeps its cluster for the commands
        after, until its block ends."""
        if self.client is not None and self.disconnect is not None:
            self.disconnect()
            self.client = None

    def run(
        self,
        tasks: Sequence[Callable[[], Any]],
        *,
        desc: str = "tiles",
        keys: Sequence[str] | None = None,
        retries: int = RETRIES,
    ) -> list[Any]:
        """Run ``tasks``; their results in order, a :class:`TaskFailure` for each task that
        still raised after ``retries`` more attempts."""
        names = list(keys) if keys is not None else [f"task {k}" for k in range(len(tasks))]
        if len(names) != len(tasks):
            raise ValueError("run: one key per task")
        if self.client is None and self.connect is not None and len(tasks) > 1:
            self.client = self.connect()
        where = self.description if self.client is not None else "this process"
        logging.getLogger("carto.engine").debug("%s: %d task(s) on %s", desc, len(tasks), where)
        # what the caller freed since the last stage (e.g. an iteration's assembly of the
        # tiles' results) back to the system before the workers' memory rises: it stayed
        # resident in this process's heap through the stage, 420-670 MB of a whole scene's
        # (issue 33)
        release_free_memory(f"before {desc}")
        with stage_bar(len(tasks), desc, quiet=self.quiet) as bar:
            if self.client is None:
                results = []
                for task, key in zip(tasks, names, strict=True):
                    value = _run_here(task, retries)
                    results.append(
                        TaskFailure(key, _cause(value)) if isinstance(value, Exception) else value
                    )
                    bar.advance()
            else:
                results = self._run_distributed(tasks, names, retries, bar)
        release_free_memory(desc)  # what the stage freed, back to the system
        return results

    def __call__(self, tasks: Sequence[Callable[[], Any]]) -> list[Any]:
        """The DEM generators' ``scheduler`` contract: results in order."""
        return self.run(tasks)

    def _run_distributed(
        self, tasks: Sequence[Callable[[], Any]], names: list[str], retries: int, bar: Any
    ) -> list[Any]:
        from distributed import wait

        from carto.framework.parallel.task_packing import pack_tasks, run_packed

        packed = pack_tasks(tasks)  # the stage's large arrays once, not in every task
        # Ctrl-C and SIGTERM are held while distributed works (it may swallow an interruption
        # in its own waits) and raised here, between waits of at most half a second
        with _signals_deferred() as pending:
            shared = self._share(packed.arrays)
            futures = [
                self.client.submit(
                    run_packed,
                    blob,
                    keys,
                    *(shared[k] for k in keys),
                    pure=False,
                    retries=retries,
                    key=_key(name),
                )
                for blob, keys, name in zip(packed.blobs, packed.keys, names, strict=True)
            ]
            index = {f.key: k for k, f in enumerate(futures)}
            results: list[Any] = [None] * len(futures)
            remaining = set(futures)
            try:
                while remaining:
                    if pending:
                        raise KeyboardInterrupt
                    try:
                        with self.client.as_current():
                            done, remaining = wait(
                                remaining, timeout=0.5, return_when="FIRST_COMPLETED"
                            )
                    except TimeoutError:
                        continue
                    for future in done:
                        k = index[future.key]
                        if future.status == "error":
                            results[k] = TaskFailure(names[k], _cause(future.exception()))
                        else:
                            results[k] = future.result()
                        future.release()
                        bar.advance()
                if pending:  # held during the last wait: an interruption all the same
                    raise KeyboardInterrupt
            except BaseException:
                self.client.cancel(futures)
                raise
            finally:
                for future in shared.values():
                    future.release()
        return results

    def _share(self, arrays: dict[str, Any]) -> dict[str, Any]:
        """``arrays`` on every worker (futures by key), each sent once for the stage's
        tasks. They are tasks of their own, not scattered data, which the cluster cannot make
        again when the worker holding it dies; and copied to every worker before the tile
        tasks are submitted: the scheduler gives a task to a worker that holds its inputs
        (distributed's ``decide_worker``), so with one copy every tile would be given to the
        worker that made it and wait for work stealing to move it."""
        import warnings

        from distributed import wait

        from carto.framework.parallel.task_packing import shared_array

        with warnings.catch_warnings():  # "large graph": sent once by design, not per task
            warnings.filterwarnings("ignore", "Sending large graph", UserWarning)
            futures = {
                key: self.client.submit(shared_array, array, pure=False, key=_key(key))
                for key, array in arrays.items()
            }
        if futures:
            with self.client.as_current():
                wait(list(futures.values()))
            self.client.replicate(list(futures.values()))
        return futures


def _key(name: str) -> str:
    import uuid

    return f"carto-{name.replace(' ', '-')}-{uuid.uuid4().hex[:12]}"


_SHARED: contextvars.ContextVar[TileEngine | None] = contextvars.ContextVar(
    "carto_shared_engine", default=None
)


@contextlib.contextmanager
def shared_engine(workers: int | None = None, *, quiet: bool = False) -> Iterator[TileEngine]:
    """An engine (:func:`open_engine`) that every :func:`open_engine` of the block without a
    scheduler, and with no workers or the same number, returns instead of its own: the
    commands of one process (``carto demo``) share its local cluster, which starts once."""
    with open_engine(workers, None, quiet=quiet) as engine:
        engine.disconnect = None  # the block's end stops the cluster, not a command's release
        token = _SHARED.set(engine)
        try:
            yield engine
        finally:
            _SHARED.reset(token)


@contextlib.contextmanager
def open_engine(
    workers: int | None = None, scheduler: str | None = None, *, quiet: bool = False
) -> Iterator[TileEngine]:
    """The engine of a command (see the module docstring); the local cluster it started is
    closed at the end of the block.

    Args:
        workers: tasks at once (default: every core, :func:`default_workers`); 1 runs them
            in this process; at most :data:`WORKERS_PER_CORE` per core. Refused with
            ``scheduler`` (the cluster has its workers).
        scheduler: the address of a running ``dask.distributed`` scheduler.
        quiet: no progress bars.

    Raises:
        UsageError: ``workers`` < 1, or a scheduler that cannot be reached.
    """
    if workers is not None and (isinstance(workers, bool) or int(workers) != workers):
        raise UsageError(f"--workers must be an integer >= 1, got {workers!r}")
    if workers is not None and workers < 1:
        raise UsageError(f"--workers must be >= 1, got {workers}")
    shared = _SHARED.get()
    if shared is not None and scheduler is None and workers in (None, shared.workers):
        yield shared  # closed by shared_engine
        return
    if scheduler is not None and workers is not None:
        raise UsageError(
            "--workers and --scheduler exclude each other: the cluster's workers run the tiles"
        )
    most = WORKERS_PER_CORE * default_workers()
    if scheduler is None and workers is not None and workers > most:
        raise UsageError(
            f"--workers {workers}: more than {WORKERS_PER_CORE} per core ({most} for the "
            f"{default_workers()} cores here) only share them and multiply the memory; give "
            "--scheduler to use a cluster"
        )
    if scheduler is not None:
        with _client(scheduler) as client:
            n = max(1, sum(client.nthreads().values()))
            announce_dashboard(client, quiet)
            yield TileEngine(n, client, f"cluster {scheduler}", quiet)
        return
    n = default_workers() if workers is None else int(workers)
    if n == 1:
        yield TileEngine(1, None, "this process", quiet)
        return
    with contextlib.ExitStack() as stack:
        yield TileEngine(
            n,
            None,
            f"LocalCluster of {n} processes",
            quiet,
            connect=lambda: announce_dashboard(stack.enter_context(_local_cluster(n)), quiet),
            disconnect=stack.close,
        )


def announce_dashboard(client: Any, quiet: bool) -> Any:
    """Say where the cluster's dask dashboard is (one line on stderr; it needs ``bokeh``:
    ``pip install carto-framework[dashboard]``); return ``client``."""
    import importlib.util

    if not quiet and importlib.util.find_spec("bokeh") is not None:
        link = getattr(client, "dashboard_link", None)
        if link:
            print(f"carto: dask dashboard: {link}", file=sys.stderr, flush=True)
    return client


SCHEDULER_TIMEOUT_S = 10.0
"""How long ``--scheduler`` may take to answer who it is."""
WORKERS_TIMEOUT_S = 30.0
"""How long a ``--scheduler`` without workers is waited for one, before the run fails (the
tasks would wait for ever)."""


def _identity(address: str, timeout_s: float = SCHEDULER_TIMEOUT_S) -> dict[str, Any]:
    """What the server at ``address`` says it is (dask's ``identity`` request), each step
    bounded by ``timeout_s``: a server that is not dask's (a web server on that port) leaves
    ``Client`` waiting past its own timeout, or decoding its reply as frame lengths of
    exabytes, then a traceback at exit."""
    import asyncio

    from distributed.comm import connect

    async def ask() -> Any:
        # the connection's own timeout first: it says that nothing listens there
        comm = await asyncio.wait_for(connect(address, timeout=timeout_s), timeout_s + 5.0)
        try:
            await asyncio.wait_for(comm.write({"op": "identity", "reply": True}), timeout_s)
            return await asyncio.wait_for(comm.read(), timeout_s)
        finally:
            comm.abort()

    try:
        reply = asyncio.run(ask())
    except TimeoutError:
        raise UsageError(
            f"--scheduler {address}: no answer from a dask scheduler within {timeout_s:g} s "
            "(another kind of server on that port?)"
        ) from None
    except (OSError, ValueError, TypeError, KeyError, EOFError, MemoryError) as exc:
        # what a foreign server's bytes make of the protocol (MemoryError: frame lengths)
        raise UsageError(f"--scheduler {address}: cannot connect: {_cause(exc)}") from None
    if not isinstance(reply, dict) or reply.get("type") != "Scheduler":
        raise UsageError(f"--scheduler {address}: not a dask scheduler (it answered {reply!r:.80})")
    return reply


@contextlib.contextmanager
def _client(address: str) -> Iterator[Any]:
    from distributed import Client

    _identity(address)
    try:
        client = Client(address, timeout="10s", set_as_default=False)
    except (OSError, TimeoutError) as exc:
        raise UsageError(f"--scheduler {address}: cannot connect: {_cause(exc)}") from None
    try:
        try:
            client.wait_for_workers(1, timeout=WORKERS_TIMEOUT_S)
        except TimeoutError:
            raise UsageError(
                f"--scheduler {address}: the scheduler has no worker after "
                f"{WORKERS_TIMEOUT_S:g} s; start some (dask worker {address}) and run again"
            ) from None
        yield client
    finally:
        client.close()


@contextlib.contextmanager
def _signals_deferred() -> Iterator[list[int]]:
    """Hold SIGINT and SIGTERM for the block (the signals received are listed); in the main
    thread only (elsewhere Python delivers no signal)."""
    import signal
    import threading

    pending: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield pending
        return
    caught = (signal.SIGINT, signal.SIGTERM)
    previous = {s: signal.signal(s, lambda signum, _frame: pending.append(signum)) for s in caught}
    try:
        yield pending
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


WORKER_ARENAS = 2
"""glibc malloc arenas per worker process unless ``MALLOC_ARENA_MAX`` is set. glibc gives
each thread that allocates its own arena, up to 8 per core; a worker's threads (dask's event
loop and task thread, OpenCV's and GDAL's pools) made 8-9 arenas of 40-52 MB each that hold
their freed memory between tiles: 350-390 MB of a worker's 1.2 GB on the strip of issue 33.
Two arenas hold it to the task thread's and one other."""


def _nanny_environ() -> dict[str, Any]:
    """What the nanny sets before it starts a worker process (what glibc reads as the
    process starts): glibc's own trim threshold (distributed sets ``MALLOC_TRIM_THRESHOLD_``
    to 64 KiB, so that glibc gives freed memory back at once; a tile task allocates and
    frees arrays of tens of MB all the time, and with that setting every one of them is
    faulted in again page by page: on the quarter scene, workers spent 40 % of their time in
    the kernel and two workers were no faster than one) and :data:`WORKER_ARENAS`."""
    arenas = os.environ.get("MALLOC_ARENA_MAX", str(WORKER_ARENAS))
    return {
        "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
        "distributed.nanny.pre-spawn-environ.MALLOC_ARENA_MAX": arenas,
    }


@contextlib.contextmanager
def _local_cluster(n: int) -> Iterator[Any]:
    # an interruption while the cluster starts would leave it half made (distributed then
    # fails on its own state), and one that lands while distributed is imported can be lost
    # (a finaliser running then swallows it): both are held until the cluster is up, then
    # raised
    with _signals_deferred() as pending:
        import dask
        from distributed import Client, LocalCluster

        for name in ("distributed", "tornado", "bokeh"):
            logging.getLogger(name).setLevel(logging.ERROR)
        with dask.config.set(_nanny_environ()):
            cluster = LocalCluster(
                n_workers=n,
                threads_per_worker=1,
                processes=True,
                dashboard_address=":0",  # None is 8787: two runs at once warned of it
                silence_logs=logging.CRITICAL,
                preload=["carto.framework.parallel.worker_setup"],
                env={
                    **_WORKER_ENV,
                    "GDAL_CACHEMAX": os.environ.get("GDAL_CACHEMAX", str(GDAL_CACHE_MB)),
                },
            )
            client = Client(cluster, set_as_default=False)
    try:
        if pending:
            raise KeyboardInterrupt
        yield client
    finally:
        client.close()
        cluster.close()
