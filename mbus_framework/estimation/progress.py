"""The progress sink interface, in a module of its own so that light modules (the signal
handling of ``mbus-run``) can use it without importing numpy and the estimation problem."""
from __future__ import annotations


class Progress:
    """Minimal progress sink; the CLI passes a live display, tests pass nothing."""

    def start(self, description: str, total: int | None = None) -> None: ...

    def advance(self, steps: int = 1, note: str = "") -> None: ...

    def set_total(self, total: int) -> None:
        """The work turned out larger (or smaller) than announced at :meth:`start`."""

    def stop(self) -> None: ...
