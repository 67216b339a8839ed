"""Run folders: created exclusively, locked while in use, with a status marker.

Every run writes into a folder of its own, and two runs never share one:

* a default folder ``<output.directory>/<date-time>-<config>`` is created with ``mkdir``,
  which fails if the folder exists, so two runs started in the same second get ``...-2``;
* a folder named with ``-o`` is used only if it is new or empty, or holds a run that failed
  before anything was measured (only its config copy and status); a folder that holds a run is
  replaced only with ``--overwrite`` (and only if it is an mbus run folder);
* while a run works in its folder it holds an exclusive lock (``flock`` on the folder, POSIX),
  so a second run naming the same folder stops with "in use by another run";
* ``status.json`` says what the folder holds: ``running``, ``done``, ``failed`` (with the
  one-line error) or ``interrupted`` (Ctrl-C, SIGTERM, or found abandoned).

A run killed outright (SIGKILL, power loss) cannot mark its folder. The next run in the same
parent folder (and the ``file`` backend reading the folder) finds ``running`` with nobody
holding the lock, marks it ``interrupted``, sets the ``status`` of any JSON record still in
progress inside it (a lab acquisition's ``shots/acquisition.json`` saying ``acquiring``) to
``interrupted``, and removes temporary files of unfinished atomic writes.
"""
from __future__ import annotations

import datetime as _dt
import json
import os
import re
import shutil
import socket
from pathlib import Path
from typing import Any

from mbus_framework import __version__
from mbus_framework.errors import MbusError, RunFolderError, one_line
from mbus_framework.pipeline.interrupts import Terminated, deferred
from mbus_framework.pipeline.storage import TMP_SUFFIX, atomic_write_json

try:  # POSIX; elsewhere folders are still created exclusively, but not locked
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None

STATUS_FILE = "status.json"
RUNNING, DONE, FAILED, INTERRUPTED = "running", "done", "failed", "interrupted"
IN_PROGRESS = frozenset({"running", "connecting", "acquiring"})
"""``status`` values of JSON records that mean "still being written" (run folder, lab acquisition)."""
RUN_FILES = ("config.yaml", "measurement.csv", "result.json", "calibration_summary.json")
"""Files that mark a folder written by an older mbus (before ``status.json``)."""


def now() -> str:
    return _dt.datetime.now().astimezone().isoformat(timespec="seconds")


def default_name(source: str) -> str:
    """``<date-time>-<config stem>`` with the stem reduced to safe characters."""
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", Path(source).stem).strip("_.")[:80] or "run"
    return f"{stamp}-{stem}"


class RunFolder:
    """An exclusively created, locked run folder; a context manager that records the outcome.

    ``with RunFolder.create(...) as folder:`` marks ``done`` when the block ends normally,
    ``interrupted`` on Ctrl-C / SIGTERM, ``failed`` (with the error line) on an exception, and
    releases the lock.
    """

    def __init__(self, path: Path, lock_fd: int | None) -> None:
        self.path = path
        self._fd = lock_fd
        self.record: dict[str, Any] = {}

    # -- creation ---------------------------------------------------------------------------
    @classmethod
    def create(cls, path: str | os.PathLike | None = None, *, parent: str | os.PathLike = "runs",
               source: str = "run", overwrite: bool = False) -> "RunFolder":
        """Reserve ``path`` (or a new default folder under ``parent``) for one run."""
        if path is None:
            folder = cls._new_default(Path(parent), default_name(source))
        else:
            folder = cls._claim(Path(path), overwrite)
        folder.record = {"status": RUNNING, "pid": os.getpid(), "host": socket.gethostname(),
                         "started": now(), "updated": now(), "error": None, "mbus_version": __version__}
        atomic_write_json(folder.path / STATUS_FILE, folder.record)
        return folder

    @classmethod
    def _new_default(cls, parent: Path, name: str) -> "RunFolder":
        _make_parent(parent)
        recover_abandoned(parent)
        for k in range(1, 10_000):
            path = parent / (name if k == 1 else f"{name}-{k}")
            try:
                os.mkdir(path)
            except FileExistsError:
                continue
            except OSError as exc:
                raise RunFolderError(f"{path}: cannot create the run folder ({exc.strerror})") from None
            fd = _lock(path)
            if fd is not False:  # False: another run named it with -o in the instant since mkdir
                return cls(path, fd)
        raise RunFolderError(f"{parent}: no free run-folder name for {name}")

    @classmethod
    def _claim(cls, path: Path, overwrite: bool) -> "RunFolder":
        _make_parent(path.parent)
        recover_abandoned(path.parent)
        try:
            os.mkdir(path)
        except FileExistsError:
            if not path.is_dir():
                raise RunFolderError(f"{path}: exists and is not a folder; name a new output folder") from None
        except OSError as exc:
            raise RunFolderError(f"{path}: cannot create the run folder ({exc.strerror})") from None
        fd = _lock(path)
        if fd is False:
            raise RunFolderError(f"{path}: in use by another run{_holder(path)}; name another output folder")
        folder = cls(path, fd)
        try:
            entries = list(path.iterdir())
            if entries:
                if not overwrite and not _failed_before_measuring(path, entries):
                    raise RunFolderError(
                        f"{path}: already holds {_describe(path)}; name a new output folder, or pass --overwrite "
                        f"to replace it")
                if not is_run_folder(path):
                    raise RunFolderError(f"{path}: is not empty and is not an mbus run folder; refusing to "
                                         f"overwrite it (name a new or empty output folder)")
                for entry in entries:
                    if entry.is_dir() and not entry.is_symlink():
                        shutil.rmtree(entry)
                    else:
                        entry.unlink()
        except BaseException:
            folder.release()
            raise
        return folder

    # -- status -----------------------------------------------------------------------------
    def set_status(self, status: str, error: str | None = None) -> None:
        """Write ``status.json`` (atomically, signals held back)."""
        self.record.update(status=status, updated=now(), error=error)
        if status != RUNNING:
            self.record["finished"] = self.record["updated"]
        with deferred():
            atomic_write_json(self.path / STATUS_FILE, self.record)

    def release(self) -> None:
        """Release the lock (the folder and its files stay)."""
        if self._fd is not None:
            fd, self._fd = self._fd, None
            os.close(fd)  # closing the descriptor drops the flock

    def __enter__(self) -> "RunFolder":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        with deferred():
            try:
                if exc is None:
                    self.set_status(DONE)
                elif isinstance(exc, KeyboardInterrupt):
                    self.set_status(INTERRUPTED, "terminated (SIGTERM)" if isinstance(exc, Terminated)
                                    else "interrupted (Ctrl-C)")
                elif isinstance(exc, MbusError):
                    self.set_status(FAILED, exc.one_line())
                else:
                    self.set_status(FAILED, one_line(f"internal error: {type(exc).__name__}: {exc}"))
            except OSError:
                pass  # the folder vanished or the disk is full: the run's own error says more
            finally:
                self.release()


