"""Issue 27 leftovers: positive intervals, fixing by property, units, specific hints, file hashes."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

import mbus_framework as mbus
from fakes.recording import POTATO, prbs_burst, simulate
from mbus_framework.estimation.uncertainty import Uncertainty, confidence_intervals, positive_interval


# -- item 9: intervals of positive quantities ------------------------------------------------
def test_synthetic_uncertainty_positive_intervals_never_reach_zero():
    values = np.array([2.0e12, 5.0, 1e-3, 3.0])
    se = np.array([1.5e12, 50.0, np.inf, 0.1])
    unc = Uncertainty(["a", "b", "c", "d"], np.diag(se**2), se, np.eye(4), dof=100, residual_std=1.0)
    ci = unc.intervals(values, positive=[True, True, True, False])
    q = stats.t.ppf(0.975, 100)
    assert np.all(ci[:3, 0] > 0)
    # log-scale: the estimate is the geometric centre, ln width = 2 q SE/v
    np.testing.assert_allclose(ci[0, 0] * ci[0, 1], values[0] ** 2, rtol=1e-12)
    np.testing.assert_allclose(np.log(ci[1, 1] / ci[1, 0]), 2 * q * se[1] / values[1], rtol=1e-12)
    assert ci[2, 1] == math.inf
    # a quantity that may be negative keeps the symmetric interval
    np.testing.assert_allclose(ci[3], [3.0 - q * 0.1, 3.0 + q * 0.1])
    # a negative value is never put on the log scale
    assert confidence_intervals([-1.0], [0.5], 2.0, [True])[0].tolist() == [-2.0, 0.0]
    lo, hi = positive_interval(10.0, 20.0, 1.96)
    assert 0 < lo < 10.0 < hi


@pytest.fixture(scope="module")
def sls_on_kv():
    """An SLS fitted to a Kelvin-Voigt record: E1_sigma is barely determined (rel. SE > 100 %)."""
    u = prbs_burst(POTATO, POTATO.n_samples)
    t, y = simulate(POTATO, u, seed=3)
    return mbus.fit(t, u, y, sample=POTATO.sample, model="sls")


@pytest.mark.slow  # an SLS fitted to a Kelvin-Voigt record: 10 s alone, minutes on a busy machine
def test_sls_poorly_determined_parameter_interval_stays_positive(sls_on_kv):
    doc = sls_on_kv.document
    unc = doc["uncertainty"]
    rel = unc["relative_standard_errors"]
    worst = max(rel, key=rel.get)
    q = stats.t.ppf(0.975, doc["fit"]["n_samples"] - len(rel))
    assert rel[worst] * q > 1.0, "the test needs a parameter whose symmetric interval would cross zero"
    for table in ("ci95", "property_ci95"):
        for name, (lo, hi) in unc[table].items():
            assert 0 < lo < hi, (table, name, lo, hi)
    value = doc["parameters"][worst]
    lo, hi = unc["ci95"][worst]
    np.testing.assert_allclose(lo * hi, value**2, rtol=1e-9)
    # the printed property table shows no interval starting at zero or below
    for line in sls_on_kv.summary().splitlines():
        if "[" in line and "," in line and "Pa" in line:
            lo_txt = line.split("[")[1].split(",")[0]
            assert float(lo_txt) > 0, line


# -- item 8: model.fixed by property name ------------------------------------------------------
@pytest.fixture(scope="module")
def potato_record():
    u = prbs_burst(POTATO, POTATO.n_samples)
    t, y = simulate(POTATO, u, seed=3)
    return t, u, y


def test_model_fixed_accepts_a_property_and_prints_it_as_fixed(potato_record):
    t, u, y = potato_record
    res = mbus.fit(t, u, y, sample=POTATO.sample, model="kelvin_voigt", fixed={"eta_tau": 5000.0})
    doc = res.document
    # eta_tau = b_tau L / A moves b_tau only: the run holds that parameter, at the matching value
    assert list(doc["fixed"]) == ["b_tau"]
    assert doc["properties"]["eta_tau"] == pytest.approx(5000.0, rel=1e-9)
    assert doc["fixed_properties"] == ["eta_tau"]
    assert "eta_tau" not in doc["uncertainty"]["property_ci95"]
    assert res.properties["eta_tau"].fixed and not res.properties["E_sigma"].fixed
    row = next(line for line in res.summary().splitlines() if line.strip().startswith("eta_tau"))
    assert "fixed" in row and "[" not in row
    assert res.parameters["b_tau"].fixed


def test_model_fixed_unknown_name_suggests_parameters_and_properties(potato_record):
    t, u, y = potato_record
    from mbus_framework.errors import ConfigError

    with pytest.raises(ConfigError) as err:
        mbus.fit(t, u, y, sample=POTATO.sample, model="kelvin_voigt", fixed={"eta_tua": 5000.0})
    msg = str(err.value)
    assert "model.fixed.eta_tua" in msg and "did you mean 'eta_tau'" in msg and "\n" not in msg
    assert "KelvinVoigt" not in msg  # no class names


class _Coupled:
    """A duck-typed model whose property P = a * b depends on two parameters."""

    from mbus_framework.interfaces.model import Parameter as _P

    parameters = (_P("a", "-", "a", typical=2.0), _P("b", "-", "b", typical=3.0))
    parameter_names = ["a", "b"]
    property_names = ["P", "a_prop"]

    def to_properties(self, theta):
        return {"P": theta[0] * theta[1], "a_prop": 2 * theta[0]}

    def from_properties(self, props):
        a = props["a_prop"] / 2
        return np.array([a, props["P"] / a])


def test_a_property_of_several_parameters_asks_to_fix_parameters():
    from mbus_framework.errors import ConfigError
    from mbus_framework.pipeline.fixed_names import resolve_fixed

    # a_prop moves a, but from_properties then moves b too (P held): two parameters change
    with pytest.raises(ConfigError, match=r"cfg.yaml: model.fixed.a_prop: this property depends on several"):
        resolve_fixed(_Coupled(), {"a_prop": 5.0}, "model.fixed", "cfg.yaml")
    # P moves b alone: accepted, b = P / a at the template... only if a is the same in every template: it is not
    with pytest.raises(ConfigError, match="fix parameters instead"):
        resolve_fixed(_Coupled(), {"P": 12.0}, "model.fixed", "cfg.yaml")
    assert resolve_fixed(_Coupled(), {"a": 1.0}, "model.fixed", "cfg.yaml") == {"a": 1.0}


# -- item 3: volts are not newtons -------------------------------------------------------------
REPO = __import__("pathlib").Path(__file__).resolve().parents[1]
CH1, CH2 = REPO / "examples/recorded/A0001CH1.CSV", REPO / "examples/recorded/A0001CH2.CSV"


def _acquire(**options):
    from mbus_plugins.backends.file import FileBackend, FileOptions

    return FileBackend(options=FileOptions(**options)).acquire(None)


def test_scope_vertical_units_are_carried_and_a_gain_makes_newtons():
    assert _acquire(path=str(CH1), response_path=str(CH2)).meta["units"] == {"u": "V", "y": "V"}
    m = _acquire(path=str(CH1), response_path=str(CH2), processing={"u_gain": 2.0})
    assert m.meta["units"] == {"u": "N", "y": "V"}
    m = _acquire(path=str(CH1), response_path=str(CH2), units={"u": "N", "y": "N"})
    assert m.meta["units"] == {"u": "N", "y": "N"} and m.meta["units_source"] == "backend.options.units"


def test_units_row_in_volts_is_carried(tmp_path):
    t = np.arange(400) * 4e-8
    u = np.where(t < 2e-6, np.sin(2 * np.pi * 1e6 * t), 0.0)
    rows = "\n".join(f"{a:.9g},{b:.9g},{c:.9g}" for a, b, c in zip(t, u, 0.5 * u))
    path = tmp_path / "rec.csv"
    path.write_text("t,u,y\ns,V,V\n" + rows + "\n")
    assert _acquire(path=str(path), units_row=True, pretrigger=False).meta["units"] == {"t": "s", "u": "V", "y": "V"}


def test_apply_units_labels_and_warns_only_without_gains():
    from mbus_framework.pipeline.units import apply_units

    def result():
        return {"parameter_units": {"k_sigma": "N/m", "input_gain": "N/unit"}, "property_units": {"E_sigma": "Pa"},
                "warnings": []}

    volts = {"units": {"u": "V", "y": "V"}, "units_source": "scope"}
    r = result()
    apply_units(r, volts, gain_estimated=False, gain_name="input_gain")
    assert r["property_units"] == {"E_sigma": "Pa (V/V)"} and len(r["warnings"]) == 1
    assert r["warnings"][0].startswith("units: scope gives u in V, y in V") and "nuisance.input_gain.estimate" in r["warnings"][0]
    r = result()
    apply_units(r, volts, gain_estimated=True, gain_name="input_gain")
    assert r["warnings"] == [] and r["property_units"] == {"E_sigma": "Pa"}
    assert r["parameter_units"]["input_gain"] == "V/V"
    r = result()
    apply_units(r, {"units": {"u": "V", "y": "N"}}, gain_estimated=True, gain_name="input_gain")
    assert r["parameter_units"]["input_gain"] == "N/V" and r["warnings"] == []
    r = result()
    apply_units(r, {}, gain_estimated=False, gain_name="input_gain")
    assert r == result()  # nothing known: nothing said


def test_scope_record_in_volts_without_gains_warns_and_labels(tmp_path, capsys):
    import json

    import yaml

    from mbus_framework.cli import main

    cfg = yaml.safe_load((REPO / "configs/recorded_gds2062.yaml").read_text())
    del cfg["backend"]["options"]["processing"]
    cfg["backend"]["options"].update(path=str(CH1), response_path=str(CH2))
    (tmp_path / "v.yaml").write_text(yaml.safe_dump(cfg))
    assert main([str(tmp_path / "v.yaml"), "-o", str(tmp_path / "out"), "--no-plots"]) == 0
    out = capsys.readouterr().out
    r = json.loads((tmp_path / "out" / "result.json").read_text())
    assert [w for w in r["warnings"] if w.startswith("units:")] == [r["warnings"][0]]
    assert r["property_units"]["E_sigma"] == "Pa (V/V)" and (r["record_units"]["u"], r["record_units"]["y"]) == ("V", "V")
    assert "Pa (V/V)" in out and "WARNING: units:" in out


# -- item 5: the data files' content hash in measurement.json -----------------------------------
def test_measurement_json_records_absolute_paths_and_sha256_of_the_data_files(tmp_path):
    import hashlib
    import json
    import shutil

    from mbus_framework.campaigns.hashing import digest
    from mbus_framework.pipeline.run import acquire, load_components

    data = tmp_path / "data"
    data.mkdir()
    for f in (CH1, CH2):
        shutil.copy(f, data / f.name)
    cfg = tmp_path / "cfg" / "run.yaml"
    cfg.parent.mkdir()
    cfg.write_text((REPO / "configs/recorded_gds2062.yaml").read_text().replace("../examples/recorded/", "../data/"))
    c = load_components(cfg)
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    acquire(c, run_dir, None)
    saved = json.loads((run_dir / "measurement.json").read_text())
    inputs = {e["key"]: e for e in saved["inputs"]}
    assert set(inputs) == {"backend.options.path", "backend.options.response_path"}
    for key, f in (("backend.options.path", CH1), ("backend.options.response_path", CH2)):
        assert inputs[key]["path"] == str((data / f.name).resolve())
        assert inputs[key]["sha256"] == hashlib.sha256(f.read_bytes()).hexdigest()
    # the campaigns' digest is the same function (one rule for a file's content hash)
    assert digest(CH1) == inputs["backend.options.path"]["sha256"] and digest(tmp_path / "nope") == "missing"


# -- item 4: specific hints: wrong time unit, swapped channels ------------------------------------
TUY = REPO / "examples/recorded/potato_tuy.csv"


def _hints(m):
    from mbus_framework.pipeline.hints import record_hints

    return record_hints(m)


def _shipped_measurements():
    from mbus_framework.pipeline.run import designed_waveform, load_components
    from mbus_framework.interfaces.backend import AcquisitionContext

    for name in ("potato.yaml", "recorded.yaml", "recorded_gds2062.yaml"):
        c = load_components(REPO / "configs" / name)
        wave = designed_waveform(c)
        yield name, c.backend.acquire(AcquisitionContext(wave, c.sample, c.model, c.registry, None, c.source))


def test_no_hint_on_the_shipped_records():
    for name, m in _shipped_measurements():
        assert _hints(m) == [], name


@pytest.mark.parametrize("scale, unit", [(1e6, "microseconds"), (1e3, "milliseconds")])
def test_time_in_micro_or_milliseconds_gets_one_hint_naming_the_factor(scale, unit):
    from mbus_framework.interfaces.backend import check_record

    m = _acquire(path=str(TUY))
    hints = _hints(check_record("rec.csv", m.t * scale, m.u, m.y))
    assert len(hints) == 1 and "\n" not in hints[0]
    assert hints[0].startswith("time:") and f"in {unit}? multiply t by {1 / scale:.0e}".replace("e-0", "e-") in hints[0]


def test_swapped_channels_get_one_hint_naming_what_to_swap():
    from mbus_framework.interfaces.backend import check_record

    m = _acquire(path=str(TUY))
    hints = _hints(check_record("rec.csv", m.t, m.y, m.u))
    assert len(hints) == 1 and hints[0].startswith("channels: the output leads the input")
    assert "backend.options.columns" in hints[0]
    pair = _acquire(path=str(CH2), response_path=str(CH1))  # CH2 (received) given as the excitation channel
    hints = _hints(pair)
    assert len(hints) == 1 and "swap backend.options.path and response_path" in hints[0]


@pytest.mark.slow
def test_shipped_configs_run_warning_free_and_a_swapped_pair_warns_once(tmp_path, capsys):
    import json

    from mbus_framework.cli import main

    for name in ("potato.yaml", "recorded.yaml", "recorded_gds2062.yaml"):
        assert main([str(REPO / "configs" / name), "-o", str(tmp_path / name), "--no-plots"]) == 0
        assert json.loads((tmp_path / name / "result.json").read_text())["warnings"] == [], name
    assert main([str(REPO / "configs/recorded_gds2062.yaml"), "-o", str(tmp_path / "sw"), "--no-plots",
                 "--set", f"backend.options.path={CH2}", "--set", f"backend.options.response_path={CH1}"]) == 0
    warnings = json.loads((tmp_path / "sw" / "result.json").read_text())["warnings"]
    assert sum(w.startswith("channels:") for w in warnings) == 1


# -- item 6: every file variant of docs/recorded-data.md loads with at most one reader option ---
VARIANTS = REPO / "examples/recorded/variants"
OPTION = {
    "renamed.csv": ("columns", {"t": "time", "u": "excitation", "y": "response"}),
    "semicolon.csv": ("delimiter", ";"),
    "decimal_comma.csv": ("decimal", ","),
    "units_row.csv": ("units_row", True),
    "preamble.csv": ("skip_rows", 2),
    "headerless.txt": ("columns", {"t": 0, "u": 1, "y": 2}),
    "commented.tsv": None,
    "scope_u.csv": ("response_path", str(VARIANTS / "scope_y.csv")),
}


@pytest.mark.parametrize("name", sorted(OPTION))
def test_each_variant_loads_with_its_one_option_and_the_error_names_it(name):
    from mbus_framework.errors import DataError

    reference = _acquire(path=str(TUY))
    option = OPTION[name]
    if option is not None:
        key = "columns" if option[0] == "response_path" else option[0]  # a lone time,value file: say which is which
        with pytest.raises(DataError, match=rf"backend\.options\.{key}"):
            _acquire(path=str(VARIANTS / name))
    m = _acquire(path=str(VARIANTS / name), **(dict([option]) if option else {}))
    np.testing.assert_array_equal(m.u, reference.u)
    np.testing.assert_array_equal(m.y, reference.y)
    np.testing.assert_allclose(m.t, reference.t, rtol=1e-12, atol=1e-18)


def test_variant_files_are_what_their_script_makes(tmp_path):
    import runpy

    runpy.run_path(str(VARIANTS / "make_variants.py"))["write"](tmp_path)
    for name in [*OPTION, "scope_y.csv"]:
        assert (tmp_path / name).read_bytes() == (VARIANTS / name).read_bytes(), name


def test_docs_show_each_variant_as_a_tested_command():
    text = (REPO / "docs/recorded-data.md").read_text()
    block = text.split("<!-- test: run -->\n```bash\n")
    commands = "\n".join(b.split("```")[0] for b in block[1:])
    for name in OPTION:
        assert f"examples/recorded/variants/{name}" in commands, name
