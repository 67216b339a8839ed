"""User-facing errors. ``mbus-run`` prints these as one line and exits non-zero."""
from __future__ import annotations

from typing import Any

MAX_SHOWN = 60
"""Characters of a user-supplied value quoted in a message (names, keys, values)."""
MAX_MESSAGE = 1000
"""Characters of a whole one-line message; longer ones keep their head and tail."""


class MbusError(Exception):
    """Base class of errors caused by input (configs, files, instruments), not by bugs."""

    exit_code = 2

    def one_line(self) -> str:
        """The message on one line (whitespace folded) and at most :data:`MAX_MESSAGE` long."""
        return one_line(str(self))


class ConfigError(MbusError):
    """A config file or override is invalid; the message names the key path."""


class PluginError(MbusError):
    """A plugin is unknown, broken or clashes with another."""


class DataError(MbusError):
    """A data file or measurement is unusable; the message names the file."""


class InstrumentError(MbusError):
    """An instrument failed; the message names the instrument and the step."""

    exit_code = 3


class EstimationError(MbusError):
    """Estimation could not run (for example, a model that cannot be simulated)."""


class ResourceError(MbusError):
    """A run would need more memory or time than is sensible; the message names the key to change."""


class RunFolderError(MbusError):
    """The output folder is in use, holds another run, or is not a folder."""


def shown(value: Any, limit: int = MAX_SHOWN) -> str:
    """``repr`` of a user-supplied value for a message: one line, at most ``limit`` characters.

    A 100,000-character plugin name or a name with a newline stays one short line.
    """
    text = repr(value)
    if len(text) > limit:
        keep = max(limit - 5, 8)
        text = f"{text[: keep // 2 + keep % 2]}[...]{text[-(keep // 2):]}"
    return text


def one_line(text: str, limit: int = MAX_MESSAGE) -> str:
    """``text`` with every run of whitespace (newlines included) folded to one space, cut to ``limit``."""
    text = " ".join(str(text).split())
    if len(text) > limit:
        half = (limit - 5) // 2
        text = f"{text[:half]}[...]{text[-half:]}"
    return text
