"""Monte Carlo study: the same simulated measurement over noise seeds, with the Cramer-Rao bound."""
from __future__ import annotations

from typing import Any

import numpy as np

from mbus_framework.errors import ConfigError, EstimationError
from mbus_framework.studies.common import (
    _base_components,
    _Context,
    _g,
    _has_option,
    _max_rel_diff,
    _pyplot,
)
from mbus_framework.studies.options import MonteCarloOptions


def cramer_rao_bound(outcome) -> dict[str, Any] | None:
    """Cramer-Rao standard errors at the truth for a simulated rig with known noise.

    CRB = sigma^2 (J^T J)^-1, J = d yhat / d theta (free parameters) at the true parameters,
    sigma = ``measurement.meta["noise_std"]``; properties by the delta method. Returns
    ``{"parameters": {...}, "properties": {...}}`` or None when there is no truth for the
    fitted model or no known noise.
    """
    from mbus_framework.estimation.uncertainty import property_covariance
    from mbus_framework.pipeline.run import make_problem

    m = outcome.measurement
    sigma = m.meta.get("noise_std")
    if not m.truth or not sigma:
        return None
    c = outcome.components
    problem = make_problem(c, c.compensator.apply(m))
    theta = np.array([m.truth[n] for n in problem.names], dtype=float)
    _, J = problem.predict_with_jacobian(theta)
    free = problem.free
    names = [n for n, f in zip(problem.names, free) if f]
    cov = covariance_from_jacobian(J[:, free], float(sigma) ** 2)
    pnames, _, pcov = property_covariance(c.model.to_properties, theta, free, cov)
    return {
        "parameters": dict(zip(names, map(float, np.sqrt(np.diag(cov))))),
        "properties": dict(zip(pnames, map(float, np.sqrt(np.clip(np.diag(pcov), 0, None))))),
    }


def covariance_from_jacobian(J: np.ndarray, variance: float) -> np.ndarray:
    """variance (J^T J)^-1 without truncation (see :func:`uncertainty.scaled_inverse_gram`)."""
    from mbus_framework.estimation.uncertainty import scaled_inverse_gram

    return variance * scaled_inverse_gram(J)[0]


