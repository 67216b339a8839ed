"""GDS-2000 CSV exports (raw-sample and time,value layouts) through the ``file`` backend."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mbus_framework.interfaces.backend import AcquisitionContext
from mbus_framework.errors import DataError
from mbus_framework.interfaces.sample import Sample
from mbus_framework.engine.simulation import simulate
from mbus_plugins.backends.file import FileBackend, FileOptions
from mbus_plugins.excitations.prbs import Prbs, PrbsOptions
from mbus_plugins.instruments.gds_csv import parse_number, read_gds_csv
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions

PRBS = {"order": 6, "bit_width": 2.4e-6, "amplitude": 1.0, "sample_rate": 5.0e6}
SAMPLE = Sample(0.05, 0.0254, 1000.0)
THETA = [3.0e8, 15.0, 5.0e7, 12.0]
DT = 2e-7
PRE = 137  # samples recorded before the burst starts


def header_rows(n: int, source: str, scale: str, period: str = "2.000E-07", extra=()) -> list[str]:
    """Header as the GDS-2000 writes it (row set of gds2000tools' gds-csv, trailing commas)."""
    rows = [f"Memory Length,{n},", "Trigger Level,0.100V,", f"Source,{source},", "Vertical Units,V,",
            f"Vertical Scale,{scale},", "Vertical Position,0.000E+00,", "Horizontal Units,S,",
            "Horizontal Scale,5.000E-05,", "Horizontal Position,0.000E+00,", "Horizontal Mode,Main,",
            f"Sampling Period,{period},", "Firmwave,V1.12,"]
    return rows + list(extra)


def scene(n: int = 1200):
    """Designed excitation, and the volts the two channels see (burst at sample PRE)."""
    wave = Prbs(PrbsOptions(**PRBS)).waveform()
    u = np.zeros(n)
    u[PRE:PRE + wave.u.size] = wave.u[: n - PRE]
    y = simulate(KelvinVoigtChain(SAMPLE, KelvinVoigtOptions(n_elements=10)), THETA, u, DT)
    return wave, u, y


def write_raw(path: Path, volts: np.ndarray, scale: float, source: str, trailing_comma=True, scale_text=None):
    codes = np.round(volts / scale * 25).astype(int)
    end = "," if trailing_comma else ""
    lines = header_rows(codes.size, source, scale_text or f"{scale:.3E}") + [f"{c}{end}" for c in codes]
    path.write_text("\r\n".join(lines) + "\r\n")
    return codes


def write_detail(path: Path, volts: np.ndarray, source: str, t0: float = -2.74e-5):
    t = t0 + np.arange(volts.size) * DT
    rows = [f"{ti:.3E},{v:.4E}" for ti, v in zip(t, volts)]
    path.write_text("\n".join(header_rows(volts.size, source, "5.000E-01", extra=["Mode,Detail,"]) + rows) + "\n")
    return t


def context(config_path="<config>") -> AcquisitionContext:
    wave = Prbs(PrbsOptions(**PRBS)).waveform()
    return AcquisitionContext(wave, SAMPLE, None, None, None, config_path)


def test_parse_number_with_si_prefixes():
    assert parse_number("5.000E-01") == 0.5
    assert parse_number("500mV") == pytest.approx(0.5)
    assert parse_number("2.5uS") == pytest.approx(2.5e-6)
    assert parse_number("200nS") == pytest.approx(2e-7)
    with pytest.raises(ValueError):
        parse_number("fast")


@pytest.mark.parametrize("trailing_comma", [True, False])
def test_raw_layout_scales_codes_by_vertical_scale_over_25(tmp_path, trailing_comma):
    _, u, _ = scene(300)
    codes = write_raw(tmp_path / "A0001CH1.CSV", u, 0.5, "CH1", trailing_comma)
    trace = read_gds_csv(tmp_path / "A0001CH1.CSV")
    assert trace.layout == "raw" and trace.header["Source"] == "CH1"
    assert trace.volts == pytest.approx(codes * 0.5 / 25)
    assert trace.dt == pytest.approx(2e-7) and trace.t[0] == 0.0 and trace.t.size == 300


def test_raw_layout_with_engineering_units_in_the_header(tmp_path):
    lines = ["Memory Length,20", "Source,CH2", "Vertical Scale,200mV", "Sampling Period,4nS"] + ["-25", "50"] * 10
    path = tmp_path / "DS0002.CSV"
    path.write_text("\n".join(lines))
    trace = read_gds_csv(path)
    assert trace.volts[:2] == pytest.approx([-0.2, 0.4]) and trace.dt == pytest.approx(4e-9)


def test_latin1_header_is_accepted(tmp_path):
    path = tmp_path / "A0003CH1.CSV"
    lines = ["Memory Length,16", "Vertical Scale,1V", "Sampling Period,1µS"] + ["25"] * 16
    path.write_bytes("\n".join(lines).encode("latin-1"))
    trace = read_gds_csv(path)
    assert trace.dt == pytest.approx(1e-6) and trace.volts[0] == pytest.approx(1.0)


def test_time_value_layout(tmp_path):
    _, u, _ = scene(400)
    t = write_detail(tmp_path / "A0004CH1.CSV", u, "CH1")
    trace = read_gds_csv(tmp_path / "A0004CH1.CSV")
    assert trace.layout == "time,value"
    assert trace.dt == pytest.approx(2e-7) and trace.t[0] == pytest.approx(t[0], abs=1e-9)
    assert trace.volts == pytest.approx(u, abs=1e-4)


@pytest.mark.parametrize("mutate, message", [
    (lambda lines: [ln for ln in lines if not ln.startswith("Vertical Scale")], "header row 'Vertical Scale' missing"),
    (lambda lines: lines[:-40], "header says Memory Length 300 but the file has 260 samples"),
    (lambda lines: lines[:20] + ["12,abc"] + lines[21:], "line 21: malformed data row '12,abc'"),
    (lambda lines: lines[:20] + ["1.5,"] + lines[21:], "raw-sample rows must be integer codes"),
    (lambda lines: [ln.replace("Vertical Scale,5.000E-01", "Vertical Scale,big") for ln in lines],
     "header 'Vertical Scale' is not a number"),
    (lambda lines: lines[:12], "no data rows after the header"),
])
def test_malformed_raw_files_name_the_file(tmp_path, mutate, message):
    _, u, _ = scene(300)
    path = tmp_path / "A0005CH1.CSV"
    write_raw(path, u, 0.5, "CH1")
    path.write_text("\n".join(mutate(path.read_text().splitlines())))
    with pytest.raises(DataError, match=f"^{path}: .*{message}"):
        read_gds_csv(path)


def test_non_uniform_time_column(tmp_path):
    _, u, _ = scene(300)
    path = tmp_path / "A0006CH1.CSV"
    write_detail(path, u, "CH1")
    lines = path.read_text().splitlines()
    lines[100] = "9.999E-05," + lines[100].split(",")[1]
    path.write_text("\n".join(lines))
    with pytest.raises(DataError, match=f"^{path}: non-uniform time column"):
        read_gds_csv(path)


@pytest.mark.parametrize("layout", ["raw", "detail"])
def test_file_backend_reads_a_channel_pair_and_aligns_it(tmp_path, layout):
    wave, u, y = scene()
    if layout == "raw":
        write_raw(tmp_path / "A0007CH1.CSV", u, 0.5, "CH1")
        write_raw(tmp_path / "A0007CH2.CSV", y, 1.0, "CH2")
    else:
        write_detail(tmp_path / "A0007CH1.CSV", u, "CH1")
        write_detail(tmp_path / "A0007CH2.CSV", y, "CH2")
    config = tmp_path / "cfg.yaml"
    backend = FileBackend(FileOptions(path="A0007CH1.CSV", response_path="A0007CH2.CSV"))
    m = backend.acquire(context(str(config)))  # relative names resolve next to the config
    assert m.meta["lags_samples"] == [PRE]
    assert m.u.size == wave.u.size and m.dt == pytest.approx(DT)
    assert np.max(np.abs(m.u - wave.u)) < 0.03
    assert np.max(np.abs(m.y - y[PRE:PRE + wave.u.size])) < 0.03


def test_pair_problems(tmp_path):
    _, u, y = scene()
    write_raw(tmp_path / "CH1.CSV", u, 0.5, "CH1")
    write_raw(tmp_path / "CH2.CSV", y[:-100], 1.0, "CH2")
    with pytest.raises(DataError, match="a GDS-2000 CSV holds one channel; give backend.options.response_path"):
        FileBackend(FileOptions(path=str(tmp_path / "CH1.CSV"))).acquire(context())
    with pytest.raises(DataError, match=r"CH2.CSV: 1100 samples of 2e-07 s but CH1.CSV has 1200"):
        FileBackend(FileOptions(path=str(tmp_path / "CH1.CSV"), response_path=str(tmp_path / "CH2.CSV"))).acquire(
            context())
    write_raw(tmp_path / "CH2.CSV", -y, 1.0, "CH2")
    with pytest.raises(DataError, match=r"the excitation channel does not match the designed excitation"):
        FileBackend(FileOptions(path=str(tmp_path / "CH2.CSV"), response_path=str(tmp_path / "CH1.CSV"))).acquire(
            context())
