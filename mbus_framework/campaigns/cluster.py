"""Reaching a Dask cluster and making its workers fit for mbus, or a one-line reason why not.

* :func:`probe` fails at once when nothing listens at a ``tcp://``/``tls://`` address
  (connection refused) instead of waiting for the connect timeout.
* :func:`check_workers` waits at most ``timeout`` seconds for a worker (``Client.wait_for_workers``),
  checks Python/Dask versions (``Client.get_versions(check=True)``) and registers
  :class:`MbusWorkerSetup` on every worker, present and future.
* :class:`MbusWorkerSetup` (a ``distributed.WorkerPlugin``) checks the worker imports the
  client's mbus version and tunes glibc's allocator (:func:`tune_malloc`).
* :func:`insecure_warning`: the scheduler runs whatever it is sent; a plain ``tcp://`` address
  that is not loopback deserves a warning (use ``tls://`` with Dask's security settings).
"""
from __future__ import annotations

import ctypes
import ipaddress
import platform
import signal
import socket
import threading
from urllib.parse import urlsplit

from distributed import WorkerPlugin

from mbus_framework import __version__
from mbus_framework.campaigns.quiet_start import quiet_heartbeat_errors
from mbus_framework.errors import MbusError

#: glibc ``mallopt`` parameters and the values set on every worker: freed memory is returned to
#: the system only above 128 MiB of free heap top, and only blocks of 32 MiB or more are mmap'd.
#: Dask's nanny sets ``MALLOC_TRIM_THRESHOLD_=65536``, which switches glibc's dynamic mmap
#: threshold off: every large numpy temporary is then mmap'd and unmapped again (measured:
#: 590k page faults and 1.4 s system time for one run, 24k and 0.15 s with these settings).
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
TRIM_THRESHOLD_B, MMAP_THRESHOLD_B = 128 << 20, 32 << 20
DIST = "mbus"  # the distribution's name, as Client.get_versions reads it from each worker's metadata


class ClusterError(MbusError):
    """The Dask cluster cannot be started, reached or used; the message names the address."""


def tune_malloc() -> bool:
    """Set :data:`TRIM_THRESHOLD_B` and :data:`MMAP_THRESHOLD_B` with glibc's ``mallopt``
    in this process; False (nothing done) on another C library."""
    if platform.libc_ver()[0] != "glibc":
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
    except OSError:
        return False
    return bool(libc.mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_B)) and bool(libc.mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_B))


class MbusWorkerSetup(WorkerPlugin):
    """Runs on every worker: refuses an mbus version other than the client's, tunes malloc.

    A worker without mbus cannot even unpickle this plugin, so registering it fails there with
    ``ModuleNotFoundError`` before any task is sent."""

    name = "mbus-setup"

    def __init__(self, version: str = __version__) -> None:
        self.version = version

    def setup(self, worker) -> None:
        import mbus_framework

        if mbus_framework.__version__ != self.version:
            raise RuntimeError(f"the worker {worker.address} has mbus {mbus_framework.__version__}, "
                               f"the client {self.version}")
        worker.mbus_malloc_tuned = tune_malloc()


def dask_setup(worker) -> None:  # noqa: ARG001 - Dask's preload hook
    """Preload of LocalCluster workers: ignore SIGINT, so the terminal's Ctrl-C (sent to the
    whole process group) stops only the client, which then cancels the fits and closes the
    cluster. (Spawned workers ignore it from their start already.) Also drops the heartbeat
    error of a worker still busy when the client closes the cluster (:mod:`.quiet_start`)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    quiet_heartbeat_errors()


def host_port(address: str) -> tuple[str, str, int | None]:
    """``(scheme, host, port)`` of a Dask address (``tcp`` when no scheme is given)."""
    parts = urlsplit(address if "://" in address else f"tcp://{address}")
    try:
        port = parts.port
    except ValueError:
        port = None
    return parts.scheme, parts.hostname or "", port


def probe(address: str, timeout: float) -> None:
    """Raise :class:`ClusterError` at once when a TCP address refuses the connection."""
    scheme, host, port = host_port(address)
    if scheme not in ("tcp", "tls") or not host or port is None:
        return
    try:
        socket.create_connection((host, port), timeout=timeout).close()
    except socket.timeout:
        raise ClusterError(f"cannot connect to the Dask scheduler at {address}: no answer within {timeout:g} s "
                           f"(raise --timeout if it is slow)") from None
    except OSError as exc:
        raise ClusterError(f"cannot connect to the Dask scheduler at {address}: {exc.strerror or exc} "
                           f"(is 'dask scheduler' running there?)") from None


def insecure_warning(address: str) -> str | None:
    """The warning for a plain ``tcp://`` scheduler that is not on this machine's loopback."""
    scheme, host, _ = host_port(address)
    if scheme != "tcp" or not host:
        return None
    try:
        if ipaddress.ip_address(socket.gethostbyname(host)).is_loopback:
            return None
    except (OSError, ValueError):
        pass
    return (f"the Dask scheduler at {address} is plain tcp:// on the network: anyone who can reach it can run code "
            f"on its workers; use tls:// with Dask's TLS settings (docs/campaigns.md)")


def check_workers(client, address: str, timeout: float) -> int:
    """Wait for at least one worker, check the versions of Python, Dask and mbus on every worker
    and set each up for mbus (present and future workers); returns the worker count."""
    from distributed.exceptions import WorkerStartTimeoutError

    try:
        client.wait_for_workers(1, timeout=timeout)
    except (WorkerStartTimeoutError, TimeoutError):
        raise ClusterError(f"the Dask scheduler at {address} has no workers (none joined within {timeout:g} s); "
                           f"start some with 'dask worker {address}' or raise --timeout") from None
    try:
        client.get_versions(check=True)
        versions = client.get_versions(packages=[DIST])
        ours = versions["client"]["packages"].get(DIST) or __version__
        workers = versions["workers"]
    except ValueError as exc:
        first = (str(exc).strip().splitlines() or ["version mismatch"])[0]
        raise ClusterError(f"the Dask cluster at {address}: {first}") from None
    for worker, info in sorted(workers.items()):
        found = ((info or {}).get("packages") or {}).get(DIST) if isinstance(info, dict) else None
        if found != ours:
            have = "cannot import mbus" if found is None else f"has mbus {found}"
            raise ClusterError(f"the Dask worker {worker} of {address} {have}; install mbus {ours} (and the "
                               f"plugins the runs use) on every worker")
    register(client, address)
    return len(client.scheduler_info(n_workers=-1).get("workers", {}))


def register(client, address: str) -> None:
    """Register :class:`MbusWorkerSetup` on every worker of ``client``."""
    try:
        client.register_plugin(MbusWorkerSetup(), name=MbusWorkerSetup.name)
    except Exception as exc:  # noqa: BLE001 - a worker's error comes back re-raised, often as a bare Exception
        text = " ".join(str(exc).split()) or type(exc).__name__
        if isinstance(exc, ImportError) or "No module named" in text:
            raise ClusterError(f"a Dask worker of {address} cannot import mbus ({text}); install mbus "
                               f"{__version__} on every worker") from None
        raise ClusterError(f"cannot set up the Dask workers of {address}: {text[:300]}; install mbus {__version__} "
                           f"on every worker") from None
