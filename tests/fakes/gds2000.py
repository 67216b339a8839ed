"""Fake GW Instek GDS-2000 on a pty: text commands and ``:ACQ<n>:MEM?`` binary blocks.

Commands end with LF, replies end with LF. Settings are integer codes as on the GDS-2000;
V/div snaps to 1-2-5 steps (2 mV..5 V), s/div to 1-2.5-5 steps (1 ns..10 s). The record has
``record_points`` samples at dt = 10 * (s/div) / record_points. ``capture`` (called by the bench
when the generator fires) stores codes round(volts / (V/div) * 25) clipped to +-125 if the scope
is armed. Blocks: ``#<d><L>`` + float32 dt (``dt_order`` byte order) + channel + 3 reserved bytes +
big-endian int16 codes, then LF if ``trailing_lf``. Fault switches act from the
``fault_from_read``-th ``:ACQ<n>:MEM?`` on.
"""
from __future__ import annotations

import re

import numpy as np

from mbus_plugins.instruments.gds2000 import block_bytes

from .pty_device import PtyDevice

EXE, CMD = 16, 32


def snap(value: float, mantissas: tuple[float, ...], lo: float, hi: float) -> float | None:
    if not lo * 0.999 <= value <= hi * 1.001:
        return None
    steps = sorted(m * 10.0**e for e in range(-10, 3) for m in mantissas)
    steps = [s for s in steps if lo * 0.999 <= s <= hi * 1.001]
    return min(steps, key=lambda s: abs(np.log(s / value)))


INT_LIMITS = {":CHAN1:COUP": 2, ":CHAN2:COUP": 2, ":CHAN1:DISP": 1, ":CHAN2:DISP": 1, ":TRIG:TYP": 3,
              ":TRIG:SOUR": 5, ":TRIG:COUP": 1, ":TRIG:SLOP": 1, ":TRIG:MOD": 3, ":ACQ:MOD": 2, ":ACQ:LENG": 1}


class FakeGDS2000(PtyDevice):
    def __init__(self, idn: str = "GW,GDS-2062,EF910123,V1.12", record_points: int = 3125,
                 dt_order: str = "big", trailing_lf: bool = True):
        super().__init__()
        self.idn = idn
        self.record_points = record_points
        self.dt_order = dt_order
        self.trailing_lf = trailing_lf
        self.values: dict[str, float] = {":CHAN1:SCAL": 1.0, ":CHAN2:SCAL": 1.0, ":CHAN1:OFFS": 0.0,
                                         ":CHAN2:OFFS": 0.0, ":TIM:SCAL": 50e-6, ":TIM:DEL": 0.0,
                                         ":TRIG:LEV": 0.0}
        self.values.update({k: 1 for k in INT_LIMITS})
        self.esr = 0
        self.armed = False
        self.triggered = False
        self.records: dict[int, np.ndarray] = {}
        self.captures = 0
        self.lines: list[str] = []
        self.reads = 0
        # fault switches (from the fault_from_read-th block query on)
        self.fault_from_read = 1
        self.block_override: bytes | None = None      # send these bytes instead of the block
        self.truncate_block: int | None = None        # send only the first k bytes of the block
        self.disconnect_in_block: int | None = None   # send k bytes of the block, then unplug
        self.silent = False
        self.reject: dict[str, int] = {}
        self._pending = b""

    @property
    def dt(self) -> float:
        return 10.0 * self.values[":TIM:SCAL"] / self.record_points

    # -- byte stream ----------------------------------------------------------------------
    def feed(self, data: bytes) -> None:
        buf = self._pending + data
        *lines, self._pending = buf.split(b"\n")
        for line in lines:
            text = line.decode("ascii", errors="replace").strip()
            if text:
                self.lines.append(text)
                for part in text.split(";"):
                    self._command(part.strip())

    def reply(self, text: str) -> None:
        if not self.silent:
            self.send(text.encode("ascii") + b"\n")

    def _command(self, part: str) -> None:
        head, _, arg = part.partition(" ")
        head = head.upper()
        if head.rstrip("?") in self.reject:
            self.esr |= self.reject[head.rstrip("?")]
            return
        if head == "*IDN?":
            self.reply(self.idn)
        elif head == "*ESR?":
            value, self.esr = self.esr, 0
            self.reply(str(value))
        elif head == "*CLS":
            self.esr = 0
        elif head in (":SING", ":SINGLE", ":RUN"):
            self.armed, self.triggered = True, False
        elif head == ":STOP":
            self.armed = False
        elif head in (":TRIG:STAT?", ":TRIGGER:STATE?"):
            self.reply("1" if self.triggered else "0")
        elif re.fullmatch(r":ACQ[1-4]:MEM\?", head):
            self._block(int(head[4]))
        elif head.endswith("?") and head[:-1] in self.values:
            value = self.values[head[:-1]]
            self.reply(str(int(value)) if head[:-1] in INT_LIMITS else f"{value:.3E}")
        elif head in self.values:
            self._set(head, arg.strip())
        else:
            self.esr |= CMD

    def _set(self, head: str, arg: str) -> None:
        try:
            value = float(arg)
        except ValueError:
            self.esr |= CMD
            return
        if head in INT_LIMITS:
            if value != int(value) or not 0 <= value <= INT_LIMITS[head]:
                self.esr |= EXE
                return
        elif head.endswith(":SCAL"):
            value = (snap(value, (1, 2, 5), 2e-3, 5.0) if head.startswith(":CHAN")
                     else snap(value, (1, 2.5, 5), 1e-9, 10.0))
            if value is None:
                self.esr |= EXE
                return
        self.values[head] = value

    # -- acquisition ----------------------------------------------------------------------
    def capture(self, volts: dict[int, np.ndarray], dt: float) -> bool:
        """Store one acquisition if armed (codes = volts / (V/div) * 25, 8-bit-like range)."""
        if not self.armed:
            return False
        assert abs(dt - self.dt) < 1e-15, "bench and scope disagree on dt"
        for ch, v in volts.items():
            codes = np.round(np.asarray(v) / self.values[f":CHAN{ch}:SCAL"] * 25.0)
            self.records[ch] = np.clip(codes, -125, 125).astype(np.int16)
        self.armed, self.triggered = False, True
        self.captures += 1
        return True

    def block_for(self, channel: int) -> bytes:
        raw = self.records.get(channel, np.zeros(self.record_points, np.int16))
        return block_bytes(self.dt, channel, raw, self.dt_order) + (b"\n" if self.trailing_lf else b"")

    def _block(self, channel: int) -> None:
        self.reads += 1
        data = self.block_for(channel)
        if self.silent:
            return
        if self.reads >= self.fault_from_read:
            if self.block_override is not None:
                self.send(self.block_override)
                return
            if self.truncate_block is not None:
                self.send(data[: self.truncate_block])
                return
            if self.disconnect_in_block is not None:
                self.send(data[: self.disconnect_in_block])
                self.disconnect()
                return
        self.send(data)
