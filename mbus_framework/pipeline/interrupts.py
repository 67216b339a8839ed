"""Ctrl-C and SIGTERM: a run always stops, and never in the middle of writing a file.

:func:`handling` (used by ``mbus-run``) installs handlers for SIGINT and SIGTERM that raise
:class:`KeyboardInterrupt` (SIGINT, exit status 130) or :class:`Terminated` (SIGTERM, 143, a
KeyboardInterrupt too, so the same clean-up code handles both). Three guarantees:

* **Stops.** A library may swallow the exception (a few compiled routines, such as scipy's
  Sobol initialisation, report "Exception ignored" and carry on); the signal is remembered,
  :func:`check` raises it again at the next checkpoint (each start of the global search, each
  pipeline stage), and the swallowed one is not printed as a traceback.
* **Files stay whole.** Inside :func:`deferred` (every atomic file write, the status marker
  updates) a signal is held back and raised when the block ends, so no half-written file or
  stray temporary file is left behind.
* **In-process use is clean.** Handlers and state are restored when :func:`handling` exits;
  without it (Python API, tests) nothing is installed and Python's own Ctrl-C applies.
"""
from __future__ import annotations

import signal
import sys
import threading
from contextlib import contextmanager
from typing import Iterator

from mbus_framework.estimation.progress import Progress


class Terminated(KeyboardInterrupt):
    """The process received SIGTERM (``kill``, a scheduler stopping the job)."""


EXIT_STATUS = {signal.SIGINT: 130, signal.SIGTERM: 143}

_state = {"installed": False, "received": None, "depth": 0, "pending": None}


def _exception(signum: int) -> KeyboardInterrupt:
    return Terminated("terminated (SIGTERM)") if signum == signal.SIGTERM else KeyboardInterrupt()


def _handler(signum, frame) -> None:  # noqa: ARG001 - signal handler signature
    if _state["received"] is None:
        _state["received"] = signum
    if _state["depth"] > 0:
        _state["pending"] = signum
        return
    raise _exception(signum)


@contextmanager
def handling() -> Iterator[None]:
    """Install the SIGINT/SIGTERM handlers for the duration of the block (main thread only)."""
    if threading.current_thread() is not threading.main_thread() or _state["installed"]:
        yield
        return
    previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    previous_hook = sys.unraisablehook
    _state.update(installed=True, received=None, depth=0, pending=None)

    def unraisable(info) -> None:
        if not isinstance(info.exc_value, KeyboardInterrupt):
            previous_hook(info)  # only our own, swallowed interruption is kept quiet

    try:
        for s in previous:
            signal.signal(s, _handler)
        sys.unraisablehook = unraisable
        yield
    finally:
        sys.unraisablehook = previous_hook
        for s, h in previous.items():
            signal.signal(s, h)
        _state.update(installed=False, depth=0, pending=None)


def received() -> int | None:
    """The first signal received inside :func:`handling` (None when none)."""
    return _state["received"]


def exit_status(default: int = 130) -> int:
    """130 after SIGINT, 143 after SIGTERM."""
    return EXIT_STATUS.get(_state["received"], default)


def check() -> None:
    """Raise the remembered interruption again (a checkpoint); no-op when none arrived."""
    if _state["installed"] and _state["received"] is not None and _state["depth"] == 0:
        raise _exception(_state["received"])


@contextmanager
def deferred() -> Iterator[None]:
    """Hold signals back for the duration of the block; a held signal is raised at its end."""
    _state["depth"] += 1
    try:
        yield
    finally:
        _state["depth"] -= 1
        if _state["depth"] == 0 and _state["pending"] is not None:
            signum, _state["pending"] = _state["pending"], None
            raise _exception(signum)


class CheckedProgress(Progress):
    """A progress sink that is a checkpoint: every call first re-raises a swallowed interruption."""

    def __init__(self, inner: Progress | None = None) -> None:
        self.inner = inner

    def start(self, description: str, total: int | None = None) -> None:
        check()
        if self.inner is not None:
            self.inner.start(description, total)

    def advance(self, steps: int = 1, note: str = "") -> None:
        check()
        if self.inner is not None:
            self.inner.advance(steps, note)

    def stop(self) -> None:
        if self.inner is not None:
            self.inner.stop()
        check()