# -- helpers ---------------------------------------------------------------------------------
#: What a run leaves behind when it fails before any data exists (reusable without --overwrite).
BEFORE_DATA = {"config.yaml", STATUS_FILE}


def _failed_before_measuring(path: Path, entries: list[Path]) -> bool:
    """True for a folder whose run failed before anything was measured or written (only its
    config copy and status): nothing is lost by reusing it."""
    if {e.name for e in entries} - BEFORE_DATA:
        return False
    try:
        return json.loads((path / STATUS_FILE).read_text()).get("status") == FAILED
    except (OSError, ValueError, AttributeError):
        return False
def _make_parent(parent: Path) -> None:
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise RunFolderError(f"{parent}: exists and is not a folder (it should hold the run folder)") from None
    except OSError as exc:
        raise RunFolderError(f"{parent}: cannot create the output folder ({exc.strerror})") from None


def _lock(path: Path) -> int | None | bool:
    """An exclusive, non-blocking lock on the folder: its descriptor, False if held, None without flock."""
    if fcntl is None:  # pragma: no cover - Windows
        return None
    fd = os.open(path, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        return False
    return fd


def is_active(path: str | os.PathLike) -> bool:
    """True when a live process holds the folder's lock (a run is working in it)."""
    fd = _lock(Path(path)) if Path(path).is_dir() else None
    if fd is False:
        return True
    if fd is not None:
        os.close(fd)
    return False


def read_status(path: str | os.PathLike) -> dict[str, Any] | None:
    """The folder's ``status.json`` (None when missing or unreadable)."""
    try:
        data = json.loads((Path(path) / STATUS_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def is_run_folder(path: Path) -> bool:
    return (path / STATUS_FILE).is_file() or sum((path / f).is_file() for f in RUN_FILES) >= 2


def _holder(path: Path) -> str:
    status = read_status(path) or {}
    pid, host = status.get("pid"), status.get("host")
    return f" (pid {pid} on {host}, started {status.get('started')})" if pid else ""


def _describe(path: Path) -> str:
    status = read_status(path)
    if status:
        return f"a run ({status.get('status')}, started {status.get('started')})"
    return "a run" if is_run_folder(path) else "other files"


def recover_abandoned(parent: str | os.PathLike) -> list[Path]:
    """Mark the abandoned runs among ``parent``'s folders interrupted (see the module docstring)."""
    recovered = []
    try:
        candidates = [p for p in Path(parent).iterdir() if (p / STATUS_FILE).is_file()]
    except OSError:
        return recovered
    for path in candidates:
        if (read_status(path) or {}).get("status") == RUNNING and recover(path):
            recovered.append(path)
    return recovered


def recover(path: str | os.PathLike) -> bool:
    """Recover one abandoned run folder; False when a live run holds it (nothing is touched)."""
    path = Path(path)
    fd = _lock(path)
    if fd is False:
        return False
    try:
        note = f"abandoned: the process ended without closing the run (killed?); found {now()}"
        for tmp in _files(path, f".*{TMP_SUFFIX}"):
            tmp.unlink(missing_ok=True)
        for record_path in _files(path, "*.json"):
            try:
                record = json.loads(record_path.read_text(encoding="utf-8"))
            except (OSError, ValueError):
                continue
            if isinstance(record, dict) and record.get("status") in IN_PROGRESS:
                was = record["status"]
                record.update(status=INTERRUPTED, updated=now(),
                              error=record.get("error") or f"{note} (while {was})")
                if record_path.name == STATUS_FILE:
                    record["finished"] = record["updated"]
                atomic_write_json(record_path, record)
        return True
    finally:
        if fd is not None:
            os.close(fd)


def _files(path: Path, pattern: str, depth: int = 2) -> list[Path]:
    """Files matching ``pattern`` in ``path`` and its subfolders down to ``depth`` levels."""
    found, level = [], [path]
    for _ in range(depth + 1):
        found += [f for d in level for f in d.glob(pattern) if f.is_file()]
        level = [s for d in level for s in d.iterdir() if s.is_dir() and not s.is_symlink()]
    return found