# ---------------------------------------------------------------------------------------
# Monte Carlo
# ---------------------------------------------------------------------------------------
def coverage_interval(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Clopper-Pearson interval of a proportion k/n."""
    from scipy import stats

    a = 1.0 - level
    lo = 0.0 if k == 0 else float(stats.beta.ppf(a / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(stats.beta.ppf(1 - a / 2, k + 1, n - k))
    return lo, hi


def monte_carlo_statistics(
    estimates: np.ndarray, truth: float, standard_errors: np.ndarray, intervals: np.ndarray,
    crb: float | None, level: float = 0.95,
) -> dict[str, Any]:
    """Bias, RMS error, spread, mean SE, coverage and efficiency of one quantity over runs."""
    est = np.asarray(estimates, float)
    se = np.asarray(standard_errors, float)
    ci = np.asarray(intervals, float).reshape(-1, 2)
    n = est.size
    err = est - truth
    rms = float(np.sqrt(np.mean(err**2)))
    covered = int(np.sum((ci[:, 0] <= truth) & (truth <= ci[:, 1])))
    c_lo, c_hi = coverage_interval(covered, n, level)
    rel = (lambda x: 100.0 * x / abs(truth)) if truth else (lambda x: float("nan"))
    crb = float(crb) if crb is not None and np.isfinite(crb) else None
    return {
        "n": n,
        "truth": float(truth),
        "mean": float(np.mean(est)),
        "bias": float(np.mean(err)),
        "bias_percent": rel(float(np.mean(err))),
        "std": float(np.std(est, ddof=1)) if n > 1 else float("nan"),
        "rmse": rms,
        "rmse_percent": rel(rms),
        "mean_se": float(np.mean(se)),
        "crb": crb,
        "crb_percent": rel(crb) if crb is not None else None,
        "rmse_over_crb": rms / crb if crb else None,
        "covered": covered,
        "coverage": covered / n if n else float("nan"),
        "coverage_low": c_lo,
        "coverage_high": c_hi,
        "within_3se": int(np.sum(np.abs(err) <= 3 * se)),
    }


def _monte_carlo(ctx: _Context):
    o: MonteCarloOptions = ctx.options
    c = _base_components(ctx)
    if not _has_option(c.backend, "seed"):
        raise ConfigError(
            f"study monte_carlo: backend '{c.config.backend.name}' has no 'seed' option; "
            "a Monte Carlo study needs a simulated rig"
        )
    first = o.first_seed if o.first_seed is not None else int(c.backend.options.seed)
    seeds = [first + i for i in range(o.n_runs)]
    crb_holder: dict[str, Any] = {}

    def keep(outcome, record):
        record["noise_std"] = outcome.measurement.meta.get("noise_std")
        if not crb_holder:
            crb_holder["computed"] = cramer_rao_bound(outcome)

    runs = []
    ctx.start(len(seeds))
    try:
        for seed in seeds:
            rec = ctx.run(f"seed-{seed:05d}", [f"backend.options.seed={seed}"], keep)
            rec["seed"] = seed
            runs.append(rec)
            ctx.advance(f"seed {seed}: " + (f"cost {rec['cost']:.4g}" if rec["ok"] else "failed"))
    finally:
        ctx.stop()
    ok = [r for r in runs if r["ok"]]
    if not ok:
        raise EstimationError(f"study monte_carlo: all {len(runs)} runs failed: {runs[0].get('error')}")
    if "truth" not in ok[0]:
        raise ConfigError(
            "study monte_carlo: the runs report no true parameters (the simulated medium differs from the "
            "fitted model); use the same model in backend.options.medium or none"
        )
    computed = crb_holder.get("computed") or {"parameters": {}, "properties": {}}
    reported = ok[0].get("cramer_rao") or {}
    rows = []
    for kind_, est_key, se_key, ci_key, truth_key in (
        ("parameter", "parameters", "standard_errors", "ci95", "truth"),
        ("property", "properties", "property_standard_errors", "property_ci95", "truth_properties"),
    ):
        for name in ok[0][se_key]:
            truth = ok[0][truth_key][name]
            crb, source = reported.get(name), "result.json"
            if crb is None:
                crb, source = computed[est_key].get(name), "computed"
            stats_ = monte_carlo_statistics(
                [r[est_key][name] for r in ok], truth, [r[se_key][name] for r in ok],
                [r[ci_key][name] for r in ok], crb, o.coverage_interval_level,
            )
            rows.append({"quantity": name, "kind": kind_, **stats_, "crb_source": source if crb is not None else None})
    summary = {
        "n_runs": len(runs),
        "n_ok": len(ok),
        "failed": [{"seed": r["seed"], "error": r["error"]} for r in runs if not r["ok"]],
        "seeds": seeds,
        "noise_std": ok[0].get("noise_std"),
        "cramer_rao_computed": computed,
        "cramer_rao_reported": reported or None,
        "cramer_rao_max_relative_difference": _max_rel_diff(computed["parameters"], reported),
        "all_within_3se": int(sum(all(abs(r["parameters"][n] - r["truth"][n]) <= 3 * r["standard_errors"][n]
                                      for n in r["standard_errors"]) for r in ok)),
        "median_run_time_s": float(np.median([r["wall_time_s"] for r in ok])),
        "runs_with_warnings": sum(bool(r.get("warnings")) for r in ok),
    }
    text = _monte_carlo_text(ctx, rows, summary)
    return rows, summary, runs, text, _monte_carlo_figure(rows, ok)



def _monte_carlo_text(ctx, rows, summary) -> str:
    lines = [
        f"Monte Carlo study: {ctx.config_path} over {summary['n_ok']} noise seeds "
        f"({summary['seeds'][0]}..{summary['seeds'][-1]}; {len(summary['failed'])} failed)",
        "",
        f"  {'quantity':<11}{'truth':>11}{'bias %':>9}{'RMS %':>9}{'mean SE %':>10}{'CRB %':>9}"
        f"{'RMS/CRB':>9}{'coverage':>10}  {'(95% interval)':<15}{'<=3SE':>6}",
    ]
    kind = None
    for r in rows:
        if r["kind"] != kind and kind is not None:
            lines.append("")
        kind = r["kind"]
        mean_se_pct = 100 * r["mean_se"] / abs(r["truth"]) if r["truth"] else None
        lines.append(
            f"  {r['quantity']:<11}{_g(r['truth'])}{_g(r['bias_percent'], '.3f', 9)}{_g(r['rmse_percent'], '.3f', 9)}"
            f"{_g(mean_se_pct, '.3f', 10)}{_g(r['crb_percent'], '.3f', 9)}{_g(r['rmse_over_crb'], '.2f', 9)}"
            f"{100 * r['coverage']:>9.1f}%  [{100 * r['coverage_low']:.0f}, {100 * r['coverage_high']:.0f}]%"
            f"{'':<6}{r['within_3se']:>5}"
        )
    lines.append("")
    lines.append(
        f"  runs with every parameter within 3 SE of the truth: {summary['all_within_3se']}/{summary['n_ok']}; "
        f"median time per run {summary['median_run_time_s']:.2f} s; runs with identifiability warnings: "
        f"{summary['runs_with_warnings']}"
    )
    src = {}
    for r in rows:
        if r.get("crb_source"):
            src.setdefault(r["crb_source"], []).append({"parameter": "parameters", "property": "properties"}[r["kind"]])
    where = "; ".join(f"{', '.join(sorted(set(v)))} from {k}" for k, v in src.items()) or "n/a"
    lines.append(f"  CRB: sigma^2 (J^T J)^-1 at the truth with the known noise std ({where})")
    return "\n".join(lines)


def _monte_carlo_figure(rows, ok):
    plt = _pyplot()
    params = [r for r in rows if r["kind"] == "parameter"]
    fig, axes = plt.subplots(2, max(len(params), 2), figsize=(3.2 * max(len(params), 2), 6.4))
    z = np.linspace(-4, 4, 200)
    for ax, r in zip(axes[0], params):
        scale = r["crb"] or r["mean_se"] or 1.0
        e = (np.array([run["parameters"][r["quantity"]] for run in ok]) - r["truth"]) / scale
        ax.hist(e, bins=max(5, int(np.sqrt(len(e)))), density=True, alpha=0.6)
        ax.plot(z, np.exp(-0.5 * z**2) / np.sqrt(2 * np.pi), "k-", lw=1, label="N(0, 1)")
        ax.set_title(r["quantity"])
        ax.set_xlabel("(estimate - truth) / CRB" if r["crb"] else "(estimate - truth) / SE")
    axes[0][0].legend(fontsize=8)
    names = [r["quantity"] for r in rows]
    x = np.arange(len(rows))
    ax = axes[1][0]
    ratios = [r["rmse_over_crb"] if r["rmse_over_crb"] is not None else np.nan for r in rows]
    ax.bar(x, ratios, color="tab:blue")
    ax.axhline(1.0, color="k", lw=0.8)
    ax.axhline(1.5, color="tab:red", ls="--", lw=0.8, label="1.5")
    ax.set_xticks(x, names, rotation=45, ha="right", fontsize=8)
    ax.set_ylabel("RMS error / Cramer-Rao bound")
    ax.legend(fontsize=8)
    ax = axes[1][1]
    cov = np.array([100 * r["coverage"] for r in rows])
    err = np.array([[100 * (r["coverage"] - r["coverage_low"]) for r in rows],
                    [100 * (r["coverage_high"] - r["coverage"]) for r in rows]])
    ax.errorbar(x, cov, yerr=err, fmt="o")
    ax.axhspan(90, 99, color="tab:green", alpha=0.15, label="90-99 %")
    ax.axhline(95, color="k", lw=0.8)
    ax.set_xticks(x, names, rotation=45, ha="right", fontsize=8)
    ax.set_ylabel("95 % interval coverage [%]")
    ax.legend(fontsize=8)
    for ax in axes[1][2:]:
        ax.axis("off")
    fig.suptitle(f"Monte Carlo over {len(ok)} noise seeds")
    fig.tight_layout()
    return fig
