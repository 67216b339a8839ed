"""A Ctrl-C that stops a LocalCluster quietly: workers that start with SIGINT ignored, a start-up
the client leaves at once, and no heartbeat error from a worker that outlives its scheduler.

A terminal's Ctrl-C goes to the whole foreground process group: the client and the worker
processes it is starting. A worker still importing (``site``, numpy, distributed) died with a
``KeyboardInterrupt`` traceback on stderr, and its nanny logged "Nanny failed to start". The
client stops its cluster itself on Ctrl-C, so the workers need not see the signal at all.

:func:`workers_ignore_sigint` makes ``multiprocessing``'s *spawn* start method (Dask's default,
``distributed.worker.multiprocessing-method``) run Python through a three-line ``/bin/sh``
wrapper, ``trap '' INT; exec PYTHON "$@"``. An ignored signal stays ignored across ``exec``
(POSIX), and CPython installs its ``KeyboardInterrupt`` handler only when SIGINT is at its
default at start-up, so the worker ignores Ctrl-C from its first instruction. The client's own
handler is untouched: the user's Ctrl-C still stops the client at once. (Blocking SIGINT in the
client would not do: the signal mask is not passed on to spawned children.)

:func:`start_cluster` builds the cluster in a helper thread, so a Ctrl-C does not cancel Dask's
start-up half way. :func:`quiet_heartbeat_errors` (run in each LocalCluster worker by its
preload) drops the worker's "Failed to communicate with scheduler during heartbeat" traceback:
a LocalCluster's scheduler lives in the client's process, so it is gone only when the client
closes it, and a worker busy with a fit when the client stops may heartbeat once more.
"""
from __future__ import annotations

import logging
import os
import shlex
import tempfile
import threading
import time
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Iterator

SHELL = "/bin/sh"
#: Seconds a Ctrl-C waits for a half-started LocalCluster to fail after its workers are killed.
STOP_TIMEOUT_S = 10.0


def write_wrapper(folder: Path, python: str) -> Path | None:
    """An executable ``/bin/sh`` script in ``folder`` that runs ``python`` with SIGINT ignored;
    None where it could not run (no ``/bin/sh``, a ``noexec`` file system)."""
    if not os.path.exists(SHELL) or os.statvfs(folder).f_flag & getattr(os, "ST_NOEXEC", 0):
        return None
    path = folder / "python-sigint-ignored"
    path.write_text(f"#!{SHELL}\ntrap '' INT\nexec {shlex.quote(python)} \"$@\"\n", encoding="utf-8")
    path.chmod(0o700)
    return path


@contextmanager
def workers_ignore_sigint() -> Iterator[None]:
    """Processes spawned in the block (the LocalCluster's workers) start with SIGINT ignored.

    Only the *spawn* start method on POSIX runs a new executable; otherwise nothing changes
    (the workers' ``dask_setup`` preload still ignores SIGINT once they have started). The
    wrapper lives only as long as the block: workers restarted later run Python directly."""
    import dask.config
    from multiprocessing import spawn

    method = dask.config.get("distributed.worker.multiprocessing-method", default="spawn")
    python = spawn.get_executable()
    if os.name != "posix" or method != "spawn" or not python:
        yield
        return
    with tempfile.TemporaryDirectory(prefix="mbus-spawn-") as folder:
        wrapper = write_wrapper(Path(folder), os.fsdecode(python))
        if wrapper is None:
            yield
            return
        spawn.set_executable(str(wrapper))
        try:
            yield
        finally:
            spawn.set_executable(python)


def start_cluster(factory, *args, **kwargs):
    """``factory(*args, **kwargs)`` (a LocalCluster) built in a helper thread while this thread
    waits, so that a Ctrl-C here raises at once without cancelling Dask half way (which left
    its nannies' failures unretrieved and its exit-time ``close`` failing, all on stderr).

    On Ctrl-C the worker processes started so far are killed (they ignore SIGINT and hold no
    work yet), Dask's start-up then fails by itself within :data:`STOP_TIMEOUT_S`, and a cluster
    that finished starting is closed; the KeyboardInterrupt is re-raised."""
    import multiprocessing

    before = set(multiprocessing.active_children())
    box: dict = {}
    done = threading.Event()  # not Thread.join: a join interrupted by Ctrl-C can leave is_alive() False

    def build() -> None:
        try:
            box["cluster"] = factory(*args, **kwargs)
        except BaseException as exc:  # noqa: BLE001 - handed to the waiting thread
            box["error"] = exc
        finally:
            done.set()

    threading.Thread(target=build, name="mbus-cluster-start", daemon=True).start()
    try:
        while not done.wait(0.1):
            pass
    except KeyboardInterrupt:
        deadline = time.monotonic() + STOP_TIMEOUT_S
        while not done.is_set() and time.monotonic() < deadline:
            for process in set(multiprocessing.active_children()) - before:
                process.kill()
            done.wait(0.05)
        if box.get("cluster") is not None:
            with suppress(Exception):
                box["cluster"].close(timeout=STOP_TIMEOUT_S)
        raise
    if "error" in box:
        raise box["error"]
    return box["cluster"]


#: The message of ``distributed.worker`` that :func:`quiet_heartbeat_errors` drops.
HEARTBEAT_ERROR = "Failed to communicate with scheduler during heartbeat."


class _NoHeartbeatError(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return record.msg != HEARTBEAT_ERROR


def quiet_heartbeat_errors(logger: logging.Logger | None = None) -> logging.Filter:
    """Drop :data:`HEARTBEAT_ERROR` records of ``logger`` (default ``distributed.worker``);
    returns the filter (to remove it again)."""
    quiet = _NoHeartbeatError()
    (logger or logging.getLogger("distributed.worker")).addFilter(quiet)
    return quiet
