"""Plumbing shared by the IEEE-488.2 instrument drivers (DS340, GDS-2000).

Every operation runs inside a named :meth:`Ieee4882Instrument.step`; any failure becomes one
:class:`~mbus_framework.errors.InstrumentError` line ``"<instrument>: <step>: <what>"``.
Settings are sent with :meth:`~Ieee4882Instrument.command`, which reads ``*ESR?`` (reading
clears it) so that a rejected command is reported by name.
"""
from __future__ import annotations

import math
from contextlib import contextmanager
from typing import Any

from mbus_framework.errors import InstrumentError

ESR_ERROR_BITS = {
    2: "query error",
    3: "device error",
    4: "execution error (value out of range)",
    5: "command error (unknown command or syntax)",
}
ESR_ERROR_MASK = sum(1 << b for b in ESR_ERROR_BITS)


def describe_esr(value: int) -> str:
    """Names of the error bits set in a standard event status register value."""
    names = [name for bit, name in ESR_ERROR_BITS.items() if value & (1 << bit)]
    return ", ".join(names) if names else "no error bits"


def one_line(exc: BaseException) -> str:
    """An exception's message folded onto one line (or its type when it has none)."""
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


def show(data: bytes) -> str:
    """Raw bytes for an error message, cut at 60."""
    return repr(data[:60]) + ("..." if len(data) > 60 else "")


class Ieee4882Instrument:
    """Base of the drivers: named steps, one-line errors, ``*ESR?``-checked commands.

    Subclasses provide ``write``, ``query``, ``open``, ``_close_transport`` and
    ``_transport_error`` (translate a transport exception into an InstrumentError).
    """

    name = "instrument"

    def __init__(self, options: Any):
        self.options = options
        self._step = "connect"
        self.identity: str | None = None
        self.settings: dict[str, Any] = {}

    # -- errors ---------------------------------------------------------------------------
    def fail(self, detail: str) -> None:
        raise InstrumentError(f"{self.name}: {self._step}: {detail}")

    @contextmanager
    def step(self, name: str):
        """Name the step for error messages; transport errors become InstrumentError."""
        previous, self._step = self._step, name
        try:
            yield
        except InstrumentError:
            raise
        except Exception as exc:  # noqa: BLE001 - translated below or re-raised
            err = self._transport_error(exc, name)
            if err is None:
                raise
            raise err from None
        finally:
            self._step = previous

    def _transport_error(self, exc: BaseException, step: str) -> InstrumentError | None:
        return None

    # -- lifetime -------------------------------------------------------------------------
    def open(self):
        raise NotImplementedError

    def _close_transport(self) -> None:
        raise NotImplementedError

    def close(self) -> None:
        try:
            self._close_transport()
        except Exception:  # noqa: BLE001 - closing a dead port must not mask the real error
            pass

    def __enter__(self):
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    # -- IEEE-488.2 common commands ------------------------------------------------------------
    def write(self, command: str) -> None:
        raise NotImplementedError

    def query(self, command: str) -> str:
        raise NotImplementedError

    def ascii_reply(self, data: bytes, what: str, hint: str = "") -> str:
        """Decode a reply; non-printable characters are a garbage reply."""
        text = data.decode("ascii", errors="replace").strip("\r\n ")
        if any(not (32 <= ord(c) < 127) for c in text):
            self.fail(f"garbage reply {show(data)} to '{what}'{hint}")
        return text

    def float_query(self, command: str) -> float:
        reply = self.query(command)
        try:
            value = float(reply)
        except ValueError:
            value = float("nan")
        if not math.isfinite(value):
            self.fail(f"garbage reply {reply!r} to '{command}' (expected a number)")
        return value

    def esr(self) -> int:
        """Read (and so clear) the standard event status register."""
        reply = self.query("*ESR?")
        try:
            value = int(reply)
        except ValueError:
            value = -1
        if not 0 <= value <= 255:
            self.fail(f"garbage reply {reply!r} to '*ESR?' (expected 0..255)")
        return value

    def command(self, command: str) -> None:
        """Send a setting and check ``*ESR?``; a set error bit names the command."""
        self.write(command)
        value = self.esr()
        if value & ESR_ERROR_MASK:
            self.fail(f"'{command}' rejected: *ESR? = {value} ({describe_esr(value)})")

    def check_identity(self, reply: str, expect_model: str | None, example: str) -> str:
        """Check the model field of an ``*IDN?`` reply and remember the identity."""
        fields = [f.strip() for f in reply.split(",")]
        if len(fields) < 2 or (expect_model and expect_model.upper() not in fields[1].upper()):
            self.fail(f"unexpected *IDN? reply {reply[:80]!r} (expected '{example}'; wrong port or baud rate?)")
        self.identity = reply
        return reply
