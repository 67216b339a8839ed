"""SRS DS340 function/arbitrary generator on RS-232 (pyserial).

Protocol (DS345 manual semantics; the DS340 uses the same command language, see
``reference/instruments.md``; items marked *unconfirmed* must be checked on the instrument):

* ASCII commands, four-letter mnemonics, terminated by LF (``write_termination``); replies end
  with CR (``read_termination``; CR/LF are stripped from replies).
* Serial frame 8 data bits, no parity, 2 stop bits (the instrument sends 2 and accepts 1 or 2);
  9600 baud by default; RTS/CTS handshake optional (``rtscts``, *unconfirmed* which is needed).
* Arbitrary waveform download, point format: ``LDWF? 0,<N>``; wait for the reply ``1``; send N
  signed 16-bit points, least-significant byte first, each within -2047..+2047 (full scale =
  the ``AMPL`` peak-to-peak value); then the checksum = sum of the points ignoring carries, also
  LSB first. Its width is *unconfirmed*: 2 bytes (the manual's wording, default) or 4 bytes (what
  one public DS345 driver sends); ``checksum_bytes`` chooses.
* ``FSMP <Hz>`` arbitrary sampling rate (the instrument may round it; the rate actually set is
  read back with ``FSMP?``), ``AMPL <x>VP`` amplitude in volts peak-to-peak (arbitrary
  waveforms need the VP unit), ``OFFS <V>``; burst, single shot: ``MTYP 5``, ``BCNT <n>``,
  ``TSRC 0``, ``MENA 1``, and ``*TRG`` fires one burst.
* ``*ESR?`` (read clears) is checked after every configuration command, so a rejected command
  is reported by name. Bits: 2 query error, 3 device error, 4 execution error (value out of
  range), 5 command error (unknown command or syntax).

Every failure raises :class:`~mbus_framework.errors.InstrumentError` with the message
``"DS340: <step>: <what happened>"``.
"""
from __future__ import annotations

import time
from typing import Any, Callable, Literal

import numpy as np
import serial
from pydantic import BaseModel, ConfigDict, Field

from mbus_framework.errors import InstrumentError

from .common import ESR_ERROR_MASK, Ieee4882Instrument, describe_esr, one_line, show

try:  # POSIX serial ports raise termios.error (not an OSError) when the device has gone
    import termios

    PORT_ERRORS: tuple[type[BaseException], ...] = (serial.SerialException, OSError, termios.error)
except ImportError:  # pragma: no cover - Windows
    PORT_ERRORS = (serial.SerialException, OSError)

POINT_LIMIT = 2047
"""Largest magnitude of an arbitrary-waveform point (full scale = +-AMPL/2)."""


_TERMINATORS = {"\n": "LF", "\r": "CR", "\r\n": "CR LF"}


class DS340Options(BaseModel):
    """Connection and output settings of the DS340 (``backend.options.generator``)."""

    model_config = ConfigDict(extra="forbid")

    port: str = Field(description="serial port: /dev/ttyUSB0 (Linux), COM3 (Windows) or a pyserial URL")
    baudrate: Literal[300, 600, 1200, 2400, 4800, 9600, 19200] = Field(
        9600, description="baud rate; must match the instrument's setting [bit/s]")
    bytesize: Literal[7, 8] = Field(8, description="data bits")
    parity: Literal["N", "E", "O"] = Field("N", description="parity: N none, E even, O odd")
    stopbits: Literal[1, 2] = Field(2, description="stop bits (the DS34x sends 2, accepts 1 or 2)")
    rtscts: bool = Field(False, description="RTS/CTS hardware handshake (unconfirmed which the DS340 needs)")
    xonxoff: bool = Field(False, description="XON/XOFF software handshake")
    write_termination: Literal["\n", "\r", "\r\n"] = Field("\n", description="command terminator")
    read_termination: Literal["\r", "\n"] = Field("\r", description="reply terminator (CR on RS-232)")
    timeout: float = Field(2.0, gt=0, description="time allowed for each reply [s]")
    ready_timeout: float = Field(5.0, gt=0, description="time allowed for the LDWF? ready reply [s]")
    checksum_bytes: Literal[2, 4] = Field(
        2, description="width of the LDWF? checksum (unconfirmed: 2 per the manual text, 4 in one public driver)")
    expect_model: str = Field("DS340", description="model expected in *IDN? field 2 ('' skips the check)")
    min_points: int = Field(8, ge=1, description="fewest arbitrary points the instrument accepts")
    max_points: int = Field(16300, ge=8, description="most arbitrary points the instrument accepts (unconfirmed)")
    reset: bool = Field(False, description="send *RST before configuring")
    amplitude_vpp: float = Field(1.0, gt=0, description="output for full-scale points +-2047, peak to peak [V]")
    offset: float = Field(0.0, description="DC offset [V]")
    burst_count: int = Field(1, ge=1, le=30000, description="waveform repetitions per trigger (BCNT)")
    sample_rate: float | None = Field(
        None, gt=0, description="FSMP [Hz]; default: the excitation's sample rate / upload_decimation")
    upload_decimation: int = Field(
        1, ge=1, description="upload every k-th excitation sample (e.g. one point per PRBS bit)")


