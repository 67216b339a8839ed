"""GW Instek GDS-2000 oscilloscope (GDS-2062) on pyvisa, ASRL resource.

The original GDS-2000's USB device port is a CDC-ACM virtual serial port (not USBTMC), so the
resource is ``ASRL/dev/ttyACM0::INSTR`` (Linux, pyvisa-py) or ``ASRL3::INSTR`` for COM3
(Windows); the RS-232 port works the same way (set ``baud_rate`` to the scope's setting).
Commands and replies end with LF. Settings use integer codes (coupling 0 AC / 1 DC / 2 GND;
trigger source 0 CH1 / 1 CH2 / 4 EXT; slope 0 rising / 1 falling; trigger mode 2 normal /
3 single; record length 0 short / 1 long).

``:ACQ<n>:MEM?`` returns an IEEE-488.2 definite-length block ``#<d><L>`` followed by L bytes:

    4 bytes   sample interval, IEEE-754 float32 [s] (big-endian in every public decoder, the
              manual says little-endian: parsed big-endian, accepted if 1e-10 <= dt <= 100 s,
              else little-endian; taken as the shortest decimal that is that float32)
    1 byte    channel number
    3 bytes   reserved
    L - 8     samples, signed 16-bit, most-significant byte first

The announced L bytes are read exactly (LF bytes inside the block are data); an optional LF
after the block is drained. Volts = raw * (V/div) / 25 (one vertical division is 25 codes, zero
at the screen centre; ``counts_per_division``); the V/div used is the value read back from the
scope, which snaps requests to its 1-2-5 steps. t_i = i * dt from the first sample.

Every failure raises :class:`~mbus_framework.errors.InstrumentError` with the message
``"GDS-2062: <step>: <what happened>"``.
"""
from __future__ import annotations

import math
import struct
import time
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from mbus_framework.errors import InstrumentError

from .common import Ieee4882Instrument, one_line

DT_MIN, DT_MAX = 1e-10, 1e2
"""Plausible sample interval [s] when decoding the block's float."""
MAX_BLOCK_BYTES = 8 + 2 * 25_000
"""Largest block of the original GDS-2000 (25 000 points)."""

COUPLING = {"ac": 0, "dc": 1, "gnd": 2}
TRIGGER_SOURCE = {"ch1": 0, "ch2": 1, "ext": 4}
SLOPE = {"rising": 0, "falling": 1}
TRIGGER_MODE = {"normal": 2, "single": 3}
RECORD_LENGTH = {"short": 0, "long": 1}


class ChannelOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    scale: float = Field(gt=0, description="vertical scale [V/div]")
    offset: float = Field(0.0, description="vertical position [V] (keep 0: its effect on raw data is unconfirmed)")
    coupling: Literal["ac", "dc", "gnd"] = Field("dc", description="input coupling")


class TriggerOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    source: Literal["ch1", "ch2", "ext"] = Field("ch1", description="trigger source")
    level: float = Field(0.1, description="trigger level [V]")
    slope: Literal["rising", "falling"] = Field("rising", description="trigger edge")
    coupling: Literal["ac", "dc"] = Field("dc", description="trigger coupling")
    mode: Literal["single", "normal"] = Field("single", description="trigger mode (:TRIG:MOD 3 / 2)")


