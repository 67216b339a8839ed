"""User-facing errors. ``mbus-run`` prints these as one line and exits non-zero."""
from __future__ import annotations


class MbusError(Exception):
    """Base class of errors caused by input (configs, files, instruments), not by bugs."""

    exit_code = 2


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
