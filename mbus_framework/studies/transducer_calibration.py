"""Transducer-pair calibration run (Chapter 5): measure a reference medium at several lengths.

A calibration run (``mbus-run configs/water_calibration.yaml``) measures every length through
the configured backend, saves every record (``records/length_XX.XXXmm.csv`` + ``.json``) before
estimating anything, writes the calibration file (NPZ arrays + JSON sidecar with frequency grid,
pair identity, reference medium, date, band) and the figures ``fig5_3_gtot.png`` and
``fig5_4_gtr.png``.

The estimation itself (eqs. 5.1-5.4) is in :mod:`mbus_framework.compensation.transfer`.
"""
from __future__ import annotations

import datetime as _dt
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from mbus_framework.compensation.calibration_file import save_calibration
from mbus_framework.compensation.transfer import (
    TransferEstimate,
    compare_with_truth,
    estimate_transfer,
    unwrap_from,
)
from mbus_framework.errors import ConfigError

DEFAULT_LENGTHS = [0.0, 0.005, 0.010, 0.015, 0.020, 0.025]


class CalibrationOptions(BaseModel):
    """The config's top-level ``calibration:`` section."""

    model_config = ConfigDict(extra="forbid")
    lengths: list[float] = Field(
        default_factory=lambda: list(DEFAULT_LENGTHS), description="reference-medium lengths [m] (0 allowed)"
    )
    reference: str = Field("water", description="name of the reference medium (recorded in the file)")
    pair: str | None = Field(None, description="transducer pair identity (default: the backend's, if it knows)")
    output: str | None = Field(
        None, description="calibration file to write (.npz, JSON sidecar beside it); default <run_dir>/calibration.npz"
    )
    band: list[float] | None = Field(
        None, description="[f_lo, f_hi] Hz to report and check (default: the rig's pair band, else 0.3-0.7 MHz)"
    )
    analysis: Literal["auto", "periodic", "transient"] = Field(
        "auto", description="periodic: steady-state periods (>= 2 whole periods needed); auto picks it when possible"
    )
    max_log_se: float = Field(0.05, gt=0, description="reliable where SE(ln|G_TR|) [Np] and SE(arg G_TR) [rad] are below")
    floor_db: float = Field(-40.0, lt=0, description="reliable only where |G_TR| is within this of its peak [dB]")

    @model_validator(mode="after")
    def _check(self):
        if len(self.lengths) < 2:
            raise ValueError("lengths: give at least two lengths")
        if any(x < 0 for x in self.lengths):
            raise ValueError("lengths: must be >= 0 (metres)")
        if len(set(self.lengths)) != len(self.lengths):
            raise ValueError("lengths: must be distinct")
        if self.band is not None and (len(self.band) != 2 or not 0 <= self.band[0] < self.band[1]):
            raise ValueError("band: expected [f_lo, f_hi] with 0 <= f_lo < f_hi (Hz)")
        return self


# ---------------------------------------------------------------------------------------------
# The calibration run
# ---------------------------------------------------------------------------------------------
def parse_options(raw: dict | None, source: str) -> CalibrationOptions:
    from mbus_framework.pipeline.config import validate_options

    return validate_options(CalibrationOptions, raw or {}, "calibration", source)


def _period_samples(info: dict, n: int, analysis: str, source: str) -> int | None:
    p = info.get("period_samples")
    whole = p is not None and abs(p - round(p)) < 1e-6 and round(p) >= 4 and n >= 2 * round(p)
    if analysis == "periodic" and not whole:
        raise ConfigError(
            f"{source}: calibration.analysis: periodic needs an excitation with an integer number of samples "
            f"per period and at least two periods (e.g. prbs with periods: 2)"
        )
    if analysis == "transient" or not whole:
        return None
    return int(round(p))


def _record_name(length: float) -> str:
    return f"length_{length * 1e3:06.3f}mm"


