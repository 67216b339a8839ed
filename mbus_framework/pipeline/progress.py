"""Progress display: a live bar on an interactive terminal, silence in CI logs."""
from __future__ import annotations

import os
import sys

from mbus_framework.estimation.progress import Progress


def interactive() -> bool:
    """True when stderr is a terminal and we are not in CI."""
    return sys.stderr.isatty() and not os.environ.get("CI")


class RichProgress(Progress):
    """A ``rich`` progress bar on stderr (one task at a time): done/total, elapsed, ETA."""

    def __init__(self) -> None:
        from rich.console import Console
        from rich.progress import (BarColumn, MofNCompleteColumn, Progress as _P, TextColumn, TimeElapsedColumn,
                                   TimeRemainingColumn)

        self._bar = _P(
            TextColumn("{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            TextColumn("ETA"),
            TimeRemainingColumn(),
            TextColumn("{task.fields[note]}"),
            console=Console(stderr=True),
            transient=True,
        )
        self._task = None

    def start(self, description: str, total: int | None = None) -> None:
        self._bar.start()
        self._task = self._bar.add_task(description, total=total, note="")

    def advance(self, steps: int = 1, note: str = "") -> None:
        if self._task is not None:
            self._bar.update(self._task, advance=steps, note=note)

    def set_total(self, total: int) -> None:
        if self._task is not None:
            self._bar.update(self._task, total=total)

    def stop(self) -> None:
        self._bar.stop()
        self._task = None


def make_progress(enabled: bool | None = None) -> Progress | None:
    if enabled is None:
        enabled = interactive()
    return RichProgress() if enabled else None


class LineProgress(Progress):
    """Plain progress lines on stderr for long work off a terminal (logs, pipes).

    Silent for the first ``after`` seconds of a task (short work prints nothing); then one
    line ``description: done/total, elapsed, ETA`` at most every ``every`` seconds.
    """

    def __init__(self, after: float = 5.0, every: float = 15.0, stream=None) -> None:
        self.after, self.every, self.stream = after, every, stream
        self._description, self._total, self._done = "", None, 0
        self._t0 = self._last = 0.0

    def start(self, description: str, total: int | None = None) -> None:
        import time

        self._description, self._total, self._done = description, total, 0
        self._t0 = time.monotonic()
        self._last = self._t0 + self.after - self.every  # first line once `after` has passed

    def advance(self, steps: int = 1, note: str = "") -> None:
        import time

        self._done += steps
        now = time.monotonic()
        if now - self._t0 < self.after or now - self._last < self.every:
            return
        self._last = now
        elapsed = now - self._t0
        text = f"{self._description}: {self._done}"
        if self._total:
            text += f"/{self._total}"
            if 0 < self._done < self._total:
                text += f", ETA {elapsed * (self._total - self._done) / self._done:.0f} s"
        print(f"{text}, {elapsed:.0f} s elapsed{f' ({note})' if note else ''}", file=self.stream or sys.stderr, flush=True)

    def set_total(self, total: int) -> None:
        self._total = total

    def stop(self) -> None:
        self._total = None


def make_long_progress() -> Progress:
    """For work that may take minutes: the live bar on a terminal, else :class:`LineProgress`."""
    return RichProgress() if interactive() else LineProgress()
