"""Fake SRS DS340 on a pty: the command subset the driver uses, byte for byte.

Behaviour modelled (DS345 manual semantics): commands end with CR or LF, several may share a
line separated by ';'; replies end with CR; ``*ESR?`` returns and clears the status bits
(4 execution error, 5 command error); ``LDWF? 0,n`` answers ``1`` and then takes 2n bytes of
little-endian int16 points plus a checksum of ``checksum_bytes`` bytes (sum ignoring carries);
a wrong checksum or a point beyond +-2047 sets the execution-error bit. ``FSMP`` is rounded to
40 MHz / N. ``*TRG`` (only with TSRC 0) calls ``on_trigger(self)``.
"""
from __future__ import annotations

import re
from typing import Callable

import numpy as np

from .pty_device import PtyDevice

EXE, CMD = 16, 32


class FakeDS340(PtyDevice):
    def __init__(self, idn: str = "StanfordResearchSystems,DS340,33123,1.03", checksum_bytes: int = 2,
                 reply_terminator: bytes = b"\r", clock: float = 40e6):
        super().__init__()
        self.idn = idn
        self.checksum_bytes = checksum_bytes
        self.term = reply_terminator
        self.clock = clock
        self.state: dict[str, float] = {}
        self.reset()
        self.esr = 0
        self.points: np.ndarray | None = None
        self.uploads: list[bytes] = []      # raw binary payloads (points + checksum) as received
        self.lines: list[str] = []          # text lines as received
        self.triggers = 0
        self.on_trigger: Callable[["FakeDS340"], None] | None = None
        # fault switches
        self.ldwf_reply = "1"               # reply to LDWF? (anything but '1' refuses the download)
        self.reject: dict[str, int] = {}    # mnemonic -> ESR bits set instead of executing it
        self.silent = False                 # never reply
        self.replies: dict[str, bytes] = {} # query -> raw reply bytes (garbage injection)
        self.corrupt_checksum = False       # compare against a wrong checksum
        self.disconnect_after_payload_bytes: int | None = None
        self.disconnect_on_trigger: int | None = None
        self._pending = b""
        self._need = 0
        self._binary = bytearray()
        self._ldwf_n = 0
        self._skip_lf = False

    def reset(self) -> None:
        self.state = {"FUNC": 0, "FSMP": self.clock, "AMPL": 1.0, "OFFS": 0.0, "MTYP": 0, "BCNT": 1,
                      "TSRC": 0, "MENA": 0}

    # -- byte stream ----------------------------------------------------------------------
    def feed(self, data: bytes) -> None:
        buf = self._pending + data
        self._pending = b""
        while buf:
            if self._need:
                if self._skip_lf and buf[:1] == b"\n" and not self._binary:
                    buf = buf[1:]
                    self._skip_lf = False
                    continue
                self._skip_lf = False
                take = buf[: self._need - len(self._binary)]
                self._binary += take
                buf = buf[len(take):]
                limit = self.disconnect_after_payload_bytes
                if limit is not None and len(self._binary) >= limit:
                    self.disconnect()
                    return
                if len(self._binary) == self._need:
                    self._finish_upload()
                continue
            match = re.search(rb"[\r\n]", buf)
            if not match:
                self._pending = buf
                return
            line, ender, buf = buf[: match.start()], buf[match.start():match.end()], buf[match.end():]
            self._line(line, ender)

    def reply(self, query: str, text: str) -> None:
        if self.silent:
            return
        self.send(self.replies.get(query, text.encode("ascii") + self.term))

    def _line(self, line: bytes, ender: bytes) -> None:
        text = line.decode("ascii", errors="replace").strip()
        if not text:
            return
        self.lines.append(text)
        for part in text.split(";"):
            self._command(part.strip(), ender)

    # -- commands -------------------------------------------------------------------------
    def _command(self, part: str, ender: bytes) -> None:
        upper = part.upper()
        mnemonic = re.split(r"[\s?]", upper, maxsplit=1)[0]
        if mnemonic in self.reject:
            self.esr |= self.reject[mnemonic]
            return
        if upper == "*IDN?":
            self.reply(upper, self.idn)
        elif upper == "*ESR?":
            value, self.esr = self.esr, 0
            self.reply(upper, str(value))
        elif upper == "*CLS":
            self.esr = 0
        elif upper == "*RST":
            self.reset()
        elif upper == "*TRG":
            self._trigger()
        elif mnemonic == "LDWF":
            self._ldwf(upper, ender)
        elif upper.endswith("?") and upper[:-1] in self.state:
            key = upper[:-1]
            value = self.state[key]
            text = {"AMPL": f"{value:.2f}VP", "FSMP": f"{value:.10g}", "OFFS": f"{value:.3f}"}.get(key, f"{int(value)}")
            self.reply(upper, text)
        else:
            self._setting(upper)

    def _setting(self, upper: str) -> None:
        m = re.fullmatch(r"(FUNC|MTYP|TSRC|MENA|BCNT)\s+(-?\d+)", upper)
        if m:
            key, value = m.group(1), int(m.group(2))
            limits = {"FUNC": (0, 5), "MTYP": (0, 6), "TSRC": (0, 4), "MENA": (0, 1), "BCNT": (1, 30000)}[key]
            if limits[0] <= value <= limits[1]:
                self.state[key] = value
            else:
                self.esr |= EXE
            return
        m = re.fullmatch(r"(FSMP|OFFS)\s+([-+]?[0-9.]+(?:E[-+]?\d+)?)", upper)
        if m:
            key, value = m.group(1), float(m.group(2))
            if key == "FSMP":
                if not 0 < value <= self.clock:
                    self.esr |= EXE
                    return
                value = self.clock / max(1, round(self.clock / value))
            elif abs(value) > 5:
                self.esr |= EXE
                return
            self.state[key] = value
            return
        m = re.fullmatch(r"AMPL\s+([-+]?[0-9.]+(?:E[-+]?\d+)?)\s*(VP|VR|DB)?", upper)
        if m:
            value, unit = float(m.group(1)), m.group(2) or "VP"
            if unit != "VP" and self.state["FUNC"] == 5 or not 0 < value <= 10:
                self.esr |= EXE
                return
            self.state["AMPL"] = value
            return
        self.esr |= CMD

    def _ldwf(self, upper: str, ender: bytes) -> None:
        m = re.fullmatch(r"LDWF\?\s*([01])\s*,\s*(\d+)", upper)
        if not m:
            self.esr |= CMD
            return
        fmt, n = int(m.group(1)), int(m.group(2))
        if fmt != 0 or not 8 <= n <= 16300:
            self.esr |= EXE
            self.reply("LDWF?", "0")
            return
        self.reply("LDWF?", self.ldwf_reply)
        if self.ldwf_reply == "1":
            self._ldwf_n = n
            self._need = 2 * n + self.checksum_bytes
            self._binary = bytearray()
            self._skip_lf = ender == b"\r"

    def _finish_upload(self) -> None:
        n = self._ldwf_n
        payload = bytes(self._binary)
        self._need, self._binary = 0, bytearray()
        self.uploads.append(payload)
        points = np.frombuffer(payload[: 2 * n], dtype="<i2").copy()
        got = int.from_bytes(payload[2 * n:], "little")
        want = int(points.astype(np.int64).sum()) & ((1 << (8 * self.checksum_bytes)) - 1)
        if self.corrupt_checksum:
            want ^= 1
        if got != want or np.abs(points.astype(np.int64)).max() > 2047:
            self.esr |= EXE
            return
        self.points = points

    def _trigger(self) -> None:
        if self.state["TSRC"] != 0:
            self.esr |= EXE
            return
        self.triggers += 1
        if self.disconnect_on_trigger is not None and self.triggers >= self.disconnect_on_trigger:
            self.disconnect()
            return
        if self.on_trigger is not None:
            self.on_trigger(self)

    # -- what the output connector carries -------------------------------------------------
    def output(self) -> tuple[np.ndarray, float, float]:
        """One burst in volts (points scaled to +-AMPL/2, plus offset), its sample rate [Hz], the idle level [V]."""
        if self.points is None:
            return np.zeros(0), self.state["FSMP"], self.state["OFFS"]
        volts = self.points / 2047.0 * self.state["AMPL"] / 2.0 + self.state["OFFS"]
        return np.tile(volts, int(self.state["BCNT"])), self.state["FSMP"], self.state["OFFS"]
