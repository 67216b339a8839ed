"""GDS-2000 driver: text commands against pyvisa-sim, binary blocks against a pty fake (pyvisa-py)."""
from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np
import pytest

from mbus_framework.errors import InstrumentError
from mbus_plugins.instruments.gds2000 import (
    ChannelOptions,
    GDS2000,
    GDS2000Options,
    block_bytes,
    parse_block_body,
)

SIM_YAML = Path(__file__).parent / "fakes" / "gds2062.yaml"


# -- block decoding --------------------------------------------------------------------------
def test_parse_block_body_big_endian_interval_and_signed_samples():
    codes = np.array([0, -1, 10, 2570, -32768, 32767, -246], np.int16)
    body = block_bytes(4e-9, 2, codes)[2 + len(str(8 + 2 * codes.size)):]
    assert body[:4] == struct.pack(">f", 4e-9)
    dt, ch, raw, order = parse_block_body(body)
    assert (dt, ch, order) == (4e-9, 2, "big")
    assert raw.tolist() == codes.tolist()


def test_parse_block_body_little_endian_fallback_and_implausible_interval():
    body = struct.pack("<f", 4e-9) + bytes([1, 0, 0, 0]) + np.array([5, -5], ">i2").tobytes()
    dt, ch, raw, order = parse_block_body(body)
    assert order == "little" and dt == 4e-9 and raw.tolist() == [5, -5]
    bad = struct.pack(">f", -1.0) + bytes(4) + bytes(4)
    with pytest.raises(ValueError, match="implausible sample interval"):
        parse_block_body(bad)
    with pytest.raises(ValueError, match="even length"):
        parse_block_body(bytes(11))


# -- text commands: pyvisa-sim ---------------------------------------------------------------
@pytest.fixture
def sim_scope():
    pyvisa = pytest.importorskip("pyvisa")
    rm = pyvisa.ResourceManager(f"{SIM_YAML}@sim")
    options = GDS2000Options(resource="ASRL1::INSTR", timeout=0.3, ch1=ChannelOptions(scale=0.5),
                             ch2=ChannelOptions(scale=0.02, coupling="ac"), timebase=2.5e-5, delay=1e-5,
                             settle=0.0, arm_delay=0.0)
    scope = GDS2000(options, resource_manager=rm).open()
    yield scope
    scope.close()


def test_sim_identify_configure_and_read_back(sim_scope):
    assert sim_scope.identify() == "GW,GDS-2062,SIM0001,V1.12"
    settings = sim_scope.configure()
    assert settings["volts_per_div"] == {1: 0.5, 2: 0.02}
    assert settings["timebase_s_per_div"] == 2.5e-5
    assert sim_scope.query(":CHAN2:COUP?") == "0"  # AC
    assert sim_scope.query(":TRIG:MOD?") == "3"  # single
    assert sim_scope.query(":TIM:DEL?") == "1.000E-05"


def test_sim_rejected_setting_names_the_command(sim_scope):
    sim_scope.options = sim_scope.options.model_copy(update={"ch2": ChannelOptions(scale=50.0)})
    message = r"^GDS-2062: configure: ':CHAN2:SCAL 5.0000E\+01' rejected: \*ESR\? = 16"
    with pytest.raises(InstrumentError, match=message):
        sim_scope.configure()


def test_sim_ascii_safe_block_with_embedded_lf(sim_scope):
    sim_scope.configure()
    trace = sim_scope.read_trace(1)
    assert trace.dt == 2e-9
    assert trace.raw.tolist() == [0, 25, 50, 75, 10, 20]  # 10 = 0x000A: an LF byte inside the block
    assert trace.volts.tolist() == pytest.approx([0.0, 0.5, 1.0, 1.5, 0.2, 0.4])
    assert trace.info["trailing_lf"] is True


def test_sim_trigger_state_polling_and_arm(sim_scope):
    sim_scope.options = sim_scope.options.model_copy(update={"wait": "trigger_state"})
    sim_scope.arm()
    sim_scope.wait_acquired()  # sim answers "1"
    sim_scope.options = sim_scope.options.model_copy(update={"triggered_replies": ["TRIGGER"], "trigger_timeout": 0.1})
    with pytest.raises(InstrumentError, match=r"^GDS-2062: wait for trigger: not triggered within 0.1 s \(last"):
        sim_scope.wait_acquired()


def test_sim_wrong_instrument_and_connect_failures():
    pyvisa = pytest.importorskip("pyvisa")
    rm = pyvisa.ResourceManager(f"{SIM_YAML}@sim")
    scope = GDS2000(GDS2000Options(resource="ASRL1::INSTR", expect_model="GDS-3", timeout=0.3), rm).open()
    with pytest.raises(InstrumentError, match=r"^GDS-2062: identify: unexpected \*IDN\? reply 'GW,GDS-2062"):
        scope.identify()
    scope.close()
    with pytest.raises(InstrumentError, match=r"^GDS-2062: connect: cannot open ASRL7::INSTR: "):
        GDS2000(GDS2000Options(resource="ASRL7::INSTR", visa_library="@nonexistent", timeout=0.3)).open()
    with pytest.raises(InstrumentError, match=r"^GDS-2062: connect: cannot open ASRL/dev/nonexistent-tty::INSTR"):
        GDS2000(GDS2000Options(resource="ASRL/dev/nonexistent-tty::INSTR", timeout=0.3)).open()


# -- binary blocks: pty fake through pyvisa-py --------------------------------------------------
needs_pty = pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs POSIX pseudo-terminals")


