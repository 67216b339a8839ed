"""DS340 driver against a byte-exact fake on a pseudo-terminal."""
from __future__ import annotations

import os
import struct

import numpy as np
import pytest

from mbus_framework.errors import InstrumentError
from mbus_plugins.instruments.ds340 import (
    DS340,
    DS340Options,
    checksum_bytes,
    encode_points,
    scale_to_points,
)

pytestmark = pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs POSIX pseudo-terminals")

from fakes.ds340 import FakeDS340  # noqa: E402

# Includes points whose bytes are LF (10, 0x050A = 1290, 0xFF0A = -246) and CR (13).
POINTS = np.array([0, 2047, -2047, 10, 13, -1, 1290, -246, 1000, -3, 7, 8], dtype=np.int16)


@pytest.fixture
def fake():
    with FakeDS340() as device:
        yield device
        assert device.errors == []


def driver(fake, **options) -> DS340:
    """The driver on the fake's pseudo-terminal. Reply timeouts 3 s: the fake runs in a thread of
    this process, which a loaded test machine can starve for a few tenths of a second (the
    timeout tests ask for their own, shorter ones)."""
    options.setdefault("timeout", 3.0)
    options.setdefault("ready_timeout", 3.0)
    return DS340(DS340Options(port=fake.port, **options)).open()


def test_checksum_and_encoding_are_little_endian_sums_ignoring_carries():
    pts = np.array([2047, 2047, -1, 5], np.int16)
    assert encode_points(pts) == b"\xff\x07\xff\x07\xff\xff\x05\x00"
    assert checksum_bytes(pts, 2) == struct.pack("<H", (2047 + 2047 - 1 + 5) & 0xFFFF)
    neg = np.array([-2047, -2047], np.int16)
    assert checksum_bytes(neg, 2) == struct.pack("<h", -4094)
    assert checksum_bytes(neg, 4) == struct.pack("<i", -4094)
    big = np.full(40, 2047, np.int16)  # sum 81880 > 0xFFFF: the carry is dropped
    assert checksum_bytes(big, 2) == struct.pack("<H", 81880 & 0xFFFF)


def test_scale_to_points_uses_full_scale():
    pts = scale_to_points(np.array([0.5, -0.5, 0.25, 0.0]))
    assert pts.tolist() == [2047, -2047, 1024, 0]
    with pytest.raises(ValueError):
        scale_to_points(np.zeros(4))


def test_identify_and_upload_are_byte_exact(fake):
    d = driver(fake)
    assert d.identify() == fake.idn
    d.upload(POINTS)
    expected = POINTS.astype("<i2").tobytes() + struct.pack("<H", int(POINTS.astype(int).sum()) & 0xFFFF)
    assert fake.uploads == [expected]
    assert np.array_equal(fake.points, POINTS)
    assert f"LDWF? 0,{POINTS.size}" in fake.lines
    # The raw byte stream: the query line, then exactly the binary payload, then the status query.
    stream = bytes(fake.received)
    marker = f"LDWF? 0,{POINTS.size}\n".encode()
    start = stream.index(marker) + len(marker)
    assert stream[start:start + len(expected)] == expected
    assert stream[start + len(expected):].startswith(b"*ESR?\n")
    d.close()


def test_four_byte_checksum_option(fake):
    fake.checksum_bytes = 4
    d = driver(fake, checksum_bytes=4)
    d.upload(POINTS)
    assert fake.uploads[0][-4:] == struct.pack("<i", int(POINTS.astype(int).sum()))
    assert np.array_equal(fake.points, POINTS)
    d.close()


def test_bad_checksum_is_an_upload_error_that_suggests_the_other_width(fake):
    fake.corrupt_checksum = True
    d = driver(fake)
    with pytest.raises(InstrumentError, match=r"^DS340: upload: waveform of 12 points rejected: \*ESR\? = 16 "
                                              r"\(execution error.*try checksum_bytes: 4"):
        d.upload(POINTS)
    d.close()


def test_checksum_width_mismatch_fails_in_the_upload_step(fake):
    fake.checksum_bytes = 4  # instrument waits for two more bytes than the driver sends
    d = driver(fake, timeout=0.3, ready_timeout=0.3)  # the upload ends in a timeout
    with pytest.raises(InstrumentError, match=r"^DS340: upload: "):
        d.upload(POINTS)
    d.close()


