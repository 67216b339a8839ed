"""Running independent fits on Dask distributed.

By default a :class:`distributed.LocalCluster` with one single-threaded worker *process* per
core (the fits are numpy/scipy code that holds the GIL; threads would not run in parallel),
one BLAS thread each, glibc's own malloc tuning (see :func:`_glibc_malloc_defaults`), fits sent
to the workers ahead rather than queued on the scheduler (:func:`_fits_sent_ahead`);
with a scheduler address the fits run on that existing cluster, which is left as it was (only
our client disconnects). Each fit is one Dask task; a worker process imports mbus once and then
runs any number of fits. Workers of an existing cluster need mbus installed (checked before the
first task: :mod:`~mbus_framework.campaigns.cluster`, which also tunes every worker's malloc) and
must see the data files and the output folder at the same paths (a shared file system).
A LocalCluster's workers ignore Ctrl-C from their start; a Ctrl-C while it starts stops the
client at once and the half-started cluster quietly (:mod:`.quiet_start`).
"""
from __future__ import annotations

import logging
import os
import signal
import threading
import uuid
import warnings
from contextlib import contextmanager
from typing import Any, Callable, Iterable, Iterator, TypeVar

from mbus_framework.campaigns.cluster import ClusterError, check_workers, insecure_warning, probe, register
from mbus_framework.campaigns.quiet_start import start_cluster, workers_ignore_sigint

PRELOAD = "mbus_framework.campaigns.cluster"  # its dask_setup runs first in each LocalCluster worker

__all__ = ["ClusterError", "CONNECT_TIMEOUT_S", "dask_client", "run_all"]

T = TypeVar("T")


class SecurityWarning(UserWarning):
    """The cluster is reachable without authentication or encryption."""

#: Environment of LocalCluster worker processes: one BLAS thread per process (the engine's
#: matrices are small; threaded BLAS only competes with the other workers), no GUI backend, and
#: no statistical profiler (it samples the task thread every 10 ms; about 7 % of a fit's CPU).
WORKER_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "MPLBACKEND": "Agg",
              "DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED": "False"}
#: Seconds to wait for a scheduler to answer and for its first worker (``--timeout``).
CONNECT_TIMEOUT_S = 15.0


@contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None, client=None,
                timeout: float | None = None) -> Iterator[Any]:
    """A ``distributed.Client``: ``client`` as given (not closed here), one connected to
    ``scheduler``, or one on a new LocalCluster of ``workers`` processes (default: one per core),
    closed with its cluster on exit. Workers are checked and set up (:mod:`.cluster`); with a
    scheduler, each step waits at most ``timeout`` seconds (default :data:`CONNECT_TIMEOUT_S`)
    and fails with a one-line :class:`ClusterError`."""
    from distributed import Client, LocalCluster

    timeout = CONNECT_TIMEOUT_S if timeout is None else float(timeout)
    if client is not None:
        register(client, "the given client")
        yield client
        return
    if scheduler:
        warning = insecure_warning(scheduler)
        if warning:
            warnings.warn(warning, SecurityWarning, stacklevel=3)
        probe(scheduler, timeout)
        try:
            connected = Client(scheduler, timeout=timeout, set_as_default=False)
        except TypeError as exc:
            if "ssl_context" not in str(exc):
                raise
            raise ClusterError(f"cannot connect to the Dask scheduler at {scheduler}: a tls:// address needs Dask's TLS "
                               f"settings (distributed.comm.tls.ca-file, .client.cert, .client.key; docs/campaigns.md)"
                               ) from None
        except (OSError, TimeoutError, ValueError) as exc:
            first = (str(exc).splitlines() or [type(exc).__name__])[0]
            raise ClusterError(f"cannot connect to the Dask scheduler at {scheduler}: {first}") from None
        try:
            check_workers(connected, scheduler, timeout)
            yield connected
        finally:
            connected.close()
        return
    if workers is not None and workers < 1:
        raise ClusterError(f"--workers must be at least 1 (got {workers})")
    n = workers or os.cpu_count() or 1
    cluster = None
    try:
        try:
            with _glibc_malloc_defaults(), _fits_sent_ahead(), workers_ignore_sigint():  # Ctrl-C stops the client
                cluster = start_cluster(
                    LocalCluster,
                    n_workers=n,
                    threads_per_worker=1,
                    processes=True,
                    dashboard_address=":0",
                    silence_logs=logging.ERROR,
                    env={**WORKER_ENV, **{k: os.environ[k] for k in WORKER_ENV if k in os.environ}},
                    preload=[PRELOAD],  # and once started, on any start method
                )
        except (OSError, TimeoutError, RuntimeError) as exc:
            first = (str(exc).splitlines() or [type(exc).__name__])[0]
            raise ClusterError(f"cannot start a Dask LocalCluster of {n} worker processes: {first}") from None
        local = Client(cluster, set_as_default=False)
        try:
            register(local, "the LocalCluster")
            yield local
        finally:
            local.close()
    finally:
        if cluster is not None:
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
def _fits_sent_ahead() -> Iterator[None]:
    """Start the LocalCluster's scheduler with ``distributed.scheduler.worker-saturation: inf``.

    Dask's default (1.1) queues tasks on the scheduler and sends a worker its next one only when
    one finishes, so each fit waits a scheduler round trip. A campaign's tasks are whole fits
    (0.1 s to minutes, a small row back), so sending them ahead costs nothing, and work stealing
    still balances the workers. Measured on 16 potato fits of 0.14 s, 2 workers over 1, four
    alternating rounds: 1.48-1.83x (median 1.62x) with the default, 1.68-1.81x (median 1.77x)
    with this.
    """
    import dask.config

    with dask.config.set({"distributed.scheduler.worker-saturation": float("inf")}):
        yield


@contextmanager
def sigint_ignored() -> Iterator[None]:
    """Ignore SIGINT for the block; the previous handler is restored after."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def run_all(client, fn: Callable[[T], Any], items: Iterable[T], on_done: Callable[[T, Any], None],
            name: Callable[[T], str] = str, group: str = "mbus") -> None:
    """Submit ``fn(item)`` for every item as one Dask task each and call ``on_done(item, value)``
    as tasks finish (``value`` is the exception when the task itself failed, e.g. a worker died).
    On Ctrl-C (or any exception) every unfinished task is cancelled before re-raising. Task keys
    are ``(group, "<name>-<random>")``: the dashboard groups every task under ``group``."""
    from distributed import as_completed

    futures = {}
    try:
        for item in items:
            key = (group, f"{name(item)}-{uuid.uuid4().hex[:8]}")
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
