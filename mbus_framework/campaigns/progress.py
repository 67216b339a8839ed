"""Campaign progress: a rich bar (done, failed, remaining, ETA) on a terminal, silence elsewhere."""
from __future__ import annotations

from mbus_framework.pipeline.progress import interactive


class CampaignProgress:
    """``with CampaignProgress(total, title) as p: ... p.finished(failed=...)``.

    ``enabled=None`` shows the bar only when stderr is a terminal outside CI.
    """

    def __init__(self, total: int, title: str, enabled: bool | None = None) -> None:
        self.total, self.done, self.failed = total, 0, 0
        self._bar = None
        if total and (interactive() if enabled is None else enabled):
            from rich.console import Console
            from rich.progress import (
                BarColumn,
                Progress,
                TextColumn,
                TimeElapsedColumn,
                TimeRemainingColumn,
            )

            self._bar = Progress(
                TextColumn("{task.description}"),
                BarColumn(),
                TextColumn("{task.completed:.0f}/{task.total:.0f} done"),
                TextColumn("[red]{task.fields[failed]} failed"),
                TextColumn("{task.fields[remaining]} remaining"),
                TextColumn("ETA"),
                TimeRemainingColumn(),
                TimeElapsedColumn(),
                console=Console(stderr=True),
                transient=False,
            )
            self._task = self._bar.add_task(title, total=total, failed=0, remaining=total)

    def __enter__(self) -> "CampaignProgress":
        if self._bar is not None:
            self._bar.start()
        return self

    def finished(self, failed: bool) -> None:
        """One fit has finished (``failed``: with an error)."""
        self.done += 1
        self.failed += bool(failed)
        if self._bar is not None:
            self._bar.update(self._task, advance=1, failed=self.failed, remaining=self.total - self.done)

    def __exit__(self, *exc) -> None:
        if self._bar is not None:
            self._bar.stop()