class GDS2000Options(BaseModel):
    """Connection, channel, timebase and trigger settings (``backend.options.scope``)."""

    model_config = ConfigDict(extra="forbid")
    resource: str = Field("ASRL/dev/ttyACM0::INSTR", description="VISA resource (ASRL...; COMn is ASRLn::INSTR)")
    visa_library: str = Field("@py", description="pyvisa backend: '@py' pyvisa-py, '' the default VISA")
    baud_rate: int = Field(19200, gt=0, description="RS-232 baud rate (ignored by the USB serial port) [bit/s]")
    timeout: float = Field(5.0, gt=0, description="time allowed for each reply [s]")
    expect_model: str = Field("GDS-2", description="text expected in *IDN? field 2 ('' skips the check)")
    name: str = Field("GDS-2062", description="instrument name used in messages")
    excitation_channel: Literal[1, 2] = Field(1, description="channel that records the generator output")
    response_channel: Literal[1, 2] = Field(2, description="channel that records the receiving transducer")
    ch1: ChannelOptions = Field(default_factory=lambda: ChannelOptions(scale=0.5))
    ch2: ChannelOptions = Field(default_factory=lambda: ChannelOptions(scale=0.05))
    timebase: float = Field(50e-6, gt=0, description="horizontal scale [s/div]")
    delay: float = Field(0.0, description="horizontal position (:TIM:DEL) [s]")
    record_length: Literal["short", "long"] = Field("long", description="record length (:ACQ:LENG 0/1)")
    trigger: TriggerOptions = Field(default_factory=TriggerOptions)
    arm_command: str = Field(":SING", description="command that arms one acquisition")
    arm_delay: float = Field(0.05, ge=0, description="wait after arming, before the generator fires [s]")
    wait: Literal["delay", "trigger_state"] = Field(
        "delay", description="after firing: wait 'settle' seconds, or poll :TRIG:STAT? (reply codes unconfirmed)")
    settle: float = Field(0.3, ge=0, description="wait after the generator fires, before reading [s]")
    trigger_timeout: float = Field(5.0, gt=0, description="limit for polling :TRIG:STAT? [s]")
    triggered_replies: list[str] = Field(["1"], description=":TRIG:STAT? replies meaning 'acquired'")
    counts_per_division: float = Field(25.0, gt=0, description="raw codes per vertical division")
    screen_counts: int = Field(100, gt=0, description="|raw| at the screen edge (4 div); reaching it warns")


@dataclass
class Trace:
    """One channel's record: raw codes, volts and the sample interval dt [s]."""

    channel: int
    dt: float
    raw: np.ndarray
    volts: np.ndarray
    volts_per_div: float
    info: dict[str, Any] = field(default_factory=dict)


def plausible_dt(value: float) -> bool:
    return math.isfinite(value) and DT_MIN <= value <= DT_MAX


def parse_block_body(body: bytes) -> tuple[float, int, np.ndarray, str]:
    """Decode the L bytes of a ``:ACQ<n>:MEM?`` block: (dt [s], channel, raw int16, float byte order).

    Raises ValueError with a one-line reason for malformed bodies.
    """
    if len(body) < 10 or len(body) % 2:
        raise ValueError(f"block of {len(body)} bytes (need an even length of at least 10)")
    (big,) = struct.unpack(">f", body[:4])
    (little,) = struct.unpack("<f", body[:4])
    if plausible_dt(big):
        dt, order = big, "big"
    elif plausible_dt(little):
        dt, order = little, "little"
    else:
        raise ValueError(f"implausible sample interval (big-endian {big:.3g} s, little-endian {little:.3g} s)")
    dt = float(str(np.float32(dt)))  # shortest decimal of the float32: 2e-07, not 2.0000000233721948e-07
    channel = body[4]
    raw = np.frombuffer(body[8:], dtype=">i2").astype(np.int16)
    return float(dt), int(channel), raw, order


def block_bytes(dt: float, channel: int, raw: np.ndarray, order: str = "big") -> bytes:
    """Encode a block the way the scope sends it (for tests and tools)."""
    body = struct.pack(">f" if order == "big" else "<f", dt) + bytes([channel, 0, 0, 0])
    body += np.asarray(raw).astype(">i2").tobytes()
    length = str(len(body))
    return b"#" + str(len(length)).encode() + length.encode() + body


