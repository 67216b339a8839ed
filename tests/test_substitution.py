"""The immersion substitution method (mbus_framework.substitution) against independent references:
the acoustic transfer matrix of a layer, published water properties, records simulated from
known laws, and the real VeroWhite plates judged against the model-free measurement."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.io

from mbus_framework.substitution.analysis import analyse
from mbus_framework.engine.continuum_laws import LAWS, velocity_attenuation, wavenumber
from mbus_framework.substitution.plate import substitution_ratio, transmission
from mbus_framework.substitution.record import SubstitutionRecord, read_mat
from mbus_framework.substitution.water import Water, density, sound_speed

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "examples" / "real" / "thetascan"


def test_water_matches_published_values():
    assert sound_speed(20.0) == pytest.approx(1482.3, abs=0.1)  # Marczak (1997) / Del Grosso
    assert sound_speed(0.0) == pytest.approx(1402.4, abs=0.1)
    assert density(20.0) == pytest.approx(998.21, abs=0.01)  # Kell (1975)
    assert density(4.0) == pytest.approx(999.97, abs=0.01)
    with pytest.raises(ValueError, match="outside"):
        sound_speed(120.0)


def _transfer_matrix_transmission(k, Zs, k0, Zw, h):
    """Pressure transmission of a layer from its acoustic transfer matrix (p, v continuous):
    [[cos kh, i Zs sin kh], [i sin kh / Zs, cos kh]], T = 2 / (a + b / Zw + c Zw + d), times
    e^{i k0 h} for the water the layer replaces."""
    a = d = np.cos(k * h)
    b = 1j * Zs * np.sin(k * h)
    c = 1j * np.sin(k * h) / Zs
    return 2 / (a + b / Zw + c * Zw + d) * np.exp(1j * k0 * h)


@pytest.mark.parametrize("law", list(LAWS))
def test_plate_transmission_matches_the_transfer_matrix(law):
    f = np.linspace(0.5e6, 5e6, 40)
    w = 2 * np.pi * f
    water = Water.at(21.0)
    L = LAWS[law]
    rho, h, w0 = 1180.0, 3e-3, 2 * np.pi * 2.25e6
    M = L.modulus(w, L.start(6.5e9 + 4e8j, w0), w0)
    k = wavenumber(M, w, rho)
    got = transmission(k, rho * w / k, w / water.speed, water.impedance, h)
    ref = _transfer_matrix_transmission(k, rho * w / k, w / water.speed, water.impedance, h)
    np.testing.assert_allclose(got, ref, rtol=1e-10)


def test_a_water_layer_transmits_everything():
    f = np.linspace(0.5e6, 5e6, 20)
    w = 2 * np.pi * f
    water = Water.at(20.0)
    M = np.full(f.size, water.density * water.speed**2, dtype=complex)
    np.testing.assert_allclose(substitution_ratio(M, w, water.density, 4e-3, water), 1.0, atol=1e-12)


def _pulse(n=2048, dt=1e-8, fc=2.25e6, t0=3e-6, bw=0.6):
    t = np.arange(n) * dt
    sigma = 1 / (np.pi * bw * fc)
    return np.exp(-(((t - t0) / sigma) ** 2)) * np.cos(2 * np.pi * fc * (t - t0))


def _simulated(law_name, p, rho=1150.0, h=3.2e-3, temperature=20.5, noise=0.0, seed=0):
    """Sample shot = irfft(R T^P) for a reference pulse through water and a plate of the law."""
    dt = 1e-8
    r = _pulse(dt=dt)
    R = np.fft.rfft(r)
    f = np.fft.rfftfreq(r.size, dt)
    w = np.maximum(2 * np.pi * f, 1.0)
    law = LAWS[law_name]
    M = law.modulus(w, p, 2 * np.pi * 2.25e6)
    s = np.fft.irfft(R * substitution_ratio(M, w, rho, h, Water.at(temperature)), r.size)
    rng = np.random.default_rng(seed)
    r = r + noise * np.max(np.abs(r)) * rng.standard_normal(r.size)
    s = s + noise * np.max(np.abs(r)) * rng.standard_normal(r.size)
    return SubstitutionRecord(r, s, dt, h, rho, temperature, source=f"simulated {law_name}"), law, M


TRUTHS = {
    "kelvin_voigt": np.array([6.0e9, 25.0]),
    "zener": np.array([5.6e9, 6.4e9, 6.0e-8]),
    "constant_q": np.array([6.2e9, 0.012]),
    "power_law": np.array([3.0e9, 2.0e8, 0.15]),
    "fractional_zener": np.array([5.4e9, 6.6e9, 6.0e-8, 0.6]),
}


@pytest.mark.parametrize("law_name", list(TRUTHS))
def test_model_free_dispersion_is_the_true_one_on_a_simulated_plate(law_name):
    rec, law, _ = _simulated(law_name, TRUTHS[law_name])
    a = analyse(rec, [law_name])
    w = 2 * np.pi * a.model_free.f
    c, alpha = velocity_attenuation(wavenumber(law.modulus(w, TRUTHS[law_name], 2 * np.pi * 2.25e6), w, rec.density), w)
    inner = (a.model_free.f > 1.2e6) & (a.model_free.f < 3.5e6)
    np.testing.assert_allclose(a.model_free.velocity[inner], c[inner], rtol=1e-3)
    np.testing.assert_allclose(a.model_free.attenuation[inner], alpha[inner], rtol=0.02, atol=1.0)


@pytest.mark.parametrize("law_name", ["kelvin_voigt", "zener", "constant_q", "fractional_zener"])
def test_each_law_recovers_its_own_plate_from_noisy_records(law_name):
    rec, law, _ = _simulated(law_name, TRUTHS[law_name], noise=1e-3, seed=3)
    a = analyse(rec, [law_name])
    fit = a.best
    lo, hi = fit.intervals(z=4.0).T
    assert np.all(lo > 0)
    assert np.all((lo <= TRUTHS[law_name]) & (TRUTHS[law_name] <= hi)), (fit.values, TRUTHS[law_name])
    assert fit.explained > 0.999
    assert a.passed()


def test_bic_prefers_the_law_that_made_the_record():
    rec, _, _ = _simulated("constant_q", TRUTHS["constant_q"], noise=1e-3, seed=5)
    a = analyse(rec, ["kelvin_voigt", "constant_q"])
    assert a.best.law.name == "constant_q"
    assert not a.passed(next(f for f in a.fits if f.law.name == "kelvin_voigt")) or a.fits[1].bic > a.fits[0].bic


def _write_mat(path, **variables):
    scipy.io.savemat(str(path), variables)
    return path


def test_mat_reader_errors_name_the_variable(tmp_path):
    t = np.arange(64) * 1e-8
    good = dict(s_ref=np.sin(t * 1e7), s=np.column_stack([np.cos(t * 1e7)] * 3), t=t, h=3e-3, rho=1100.0, Temp=20.0)
    rec = read_mat(_write_mat(tmp_path / "good.mat", **good), column=2)
    assert rec.sample.size == 64 and rec.dt == pytest.approx(1e-8) and rec.thickness == 3e-3
    missing = {k: v for k, v in good.items() if k != "rho"}
    with pytest.raises(ValueError, match=r"no variable 'rho' for the density"):
        read_mat(_write_mat(tmp_path / "missing.mat", **missing))
    with pytest.raises(ValueError, match=r"column 5 of 's' is out of range \(it has 3 columns\)"):
        read_mat(tmp_path / "good.mat", column=5)
    (tmp_path / "x.mat").write_text("junk")
    with pytest.raises(ValueError, match="not a readable MATLAB"):
        read_mat(tmp_path / "x.mat")
    assert read_mat(tmp_path / "missing.mat", overrides={"density": 900.0}).density == 900.0
    renamed = {"ref": good["s_ref"], "out": good["s"], "t": t, "h": 3e-3, "rho": 1100.0, "Temp": 20.0}
    rec = read_mat(_write_mat(tmp_path / "renamed.mat", **renamed), variables={"reference": "ref", "sample": "out"})
    assert rec.reference.size == 64


@pytest.mark.parametrize("name", ["VW100a", "VW0"])
def test_real_plates_agree_with_the_model_free_measurement(name):
    """Published check (issue 23): phase velocity within 1 % at 1.5-3 MHz, attenuation within
    20 % or 1.5 dB/cm at 2-3 MHz, >= 95 % of the in-band energy explained, no warning."""
    from mbus_framework.substitution.report import warnings_for

    a = analyse(read_mat(DATA / f"{name}.mat"), ["constant_q"])
    rows = a.checks()
    assert {r["frequency_Hz"] for r in rows} == {1.5e6, 2e6, 2.5e6, 3e6}
    assert a.passed(), rows
    assert a.best.explained >= 0.95
    assert warnings_for(a) == []
    c = a.best.dispersion.at(2.25e6)[0]
    assert c == pytest.approx({"VW100a": 2440.0, "VW0": 2070.0}[name], rel=0.01)


def test_kelvin_voigt_is_flagged_on_a_real_polymer():
    """Kelvin-Voigt attenuation grows as f^2; the polymer's grows as about f: the check must
    say so (a warning the user can act on) rather than accept it."""
    from mbus_framework.substitution.report import warnings_for

    a = analyse(read_mat(DATA / "VW100a.mat"), ["kelvin_voigt"])
    assert not a.passed()
    assert any("departs from the model-free" in w for w in warnings_for(a))


def test_mbus_run_on_a_real_config_and_the_same_config_with_another_file(tmp_path, capsys):
    import json

    from mbus_framework.cli import main

    cfg = ROOT / "configs" / "real" / "vw100a.yaml"
    assert main([str(cfg), "-o", str(tmp_path / "a"), "--no-plots"]) == 0
    out = capsys.readouterr().out
    assert "M0" in out and "Pa" in out and "No warnings" in out
    res = json.loads((tmp_path / "a" / "result.json").read_text())
    assert res["fits"][0]["passed"] and set(res["fits"][0]["dispersion"]) >= {
        "frequency_Hz", "phase_velocity_m_s", "attenuation_dB_per_cm", "phase_velocity_se_m_s"}
    other = str(DATA / "VW0.mat")
    assert main([str(cfg), "-o", str(tmp_path / "b"), "--no-plots", "--set", f"data={other}"]) == 0
    res = json.loads((tmp_path / "b" / "result.json").read_text())
    assert res["record"]["thickness_m"] == pytest.approx(2.64e-3) and res["fits"][0]["passed"]


def test_config_errors_are_one_line(tmp_path, capsys):
    from mbus_framework.cli import main

    cfg = tmp_path / "c.yaml"
    cfg.write_text("experiment: substitution\ndata: nowhere.mat\n")
    assert main([str(cfg)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "data: nowhere.mat: file not found" in err
    cfg.write_text(f"experiment: substitution\ndata: {DATA / 'VW0.mat'}\nlaw: maxwel\n")
    assert main([str(cfg)]) == 2
    assert "law: maxwel: choose from" in capsys.readouterr().err


def test_a_lumped_chain_converges_to_the_plate_it_spans():
    """The chain's transfer-matrix product (masses and links between water half-spaces)
    approaches the exact transmission of the continuous layer it spans, (n - 1) h / n thick
    (n masses, n - 1 links), with second-order discretisation error: x3 or better per 2.5x n."""
    from mbus_framework.substitution.chains import ChainLaw

    w = 2 * np.pi * np.linspace(0.5e6, 4e6, 30)
    water, rho, h = Water.at(20.0), 1185.0, 4e-3
    p = np.array([7e9, 16.0])
    M = LAWS["kelvin_voigt"].modulus(w, p, 1.0)
    k = wavenumber(M, w, rho)
    errors = []
    for n in (20, 50, 100):
        span = h * (n - 1) / n
        exact = transmission(k, rho * w / k, w / water.speed, water.impedance, span) * np.exp(1j * w / water.speed * (h - span))
        chain = ChainLaw("kv", LAWS["kelvin_voigt"], "kelvin_voigt", n).transmission(w, p, rho, h, water)
        errors.append(np.max(np.abs(chain - exact)))
    assert errors[1] < errors[0] / 3 and errors[2] < errors[1] / 3, errors


def test_chains_are_ranked_beside_the_laws_on_a_real_plate():
    a = analyse(read_mat(DATA / "VW100a.mat"), ["constant_q", "kelvin_voigt_chain"])
    assert [f.law.name for f in a.fits] == ["constant_q", "kelvin_voigt_chain"]
    assert not a.passed(a.fits[1])  # a Kelvin-Voigt chain's attenuation grows as f^2


def test_residual_structure_tells_white_from_structured_residuals():
    from mbus_framework.substitution.fit import residual_structure

    rng = np.random.default_rng(4)
    white = rng.normal(size=400) + 1j * rng.normal(size=400)
    smooth = np.convolve(white, np.ones(8) / 8, mode="same")  # a misfit that varies slowly with frequency
    assert residual_structure(white)["p_value"] > 0.01
    s = residual_structure(smooth)
    assert s["p_value"] < 1e-6 and s["lag1_correlation"] > 0.5


def test_compare_models_ranks_every_family_on_a_real_plate(tmp_path):
    import json
    import subprocess
    import sys

    out = tmp_path / "cmp"
    proc = subprocess.run([sys.executable, "-m", "mbus_framework.cli", str(ROOT / "configs" / "real" / "vw0.yaml"),
                           "--compare-models", "constant_q,fractional_zener,sls_chain,kelvin_voigt_chain",
                           "--out", str(out), "--no-plots"], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert "laws ranked by BIC" in proc.stdout
    rows = (out / "compare.csv").read_text().splitlines()
    ranked = [r.split(",")[0] for r in rows[1:]]
    assert sorted(ranked) == sorted(["constant_q", "fractional_zener", "sls_chain", "kelvin_voigt_chain"])
    assert ranked[-1] == "kelvin_voigt_chain"  # alpha ~ f^2 cannot follow a near-linear attenuation
    result = json.loads((out / "result.json").read_text())
    assert all({"lag1_correlation", "p_value"} <= set(f["residual_structure"]) for f in result["fits"])


def test_any_registered_chain_model_fits_a_real_plate_as_its_own_chain():
    """model:<name> builds the plate from the registered plugin's own masses and normal links:
    model:sls is the hand-wired sls_chain (same BIC), and a generalized Maxwell chain (two arms)
    describes the softer plate as well as the constant-Q law."""
    a = analyse(read_mat(DATA / "VW0.mat"), ["sls_chain", "model:sls", "model:generalized_maxwell", "constant_q"])
    by = {f.law.name: f for f in a.fits}
    assert by["model:sls"].bic == pytest.approx(by["sls_chain"].bic, abs=0.5)
    assert by["model:generalized_maxwell"].explained > 0.99 and a.passed(by["model:generalized_maxwell"])
    assert list(by["model:generalized_maxwell"].law.parameters)[:1] == ["E_sigma"]


def test_registered_models_the_experiment_cannot_use_are_one_line_errors(tmp_path):
    from mbus_framework.errors import ConfigError
    from mbus_framework.substitution.config import check_laws

    assert check_laws(["model:fractional_zener", "all"], "x.yaml")[:1] == ["kelvin_voigt"]
    for bad in ("model:layered", "model:no_such_model"):
        with pytest.raises(ConfigError, match=r"x.yaml: law: " + bad) as err:
            check_laws([bad], "x.yaml")
        assert "\n" not in str(err.value)
