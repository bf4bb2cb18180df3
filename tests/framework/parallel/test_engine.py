"""The tile engine: results in order, retries, failure records, in this process and on a
LocalCluster of worker processes; usage errors of its options."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pytest

from carto.framework.errors import UsageError
from carto.framework.parallel.engine import TaskFailure, TileEngine, open_engine, shared_engine


def square(x: int) -> int:
    if x == 3:
        raise ValueError("three is refused\nsecond line")
    return x * x


def flaky(counter: str, x: int) -> int:
    """Fails on its first call (counted in a file), then succeeds."""
    path = Path(counter)
    calls = int(path.read_text()) if path.exists() else 0
    path.write_text(str(calls + 1))
    if calls == 0:
        raise OSError("transient")
    return x


def interrupted() -> None:
    raise KeyboardInterrupt


def dies_once(marker: str, x: int, table: np.ndarray | None = None) -> float:
    """Kills its worker process on its first call (marked in a file), then returns ``x``
    (plus the sum of ``table``, into which it writes ``x`` first)."""
    import os

    path = Path(marker)
    if not path.exists():
        path.write_text("died")
        os._exit(1)
    if table is None:
        return x
    table += x
    return float(table.sum())


def pid_on(table: np.ndarray, k: int) -> tuple[int, float]:
    """The worker's process id after a short wait (so that one worker cannot take every
    task), and ``table[k]``."""
    import os
    import time

    time.sleep(0.3)
    return os.getpid(), float(table[k])


def worker_facts(_: int) -> tuple[int, str | None, str | None, str | None]:
    import os

    env = os.environ
    return (
        os.getpid(),
        env.get("GDAL_CACHEMAX"),
        env.get("MALLOC_TRIM_THRESHOLD_"),
        env.get("MALLOC_ARENA_MAX"),
    )


def _check(engine: TileEngine, tmp_path: Path) -> None:
    tasks = [functools.partial(square, k) for k in range(6)]
    keys = [f"tile {k}" for k in range(6)]
    out = engine.run(tasks, keys=keys)
    assert out[:3] == [0, 1, 4]
    assert out[4:] == [16, 25]
    assert out[3] == TaskFailure("tile 3", "ValueError: three is refused")
    counter = tmp_path / "count.txt"
    assert engine.run([functools.partial(flaky, str(counter), 7)]) == [7]
    assert counter.read_text() == "2"  # failed once, retried once


def test_a_stage_gives_the_freed_heap_back_before_and_after(monkeypatch):
    from carto.framework.parallel import engine as engine_module

    stages: list[str] = []
    monkeypatch.setattr(engine_module, "release_free_memory", stages.append)
    with open_engine(1) as engine:
        assert engine.run([functools.partial(square, 2)], desc="tiles of x") == [4]
    # before: what the caller freed since the last stage; after: what the stage freed
    assert stages == ["before tiles of x", "tiles of x"]


def test_the_users_malloc_arenas_are_kept(monkeypatch):
    from carto.framework.parallel.engine import WORKER_ARENAS, _nanny_environ

    key = "distributed.nanny.pre-spawn-environ.MALLOC_ARENA_MAX"
    monkeypatch.delenv("MALLOC_ARENA_MAX", raising=False)
    assert _nanny_environ()[key] == str(WORKER_ARENAS)
    monkeypatch.setenv("MALLOC_ARENA_MAX", "8")
    assert _nanny_environ()[key] == "8"


def test_in_this_process(tmp_path):
    with open_engine(1) as engine:
        assert engine.client is None
        assert engine.workers == 1
        _check(engine, tmp_path)
        with pytest.raises(KeyboardInterrupt):
            engine.run([interrupted])


def test_on_a_local_cluster_of_processes(tmp_path, monkeypatch):
    import os

    monkeypatch.delenv("GDAL_CACHEMAX", raising=False)
    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)
    monkeypatch.delenv("MALLOC_ARENA_MAX", raising=False)
    with open_engine(2) as engine:
        assert engine.workers == 2
        assert "LocalCluster of 2 processes" in engine.description
        _check(engine, tmp_path)
        tasks = [functools.partial(worker_facts, k) for k in range(4)]
        first = engine.run(tasks)
        # the workers are other processes, with GDAL's block cache bounded and glibc's own
        # trim threshold (not distributed's 64 KiB, which faults every large array in anew)
        # and two malloc arenas
        assert {pid for pid, *_ in first}.isdisjoint({os.getpid()})
        assert {cache for _, cache, _, _ in first} == {"256"}
        assert {trim for _, _, trim, _ in first} == {None}
        assert {arenas for *_, arenas in first} == {"2"}
        # released: the worker processes stop; the next stage starts new ones
        engine.release()
        assert engine.client is None
        for pid, *_ in first:
            with pytest.raises(ProcessLookupError):
                os.kill(pid, 0)
        again = engine.run(tasks)
        assert {pid for pid, *_ in again}.isdisjoint({pid for pid, *_ in first})
        (tmp_path / "again").mkdir()
        _check(engine, tmp_path / "again")
        # tasks that share a large array (sent once, issue 33) still run on every worker
        table = np.arange(200_000, dtype=float)
        shared = engine.run([functools.partial(pid_on, table, k) for k in range(8)])
        assert [v for _, v in shared] == list(range(8))
        assert len({pid for pid, _ in shared}) == 2


def test_the_commands_of_a_shared_engine_use_its_worker_processes(tmp_path):
    """Inside :func:`shared_engine` the engines of commands are the shared one: the second
    command's tasks run on the first one's worker processes (started once, not stopped by a
    command's release), and the block's end stops them; other worker counts keep engines of
    their own."""
    import os

    tasks = [functools.partial(worker_facts, k) for k in range(4)]
    with shared_engine(2, quiet=True) as shared:
        with open_engine(quiet=True) as first:
            pids = {pid for pid, *_ in first.run(tasks)}
            first.release()  # a command's release keeps the shared cluster for the next
        with open_engine(2, quiet=True) as second:
            assert second is first is shared
            assert {pid for pid, *_ in second.run(tasks)} == pids
        with open_engine(1) as own:
            assert own is not shared
            assert own.client is None
        _check(shared, tmp_path)
    assert not pids & {os.getpid()}
    for pid in pids:
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)
    with open_engine(1) as after:
        assert after is not shared


def test_on_a_running_cluster(tmp_path):
    from distributed import LocalCluster

    with (
        LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None) as cluster,
        open_engine(scheduler=cluster.scheduler_address) as engine,
    ):
        assert engine.workers == 2
        assert cluster.scheduler_address in engine.description
        _check(engine, tmp_path)


@pytest.mark.parametrize("workers", [0, -2, 1.5, True])
def test_bad_workers(workers):
    with pytest.raises(UsageError, match="--workers"), open_engine(workers):
        pass


def test_workers_beyond_the_cores_or_beside_a_scheduler_are_refused():
    """1000 processes on a few cores only share them (each with its tiles' memory); beside
    --scheduler, --workers would be ignored: both refused before anything starts."""
    from carto.framework.parallel.engine import WORKERS_PER_CORE, default_workers

    too_many = WORKERS_PER_CORE * default_workers() + 1
    with pytest.raises(UsageError, match=f"--workers {too_many}: more than"), open_engine(too_many):
        pass
    with (
        pytest.raises(UsageError, match="--workers and --scheduler exclude each other"),
        open_engine(2, scheduler="tcp://127.0.0.1:9"),
    ):
        pass


def test_a_server_that_is_not_dask_is_refused_within_the_timeout(monkeypatch):
    """A web server on the --scheduler port: dask's Client waited past its own timeout, then
    printed a traceback at exit (or tried to allocate exabytes, issue 31); one usage error
    within the probe's timeout instead."""
    import http.server
    import threading

    from carto.framework.parallel import engine as engine_module

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), http.server.SimpleHTTPRequestHandler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    monkeypatch.setattr(
        engine_module, "_identity", functools.partial(engine_module._identity, timeout_s=2.0)
    )
    address = f"tcp://127.0.0.1:{server.server_address[1]}"
    try:
        with (
            pytest.raises(UsageError, match=f"--scheduler {address}: no answer from a dask"),
            open_engine(scheduler=address),
        ):
            pass
    finally:
        server.shutdown()
        server.server_close()


def test_unreachable_scheduler():
    with (
        pytest.raises(UsageError, match=r"--scheduler tcp://127\.0\.0\.1:9"),
        open_engine(scheduler="tcp://127.0.0.1:9"),
    ):
        pass


INTERRUPTED = """
import functools, os, signal, sys, threading, time
from carto.framework.parallel.engine import open_engine

def slow(x):
    time.sleep(2.0)
    return x

if __name__ == "__main__":
    threading.Timer(float(sys.argv[1]), lambda: os.kill(os.getpid(), signal.SIGINT)).start()
    try:
        with open_engine(2) as engine:
            engine.run([functools.partial(slow, k) for k in range(6)])
        print("completed")
    except KeyboardInterrupt:
        print("interrupted")
"""


@pytest.mark.parametrize("delay_s", [0.3, 1.5])
def test_ctrl_c_while_the_local_cluster_starts_or_runs_is_an_interruption(tmp_path, delay_s):
    """distributed fails on its own half-made state when interrupted while a LocalCluster
    starts (AssertionError: Status.init): the engine holds the signal until it is up."""
    import subprocess
    import sys

    script = tmp_path / "interrupted.py"
    script.write_text(INTERRUPTED)
    res = subprocess.run(
        [sys.executable, str(script), str(delay_s)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert res.stdout.strip() == "interrupted", res.stderr[-2000:]


def test_a_scheduler_without_workers_fails_after_the_timeout(monkeypatch):
    """A scheduler no worker has joined: the tasks would wait for ever (issue 34, item 6);
    the run fails with a usage error that says how to start one."""
    from distributed import LocalCluster

    from carto.framework.parallel import engine as engine_module

    monkeypatch.setattr(engine_module, "WORKERS_TIMEOUT_S", 2.0)
    with LocalCluster(n_workers=0, dashboard_address=None) as cluster:
        address = cluster.scheduler_address
        with (
            pytest.raises(UsageError, match=f"--scheduler {address}: the scheduler has no worker"),
            open_engine(scheduler=address),
        ):
            pass


def test_a_worker_killed_mid_run_is_replaced_and_its_task_run_again(tmp_path):
    """A worker process that dies under a task (killed, out of memory) is not fatal (issue
    34, item 6): the cluster's nanny starts another, the task runs again, every result
    comes back in order, on a real LocalCluster of processes."""
    marker = tmp_path / "died.txt"
    with open_engine(2) as engine:
        tasks = [functools.partial(dies_once, str(marker), k) for k in range(4)]
        assert engine.run(tasks) == [0, 1, 2, 3]
        assert marker.read_text() == "died"
        # tasks that share a large array (sent once to every worker, issue 33): a dead
        # worker's replacement gets it, and each task writes into its own copy of it
        marker.unlink()
        table = np.arange(100_000, dtype=float)
        tasks = [functools.partial(dies_once, str(marker), k, table) for k in range(6)]
        expected = [float((table + k).sum()) for k in range(6)]
        assert engine.run(tasks) == expected
    assert marker.read_text() == "died"


def test_the_dashboard_is_announced_when_bokeh_can_serve_it(monkeypatch, capsys):
    import importlib.util
    import types

    from carto.framework.parallel.engine import announce_dashboard

    client = types.SimpleNamespace(dashboard_link="http://127.0.0.1:40123/status")
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name: object() if name == "bokeh" else real(name)
    )
    assert announce_dashboard(client, quiet=False) is client
    assert "carto: dask dashboard: http://127.0.0.1:40123/status" in capsys.readouterr().err
    announce_dashboard(client, quiet=True)
    assert capsys.readouterr().err == ""
    monkeypatch.setattr(importlib.util, "find_spec", lambda name: None)  # no bokeh: nothing
    announce_dashboard(client, quiet=False)
    assert capsys.readouterr().err == ""