class GDS2000(Ieee4882Instrument):
    """Driver; use as a context manager or call :meth:`open` / :meth:`close`.

    ``resource_manager`` may be given (tests pass a pyvisa-sim manager).
    """

    def __init__(self, options: GDS2000Options, resource_manager=None):
        super().__init__(options)
        self.name = options.name
        self._rm = resource_manager
        self._res = None

    # -- plumbing -------------------------------------------------------------------------
    def _transport_error(self, exc: BaseException, step: str) -> InstrumentError | None:
        import pyvisa

        from .ds340 import PORT_ERRORS

        o = self.options
        if isinstance(exc, pyvisa.errors.VisaIOError):
            if exc.error_code == pyvisa.constants.StatusCode.error_timeout:
                return InstrumentError(f"{self.name}: {step}: no reply within {o.timeout:g} s on {o.resource}")
            return InstrumentError(f"{self.name}: {step}: VISA error {exc.abbreviation} on {o.resource}")
        if isinstance(exc, (pyvisa.errors.Error, *PORT_ERRORS)):
            what = (f"cannot open {o.resource}" if step == "connect"
                    else f"connection to {o.resource} failed (disconnected?)")
            return InstrumentError(f"{self.name}: {step}: {what}: {one_line(exc)}")
        return None

    def open(self) -> "GDS2000":
        import pyvisa

        o = self.options
        with self.step("connect"):
            try:
                if self._rm is None:
                    self._rm = pyvisa.ResourceManager(o.visa_library)
                self._res = self._rm.open_resource(
                    o.resource, read_termination="\n", write_termination="\n", timeout=int(o.timeout * 1000))
            except (ValueError, LookupError) as exc:
                hint = " (install pyvisa-py or set visa_library)" if "VISA" in str(exc) else ""
                self.fail(f"cannot open {o.resource}: {one_line(exc)}{hint}")
            if o.resource.upper().startswith("ASRL") and hasattr(self._res, "baud_rate"):
                self._res.baud_rate = o.baud_rate
        return self

    def _close_transport(self) -> None:
        if self._res is not None:
            res, self._res = self._res, None
            res.close()

    def write(self, command: str) -> None:
        self._res.write(command)

    def query(self, command: str) -> str:
        self._res.write(command)
        return self.ascii_reply(self._res.read_raw(), command)

    # -- instrument operations ------------------------------------------------------------
    def identify(self) -> str:
        o = self.options
        with self.step("identify"):
            reply = self.check_identity(self.query("*IDN?"), o.expect_model, f"GW,{o.expect_model or '<model>'},...")
            self.write("*CLS")
            self.esr()
        return reply

    def configure(self) -> dict[str, Any]:
        """Acquisition, channels, timebase and trigger; returns the settings read back."""
        o = self.options
        t = o.trigger
        with self.step("configure"):
            commands = [":ACQ:MOD 0", f":ACQ:LENG {RECORD_LENGTH[o.record_length]}"]
            for n, ch in ((1, o.ch1), (2, o.ch2)):
                commands += [f":CHAN{n}:DISP 1", f":CHAN{n}:COUP {COUPLING[ch.coupling]}",
                             f":CHAN{n}:SCAL {ch.scale:.4E}", f":CHAN{n}:OFFS {ch.offset:.4E}"]
            commands += [f":TIM:SCAL {o.timebase:.4E}", f":TIM:DEL {o.delay:.4E}", ":TRIG:TYP 0",
                         f":TRIG:SOUR {TRIGGER_SOURCE[t.source]}", f":TRIG:COUP {1 if t.coupling == 'dc' else 0}",
                         f":TRIG:SLOP {SLOPE[t.slope]}", f":TRIG:LEV {t.level:.4E}",
                         f":TRIG:MOD {TRIGGER_MODE[t.mode]}"]
            for cmd in commands:
                self.command(cmd)
            scales = {n: self.float_query(f":CHAN{n}:SCAL?") for n in (1, 2)}
            for n, s in scales.items():
                if s <= 0:
                    self.fail(f"':CHAN{n}:SCAL?' returned {s:g} V/div")
            self.settings = {
                "resource": o.resource, "volts_per_div": scales,
                "volts_per_div_requested": {1: o.ch1.scale, 2: o.ch2.scale},
                "offset_v": {1: self.float_query(":CHAN1:OFFS?"), 2: self.float_query(":CHAN2:OFFS?")},
                "coupling": {1: o.ch1.coupling, 2: o.ch2.coupling},
                "timebase_s_per_div": self.float_query(":TIM:SCAL?"), "delay_s": o.delay,
                "record_length": o.record_length, "trigger": t.model_dump(),
                "counts_per_division": o.counts_per_division,
                "excitation_channel": o.excitation_channel, "response_channel": o.response_channel,
            }
        return dict(self.settings)

    def arm(self) -> None:
        """Arm one acquisition; ``*ESR?`` confirms the scope has taken the command."""
        with self.step("arm"):
            self.command(self.options.arm_command)
            time.sleep(self.options.arm_delay)

    def run(self) -> None:
        with self.step("run"):
            self.write(":RUN")

    def stop(self) -> None:
        with self.step("stop"):
            self.write(":STOP")

    def wait_acquired(self) -> None:
        """Wait for the acquisition after the generator fired (``wait`` option)."""
        o = self.options
        with self.step("wait for trigger"):
            if o.wait == "delay":
                time.sleep(o.settle)
                return
            deadline = time.monotonic() + o.trigger_timeout
            reply = ""
            while time.monotonic() < deadline:
                reply = self.query(":TRIG:STAT?")
                if reply in o.triggered_replies:
                    return
                time.sleep(0.02)
            self.fail(f"not triggered within {o.trigger_timeout:g} s (last :TRIG:STAT? reply {reply!r}); "
                      f"check the trigger source, level and the generator output")

    def read_trace(self, channel: int) -> Trace:
        """``:ACQ<channel>:MEM?``: read the block exactly and convert to volts."""
        o = self.options
        with self.step(f"read CH{channel}"):
            vdiv = self.settings.get("volts_per_div", {}).get(channel)
            vdiv = float(vdiv if vdiv is not None else self.float_query(f":CHAN{channel}:SCAL?"))
            command = f":ACQ{channel}:MEM?"
            self.write(command)
            head = self._read_exact(2, "block header")
            if head[:1] != b"#" or not head[1:2].isdigit() or head[1:2] == b"0":
                self.fail(f"garbage reply {head!r} to '{command}' (expected a '#<digits><length>' block)")
            digits = self._read_exact(int(head[1:2]), "block length")
            if not digits.isdigit():
                self.fail(f"garbage block length {digits!r} in the reply to '{command}'")
            length = int(digits)
            if length > MAX_BLOCK_BYTES or length < 10 or length % 2:
                self.fail(f"impossible block length {length} bytes (even, 10..{MAX_BLOCK_BYTES})")
            body = self._read_exact(length, f"the {length}-byte block")
            trailing = self._drain_terminator()
            try:
                dt, ch, raw, order = parse_block_body(body)
            except ValueError as exc:
                self.fail(str(exc))
            if ch != channel:
                self.fail(f"block is for channel {ch}, asked for {channel}")
            if not raw.any():
                self.fail("all samples are zero (no acquisition? check that the scope triggered)")
            volts = raw.astype(float) * vdiv / o.counts_per_division
            peak = int(np.max(np.abs(raw.astype(np.int32))))
            info = {"float_byte_order": order, "points": int(raw.size), "trailing_lf": trailing,
                    "peak_counts": peak, "clipped": peak >= o.screen_counts,
                    "low_bytes_all_zero": bool(not (raw.astype(np.int32) & 0xFF).any())}
            return Trace(channel, dt, raw, volts, vdiv, info)

    def _read_exact(self, count: int, what: str) -> bytes:
        """Exactly ``count`` bytes (termination characters are data here)."""
        import pyvisa

        out = bytearray()
        while len(out) < count:
            try:
                out += self._res.read_bytes(min(512, count - len(out)), break_on_termchar=False)
            except pyvisa.errors.VisaIOError as exc:
                if exc.error_code == pyvisa.constants.StatusCode.error_timeout:
                    self.fail(f"short read: {what} incomplete after the {self.options.timeout:g} s timeout "
                              f"(received {len(out)}+ of {count} bytes)")
                raise
        return bytes(out)

    def _drain_terminator(self) -> bool:
        """Consume an optional LF after the block (its presence is unconfirmed)."""
        import pyvisa

        res = self._res
        saved = res.timeout
        res.timeout = 100
        try:
            byte = res.read_bytes(1, break_on_termchar=False)
        except pyvisa.errors.VisaIOError:
            return False
        finally:
            res.timeout = saved
        if byte != b"\n":
            self.fail(f"unexpected byte {byte!r} after the block (expected LF or nothing)")
        return True
