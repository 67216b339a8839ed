"""Running independent fits on Dask distributed.

By default a :class:`distributed.LocalCluster` with one single-threaded worker *process* per
core (the fits are numpy/scipy code that holds the GIL; threads would not run in parallel),
one BLAS thread each, glibc's own malloc tuning (see :func:`_glibc_malloc_defaults`);
with a scheduler address the fits run on that existing cluster, which is left as it was (only
our client disconnects). Each fit is one Dask task; a worker process imports mbus once and then
runs any number of fits. Workers of an existing cluster need mbus installed and must see the
data files and the output folder at the same paths (a shared file system).
"""
from __future__ import annotations

import logging
import os
import signal
import threading
import uuid
from contextlib import contextmanager
from typing import Any, Callable, Iterable, Iterator, TypeVar

from mbus_framework.errors import MbusError

T = TypeVar("T")

#: Environment of LocalCluster worker processes: one BLAS thread per process (the engine's
#: matrices are small; threaded BLAS only competes with the other workers), no GUI backend, and
#: no statistical profiler (it samples the task thread every 10 ms; about 7 % of a fit's CPU).
WORKER_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "MPLBACKEND": "Agg",
              "DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED": "False"}
CONNECT_TIMEOUT_S = 10


class ClusterError(MbusError):
    """The Dask cluster cannot be started or reached; the message names the address."""


@contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None, client=None) -> Iterator[Any]:
    """A ``distributed.Client``: ``client`` as given (not closed here), one connected to
    ``scheduler``, or one on a new LocalCluster of ``workers`` processes (default: one per core),
    closed with its cluster on exit."""
    from distributed import Client, LocalCluster

    if client is not None:
        yield client
        return
    if scheduler:
        try:
            connected = Client(scheduler, timeout=CONNECT_TIMEOUT_S, set_as_default=False)
        except (OSError, TimeoutError, ValueError) as exc:
            first = (str(exc).splitlines() or [type(exc).__name__])[0]
            raise ClusterError(f"cannot connect to the Dask scheduler at {scheduler}: {first}") from None
        try:
            yield connected
        finally:
            connected.close()
        return
    if workers is not None and workers < 1:
        raise ClusterError(f"--workers must be at least 1 (got {workers})")
    n = workers or os.cpu_count() or 1
    try:
        with _sigint_ignored(), _glibc_malloc_defaults():
            cluster = LocalCluster(
                n_workers=n,
                threads_per_worker=1,
                processes=True,
                dashboard_address=":0",
                silence_logs=logging.ERROR,
                env={**WORKER_ENV, **{k: os.environ[k] for k in WORKER_ENV if k in os.environ}},
            )
    except (OSError, TimeoutError, RuntimeError) as exc:
        first = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise ClusterError(f"cannot start a Dask LocalCluster of {n} worker processes: {first}") from None
    try:
        local = Client(cluster, set_as_default=False)
        try:
            yield local
        finally:
            local.close()
    finally:
        cluster.close()


@contextmanager
def _glibc_malloc_defaults() -> Iterator[None]:
    """Start worker processes without Dask's ``MALLOC_TRIM_THRESHOLD_=65536``.

    Setting it switches off glibc's dynamic mmap threshold, so every large numpy temporary of a
    fit is mmap'd and unmapped again: measured on a potato fit, 280,000 page faults and 0.10 s of
    system time per fit instead of 5,000 and 0.005 s (a fit costs about 0.25 s of user time).
    """
    import dask.config
    import distributed  # noqa: F401 - loads the distributed.* config defaults

    key = "distributed.nanny.pre-spawn-environ"
    environ = {k: v for k, v in (dask.config.get(key, default={}) or {}).items() if k != "MALLOC_TRIM_THRESHOLD_"}
    with dask.config.set({key: environ}):
        yield


@contextmanager
def _sigint_ignored() -> Iterator[None]:
    """Ignore SIGINT while worker processes are started (a child keeps an ignored SIGINT
    ignored, and Python then installs no KeyboardInterrupt handler in it); restored after."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def run_all(client, fn: Callable[[T], Any], items: Iterable[T], on_done: Callable[[T, Any], None],
            name: Callable[[T], str] = str) -> None:
    """Submit ``fn(item)`` for every item as one Dask task each and call ``on_done(item, value)``
    as tasks finish (``value`` is the exception when the task itself failed, e.g. a worker died).
    On Ctrl-C (or any exception) every unfinished task is cancelled before re-raising."""
    from distributed import as_completed

    futures = {}
    try:
        for item in items:
            key = f"mbus-{name(item)}-{uuid.uuid4().hex[:8]}"
            futures[client.submit(fn, item, key=key, pure=False)] = item
        for future in as_completed(list(futures), loop=client.loop):
            item = futures.pop(future)
            try:
                value = future.result()
            except Exception as exc:  # noqa: BLE001 - a lost worker or a cancelled task: the caller records it
                value = exc
            on_done(item, value)
    except BaseException:
        if futures:
            client.cancel(list(futures), force=True)
        raise