def run_calibration(config_path, overrides=None, out_dir=None, progress=None, overwrite=False) -> str:
    """Measure the reference medium at every length, estimate G_TR and gamma, save and plot.

    Returns a readable summary. Files go to ``out_dir`` (default: a new run folder, reserved
    as every run's is); an existing ``calibration.output`` file is replaced only with ``overwrite``.
    """
    from mbus_framework.pipeline import limits
    from mbus_framework.pipeline.components import require_excitation
    from mbus_framework.pipeline.config import load_config
    from mbus_framework.pipeline.run import build_components
    from mbus_framework.pipeline.run_folder import RunFolder

    source = str(config_path)
    config = load_config(config_path, overrides)
    opts = parse_options(config.calibration, source)
    if opts.output:
        try:
            targets = [Path(opts.output).with_suffix(s) for s in (".npz", ".json")]
            present = [p for p in targets if p.exists() or p.is_symlink()]
        except (OSError, ValueError) as exc:
            raise ConfigError(f"{source}: calibration.output: not a usable file name ({type(exc).__name__}: "
                              f"{str(exc)[:80]})") from None
        if present and not overwrite:
            raise ConfigError(f"{source}: calibration.output: {present[0]} exists; pass --overwrite to replace it")
    c = build_components(config, source)
    if config.backend.name == "simulated" and getattr(c.backend.options, "wave", None) is None:
        raise ConfigError(
            f"{source}: calibration: the simulated rig needs backend.options.wave (a reference propagation path)"
        )
    require_excitation(c, "a calibration run")
    waveform = limits.checked_waveform(c)
    period = _period_samples(waveform.info, len(waveform.u), opts.analysis, source)
    with RunFolder.create(out_dir, parent=config.output.directory, source=source, overwrite=overwrite) as folder:
        return _calibrate(config, opts, c, waveform, period, folder.path, source, progress)


def _calibrate(config, opts, c, waveform, period, run_dir: Path, source: str, progress) -> str:
    """The measurements, the estimate and the files of :func:`run_calibration`."""
    import yaml

    from mbus_framework.interfaces.backend import AcquisitionContext
    from mbus_framework.interfaces.sample import Sample
    from mbus_framework.pipeline.folder_report import write_folder_report
    from mbus_framework.pipeline.storage import (
        atomic_write_json,
        atomic_write_text,
        write_waveforms,
    )

    atomic_write_text(run_dir / "config.yaml", yaml.safe_dump(config.model_dump(mode="json"), sort_keys=False))

    lengths = sorted(opts.lengths)
    if progress:
        progress.start("calibration: measuring the reference", total=len(lengths))
    records, files = [], []
    try:
        for j, length in enumerate(lengths):
            sample = Sample(length, config.sample.diameter, config.sample.density)
            name = _record_name(length)
            context = AcquisitionContext(waveform, sample, c.model, c.registry, run_dir / "records" / name, source)
            m = _backend_for_record(c.backend, j).acquire(context)
            write_waveforms(run_dir / "records" / f"{name}.csv", m.t, m.u, m.y)
            atomic_write_json(run_dir / "records" / f"{name}.json", {"length_m": length, "meta": m.meta, "dt_s": m.dt})
            records.append((m.t, m.u, m.y))
            files.append(f"records/{name}.csv")
            if progress:
                progress.advance(1, f"{length * 1e3:g} mm")
    finally:
        if progress:
            progress.stop()

    pair_name = opts.pair or _backend_pair(c.backend) or "unnamed transducer pair"
    band = tuple(opts.band) if opts.band else _default_band(c.backend)
    est = estimate_transfer(
        records, lengths, config.model.hold, period, opts.max_log_se, opts.floor_db, band
    )
    if not np.any((est.f >= band[0]) & (est.f <= band[1])):
        raise ConfigError(f"{source}: calibration.band: {band[0]:g}-{band[1]:g} Hz holds no frequency line of the "
                          f"records ({est.f.size} lines up to {est.f.max(initial=0):g} Hz); widen the band or "
                          f"lengthen the record")
    truth = getattr(c.backend, "true_transducer_response", None)
    check = compare_with_truth(est.f, est.G_TR, truth(est.f), band) if truth else None
    meta = {
        "pair": pair_name,
        "reference": opts.reference,
        "date": _dt.datetime.now().astimezone().isoformat(timespec="seconds"),
        "lengths_m": lengths,
        "band_hz": list(band),
        "reliable_band_hz": list(est.reliable_band),
        "pivot_hz": est.pivot_hz,
        "sample_rate_hz": 1.0 / float(records[0][0][1] - records[0][0][0]),
        "analysis": "periodic" if period else "transient",
        "period_samples": period,
        "hold": config.model.hold,
        "n_lines": int(est.f.size),
        "n_reliable_lines": int(est.reliable.sum()),
        "reference_sound_speed_m_s": est.sound_speed(band),
        "delays_s": est.delays_s.tolist(),
        "excitation": {"name": config.excitation.name, **{k: v for k, v in waveform.info.items() if _scalar(v)}},
        "backend": config.backend.name,
        "config": source,
        "run_dir": str(run_dir),
        "records": files,
        "check_against_true_response": check,
    }
    outputs = [save_calibration(run_dir / "calibration.npz", est, meta)]
    if opts.output:
        outputs.append(save_calibration(opts.output, est, meta))
    plots = []
    if config.output.plots:
        plots = write_calibration_plots(run_dir, est, band, truth, pair_name)
    atomic_write_json(run_dir / "calibration_summary.json", {**meta, "files": [str(p) for o in outputs for p in o] + plots})
    text = summary_text(meta, est, outputs, plots)
    write_folder_report(run_dir, "mbus transducer calibration", text, source)
    return text


