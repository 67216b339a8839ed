"""One campaign run at a time per folder, and only the current run's fits are committed.

* :class:`CampaignLock` holds an exclusive ``flock`` on ``<campaign>/.lock`` for the whole run:
  a second ``mbus-run`` on the same folder stops at once with a one-line error naming the
  process that holds it.
* Each run writes a new random *attempt token* to ``<campaign>/.attempt``. A task carries the
  token it was sent with; a worker commits its finished run folder only while the file still
  holds that token (:func:`is_current`), so a fit left running by an earlier, interrupted run
  cannot overwrite what a newer run wrote.
"""
from __future__ import annotations

import json
import os
import socket
import uuid
from pathlib import Path

from mbus_framework.errors import RunFolderError
from mbus_framework.pipeline.storage import atomic_write_text

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows: no lock, tokens still apply
    fcntl = None

LOCK_FILE = ".lock"
ATTEMPT_FILE = ".attempt"


class CampaignLock:
    """``with CampaignLock(out) as lock: lock.token`` - the folder locked, a new token written."""

    def __init__(self, out: Path) -> None:
        self.out = Path(out)
        self.token = uuid.uuid4().hex
        self._fd: int | None = None

    def __enter__(self) -> "CampaignLock":
        self.out.mkdir(parents=True, exist_ok=True)
        path = self.out / LOCK_FILE
        if fcntl is not None:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                os.close(fd)
                raise RunFolderError(f"{self.out}: another mbus-run is running this campaign{_holder(path)}; "
                                     f"wait for it to finish or name another folder with -o") from None
            os.ftruncate(fd, 0)
            os.write(fd, json.dumps({"pid": os.getpid(), "host": socket.gethostname()}).encode())
            self._fd = fd
        atomic_write_text(self.out / ATTEMPT_FILE, self.token)
        return self

    def __exit__(self, *exc) -> None:
        if self._fd is not None:
            fd, self._fd = self._fd, None
            os.close(fd)  # drops the flock; the token stays: fits of this run may still commit


def is_current(out: str | Path, token: str) -> bool:
    """True when ``token`` is the campaign folder's current attempt (an empty token always is)."""
    if not token:
        return True
    try:
        return (Path(out) / ATTEMPT_FILE).read_text(encoding="utf-8").strip() == token
    except OSError:
        return False


def _holder(path: Path) -> str:
    try:
        who = json.loads(path.read_text(encoding="utf-8"))
        return f" (pid {who['pid']} on {who['host']})"
    except (OSError, ValueError, KeyError, TypeError):
        return ""
