"""Human-facing output of a run: the printed summary and the PNG figures."""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from mbus_framework.interfaces.excitation import Waveform
    from mbus_framework.pipeline.components import Components
    from mbus_framework.estimation.problem import FitProblem, FitResult


def summary_text(result: dict[str, Any], run_dir: Path | None = None) -> str:
    """Plain-text summary: parameters, properties (with CIs and truth), fit and solver."""
    lines: list[str] = []
    title = result.get("title") or result.get("config")
    lines.append(f"mbus identification: {title}")
    lines.append(f"model {result['model']['name']} {result['model']['options']}")
    first = [w for w in result.get("warnings", []) if w.startswith("measurement: ")]  # partial acquisitions
    lines += [f"  WARNING: {w}" for w in first]
    unc = result.get("uncertainty", {})
    truth = result.get("truth", {})
    err = result.get("error_percent", {})
    se = unc.get("relative_standard_errors", {})
    lines.append("")
    head = f"  {'parameter':<12}{'estimate':>14} {'unit':<8}{'rel. SE':>10}"
    if truth:
        head += f"{'truth':>14}{'error':>10}"
    lines.append(head)
    for name, value in result["parameters"].items():
        fixed = name in result.get("fixed", {})
        row = f"  {name:<12}{value:>14.5g} {result['parameter_units'].get(name, ''):<8}"
        row += f"{'fixed':>10}" if fixed else (f"{100 * se[name]:>9.3g}%" if name in se else f"{'':>10}")
        if name in truth:
            row += f"{truth[name]:>14.5g}{err.get(name, float('nan')):>9.3f}%"
        lines.append(row)
    lines.append("")
    tprops = result.get("truth_properties", {})
    pci = unc.get("property_ci95", {})
    head = f"  {'property':<12}{'estimate':>14} {'unit':<8}{'95% interval':>28}"
    if tprops:
        head += f"{'truth':>14}{'error':>10}"
    lines.append(head)
    for name, value in result["properties"].items():
        row = f"  {name:<12}{value:>14.5g} {result['property_units'].get(name, ''):<8}"
        if name in pci:
            lo, hi = pci[name]
            row += f"{f'[{lo:.4g}, {hi:.4g}]':>28}"
        else:
            row += f"{'':>28}"
        if name in tprops and tprops[name]:
            row += f"{tprops[name]:>14.5g}{100 * (value / tprops[name] - 1):>9.3f}%"
        lines.append(row)
    fit, sol, strat = result["fit"], result["solver"], result.get("strategy", {})
    lines.append("")
    lines.append(f"  fit: mse {fit['mse']:.4g}, nrmse {fit['nrmse']:.4g} over {fit['n_samples']} samples")
    state = "converged" if sol["success"] else "NOT converged"
    lines.append(
        f"  solver {sol['name']}: {state} (status {sol['status']}: {sol['message']}); "
        f"{sol['nfev']} evaluations, {sol['wall_time_s']:.2f} s"
    )
    if strat.get("starts"):
        lines.append(
            f"  strategy: start from {strat.get('initial_source')}, {len(strat['starts'])} start(s) tried, "
            f"start {strat.get('winner')} won; accepted: {strat.get('accepted_because', '')}"
        )
    crb = unc.get("cramer_rao", {})
    if crb:
        lines.append(
            "  Cramer-Rao standard errors at the truth: "
            + ", ".join(f"{n} {100 * v / abs(truth[n]):.3g}%" for n, v in crb.items() if truth.get(n))
        )
    for w in result.get("warnings", []):
        if w not in first:
            lines.append(f"  WARNING: {w}")
    if run_dir is not None:
        lines.append(f"  output: {run_dir}")
    return "\n".join(lines)


def write_plots(
    run_dir: Path, c: "Components", problem: "FitProblem", fit: "FitResult", waveform: "Waveform"
) -> dict[str, str]:
    """Fig. 3.9 (measured vs predicted), Fig. 3.7 (excitation spectrum), Fig. 3.8 (trace)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files: dict[str, str] = {}
    t_us = problem.t * 1e6
    yhat = problem.y - fit.residuals

    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 6), sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    ax1.plot(t_us, problem.y, lw=0.7, color="0.55", label="measured")
    ax1.plot(t_us, yhat, lw=0.9, color="C3", label="model")
    ax1.set_ylabel("output force y [N]")
    ax1.legend(loc="upper right")
    ax1.set_title(f"{c.config.title or c.source}: measured vs predicted output")
    ax2.plot(t_us, fit.residuals, lw=0.6, color="C0")
    ax2.set_ylabel("residual [N]")
    ax2.set_xlabel("time [us]")
    fig.tight_layout()
    fig.savefig(run_dir / "fit.png", dpi=110)
    plt.close(fig)
    files["fit_plot"] = "fit.png"

    spec = c.excitation.spectrum()
    fig, ax = plt.subplots(figsize=(7, 4))
    keep = spec.f > 0
    power_db = 10 * np.log10(np.maximum(spec.power[keep] / spec.power[keep].max(), 1e-12))
    ax.semilogx(spec.f[keep] / 1e6, power_db, lw=0.7)
    bw = spec.bandwidth_3db()
    ax.axvline(bw / 1e6, ls="--", color="k", lw=0.8, label=f"-3 dB: {bw / 1e6:.3g} MHz")
    ax.set_xlabel("frequency [MHz]")
    ax.set_ylabel("relative power [dB]")
    ax.set_ylim(-60, 5)
    ax.legend()
    ax.set_title(f"excitation spectrum ({c.config.excitation.name})")
    fig.tight_layout()
    fig.savefig(run_dir / "excitation.png", dpi=110)
    plt.close(fig)
    files["excitation_plot"] = "excitation.png"

    if fit.trace:
        names = fit.names
        theta = np.array([rec["theta"] for rec in fit.trace])
        cost = np.array([rec["cost"] for rec in fit.trace])
        stages = [rec.get("stage", "") for rec in fit.trace]
        fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4))
        final = np.where(theta[-1] != 0, theta[-1], 1.0)
        for i, n in enumerate(names):
            ax1.plot(theta[:, i] / final[i], marker=".", label=n)
        ax1.set_xlabel("iteration")
        ax1.set_ylabel("parameter / final value")
        ax1.legend()
        ax2.semilogy(cost, marker=".")
        for k in range(1, len(stages)):
            if stages[k] != stages[k - 1]:
                for ax in (ax1, ax2):
                    ax.axvline(k - 0.5, color="0.8", lw=0.8)
        ax2.set_xlabel("iteration")
        ax2.set_ylabel("cost 1/2 sum r^2 (band stages: filtered)")
        fig.suptitle("convergence of the winning start (Fig. 3.8); grey lines: continuation stages")
        fig.tight_layout()
        fig.savefig(run_dir / "convergence.png", dpi=110)
        plt.close(fig)
        files["convergence_plot"] = "convergence.png"
    return files