def _backend_for_record(backend, j: int):
    """A virtual rig with a ``seed`` gets seed + j for record j: independent noise per length,
    as separate lab measurements have."""
    seed = getattr(backend.options, "seed", None)
    if j == 0 or not isinstance(seed, int):
        return backend
    return type(backend)(backend.options.model_copy(update={"seed": seed + j}))


def _scalar(v) -> bool:
    return isinstance(v, (int, float, str, bool)) or v is None


def _backend_pair(backend) -> str | None:
    ident = getattr(backend, "transducer_identity", None)
    return ident() if callable(ident) else None


def _default_band(backend) -> tuple[float, float]:
    pair = getattr(backend, "pair", None)
    if pair is not None and hasattr(pair, "band"):
        return pair.band()
    return (0.3e6, 0.7e6)


def summary_text(meta: dict, est: TransferEstimate, outputs, plots) -> str:
    lo, hi = meta["band_hz"]
    rlo, rhi = meta["reliable_band_hz"]
    sel = (est.f >= lo) & (est.f <= hi)
    lines = [
        f"transducer calibration: {meta['pair']} with {meta['reference']} ({meta['backend']} backend)",
        f"  lengths [mm]: {', '.join(f'{x * 1e3:g}' for x in meta['lengths_m'])}  "
        f"({meta['analysis']} analysis, {meta['n_lines']} lines, hold {meta['hold']})",
        f"  reliable band: {rlo / 1e6:.3f}-{rhi / 1e6:.3f} MHz ({meta['n_reliable_lines']} lines); "
        f"checked band {lo / 1e6:.3f}-{hi / 1e6:.3f} MHz",
        f"  |G_TR| peak {20 * np.log10(np.max(np.abs(est.G_TR[sel]))):.2f} dB at "
        f"{est.f[sel][np.argmax(np.abs(est.G_TR[sel]))] / 1e6:.3f} MHz; "
        f"median SE of ln|G_TR| in band {np.median(est.se_log_magnitude[sel]) * 8.686:.3f} dB, "
        f"of arg G_TR {np.degrees(np.median(est.se_phase[sel])):.2f} deg",
        f"  reference sound speed from Im gamma: {meta['reference_sound_speed_m_s']:.1f} m/s",
    ]
    chk = meta.get("check_against_true_response")
    if chk:
        lines.append(
            f"  vs the rig's true transducer response: max |error| {chk['max_abs_magnitude_error_db']:.3f} dB, "
            f"{chk['max_abs_phase_error_deg']:.2f} deg (rms {chk['rms_magnitude_error_db']:.3f} dB, "
            f"{chk['rms_phase_error_deg']:.2f} deg)"
        )
    for npz, side in outputs:
        lines.append(f"  calibration file: {npz} (+ {side.name})")
    for p in plots:
        lines.append(f"  figure: {Path(meta['run_dir']) / p}")
    lines.append(f"  records: {Path(meta['run_dir']) / 'records'}")
    return "\n".join(lines)


