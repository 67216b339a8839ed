"""Excitation design: the PRBS proposal for a transducer band (Section 3.4.4) and the D-optimal
ranking of candidate excitations (log det of the Fisher information)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from mbus_framework.compensation.filters import SpectralFilter
from mbus_framework.errors import ConfigError
from mbus_framework.estimation.problem import FitProblem
from mbus_framework.interfaces.sample import Sample
from mbus_framework.studies.design import (
    X_STAR,
    fisher_logdet,
    propose_prbs,
    rank_excitations,
    run_design,
)
from mbus_plugins.backends.transducers import TransducerPair, TransducerPairOptions
from mbus_plugins.excitations.prbs import Prbs, PrbsOptions
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions
from test_report import assert_folder_report

FS, N = 25e6, 5000
POTATO = {"E_sigma": 2.42e10, "eta_sigma": 7.18e3, "E_tau": 6.56e9, "eta_tau": 5.14e3}


def test_bit_width_maximises_the_prbs_density_at_the_top_of_the_band():
    assert np.tan(np.pi * X_STAR) == pytest.approx(2 * np.pi * X_STAR, rel=1e-4)
    f_hi = 0.7e6
    tb = np.linspace(0.05, 1.0, 20000) / f_hi
    density = tb * np.sinc(f_hi * tb) ** 2  # A^2 T_b sinc^2(f T_b), A = 1
    assert tb[np.argmax(density)] * f_hi == pytest.approx(X_STAR, abs=1e-4)
    p = propose_prbs((0.3e6, 0.7e6), FS, N)
    assert p.samples_per_bit == 13 and p.bit_width == pytest.approx(0.52e-6)
    assert p.order == 9 and p.period_samples == 511 * 13 >= N > 255 * 13  # no repeat within the record
    assert p.bandwidth_3db == pytest.approx(0.443 / 0.52e-6)
    assert p.density_at_f_hi_db == pytest.approx(20 * np.log10(np.sinc(0.7e6 * 0.52e-6)))
    # Fig. 3.7 setting 1 (6.25 MS/s, 6200 samples): 3 samples a bit (0.48 us); 2047 x 3 = 6141 < 6200
    # samples would repeat, so order 12.
    q = propose_prbs((0.3e6, 0.7e6), 6.25e6, 6200)
    assert q.samples_per_bit == 3 and q.order == 12


def prbs_waveform(k: int, order: int):
    return Prbs(PrbsOptions(order=order, bit_width=k / FS, sample_rate=FS, n_samples=N)).waveform()


@pytest.fixture(scope="module")
def potato():
    model = KelvinVoigtChain(Sample(0.03, 0.0254, 1080.0), KelvinVoigtOptions(n_elements=10))
    return model, model.from_properties(POTATO)


def test_band_matched_prbs_ranks_above_badly_matched_ones(potato):
    """Through the 0.5 MHz pair, a PRBS whose main lobe covers 0.3-0.7 MHz carries more
    information than one with 8x longer bits (first null at 0.24 MHz, below the band) or one
    spreading its power to 3.5 MHz with 4x shorter bits."""
    model, theta = potato
    pair = TransducerPair(TransducerPairOptions())
    rig = SpectralFilter(pair.response)
    cands = [("matched", "prbs", {}, prbs_waveform(13, 9)), ("long bits", "prbs", {}, prbs_waveform(104, 6)),
             ("short bits", "prbs", {}, prbs_waveform(3, 11))]
    ranked = rank_excitations(model, theta, cands, 1e-4, (0.34e6, 0.74e6), rig)
    order = [r.label for r in ranked]
    assert order.index("matched") < order.index("long bits")
    assert order.index("matched") < order.index("short bits")
    top = ranked[0]
    assert top.efficiency == 1.0 and all(r.efficiency < 1 for r in ranked[1:])
    assert 0 < ranked[-1].efficiency < 0.5
    assert {r.label: r.band_power_fraction for r in ranked}["long bits"] < 0.1


def test_logdet_shifts_by_minus_2p_log_sigma_and_matches_the_cramer_rao_bound(potato):
    model, theta = potato
    w = prbs_waveform(10, 9)
    problem = FitProblem(model=model, t=w.t, u=w.u, y=np.zeros(N))
    a, rse_a = fisher_logdet(problem, theta, 1e-4)
    b, rse_b = fisher_logdet(problem, theta, 2e-4)
    assert b - a == pytest.approx(-2 * 4 * np.log(2), rel=1e-9)
    np.testing.assert_allclose(rse_b, 2 * rse_a, rtol=1e-9)
    # The relative SEs are the Cramer-Rao bound: sqrt(diag((J^T J)^-1)) sigma / theta.
    _, J = problem.predict_with_jacobian(theta)
    crb = np.sqrt(np.diag(np.linalg.inv(J.T @ J))) * 1e-4 / theta
    np.testing.assert_allclose(rse_a, crb, rtol=1e-6)


def write_config(tmp_path: Path, **extra) -> Path:
    cfg = yaml.safe_load(Path("configs/potato_compensated.yaml").read_text())
    cfg["compensator"] = {"name": "none"}
    cfg["output"] = {"directory": str(tmp_path / "runs"), "plots": True}
    cfg.update(extra)
    path = tmp_path / "potato.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def test_design_run_prints_the_ranking_and_plots_the_spectra(tmp_path):
    out = tmp_path / "design"
    text = run_design(write_config(tmp_path), [], out)
    assert "proposed PRBS: bit width 0.52 us (13 samples), order 9" in text
    assert "the rig's virtual pair" in text and "band 0.339-0.738 MHz" in text
    result = json.loads((out / "design.json").read_text())
    labels = [r["label"] for r in result["ranking"]]
    assert len(labels) == 9 and labels[0].startswith("prbs")
    rank = {lab.split(" (")[0]: i for i, lab in enumerate(labels)}
    assert rank["prbs proposed"] < rank["prbs x8 bit width"]
    assert rank["prbs proposed"] < rank["prbs x0.5 bit width"]
    assert (out / "design_spectra.png").stat().st_size > 20_000
    assert_folder_report(out, 1, "proposed PRBS: bit width 0.52 us (13 samples), order 9")
    assert result["nominal_source"] == "backend truth"


def test_design_options_from_the_yaml_and_from_set(tmp_path):
    cfg = write_config(tmp_path, design={"band": [0.2e6, 0.5e6], "noise_std": 1e-4,
                                         "candidates": [{"label": "A", "name": "prbs", "options": {"bit_width": 0.4e-6}},
                                                        {"label": "B", "name": "sine_sweep",
                                                         "options": {"f_start": 0.2e6, "f_stop": 0.5e6}}]})
    text = run_design(cfg, ["design.band=[0.25e6, 0.5e6]"], tmp_path / "d")
    assert "band 0.250-0.500 MHz (design.band)" in text and "noise std 0.0001 (design.noise_std)" in text
    result = json.loads((tmp_path / "d" / "design.json").read_text())
    assert sorted(r["label"] for r in result["ranking"]) == ["A", "B"]
    with pytest.raises(ConfigError, match="design.bnad: unknown key; did you mean 'band'"):
        run_design(cfg, ["design.bnad=[1, 2]"], tmp_path / "e")
    with pytest.raises(ConfigError, match="Nyquist"):
        run_design(cfg, ["design.band=[1e6, 20e6]"], tmp_path / "e")
    with pytest.raises(ConfigError, match=r"design.candidates.0.options.bit_widht"):
        run_design(cfg, ["design.candidates=[{name: prbs, options: {bit_widht: 1.0e-6}}]"], tmp_path / "e")


def test_design_without_transducers_uses_the_default_band(tmp_path):
    cfg = yaml.safe_load(Path("configs/potato.yaml").read_text())
    cfg["output"] = {"directory": str(tmp_path / "runs"), "plots": False}
    path = tmp_path / "plain.yaml"
    path.write_text(yaml.safe_dump(cfg))
    text = run_design(path, [], tmp_path / "d")
    assert "band 0.300-0.700 MHz (default" in text and "medium model only" in text


def test_cli_design_excitation(tmp_path, capsys):
    from mbus_framework.cli import main

    assert main([str(write_config(tmp_path)), "--design-excitation", "-o", str(tmp_path / "cli"), "--set",
                 "output.plots=false"]) == 0
    assert "D-eff" in capsys.readouterr().out
