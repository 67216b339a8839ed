"""Excitation design (Section 3.4.4, Fig. 3.7): propose a PRBS for a transducer band and rank
candidate excitations by D-optimality.

PRBS proposal
-------------
At a fixed amplitude A a PRBS of bit width T_b has the power density A^2 T_b sinc^2(f T_b)
(a line spectrum on this envelope). The density at the top of the band, f_hi, is largest for
f_hi T_b = x* with tan(pi x*) = 2 pi x*, x* = 0.3710 (the band then lies inside the main lobe,
-2.1 dB at f_hi). The proposal rounds T_b = x* / f_hi to whole samples of the record,
T_b = k / f_s, and takes the smallest order n with (2^n - 1) k >= n_samples, so the sequence
does not repeat within the record (the dissertation's 0.4 us bits, order 9, at 25 MS/s for
5000 samples follow the same logic).

D-optimal ranking
-----------------
For each candidate u (same record length, sample rate and peak amplitude as the configured
excitation: the generator's range is the constraint) the Fisher information at nominal
parameters theta_0 is

    F = J^T J / sigma^2,     J = d yhat / d ln(theta)  (N x p),

with yhat the model output through the rig's transducer pair when it has one (the backend's
virtual pair, or a calibration's G_TR), from ``FitProblem(...).predict_with_jacobian``. The
candidates are ranked by log det F (D-optimality: the smallest joint confidence region); the
D-efficiency of a candidate relative to the best is exp((log det F - log det F_best) / p), and
sqrt(diag F^-1) are its Cramer-Rao relative standard errors. Log-parameters make F
dimensionless; the ranking does not depend on that choice or on sigma.

Options come from an optional ``design:`` mapping (in the YAML or ``--set design.key=value``),
removed before the run config is validated:

    design:
      band: [0.3e6, 0.7e6]      # Hz (default: the rig's pair -6 dB band, else 0.3-0.7 MHz)
      nominal: {...}            # parameters or properties (default: backend truth, then model.initial)
      noise_std: 1.0e-3         # output noise std (default: from the backend's noise options)
      calibration: path.npz     # G_TR to put in the path (default: the rig's pair, or the
                                # transfer_function compensator's calibration)
      candidates:               # default: configured, proposed PRBS and bit-width ladder, sweeps, multisine
        - {label: my prbs, name: prbs, options: {bit_width: 0.4e-6, order: 9}}
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from mbus_framework.errors import ConfigError

#: Root of tan(pi x) = 2 pi x: f_hi T_b maximising the PRBS density T_b sinc^2(f_hi T_b).
X_STAR = 0.37101


class CandidateRef(BaseModel):
    model_config = ConfigDict(extra="forbid")
    label: str | None = None
    name: str
    options: dict[str, Any] = Field(default_factory=dict)


class DesignOptions(BaseModel):
    """The optional ``design:`` section (see the module docstring)."""

    model_config = ConfigDict(extra="forbid")
    band: list[float] | None = Field(None, description="transducer band [f_lo, f_hi] Hz")
    nominal: dict[str, float] | None = Field(None, description="nominal parameters or properties")
    noise_std: float | None = Field(None, gt=0, description="output noise std")
    calibration: str | None = Field(None, description="calibration file whose G_TR is put in the path")
    candidates: list[CandidateRef] | None = Field(None, description="excitations to rank (default: a standard set)")

    @model_validator(mode="after")
    def _band(self):
        if self.band is not None and (len(self.band) != 2 or not 0 <= self.band[0] < self.band[1]):
            raise ValueError("band: expected [f_lo, f_hi] with 0 <= f_lo < f_hi (Hz)")
        return self


@dataclass
class PrbsProposal:
    bit_width: float
    samples_per_bit: int
    order: int
    period_samples: int
    bandwidth_3db: float
    density_at_f_hi_db: float  # relative to the envelope maximum (f -> 0)

    def options(self, sample_rate: float, n_samples: int, amplitude: float) -> dict:
        return {
            "order": self.order,
            "bit_width": self.bit_width,
            "sample_rate": sample_rate,
            "n_samples": n_samples,
            "amplitude": amplitude,
        }


def propose_prbs(band: tuple[float, float], sample_rate: float, n_samples: int) -> PrbsProposal:
    """Bit width and order for a PRBS covering ``band`` (see the module docstring)."""
    f_hi = band[1]
    k = max(1, int(round(X_STAR * sample_rate / f_hi)))
    return prbs_for_samples_per_bit(k, sample_rate, n_samples, f_hi)


def prbs_for_samples_per_bit(k: int, sample_rate: float, n_samples: int, f_hi: float) -> PrbsProposal:
    order = next((n for n in range(3, 21) if (2**n - 1) * k >= n_samples), 20)
    tb = k / sample_rate
    return PrbsProposal(
        bit_width=tb,
        samples_per_bit=k,
        order=order,
        period_samples=(2**order - 1) * k,
        bandwidth_3db=0.443 / tb,
        density_at_f_hi_db=float(20 * np.log10(abs(np.sinc(f_hi * tb)))),
    )


@dataclass
class Ranked:
    label: str
    name: str
    options: dict
    logdet: float
    relative_se: dict[str, float]
    crest_factor: float
    band_power_fraction: float
    rms: float
    spectrum: tuple[np.ndarray, np.ndarray] = field(repr=False, default=None)
    efficiency: float = 1.0


def fisher_logdet(problem, theta: np.ndarray, sigma: float) -> tuple[float, np.ndarray]:
    """(log det F, Cramer-Rao relative SEs) with F = J^T J / sigma^2, J w.r.t. ln(theta)."""
    _, J = problem.predict_with_jacobian(theta)
    Jl = J * theta[None, :]
    F = Jl.T @ Jl / sigma**2
    sign, logdet = np.linalg.slogdet(F)
    if sign <= 0 or not np.isfinite(logdet):
        return -np.inf, np.full(theta.size, np.inf)
    return float(logdet), np.sqrt(np.clip(np.diag(np.linalg.pinv(F)), 0, None))


def rank_excitations(
    model,
    theta: np.ndarray,
    waveforms: list[tuple[str, str, dict, Any]],
    sigma: float,
    band: tuple[float, float],
    rig_filter: Callable | None = None,
    hold: str = "zoh",
) -> list[Ranked]:
    """Rank (label, plugin name, options, Waveform) by log det of the Fisher information."""
    from mbus_framework.estimation.problem import FitProblem
    from mbus_framework.interfaces.excitation import crest_factor, power_spectrum

    out = []
    for label, name, options, w in waveforms:
        problem = FitProblem(model=model, t=w.t, u=w.u, y=np.zeros_like(w.u), hold=hold, output_filter=rig_filter)
        logdet, rse = fisher_logdet(problem, theta, sigma)
        spec = power_spectrum(w.u, w.dt)
        inband = (spec.f >= band[0]) & (spec.f <= band[1])
        out.append(
            Ranked(
                label=label,
                name=name,
                options=options,
                logdet=logdet,
                relative_se=dict(zip(model.parameter_names, map(float, rse))),
                crest_factor=crest_factor(w.u),
                band_power_fraction=float(spec.power[inband].sum() / spec.power.sum()),
                rms=float(np.sqrt(np.mean(w.u**2))),
                spectrum=(spec.f, spec.power),
            )
        )
    out.sort(key=lambda r: -r.logdet)
    p = theta.size
    best = out[0].logdet
    for r in out:
        r.efficiency = float(math.exp((r.logdet - best) / p)) if np.isfinite(r.logdet) else 0.0
    return out


def _split_design(config_path, overrides) -> tuple[dict, DesignOptions]:
    from mbus_framework.pipeline.config import (
        apply_overrides,
        read_yaml,
        validate_options,
    )

    data = apply_overrides(read_yaml(config_path), overrides or [])
    raw = data.pop("design", None)
    return data, validate_options(DesignOptions, raw or {}, "design", str(config_path))


def default_candidates(c, proposal: PrbsProposal, band, fs: float, n: int, amplitude: float) -> list[CandidateRef]:
    """The configured excitation, the proposed PRBS, a bit-width ladder around it, two sweeps
    and a Schroeder multisine over the band."""
    cands = [CandidateRef(label=f"configured ({c.config.excitation.name})", name=c.config.excitation.name,
                          options=dict(c.config.excitation.options))]
    k0 = proposal.samples_per_bit
    for factor in (1, 0.5, 2, 4, 8):
        k = max(1, int(round(k0 * factor)))
        pp = prbs_for_samples_per_bit(k, fs, n, band[1])
        tag = "proposed" if factor == 1 else f"x{factor:g} bit width"
        cands.append(CandidateRef(label=f"prbs {tag} ({pp.bit_width * 1e6:.3g} us, order {pp.order})",
                                  name="prbs", options=pp.options(fs, n, amplitude)))
    common = {"sample_rate": fs, "n_samples": n, "amplitude": amplitude}
    cands.append(CandidateRef(label="linear sweep over the band", name="sine_sweep",
                              options={"kind": "linear", "f_start": band[0], "f_stop": band[1], "taper": 0.05, **common}))
    cands.append(CandidateRef(label="log sweep over the band", name="sine_sweep",
                              options={"kind": "log", "f_start": max(band[0], 1.0), "f_stop": band[1], "taper": 0.05, **common}))
    cands.append(CandidateRef(label="Schroeder multisine over the band", name="multisine",
                              options={"f_min": band[0], "f_max": band[1], **common}))
    return cands


def run_design(config_path, overrides=None, out_dir=None) -> str:
    """``mbus-run CONFIG --design-excitation``: print the ranking, write design.json and the spectra plot."""
    from mbus_framework.pipeline.config import validate_options, validate_structure
    from mbus_framework.pipeline.components import require_excitation
    from mbus_framework.pipeline.run import build_components, new_run_dir
    from mbus_framework.pipeline.folder_report import write_folder_report
    from mbus_framework.pipeline.storage import atomic_write_json

    source = str(config_path)
    data, d = _split_design(config_path, overrides)
    config = validate_structure(data, source)
    c = build_components(config, source)
    ref = require_excitation(c, "--design-excitation").waveform()
    fs, n = ref.sample_rate, len(ref.u)
    amplitude = float(np.max(np.abs(ref.u)))

    pair = getattr(c.backend, "pair", None)
    if d.band is not None:
        band, band_source = (float(d.band[0]), float(d.band[1])), "design.band"
    elif pair is not None:
        band, band_source = pair.band(), "the rig's transducer pair (-6 dB)"
    else:
        band, band_source = (0.3e6, 0.7e6), "default design band (no transducers in the config)"
    if band[1] >= fs / 2:
        raise ConfigError(f"{source}: design.band: {band[1]:g} Hz is above the Nyquist frequency {fs / 2:g} Hz")

    theta, nominal_source = _nominal(c, d, source)
    rig_filter, rig_text, rig_response = _rig(c, d, source)
    sigma, sigma_source = _noise(c, d, theta, ref, rig_filter)

    proposal = propose_prbs(band, fs, n)
    refs = d.candidates or default_candidates(c, proposal, band, fs, n, amplitude)
    waveforms = []
    for i, cand in enumerate(refs):
        where = f"design.candidates.{i}"
        spec = c.registry.get("excitation", cand.name)
        options = dict(cand.options)
        if d.candidates is not None:  # the user's candidates share the record unless they say otherwise
            options.setdefault("sample_rate", fs)
            if cand.name != "from_file":
                options.setdefault("n_samples", n)
        opts = validate_options(spec.implementation.Options, options, f"{where}.options", source)
        w = spec.implementation(opts).waveform()
        if len(w.u) != n or abs(w.sample_rate - fs) > 1e-9 * fs:
            raise ConfigError(f"{source}: {where}: record must match the configured one ({n} samples at {fs:g} Hz)")
        waveforms.append((cand.label or cand.name, cand.name, options, w))

    ranked = rank_excitations(c.model, theta, waveforms, sigma, band, rig_filter, config.model.hold)
    out = Path(out_dir) if out_dir else Path(str(new_run_dir(config, source)) + "-design")
    out.mkdir(parents=True, exist_ok=True)
    files = []
    if config.output.plots:
        files.append(plot_spectra(out, ranked, band, rig_response, fs, band_label(band_source)))
    result = {
        "config": source,
        "band_hz": list(band),
        "band_source": band_source,
        "nominal": dict(zip(c.model.parameter_names, map(float, theta))),
        "nominal_source": nominal_source,
        "noise_std": sigma,
        "noise_source": sigma_source,
        "rig_path": rig_text,
        "record": {"n_samples": n, "sample_rate_hz": fs, "peak_amplitude": amplitude},
        "proposed_prbs": proposal.__dict__,
        "ranking": [
            {k: v for k, v in r.__dict__.items() if k != "spectrum"} for r in ranked
        ],
        "files": files,
    }
    atomic_write_json(out / "design.json", result)
    text = design_text(result, ranked, c.model.parameter_names, out, files)
    write_folder_report(out, "mbus excitation design", text, source)
    return text


def _nominal(c, d: DesignOptions, source: str) -> tuple[np.ndarray, str]:
    if d.nominal:
        return c.model.theta_from_mapping(d.nominal, f"{source}: design.nominal"), "design.nominal"
    truth = getattr(c.backend.options, "truth", None)
    if truth:
        return c.model.theta_from_mapping(truth, f"{source}: backend.options.truth"), "backend truth"
    if c.config.model.initial:
        return c.model.theta_from_mapping(c.config.model.initial, f"{source}: model.initial"), "model.initial"
    raise ConfigError(f"{source}: design.nominal: give nominal parameters (no backend truth or model.initial)")


def _rig(c, d: DesignOptions, source: str):
    """(output filter or None, description, |G_TR| function for the plot or None)."""
    from mbus_framework.compensation.calibration_file import load_calibration
    from mbus_framework.compensation.filters import SpectralFilter as spectral

    if d.calibration:
        cal = load_calibration(d.calibration)
        resp = lambda f: cal.response(f, extend=True)  # noqa: E731
        return spectral(resp), f"calibration {d.calibration} ({cal.meta.get('pair', '?')})", resp
    pair = getattr(c.backend, "pair", None)
    if pair is not None:
        return spectral(pair.response), f"the rig's virtual pair '{pair.name}'", pair.response
    cal_path = getattr(c.compensator.options, "calibration", None)
    if isinstance(cal_path, str):
        cal = load_calibration(cal_path)
        resp = lambda f: cal.response(f, extend=True)  # noqa: E731
        return spectral(resp), f"compensator calibration {cal_path}", resp
    return None, "medium model only (no transducer response known)", None


def _noise(c, d: DesignOptions, theta, ref, rig_filter) -> tuple[float, str]:
    if d.noise_std:
        return float(d.noise_std), "design.noise_std"
    noise = getattr(c.backend.options, "noise", None)
    if noise is not None and getattr(noise, "absolute_std", None):
        return float(noise.absolute_std), "backend absolute_std"
    if noise is not None and getattr(noise, "relative_std", 0) > 0:
        from mbus_framework.estimation.problem import FitProblem

        p = FitProblem(model=c.model, t=ref.t, u=ref.u, y=np.zeros_like(ref.u), output_filter=rig_filter,
                       hold=c.config.model.hold)
        y = p.predict(theta)
        return float(noise.relative_std * np.sqrt(np.mean(y**2))), "backend relative_std x RMS(configured output)"
    return 1.0, "unit (ranking only)"


def design_text(result: dict, ranked: list[Ranked], names: list[str], out: Path, files: list[str]) -> str:
    pp = result["proposed_prbs"]
    lo, hi = result["band_hz"]
    rec = result["record"]
    lines = [
        f"excitation design: band {lo / 1e6:.3f}-{hi / 1e6:.3f} MHz ({result['band_source']}); "
        f"nominal from {result['nominal_source']}; path: {result['rig_path']}",
        f"  record: {rec['n_samples']} samples at {rec['sample_rate_hz'] / 1e6:g} MS/s, peak amplitude "
        f"{rec['peak_amplitude']:g}; noise std {result['noise_std']:.3g} ({result['noise_source']})",
        f"  proposed PRBS: bit width {pp['bit_width'] * 1e6:.3g} us ({pp['samples_per_bit']} samples), order "
        f"{pp['order']} (period {pp['period_samples']} samples), -3 dB bandwidth {pp['bandwidth_3db'] / 1e6:.3f} MHz, "
        f"density at {hi / 1e6:.2f} MHz {pp['density_at_f_hi_db']:.1f} dB",
        "",
        f"  {'rank':>4}  {'candidate':<40} {'log det F':>10} {'D-eff':>6} {'crest':>6} {'in band':>7}  "
        + " ".join(f"{'SE ' + n:>11}" for n in names),
    ]
    for i, r in enumerate(ranked, 1):
        lines.append(
            f"  {i:>4}  {r.label[:40]:<40} {r.logdet:>10.2f} {r.efficiency:>6.3f} {r.crest_factor:>6.2f} "
            f"{100 * r.band_power_fraction:>6.1f}%  "
            + " ".join(f"{100 * r.relative_se[n]:>10.3g}%" for n in names)
        )
    lines.append("")
    lines.append("  (D-eff: D-efficiency vs the best; SE: Cramer-Rao relative standard errors; in band: power fraction)")
    lines.append(f"  written: {out / 'design.json'}" + "".join(f", {out / f}" for f in files))
    return "\n".join(lines)


def band_label(band_source: str) -> str:
    """Legend of the shaded band: a transducer band only when the band comes from transducers."""
    if "transducer" in band_source and "no transducers" not in band_source:
        return "transducer band"
    if band_source == "design.band":
        return "design.band"
    return "design band (default; no transducers)"


def plot_spectra(out: Path, ranked: list[Ranked], band, rig_response, fs: float,
                 band_text: str = "transducer band") -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8.5, 5))
    fmax = min(3 * band[1], fs / 2)
    for i, r in enumerate(ranked):
        f, p = r.spectrum
        sel = (f > 0) & (f <= fmax)
        smooth = np.convolve(p, np.ones(9) / 9, mode="same")
        ax.plot(f[sel] / 1e6, 10 * np.log10(np.maximum(smooth[sel], 1e-30)), lw=1.0 if i else 1.8,
                label=f"{i + 1}. {r.label} (D-eff {r.efficiency:.2f})")
    ax.axvspan(band[0] / 1e6, band[1] / 1e6, color="0.9", zorder=0, label=band_text)
    top = max(10 * np.log10(np.max(r.spectrum[1])) for r in ranked)
    if rig_response is not None:
        f = np.linspace(0, fmax, 800)[1:]
        ax.plot(f / 1e6, top + 20 * np.log10(np.maximum(np.abs(rig_response(f)), 1e-12)), "k--", lw=1,
                label="|G_TR| (dB, shifted)")
    ax.set_ylim(top - 50, top + 12)
    ax.set_xlabel("frequency [MHz]")
    ax.set_ylabel("power density [dB re 1 u^2/Hz]")
    ax.set_title("candidate excitations (same record and peak amplitude), ranked by D-optimality")
    ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    fig.savefig(out / "design_spectra.png", dpi=110)
    plt.close(fig)
    return "design_spectra.png"