def write_calibration_plots(run_dir: Path, est: TransferEstimate, band, truth, pair_name: str) -> list[str]:
    """Fig. 5.3 (|G_tot| per length and |G_TR|) and Fig. 5.4 (G_TR vs the true response)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lo, hi = band
    view = (est.f > 0) & (est.f <= min(2.0 * hi, est.f[-1]))
    fm = est.f[view] / 1e6
    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    for length, g in zip(est.lengths, est.G_tot):
        ax.plot(fm, 20 * np.log10(np.abs(g[view]) + 1e-300), lw=0.7, label=f"|G_tot|, {length * 1e3:g} mm")
    ax.plot(fm, 20 * np.log10(np.abs(est.G_TR[view])), "k", lw=1.6, label="|G_TR| (fit)")
    ax.axvspan(lo / 1e6, hi / 1e6, color="0.9", zorder=0)
    ax.set_xlabel("frequency [MHz]")
    ax.set_ylabel("magnitude [dB]")
    peak = 20 * np.log10(np.max(np.abs(est.G_TR[view])))
    ax.set_ylim(peak - 60, peak + 10)
    ax.set_title(f"Fig. 5.3: |G_tot| through the reference at each length, and |G_TR|\n{pair_name}", fontsize=10)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(run_dir / "fig5_3_gtot.png", dpi=110)
    plt.close(fig)

    fig, (a1, a2) = plt.subplots(2, 1, figsize=(7.5, 6), sharex=True)
    rel = est.reliable & view
    a1.plot(fm, 20 * np.log10(np.abs(est.G_TR[view])), lw=1.2, label="estimated (multi-length fit)")
    a1.plot(est.f[rel] / 1e6, 20 * np.log10(np.abs(est.G_TR[rel])), ".", ms=2, color="C0", label="reliable lines")
    phase_est = est.log_G_TR.imag[view]
    if truth is not None:
        gt = truth(est.f[view])
        a1.plot(fm, 20 * np.log10(np.abs(gt)), "--", lw=1.2, color="k", label="true (virtual rig)")
        k = np.argmin(np.abs(est.f[view] - est.pivot_hz))
        ph_true = unwrap_from(np.angle(gt), int(k))
        ph_true += 2 * np.pi * np.round((phase_est[k] - ph_true[k]) / (2 * np.pi))
        a2.plot(fm, np.degrees(ph_true), "--", lw=1.2, color="k", label="true (virtual rig)")
    a2.plot(fm, np.degrees(phase_est), lw=1.2, label="estimated")
    for a in (a1, a2):
        a.axvspan(lo / 1e6, hi / 1e6, color="0.9", zorder=0)
        a.legend(fontsize=8)
    a1.set_ylabel("|G_TR| [dB]")
    a1.set_ylim(20 * np.log10(np.max(np.abs(est.G_TR[view]))) - 50, None)
    a2.set_ylabel("arg G_TR [deg]")
    sel = (est.f >= lo) & (est.f <= hi)
    span = np.degrees(est.log_G_TR.imag[sel])
    a2.set_ylim(span.min() - 360, span.max() + 360)
    a2.set_xlabel("frequency [MHz]")
    a1.set_title(f"Fig. 5.4: transducer pair response G_TR, estimated vs true\n{pair_name}", fontsize=10)
    fig.tight_layout()
    fig.savefig(run_dir / "fig5_4_gtr.png", dpi=110)
    plt.close(fig)
    return ["fig5_3_gtot.png", "fig5_4_gtr.png"]
