"""Progress display: a live bar on an interactive terminal, silence in CI logs."""
from __future__ import annotations

import os
import sys

from mbus_framework.estimation.progress import Progress


def interactive() -> bool:
    """True when stderr is a terminal and we are not in CI."""
    return sys.stderr.isatty() and not os.environ.get("CI")


class RichProgress(Progress):
    """A ``rich`` progress bar on stderr (one task at a time)."""

    def __init__(self) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress as _P, TextColumn, TimeElapsedColumn

        self._bar = _P(
            TextColumn("{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
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

    def stop(self) -> None:
        self._bar.stop()
        self._task = None


def make_progress(enabled: bool | None = None) -> Progress | None:
    if enabled is None:
        enabled = interactive()
    return RichProgress() if enabled else None