def checksum_bytes(points: np.ndarray, width: int) -> bytes:
    """Sum of the points ignoring carries, ``width`` bytes, least-significant byte first."""
    total = int(np.asarray(points, dtype=np.int64).sum())
    return (total & ((1 << (8 * width)) - 1)).to_bytes(width, "little")


def encode_points(points: np.ndarray) -> bytes:
    """Points as signed 16-bit little-endian bytes."""
    return np.asarray(points).astype("<i2").tobytes()


def scale_to_points(u: np.ndarray) -> np.ndarray:
    """Designed samples scaled so the largest magnitude is 2047 (rounded to integers)."""
    u = np.asarray(u, dtype=float)
    peak = float(np.max(np.abs(u))) if u.size else 0.0
    if not np.isfinite(peak) or peak == 0.0:
        raise ValueError("excitation is all zero or not finite")
    return np.round(u / peak * POINT_LIMIT).astype(np.int16)


class DS340(Ieee4882Instrument):
    """Driver; use as a context manager or call :meth:`open` / :meth:`close`.

    ``serial_factory`` builds the port (default :func:`serial.serial_for_url`, which takes
    device names and URLs such as ``socket://host:port``).
    """

    name = "DS340"

    def __init__(self, options: DS340Options, serial_factory: Callable[..., Any] = serial.serial_for_url):
        super().__init__(options)
        self._factory = serial_factory
        self._ser = None

    # -- plumbing -------------------------------------------------------------------------
    def _transport_error(self, exc: BaseException, step: str) -> InstrumentError | None:
        o = self.options
        if isinstance(exc, serial.SerialTimeoutException):
            return InstrumentError(
                f"{self.name}: {step}: write to {o.port} timed out (handshake lines? rtscts={o.rtscts})")
        if isinstance(exc, PORT_ERRORS):
            what = (f"cannot open serial port {o.port}" if step == "connect"
                    else f"serial port {o.port} failed (disconnected?)")
            return InstrumentError(f"{self.name}: {step}: {what}: {one_line(exc)}")
        return None

    def open(self) -> "DS340":
        o = self.options
        with self.step("connect"):
            self._ser = self._factory(
                o.port, baudrate=o.baudrate, bytesize=o.bytesize, parity=o.parity, stopbits=o.stopbits,
                rtscts=o.rtscts, xonxoff=o.xonxoff, timeout=o.timeout, write_timeout=o.timeout)
            self._ser.reset_input_buffer()
        return self

    def _close_transport(self) -> None:
        if self._ser is not None:
            ser, self._ser = self._ser, None
            ser.close()

    def write(self, command: str) -> None:
        """Send one command line."""
        self._ser.write((command + self.options.write_termination).encode("ascii"))
        self._ser.flush()

    def query(self, command: str, timeout: float | None = None) -> str:
        """Send a query and return its reply without the terminator."""
        self._ser.reset_input_buffer()
        self.write(command)
        return self.read_reply(command, timeout)

    def read_reply(self, what: str, timeout: float | None = None) -> str:
        o = self.options
        limit = o.timeout if timeout is None else timeout
        term = o.read_termination.encode()
        if self._ser.timeout != limit:
            self._ser.timeout = limit
        data = self._ser.read_until(term)
        if not data.endswith(term):
            term_name = _TERMINATORS[o.read_termination]
            if data:
                self.fail(f"incomplete reply {show(data)} to '{what}' (no {term_name} within {limit:g} s)")
            self.fail(f"no reply to '{what}' within {limit:g} s on {o.port} "
                      f"(cable, power, baud rate {o.baudrate}, framing {o.bytesize}{o.parity}{o.stopbits}?)")
        return self.ascii_reply(data, what, " (baud rate or framing mismatch?)")

    # -- instrument operations ------------------------------------------------------------
    def identify(self) -> str:
        """``*IDN?`` and check the model; clears the status registers."""
        o = self.options
        with self.step("identify"):
            reply = self.check_identity(
                self.query("*IDN?"), o.expect_model, f"StanfordResearchSystems,{o.expect_model or '<model>'},..."
            )
            if o.reset:
                self.write("*RST")
            self.write("*CLS")
            self.esr()
        return reply

    def upload(self, points: np.ndarray) -> None:
        """Download an arbitrary waveform (point format) with the LDWF? handshake."""
        o = self.options
        with self.step("upload"):
            pts = np.asarray(points)
            if pts.ndim != 1 or not np.issubdtype(pts.dtype, np.integer):
                self.fail("points must be a 1-D integer array")
            n = int(pts.size)
            if not o.min_points <= n <= o.max_points:
                self.fail(f"{n} points outside {o.min_points}..{o.max_points} (min_points/max_points)")
            worst = int(np.max(np.abs(pts.astype(np.int64))))
            if worst > POINT_LIMIT:
                self.fail(f"point magnitude {worst} exceeds {POINT_LIMIT}")
            self.esr()  # clear stale bits so the check below is about this download
            reply = self.query(f"LDWF? 0,{n}", timeout=o.ready_timeout)
            if reply != "1":
                self.fail(f"instrument not ready for the waveform: reply {reply!r} to 'LDWF? 0,{n}' (expected '1')")
            payload = encode_points(pts) + checksum_bytes(pts, o.checksum_bytes)
            bits = 1 + o.bytesize + (o.parity != "N") + o.stopbits
            seconds = len(payload) * bits / o.baudrate
            self._ser.write_timeout = 1.5 * seconds + o.timeout
            try:
                started = time.monotonic()
                self._ser.write(payload)
                self._ser.flush()
                self.settings["upload_seconds"] = time.monotonic() - started
            finally:
                self._ser.write_timeout = o.timeout
            value = self.esr()
            if value & ESR_ERROR_MASK:
                other = 4 if o.checksum_bytes == 2 else 2
                self.fail(f"waveform of {n} points rejected: *ESR? = {value} ({describe_esr(value)}); "
                          f"if the checksum width is wrong try checksum_bytes: {other}")
            self.settings.update(points=n, checksum_bytes=o.checksum_bytes)

    def configure(self, sample_rate: float) -> dict[str, Any]:
        """Arbitrary function, FSMP, amplitude (Vpp), offset, single-shot burst; returns settings read back."""
        o = self.options
        with self.step("configure"):
            for cmd in ("FUNC 5", f"FSMP {sample_rate:.10g}", f"AMPL {o.amplitude_vpp:.6g}VP",
                        f"OFFS {o.offset:.6g}", "MTYP 5", f"BCNT {o.burst_count}", "TSRC 0", "MENA 1"):
                self.command(cmd)
            actual = self.float_query("FSMP?")
            ampl = self.query("AMPL?")
            if not ampl.upper().endswith("VP"):
                self.fail(f"AMPL? reply {ampl!r} is not in VP (arbitrary waveforms need Vpp)")
            self.settings.update(
                sample_rate_requested_hz=float(sample_rate), sample_rate_hz=actual,
                amplitude=ampl, amplitude_vpp=o.amplitude_vpp, offset_v=o.offset, burst_count=o.burst_count,
                trigger_source="single (TSRC 0)", port=o.port, baudrate=o.baudrate,
                framing=f"{o.bytesize}{o.parity}{o.stopbits}", rtscts=o.rtscts)
        return dict(self.settings)

    def trigger(self) -> None:
        """Fire one burst (``*TRG``, needs TSRC 0)."""
        with self.step("trigger"):
            self.command("*TRG")