@pytest.fixture
def pty_scope(request):
    """The driver on a pseudo-terminal with the fake scope behind it. Reply timeout 3 s (the fake
    runs in a thread of this process, which a loaded test machine can starve for a few tenths of
    a second); the tests of timeouts ask for 0.3 s with ``indirect`` parametrisation."""
    pytest.importorskip("pyvisa_py", reason="pyvisa-py opens ASRL resources on serial ports")
    from fakes.gds2000 import FakeGDS2000

    timeout = getattr(request, "param", 3.0)
    with FakeGDS2000(record_points=500) as fake:
        options = GDS2000Options(resource=f"ASRL{fake.port}::INSTR", timeout=timeout, ch1=ChannelOptions(scale=0.5),
                                 ch2=ChannelOptions(scale=0.2), timebase=1e-6, settle=0.0, arm_delay=0.0)
        scope = GDS2000(options).open()
        scope.configure()
        yield fake, scope
        scope.close()
        assert fake.errors == []


def _load(fake, channel: int, codes) -> None:
    fake.records[channel] = np.asarray(codes, np.int16)


# Samples whose bytes include LF (0x0A) and CR (0x0D) and negative values (0xFF..).
CODES = np.tile(np.array([0, 10, 13, -10, 2570, -246, 125, -125, 3338, -1], np.int16), 50)


@needs_pty
@pytest.mark.parametrize("order", ["big", "little"])
@pytest.mark.parametrize("trailing_lf", [True, False])
def test_pty_block_exact(pty_scope, order, trailing_lf):
    fake, scope = pty_scope
    fake.dt_order, fake.trailing_lf = order, trailing_lf
    _load(fake, 1, CODES)
    _load(fake, 2, -CODES)
    a = scope.read_trace(1)
    b = scope.read_trace(2)
    assert a.raw.tolist() == CODES.tolist() and b.raw.tolist() == (-CODES).tolist()
    assert a.dt == 2e-8 and a.info["float_byte_order"] == order and a.info["trailing_lf"] is trailing_lf
    assert a.volts == pytest.approx(CODES * 0.5 / 25) and b.volts == pytest.approx(-CODES * 0.2 / 25)
    assert a.info["clipped"]  # codes reach +-125 > 100 (screen edge)


@needs_pty
def test_pty_run_stop_and_single_shot_arming(pty_scope):
    fake, scope = pty_scope
    scope.run()
    scope.esr()  # a round trip: the fake has processed everything before it
    assert fake.armed
    scope.stop()
    scope.esr()
    assert not fake.armed
    scope.arm()  # ':SING', confirmed with *ESR?
    assert fake.armed and fake.lines[-2:] == [":SING", "*ESR?"]
    assert fake.values[":TRIG:MOD"] == 3 and fake.values[":ACQ:LENG"] == 1


@needs_pty
@pytest.mark.parametrize("pty_scope", [0.3], indirect=True)
def test_pty_timeout_short_read(pty_scope):
    fake, scope = pty_scope
    _load(fake, 1, CODES)
    fake.truncate_block = 300
    with pytest.raises(InstrumentError, match=r"^GDS-2062: read CH1: short read: the 1008-byte block incomplete "
                                              r"after the 0.3 s timeout \(received \d+\+ of 1008 bytes\)"):
        scope.read_trace(1)


@needs_pty
@pytest.mark.parametrize("pty_scope", [0.3], indirect=True)
def test_pty_silent_scope(pty_scope):
    fake, scope = pty_scope
    fake.silent = True
    with pytest.raises(InstrumentError, match=r"^GDS-2062: read CH1: short read: block header incomplete"):
        scope.read_trace(1)


@needs_pty
@pytest.mark.parametrize("garbage, message", [
    (b"ERR\n", r"garbage reply b'ER' to ':ACQ1:MEM\?'"),
    (b"#9999999999\n", r"impossible block length 999999999 bytes"),
    (b"#A12\n", r"garbage reply b'#A'"),
    (b"#2x5\n", r"garbage block length b.x5."),
])
def test_pty_garbage_replies(pty_scope, garbage, message):
    fake, scope = pty_scope
    fake.block_override = garbage
    with pytest.raises(InstrumentError, match=r"^GDS-2062: read CH1: " + message):
        scope.read_trace(1)


@needs_pty
def test_pty_wrong_channel_implausible_interval_and_empty_record(pty_scope):
    fake, scope = pty_scope
    body = block_bytes(2e-8, 2, CODES)
    fake.block_override = body + b"\n"
    with pytest.raises(InstrumentError, match="block is for channel 2, asked for 1"):
        scope.read_trace(1)
    fake.block_override = b"#218" + struct.pack(">f", float("nan")) + bytes([1, 0, 0, 0]) + bytes(10) + b"\n"
    with pytest.raises(InstrumentError, match="implausible sample interval"):
        scope.read_trace(1)
    fake.block_override = None
    with pytest.raises(InstrumentError, match=r"read CH1: all samples are zero \(no acquisition"):
        scope.read_trace(1)  # nothing captured yet


@needs_pty
def test_pty_disconnect_mid_block(pty_scope):
    fake, scope = pty_scope
    _load(fake, 1, CODES)
    fake.disconnect_in_block = 400
    with pytest.raises(InstrumentError, match=r"^GDS-2062: read CH1: (connection to ASRL/dev/\S+ failed "
                                              r"\(disconnected\?\)|short read)"):
        scope.read_trace(1)
