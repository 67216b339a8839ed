"""What a substitution analysis publishes: result.json, dispersion.csv, dispersion.png and the
printed summary (properties with units and 95 % intervals, phase velocity and attenuation at the
band centre, the model against the model-free measurement, explained in-band energy)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from mbus_framework.substitution.analysis import SubstitutionAnalysis
from mbus_framework.substitution.fit import LawFit

#: A law explaining less of the sample shot's in-band energy than this gets a warning.
MIN_EXPLAINED = 0.95


def warnings_for(a: SubstitutionAnalysis) -> list[str]:
    """Warnings the user can act on; none on a law that explains the record."""
    out = []
    best = a.best
    if best.explained < MIN_EXPLAINED:
        out.append(
            f"{best.law.name} explains {100 * best.explained:.1f} % of the sample shot's in-band energy "
            f"(< {100 * MIN_EXPLAINED:.0f} %): try other laws (law: all) or check thickness, density and passes"
        )
    bad = [r for r in a.checks(best) if r.get("velocity_ok") is False or r.get("attenuation_ok") is False]
    if bad:
        where = ", ".join(f"{r['frequency_Hz'] / 1e6:g} MHz" for r in bad)
        out.append(f"{best.law.name} departs from the model-free phase velocity or attenuation at {where}: "
                   "its properties do not describe this record there (law: all ranks the others)")
    return out


def _fit_section(fit: LawFit, a: SubstitutionAnalysis) -> dict[str, Any]:
    lo_hi = fit.intervals()
    f0 = fit.w0 / (2 * np.pi)
    c0, a0 = fit.dispersion.at(f0)
    return {
        "law": fit.law.name,
        "properties": {
            name: {"value": float(v), "unit": unit, "se": float(se), "ci95": [float(lo), float(hi)]}
            for name, unit, v, se, (lo, hi) in zip(fit.law.parameters, fit.law.units, fit.values, fit.standard_errors, lo_hi)
        },
        "band_centre_Hz": f0,
        "phase_velocity_at_centre_m_s": c0,
        "attenuation_at_centre_dB_per_cm": a0,
        "explained_in_band_energy": fit.explained,
        "bic": fit.bic,
        "residual_structure": fit.structure,
        "nfev": fit.nfev,
        "solver_message": fit.status,
        "dispersion": {
            "frequency_Hz": fit.dispersion.f.tolist(),
            "phase_velocity_m_s": fit.dispersion.velocity.tolist(),
            "phase_velocity_se_m_s": fit.velocity_se.tolist(),
            "attenuation_dB_per_cm": fit.dispersion.attenuation_dB_per_cm.tolist(),
            "attenuation_se_dB_per_cm": (fit.attenuation_se * 20 / np.log(10) / 100).tolist(),
        },
        "model_free_check": a.checks(fit),
        "passed": a.passed(fit),
    }


def result_dict(a: SubstitutionAnalysis, title: str = "") -> dict[str, Any]:
    r = a.record
    mf = a.model_free
    return {
        "experiment": "substitution",
        "title": title,
        "source": r.source,
        "record": {"samples": int(r.reference.size), "dt_s": r.dt, "thickness_m": r.thickness,
                   "density_kg_m3": r.density, "water_temperature_C": r.temperature_C, "passes": r.passes},
        "water": {"speed_m_s": a.water.speed, "density_kg_m3": a.water.density},
        "band_Hz": [float(a.spectra.f[0]), float(a.spectra.f[-1])],
        "delay_s": a.spectra.delay,
        "model_free": {"frequency_Hz": mf.f.tolist(), "phase_velocity_m_s": mf.velocity.tolist(),
                       "attenuation_dB_per_cm": mf.attenuation_dB_per_cm.tolist()},
        "fits": [_fit_section(f, a) for f in a.fits],
        "best": a.best.law.name,
        "warnings": warnings_for(a),
    }


def summary(a: SubstitutionAnalysis, run_dir: Path | None = None) -> str:
    best = a.best
    r = a.record
    lines = [f"substitution: {Path(r.source).name}  plate {r.thickness * 1e3:.3f} mm, {r.density:g} kg/m^3, "
             f"water {r.temperature_C:g} deg C ({a.water.speed:.1f} m/s), {r.passes} pass(es)",
             f"band {a.spectra.f[0] / 1e6:.2f}-{a.spectra.f[-1] / 1e6:.2f} MHz ({a.spectra.f.size} lines)",
             f"law: {best.law.name}  (explains {100 * best.explained:.2f} % of the in-band energy)"]
    lines.append(f"  {'property':<9} {'value':>11} {'unit':<9} [95 % interval]")
    for name, unit, v, (lo, hi) in zip(best.law.parameters, best.law.units, best.values, best.intervals()):
        lines.append(f"  {name:<9} {v:11.4g} {unit:<9} [{lo:.4g}, {hi:.4g}]")
    c0, a0 = best.dispersion.at(best.w0 / (2 * np.pi))
    lines.append(f"at {best.w0 / 2 / np.pi / 1e6:.2f} MHz: phase velocity {c0:.1f} m/s, attenuation {a0:.2f} dB/cm")
    lines.append("  f [MHz]   c model  c model-free   alpha model  alpha model-free [dB/cm]")
    for row in a.checks(best):
        ok = row.get("velocity_ok", True) and row.get("attenuation_ok", True)
        lines.append(f"  {row['frequency_Hz'] / 1e6:6.2f}  {row['velocity_model']:8.1f}  {row['velocity_model_free']:12.1f}"
                     f"   {row['attenuation_model_dB_cm']:11.2f}  {row['attenuation_model_free_dB_cm']:16.2f}  {'ok' if ok else 'DIFFERS'}")
    if len(a.fits) > 1:
        lines += ranking_lines(a)
    w = warnings_for(a)
    lines += [f"WARNING: {x}" for x in w] or ["No warnings"]
    if run_dir is not None:
        lines.append(f"run folder: {run_dir}")
    return "\n".join(lines)


def ranking_lines(a: SubstitutionAnalysis) -> list[str]:
    """The laws ranked by BIC with the in-band energy they explain, the structure left in their
    residual (lag-1 correlation across lines, Ljung-Box p) and the model-free verdict."""
    width = max(18, *(len(f.law.name) for f in a.fits))
    out = ["laws ranked by BIC (lower is better; residual r1: lag-1 correlation across lines, 0 if white):",
           f"  {'law':<{width}} {'params':>6} {'BIC':>9} {'dBIC':>8} {'explains':>9} {'r1':>6}  model-free"]
    b0 = a.fits[0].bic
    for f in a.fits:
        out.append(f"  {f.law.name:<{width}} {len(f.values):>6} {f.bic:9.1f} {f.bic - b0:8.1f} {100 * f.explained:8.2f}% "
                   f"{f.structure.get('lag1_correlation', float('nan')):6.2f}  "
                   f"{'agrees' if a.passed(f) else 'departs'}")
    return out


def write_ranking_csv(a: SubstitutionAnalysis, path: Path) -> None:
    """compare.csv: one row per law, best BIC first."""
    head = "law,parameters,bic,delta_bic,explained_fraction,residual_lag1_correlation,ljung_box_p,agrees_with_model_free"
    rows = [head] + [
        f"{f.law.name},{len(f.values)},{f.bic:.6g},{f.bic - a.fits[0].bic:.6g},{f.explained:.6g},"
        f"{f.structure.get('lag1_correlation', float('nan')):.4g},{f.structure.get('p_value', float('nan')):.4g},"
        f"{a.passed(f)}" for f in a.fits]
    path.write_text("\n".join(rows) + "\n")


def write_dispersion_csv(a: SubstitutionAnalysis, path: Path) -> None:
    best = a.best
    head = "frequency_Hz,phase_velocity_m_s,phase_velocity_se_m_s,attenuation_dB_per_cm,attenuation_se_dB_per_cm," \
           "model_free_phase_velocity_m_s,model_free_attenuation_dB_per_cm"
    cols = np.column_stack([best.dispersion.f, best.dispersion.velocity, best.velocity_se,
                            best.dispersion.attenuation_dB_per_cm, best.attenuation_se * 20 / np.log(10) / 100,
                            a.model_free.velocity, a.model_free.attenuation_dB_per_cm])
    np.savetxt(path, cols, delimiter=",", header=head, comments="", fmt="%.8g")


def plot_dispersion(a: SubstitutionAnalysis, path: Path) -> None:
    """Phase velocity [m/s] and attenuation [dB/cm] against frequency [MHz]: each law's curve
    (95 % band for the best) over the model-free measurement."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(7, 6.5), sharex=True)
    f = a.model_free.f / 1e6
    ax1.plot(f, a.model_free.velocity, "k.", ms=4, label="model-free (spectral ratio)")
    ax2.plot(f, a.model_free.attenuation_dB_per_cm, "k.", ms=4, label="model-free (spectral ratio)")
    for i, fit in enumerate(a.fits):
        d = fit.dispersion
        ax1.plot(f, d.velocity, label=fit.law.name, lw=2 if i == 0 else 1)
        ax2.plot(f, d.attenuation_dB_per_cm, label=fit.law.name, lw=2 if i == 0 else 1)
        if i == 0:
            se_a = fit.attenuation_se * 20 / np.log(10) / 100
            ax1.fill_between(f, d.velocity - 1.96 * fit.velocity_se, d.velocity + 1.96 * fit.velocity_se, alpha=0.25)
            ax2.fill_between(f, d.attenuation_dB_per_cm - 1.96 * se_a, d.attenuation_dB_per_cm + 1.96 * se_a, alpha=0.25)
    ax1.set_ylabel("phase velocity [m/s]")
    ax2.set_ylabel("attenuation [dB/cm]")
    ax2.set_xlabel("frequency [MHz]")
    ax1.set_title(f"{Path(a.record.source).name}: dispersion")
    ax1.legend(fontsize=8)
    ax1.grid(alpha=0.3)
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write_html(a: SubstitutionAnalysis, path: Path, figure: Path | None) -> None:
    """report.html: the summary and, when drawn, the dispersion figure (embedded)."""
    import base64
    import html

    img = ""
    if figure is not None and figure.is_file():
        data = base64.b64encode(figure.read_bytes()).decode("ascii")
        img = f'<img alt="dispersion: phase velocity and attenuation against frequency" src="data:image/png;base64,{data}">'
    title = html.escape(Path(a.record.source).name)
    path.write_text(
        f"<!doctype html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>{title}: substitution</title></head>"
        f"<body><h1>{title}: substitution method</h1><pre>{html.escape(summary(a))}</pre>{img}</body></html>\n",
        encoding="utf-8",
    )