def test_refused_download(fake):
    fake.ldwf_reply = "0"
    d = driver(fake)
    with pytest.raises(InstrumentError, match=r"^DS340: upload: instrument not ready .* reply '0' to 'LDWF\? 0,12'"):
        d.upload(POINTS)
    assert fake.uploads == []
    d.close()


def test_points_are_checked_before_anything_is_sent(fake):
    d = driver(fake)
    with pytest.raises(InstrumentError, match="point magnitude 2048 exceeds 2047"):
        d.upload(np.array([0, 2048] * 4, np.int16))
    with pytest.raises(InstrumentError, match=r"4 points outside 8\.\.16300"):
        d.upload(np.zeros(4, np.int16))
    assert not any(line.startswith("LDWF") for line in fake.lines)
    d.close()


def test_configure_sends_the_burst_setup_and_reads_back_the_rate(fake):
    d = driver(fake, amplitude_vpp=2.0, offset=0.1, burst_count=3)
    d.identify()
    d.upload(POINTS)
    settings = d.configure(6.25e6)
    sent = [line for line in fake.lines if line != "*ESR?"]
    assert sent[-10:] == ["FUNC 5", "FSMP 6250000", "AMPL 2VP", "OFFS 0.1", "MTYP 5", "BCNT 3", "TSRC 0",
                          "MENA 1", "FSMP?", "AMPL?"]
    assert settings["sample_rate_hz"] == pytest.approx(40e6 / 6)  # the fake rounds to 40 MHz / N
    assert settings["amplitude"] == "2.00VP"
    assert fake.state["BCNT"] == 3 and fake.state["MTYP"] == 5 and fake.state["TSRC"] == 0
    d.trigger()
    assert fake.triggers == 1
    d.close()


def test_rejected_command_is_named(fake):
    fake.reject["MTYP"] = 32
    d = driver(fake)
    with pytest.raises(InstrumentError, match=r"^DS340: configure: 'MTYP 5' rejected: \*ESR\? = 32 \(command error"):
        d.configure(1e6)
    d.close()


def test_out_of_range_value_is_an_execution_error(fake):
    d = driver(fake, amplitude_vpp=20.0)
    with pytest.raises(InstrumentError, match=r"'AMPL 20VP' rejected: \*ESR\? = 16 \(execution error"):
        d.configure(1e6)
    d.close()


def test_silent_instrument_times_out(fake):
    fake.silent = True
    d = driver(fake, timeout=0.2)
    with pytest.raises(InstrumentError, match=r"^DS340: identify: no reply to '\*IDN\?' within 0.2 s on /dev/"):
        d.identify()
    d.close()


def test_wrong_instrument_or_garbage_identity(fake):
    fake.idn = "GW,GDS-2062,EF1,V1"
    d = driver(fake, timeout=0.3)  # the cut-off reply ends in a timeout
    with pytest.raises(InstrumentError, match=r"^DS340: identify: unexpected \*IDN\? reply 'GW,GDS-2062"):
        d.identify()
    fake.replies["*IDN?"] = b"\xf8\x80\x7f\xfe\r"  # what a baud-rate mismatch looks like
    with pytest.raises(InstrumentError, match=r"^DS340: identify: garbage reply b'\\xf8"):
        d.identify()
    fake.replies["*IDN?"] = b"StanfordResearchSystems,DS3"  # cut off: no terminator
    with pytest.raises(InstrumentError, match=r"^DS340: identify: incomplete reply b'StanfordResearchSystems,DS3'"):
        d.identify()
    d.close()


def test_garbage_status_reply(fake):
    fake.replies["*ESR?"] = b"OK\r"
    d = driver(fake)
    with pytest.raises(InstrumentError, match=r"^DS340: configure: garbage reply 'OK' to '\*ESR\?'"):
        d.configure(1e6)
    d.close()


def test_disconnect_mid_upload(fake):
    fake.disconnect_after_payload_bytes = 7
    d = driver(fake)
    with pytest.raises(InstrumentError, match=r"^DS340: upload: serial port /dev/\S+ failed \(disconnected\?\)"):
        d.upload(POINTS)
    d.close()


def test_open_failure_names_the_port(tmp_path):
    d = DS340(DS340Options(port=str(tmp_path / "ttyUSB9"), timeout=0.2))
    with pytest.raises(InstrumentError, match=r"^DS340: connect: cannot open serial port .*ttyUSB9: "):
        d.open()
