"""Collecting every problem of a campaign before any fit starts, one line each."""
from __future__ import annotations

from mbus_framework.errors import ConfigError


class CampaignError(ConfigError):
    """A campaign file or sample sheet is invalid. ``lines`` holds every problem found, each a
    complete one-line message naming the file, row and column; ``str()`` is the first line
    with a count of the others."""

    def __init__(self, lines: list[str]):
        self.lines = list(lines)
        more = len(self.lines) - 1
        super().__init__(self.lines[0] + (f" (and {more} more problem{'s' * (more > 1)})" if more else ""))


class Problems:
    """An ordered, de-duplicated list of one-line problems; :meth:`raise_if_any` ends validation."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    def add(self, line: str) -> None:
        if line not in self.lines:
            self.lines.append(line)

    def __bool__(self) -> bool:
        return bool(self.lines)

    def raise_if_any(self) -> None:
        if self.lines:
            raise CampaignError(self.lines)
