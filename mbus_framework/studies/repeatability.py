"""Repeatability over PRBS realisations of one bandwidth (Table 3.2)."""
from __future__ import annotations

import numpy as np

from mbus_framework.errors import ConfigError, EstimationError
from mbus_framework.pipeline.components import require_excitation
from mbus_framework.studies.common import (
    _base_components,
    _Context,
    _has_option,
    _pyplot,
)
from mbus_framework.studies.options import RepeatabilityOptions


# ---------------------------------------------------------------------------------------
# Repeatability over PRBS realisations (Table 3.2)
# ---------------------------------------------------------------------------------------
def repeatability_statistics(values: np.ndarray) -> dict[str, float]:
    v = np.asarray(values, float)
    mean = float(np.mean(v))
    std = float(np.std(v, ddof=1)) if v.size > 1 else float("nan")
    return {"mean": mean, "std": std, "std_over_mean": std / abs(mean) if mean else float("nan")}


def _repeatability(ctx: _Context):
    o: RepeatabilityOptions = ctx.options
    c = _base_components(ctx)
    require_excitation(c, "study repeatability")
    can_shift, can_seed = _has_option(c.excitation, "shift"), _has_option(c.backend, "seed")
    vary = o.vary
    if vary == "auto":
        vary = "shift+seed" if can_shift and can_seed else "shift" if can_shift else "seed"
    if "shift" in vary and not can_shift:
        raise ConfigError(f"study repeatability: excitation '{c.config.excitation.name}' has no 'shift' option; use vary=seed")
    if "seed" in vary and not can_seed:
        raise ConfigError(f"study repeatability: backend '{c.config.backend.name}' has no 'seed' option; use vary=shift")
    step = o.shift_step
    if "shift" in vary and step is None:
        period = int(2 ** getattr(c.excitation.options, "order", 9) - 1)
        step = max(1, period // o.n_runs)
    base_shift = int(getattr(c.excitation.options, "shift", 0) or 0)
    first_seed = o.first_seed if o.first_seed is not None else int(getattr(c.backend.options, "seed", 0) or 0)
    runs = []
    ctx.start(o.n_runs)
    try:
        for i in range(o.n_runs):
            extra, info = [], {}
            if "shift" in vary:
                info["shift"] = base_shift + i * step
                extra.append(f"excitation.options.shift={info['shift']}")
            if "seed" in vary:
                info["seed"] = first_seed + i
                extra.append(f"backend.options.seed={info['seed']}")
            rec = ctx.run(f"prbs-{i + 1:02d}", extra)
            rec.update(info, realisation=i + 1)
            runs.append(rec)
            ctx.advance(f"PRBS-{i + 1}: " + (f"nrmse {rec['nrmse']:.3g}" if rec["ok"] else "failed"))
    finally:
        ctx.stop()
    ok = [r for r in runs if r["ok"]]
    if len(ok) < 2:
        raise EstimationError(f"study repeatability: fewer than two runs succeeded: {[r.get('error') for r in runs]}")
    pnames, parnames = list(ok[0]["properties"]), list(ok[0]["parameters"])
    rows = []
    for r in ok:
        row = {"run": f"PRBS-{r['realisation']}", "shift": r.get("shift"), "seed": r.get("seed")}
        row.update({p: r["properties"][p] for p in pnames})
        row.update({p: r["parameters"][p] for p in parnames})
        row["nrmse"] = r["nrmse"]
        rows.append(row)
    stats_ = {q: repeatability_statistics([r[src][q] for r in ok])
              for src, names in (("properties", pnames), ("parameters", parnames)) for q in names}
    for q in pnames:  # within-run uncertainty, to compare with the spread between runs
        ses = [r["property_standard_errors"].get(q) for r in ok]
        if all(s is not None for s in ses):
            stats_[q]["mean_relative_se"] = float(np.mean([s / abs(r["properties"][q]) for s, r in zip(ses, ok)]))
    truth = ok[0].get("truth_properties") or {}
    for q in pnames:
        if q in truth and truth[q]:
            stats_[q]["mean_error"] = stats_[q]["mean"] / truth[q] - 1.0
    rows.append({"run": "Mean", **{q: stats_[q]["mean"] for q in pnames + parnames}})
    rows.append({"run": "Std/Mean", **{q: stats_[q]["std_over_mean"] for q in pnames + parnames}})
    summary = {
        "vary": vary,
        "shift_step_bits": step if "shift" in vary else None,
        "statistics": stats_,
        "truth_properties": truth or None,
        "n_ok": len(ok),
        "failed": [{"run": r["label"], "error": r["error"]} for r in runs if not r["ok"]],
    }
    text = _repeatability_text(ctx, rows, summary, pnames)
    return rows, summary, runs, text, _repeatability_figure(ok, pnames, stats_, truth)


def _repeatability_text(ctx, rows, summary, pnames) -> str:
    what = {"shift": "PRBS start shifted", "seed": "noise seed", "shift+seed": "PRBS start shifted and new noise seed"}
    lines = [
        f"Repeatability over {summary['n_ok']} excitation realisations of the same bandwidth: {ctx.config_path}",
        f"  ({what[summary['vary']]}" + (f", {summary['shift_step_bits']} bits apart)" if summary["shift_step_bits"] else ")"),
        "",
        f"  {'excitation':<11}{'shift':>6}{'seed':>6}" + "".join(f"{p:>13}" for p in pnames),
    ]
    for r in rows:
        if r["run"] == "Std/Mean":
            lines.append(f"  {'Std/Mean':<23}" + "".join(f"{100 * r[p]:>12.3g}%" for p in pnames))
        elif r["run"] == "Mean":
            lines.append(f"  {'Mean':<23}" + "".join(f"{r[p]:>13.4g}" for p in pnames))
        else:
            sh = "" if r.get("shift") is None else r["shift"]
            sd = "" if r.get("seed") is None else r["seed"]
            lines.append(f"  {r['run']:<11}{sh!s:>6}{sd!s:>6}" + "".join(f"{r[p]:>13.4g}" for p in pnames))
    st = summary["statistics"]
    if all("mean_relative_se" in st[p] for p in pnames):
        lines.append(f"  {'mean SE/est.':<23}" + "".join(f"{100 * st[p]['mean_relative_se']:>12.3g}%" for p in pnames))
    truth = summary.get("truth_properties")
    if truth:
        lines.append(f"  {'truth':<23}" + "".join(f"{truth[p]:>13.4g}" if p in truth else f"{'':>13}" for p in pnames))
    return "\n".join(lines)


def _repeatability_figure(ok, pnames, stats_, truth):
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(pnames), figsize=(3.0 * len(pnames), 3.4), squeeze=False)
    x = np.arange(1, len(ok) + 1)
    for ax, p in zip(axes[0], pnames):
        v = np.array([r["properties"][p] for r in ok])
        se = np.array([r["property_standard_errors"].get(p, np.nan) for r in ok], float)
        ax.errorbar(x, v, yerr=1.96 * np.nan_to_num(se), fmt="o", capsize=2)
        m, s = stats_[p]["mean"], stats_[p]["std"]
        ax.axhline(m, color="tab:blue", lw=1)
        ax.axhspan(m - s, m + s, color="tab:blue", alpha=0.15)
        if p in truth:
            ax.axhline(truth[p], color="k", ls=":", lw=1)
        ax.set_title(f"{p}\nstd/mean {100 * stats_[p]['std_over_mean']:.2g} %", fontsize=9)
        ax.set_xticks(x, [f"PRBS-{r['realisation']}" for r in ok], rotation=45, fontsize=7)
    fig.suptitle("Repeatability over PRBS realisations (Table 3.2)")
    fig.tight_layout()
    return fig
