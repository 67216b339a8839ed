"""Studies of Chapter 3: many identification runs over one base config, one table and plot.

Three kinds, each ``run_study(kind, config, overrides, out_dir, progress, **options)``:

``monte_carlo``
    The same simulated measurement repeated over noise seeds (``backend.options.seed``). Per
    parameter and per material property: bias, RMS error, the mean of the runs' own standard
    errors, the coverage of the truth by the runs' 95 % intervals, and the Cramer-Rao bound
    (CRB = sigma^2 (J^T J)^-1 at the truth, sigma the known noise std) with the ratio
    RMS error / CRB (1 for an efficient, unbiased estimator).
``element_sweep``
    One fixed data record fitted with n = 2..40 elements (Figs. 3.10-3.11): the material
    properties against n and the n from which each property settles (every later estimate
    within ``tolerance`` of it). By default the record comes from a fine chain (40 elements)
    of the config's true medium, so the truth is one medium, not one n. A coarse chain cannot
    match that record and its cost has more local minima, so each n is also refitted from its
    finer neighbour's estimate (``warm_start``) and the lower cost is kept.
``repeatability``
    Different PRBS realisations of the same bandwidth (``excitation.options.shift``, and a new
    noise seed for a simulated rig): each property's mean and std/mean (Table 3.2).

Every study writes into its folder ``<kind>.csv`` (the table), ``<kind>.json`` (summary,
table, options, the compact record of every run), ``<kind>.png`` (plot) and ``runs/<label>/``
with each run's ``result.json`` and ``config.yaml`` (the whole run folder with
``keep_runs=true``). Runs are executed without plots and without their own progress display.

From the command line (``mbus-run CONFIG --study KIND --study-option key=value``), options
are parsed by :func:`parse_study_options` and validated per kind (unknown keys rejected with
a "did you mean").
"""
from __future__ import annotations

import csv
import datetime as _dt
import io
import math
import os
import platform
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Literal

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from mbus_framework import __version__
from mbus_framework.pipeline.config import format_validation_error, load_config
from mbus_framework.errors import ConfigError, EstimationError
from mbus_framework.estimation.problem import Progress
from mbus_framework.pipeline.storage import atomic_write_bytes, atomic_write_json, atomic_write_text

KINDS = ("monte_carlo", "element_sweep", "repeatability")


# ---------------------------------------------------------------------------------------
# Options
# ---------------------------------------------------------------------------------------
class _Options(BaseModel):
    model_config = ConfigDict(extra="forbid")
    keep_runs: bool = Field(False, description="keep every run's whole folder (waveforms too), not only result.json")


class MonteCarloOptions(_Options):
    n_runs: int = Field(50, ge=2, description="number of noise seeds")
    first_seed: int | None = Field(None, description="first seed (default: the config's backend.options.seed)")
    coverage_interval_level: float = Field(
        0.95, gt=0, lt=1,
        description="confidence level of the Clopper-Pearson interval around each measured coverage "
        "(the runs' own intervals are always 95 %)",
    )


class ElementSweepOptions(_Options):
    n_values: list[int] = Field(
        default_factory=lambda: [2, 3, 4, 5, 6, 8, 10, 12, 15, 20, 25, 30, 35, 40],
        description="element counts; a list, 'a..b' (every n), 'a..b:step' or 'a,b,c'",
    )
    reference_n: int | None = Field(
        40, ge=1, le=400,
        description="simulated rig without its own medium: data from this many elements of the config's "
        "true medium (null: the config's own backend, unchanged)",
    )
    tolerance: float = Field(0.02, gt=0, description="settled: every later estimate within this relative change")
    warm_start: bool = Field(
        True,
        description="also fit each n from its finer neighbour's estimate (a second pass, finest first) and keep "
        "the lower cost: a coarse chain cannot match the fine medium, and its cost has more local minima",
    )

    @field_validator("n_values", mode="before")
    @classmethod
    def _parse_n_values(cls, value):
        return parse_int_list(value)

    @field_validator("n_values")
    @classmethod
    def _check_n_values(cls, value):
        if len(value) < 2:
            raise ValueError("give at least two element counts")
        if min(value) < 1:
            raise ValueError("element counts must be >= 1")
        return sorted(set(value))


class RepeatabilityOptions(_Options):
    n_runs: int = Field(5, ge=2, description="number of excitation realisations")
    vary: Literal["auto", "shift", "seed", "shift+seed"] = Field(
        "auto",
        description="what differs between runs: the PRBS start (excitation.options.shift), the noise seed, "
        "or both (auto: shift, plus the seed on a rig that has one)",
    )
    shift_step: int | None = Field(None, ge=1, description="bits between realisations (default: period / n_runs)")
    first_seed: int | None = Field(None, description="first noise seed (default: the config's)")


OPTIONS: dict[str, type[_Options]] = {
    "monte_carlo": MonteCarloOptions,
    "element_sweep": ElementSweepOptions,
    "repeatability": RepeatabilityOptions,
}


def parse_int_list(value: Any) -> list[int]:
    """``[2, 4]``, ``8``, ``"2..40"``, ``"2..40:2"``, ``"2,4,8"`` -> list of ints."""
    if isinstance(value, bool):
        raise ValueError("expected integers")
    if isinstance(value, int):
        return [value]
    if isinstance(value, (list, tuple)):
        out = []
        for v in value:
            if isinstance(v, bool) or not isinstance(v, int):
                raise ValueError(f"expected integers, got {v!r}")
            out.append(int(v))
        return out
    if isinstance(value, str):
        text = value.strip().strip("[]")
        try:
            if ".." in text:
                span, _, step = text.partition(":")
                a, _, b = span.partition("..")
                a, b, s = int(a), int(b), int(step) if step else 1
                if s < 1 or b < a:
                    raise ValueError
                return list(range(a, b + 1, s))
            return [int(p) for p in text.replace(" ", ",").split(",") if p]
        except ValueError:
            raise ValueError(f"cannot read element counts from {value!r}; use e.g. 2..40, 2..40:2 or 2,4,8") from None
    raise ValueError(f"expected a list of integers, got {type(value).__name__}")


def parse_study_options(items: list[str] | None) -> dict[str, Any]:
    """``["n_runs=50", "n_values=2..40"]`` -> ``{"n_runs": 50, "n_values": "2..40"}``.

    Values are read as YAML (numbers, booleans, lists ``[2, 4]``, null); a later key
    replaces an earlier one. Raises :class:`ConfigError` naming the bad item.
    """
    out: dict[str, Any] = {}
    for item in items or []:
        key, sep, text = str(item).partition("=")
        key = key.strip()
        if not sep or not key or not key.replace("_", "").isalnum():
            raise ConfigError(f"--study-option '{item}': expected key=value, e.g. n_runs=50")
        try:
            value = yaml.safe_load(text) if text.strip() else ""
        except yaml.YAMLError:
            value = text
        out[key] = value
    return out


def validate_study_options(kind: str, options: dict[str, Any]):
    if kind not in OPTIONS:
        from mbus_framework.suggest import did_you_mean

        raise ConfigError(f"unknown study '{kind}'{did_you_mean(kind, KINDS)}; choose one of: {', '.join(KINDS)}")
    try:
        return OPTIONS[kind].model_validate(options)
    except ValidationError as exc:
        raise ConfigError(f"study {kind}: {format_validation_error(exc, OPTIONS[kind], 'option')}") from None


# ---------------------------------------------------------------------------------------
# Result
# ---------------------------------------------------------------------------------------
@dataclass
class StudyResult:
    """What a study produced.

    rows:    the table (also ``<kind>.csv``), one dict per row
    summary: the JSON summary (also ``<kind>.json``); kind-specific keys documented per study
    runs:    compact record of every run (estimates, standard errors, intervals, truth)
    text:    the printed table
    files:   name -> path of everything written
    """

    kind: str
    out_dir: Path
    rows: list[dict[str, Any]]
    summary: dict[str, Any]
    runs: list[dict[str, Any]]
    text: str
    files: dict[str, Path] = field(default_factory=dict)


# ---------------------------------------------------------------------------------------
# Entry point
# ---------------------------------------------------------------------------------------
def run_study(
    kind: str,
    config_path: str | Path,
    overrides: list[str] | None = None,
    out_dir: str | Path | None = None,
    progress: Progress | None = None,
    **options: Any,
) -> StudyResult:
    """Run study ``kind`` over the base config (with ``--set``-style ``overrides``).

    ``out_dir`` defaults to ``<output.directory>/<date-time>-<config>-<kind>``. ``options``
    are the kind's options (see ``MonteCarloOptions``, ``ElementSweepOptions``,
    ``RepeatabilityOptions``); bad options raise :class:`ConfigError`.
    """
    opts = validate_study_options(kind, options)
    overrides = list(overrides or [])
    config = load_config(config_path, overrides)  # fail early on a bad base config
    if out_dir is None:
        stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
        out_dir = Path(config.output.directory) / f"{stamp}-{Path(config_path).stem}-{kind}"
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ctx = _Context(kind, str(config_path), overrides, out, progress, opts)
    t0 = time.perf_counter()
    study = {"monte_carlo": _monte_carlo, "element_sweep": _element_sweep, "repeatability": _repeatability}[kind]
    rows, summary, runs, text, fig = study(ctx)
    text += f"\n\n  written to {out}/: {kind}.csv (table), {kind}.json (summary and every run), " + (
        f"{kind}.png (plot), runs/ (each run's result.json)" if fig is not None else "runs/")
    summary = {
        "kind": kind,
        "config": str(config_path),
        "overrides": overrides,
        "options": opts.model_dump(mode="json"),
        "created": _dt.datetime.now().isoformat(timespec="seconds"),
        "mbus_version": __version__,
        "machine": machine_info(),
        "wall_time_s": time.perf_counter() - t0,
        **summary,
        "table": rows,
        "runs": runs,
    }
    files = {
        "csv": atomic_write_text(out / f"{kind}.csv", table_csv(rows)),
        "json": atomic_write_json(out / f"{kind}.json", summary),
        "text": atomic_write_text(out / f"{kind}.txt", text + "\n"),
    }
    if fig is not None:
        files["png"] = _save_figure(fig, out / f"{kind}.png")
    return StudyResult(kind, out, rows, summary, runs, text, files)


def machine_info() -> dict[str, Any]:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "platform": platform.platform(),
        "load_average_1min": load,
    }


# ---------------------------------------------------------------------------------------
# Running the member runs
# ---------------------------------------------------------------------------------------
@dataclass
class _Context:
    kind: str
    config_path: str
    overrides: list[str]
    out_dir: Path
    progress: Progress | None
    options: Any

    def run(self, label: str, extra: list[str], keep_outcome: Callable | None = None) -> dict[str, Any]:
        """One identification with ``extra`` overrides; returns its compact record.

        ``keep_outcome(outcome, record)`` may add to the record while the outcome is alive.
        An :class:`EstimationError` is recorded (``ok: false``), not raised.
        """
        from mbus_framework.pipeline.run import execute

        dest = self.out_dir / "runs" / label
        record: dict[str, Any] = {"label": label, "overrides": list(extra)}
        t0 = time.perf_counter()
        with tempfile.TemporaryDirectory(prefix="mbus-study-") as tmp:
            run_dir = dest if self.options.keep_runs else Path(tmp) / label
            if dest.exists() and self.options.keep_runs:
                shutil.rmtree(dest)
            try:
                outcome = execute(self.config_path, self.overrides + extra, run_dir, progress=None, plots=False)
            except EstimationError as exc:
                record.update(ok=False, error=str(exc), wall_time_s=time.perf_counter() - t0)
                return record
            record.update(ok=True, **compact_record(outcome.result))
            record["wall_time_s"] = time.perf_counter() - t0
            if keep_outcome is not None:
                keep_outcome(outcome, record)
            if not self.options.keep_runs:
                dest.mkdir(parents=True, exist_ok=True)
                for name in ("result.json", "config.yaml"):
                    if (run_dir / name).exists():
                        shutil.copyfile(run_dir / name, dest / name)
        return record

    def start(self, total: int) -> None:
        if self.progress:
            self.progress.start(f"study {self.kind}", total=total)

    def advance(self, note: str) -> None:
        if self.progress:
            self.progress.advance(1, note)

    def stop(self) -> None:
        if self.progress:
            self.progress.stop()


def compact_record(result: dict[str, Any]) -> dict[str, Any]:
    """The numbers a study needs from one result.json."""
    unc = result.get("uncertainty", {}) or {}
    rec = {
        "parameters": dict(result["parameters"]),
        "properties": dict(result["properties"]),
        "standard_errors": dict(unc.get("standard_errors", {})),
        "ci95": dict(unc.get("ci95", {})),
        "property_standard_errors": dict(unc.get("property_standard_errors", {})),
        "property_ci95": dict(unc.get("property_ci95", {})),
        "cost": result["solver"]["cost"],
        "nrmse": result["fit"]["nrmse"],
        "solver_success": result["solver"]["success"],
        "solver_time_s": result["solver"]["wall_time_s"],
        "accepted_because": (result.get("strategy") or {}).get("accepted_because"),
    }
    if result.get("truth"):
        rec["truth"] = dict(result["truth"])
    if result.get("truth_properties"):
        rec["truth_properties"] = dict(result["truth_properties"])
    if unc.get("cramer_rao"):
        rec["cramer_rao"] = dict(unc["cramer_rao"])
    if result.get("warnings"):
        rec["warnings"] = result["warnings"]
    return rec


def _base_components(ctx: _Context):
    from mbus_framework.pipeline.run import build_components

    config = load_config(ctx.config_path, ctx.overrides)
    return build_components(config, ctx.config_path)


def _has_option(component, name: str) -> bool:
    return name in type(component.options).model_fields


# ---------------------------------------------------------------------------------------
# Cramer-Rao bound
# ---------------------------------------------------------------------------------------
def cramer_rao_bound(outcome) -> dict[str, Any] | None:
    """Cramer-Rao standard errors at the truth for a simulated rig with known noise.

    CRB = sigma^2 (J^T J)^-1, J = d yhat / d theta (free parameters) at the true parameters,
    sigma = ``measurement.meta["noise_std"]``; properties by the delta method. Returns
    ``{"parameters": {...}, "properties": {...}}`` or None when there is no truth for the
    fitted model or no known noise.
    """
    from mbus_framework.pipeline.run import make_problem
    from mbus_framework.estimation.uncertainty import property_covariance

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


def _max_rel_diff(a: dict, b: dict) -> float | None:
    common = [k for k in a if k in b and b[k]]
    if not common:
        return None
    return float(max(abs(a[k] / b[k] - 1.0) for k in common))


def _g(x, fmt=".4g", width=11) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return f"{'-':>{width}}"
    return f"{x:>{width}{fmt}}"


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


# ---------------------------------------------------------------------------------------
# Element-count sweep (Figs. 3.10-3.11)
# ---------------------------------------------------------------------------------------
def settle_index(values: list[float] | np.ndarray, tolerance: float) -> int | None:
    """First index k from which every later value is within ``tolerance`` (relative) of
    values[k]; None when only the last value qualifies (not settled within the sweep)."""
    v = np.asarray(values, float)
    for k in range(v.size - 1):
        if not np.isfinite(v[k]) or v[k] == 0:
            continue
        later = v[k + 1:]
        if np.all(np.isfinite(later)) and np.all(np.abs(later - v[k]) <= tolerance * abs(v[k])):
            return k
    return None


def _sweep_mapping_to_properties(model, mapping: dict[str, float], where: str) -> dict[str, float]:
    return model.to_properties(model.theta_from_mapping(mapping, where))


def _element_sweep(ctx: _Context):
    o: ElementSweepOptions = ctx.options
    c = _base_components(ctx)
    if not _has_option(c.model, "n_elements"):
        raise ConfigError(f"study element_sweep: model '{c.config.model.name}' has no 'n_elements' option")
    model_opts = c.model.options.model_dump(mode="json")
    base: list[str] = []
    reference = "the config's backend"
    bo = c.backend.options
    if o.reference_n is not None and hasattr(bo, "truth") and hasattr(bo, "medium") and bo.medium is None:
        # The truth is a medium, not a parameter vector of one n: convert it to properties with
        # the config's model, and simulate it with a fine chain of the same model.
        props = _sweep_mapping_to_properties(c.model, dict(bo.truth), f"{ctx.config_path}: backend.options.truth")
        medium = {"name": c.config.model.name, "options": {**model_opts, "n_elements": o.reference_n}}
        base += [f"backend.options.truth={_flow(props)}", f"backend.options.medium={_flow(medium)}"]
        reference = f"{c.config.model.name} with {o.reference_n} elements (the config's truth as material properties)"
    elif hasattr(bo, "medium") and bo.medium is not None:
        reference = f"the config's medium {bo.medium.name} {bo.medium.options}"
    if c.config.model.initial:  # parameters depend on n, properties do not
        init = _sweep_mapping_to_properties(c.model, dict(c.config.model.initial), f"{ctx.config_path}: model.initial")
        base.append(f"model.initial={_flow(init)}")
    fixed_props = None
    if c.config.model.fixed:
        theta = np.array([p.typical for p in c.model.parameters])
        if c.config.model.initial:
            theta = c.model.theta_from_mapping(c.config.model.initial, "model.initial")
        for k, v in c.config.model.fixed.items():
            theta[c.model.parameter_names.index(k)] = v
        fixed_props = (c.model.to_properties(theta), list(c.config.model.fixed))

    def fixed_override(n: int) -> list[str]:
        if fixed_props is None:
            return []
        from mbus_framework.pipeline.run import build_components

        cfg = load_config(ctx.config_path, ctx.overrides + [f"model.options.n_elements={n}"])
        model_n = build_components(cfg, ctx.config_path).model
        theta_n = np.asarray(model_n.from_properties(fixed_props[0]), float)
        return [f"model.fixed={_flow({k: float(theta_n[model_n.parameter_names.index(k)]) for k in fixed_props[1]})}"]

    def fit(n: int, label: str, extra: list[str]) -> dict:
        rec = ctx.run(label, base + [f"model.options.n_elements={n}"] + fixed_override(n) + extra)
        rec["n_elements"] = n
        return rec

    def better(a: dict | None, b: dict | None) -> dict | None:
        if a is None or not a["ok"]:
            return b
        if b is None or not b["ok"]:
            return a
        return b if b["cost"] < a["cost"] else a

    ns = o.n_values
    runs: list[dict] = []
    ctx.start(len(ns) + (len(ns) - 1 if o.warm_start else 0))
    try:
        cold: dict[int, dict] = {}
        for n in ns:
            cold[n] = rec = fit(n, f"n-{n:03d}", [])
            rec["start"] = "config"
            runs.append(rec)
            ctx.advance(f"n = {n}: " + (f"nrmse {rec['nrmse']:.3g}" if rec["ok"] else "failed"))
        best = dict(cold)
        if o.warm_start:  # second pass, finest first: start each n from its finer neighbour's estimate
            for finer, n in zip(ns[::-1], ns[-2::-1]):
                src = best[finer]
                if not src["ok"]:
                    ctx.advance(f"n = {n}: no warm start")
                    continue
                rec = fit(n, f"n-{n:03d}-warm", [f"model.initial={_flow(src['properties'])}"])
                rec["start"] = f"warm from n = {finer}"
                runs.append(rec)
                best[n] = better(best[n], rec)
                ctx.advance(f"n = {n} (warm): " + (f"nrmse {rec['nrmse']:.3g}" if rec["ok"] else "failed"))
    finally:
        ctx.stop()
    ok = [best[n] for n in ns if best[n]["ok"]]
    if len(ok) < 2:
        raise EstimationError(f"study element_sweep: fewer than two runs succeeded: {[r.get('error') for r in runs]}")
    pnames = list(ok[0]["properties"])
    truth = ok[-1].get("truth_properties") or {}
    rows = []
    prev = None
    for r in ok:
        row: dict[str, Any] = {"n_elements": r["n_elements"], "run": r["label"], "start": r["start"]}
        for p in pnames:
            v = r["properties"][p]
            row[p] = v
            row[f"{p}_se"] = r["property_standard_errors"].get(p)
            row[f"{p}_change"] = (v / prev["properties"][p] - 1.0) if prev and prev["properties"][p] else None
            if p in truth and truth[p]:
                row[f"{p}_error"] = v / truth[p] - 1.0
        row["nrmse"] = r["nrmse"]
        row["warnings"] = len(r.get("warnings") or [])
        row["cost"] = r["cost"]
        others = [x for x in runs if x["n_elements"] == r["n_elements"] and x is not r and x["ok"]]
        row["other_start_cost"] = others[0]["cost"] if others else None
        row["wall_time_s"] = sum(x["wall_time_s"] for x in runs if x["n_elements"] == r["n_elements"])
        rows.append(row)
        prev = r
    settle = {}
    for p in pnames:
        k = settle_index([r["properties"][p] for r in ok], o.tolerance)
        settle[p] = ok[k]["n_elements"] if k is not None else None
    known = [v for v in settle.values() if v is not None]
    summary = {
        "n_values": o.n_values,
        "reference": reference,
        "truth_properties": truth or None,
        "tolerance": o.tolerance,
        "settled_at": settle,
        "all_settled_at": max(known) if len(known) == len(settle) else None,
        "warm_start": o.warm_start,
        "warm_start_won": [r["n_elements"] for r in ok if r["start"] != "config"],
        "failed": [{"n_elements": r["n_elements"], "run": r["label"], "error": r["error"]} for r in runs if not r["ok"]],
    }
    text = _sweep_text(ctx, rows, summary, pnames)
    return rows, summary, runs, text, _sweep_figure(ok, pnames, truth, settle)


def _flow(mapping: dict) -> str:
    """A mapping as one-line YAML for an override value."""
    return yaml.safe_dump(_plain(mapping), default_flow_style=True, width=10**6).strip()


def _plain(x):
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, (np.floating, float)):
        return float(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    return x


def _sweep_text(ctx, rows, summary, pnames) -> str:
    lines = [
        f"Element-count sweep: {ctx.config_path}, data from {summary['reference']}",
        "",
        f"  {'n':>4}" + "".join(f"{p:>14}" for p in pnames) + f"{'nrmse':>9}{'time s':>8}  start",
    ]
    for r in rows:
        lines.append(f"  {r['n_elements']:>4}" + "".join(f"{r[p]:>14.5g}" for p in pnames)
                     + f"{r['nrmse']:>9.3g}{r['wall_time_s']:>8.1f}  {r['start']}")
    truth = summary.get("truth_properties")
    if truth:
        lines.append(f"  {'true':>4}" + "".join(f"{truth[p]:>14.5g}" if p in truth else f"{'':>14}" for p in pnames))
    lines.append("")
    tol = 100 * summary["tolerance"]
    for p in pnames:
        n = summary["settled_at"][p]
        lines.append(f"  {p:<12} settles at n = {n} (later estimates within {tol:g} %)" if n is not None
                     else f"  {p:<12} does not settle within the sweep (tolerance {tol:g} %)")
    if summary["warm_start"]:
        lines.append("  each n was fitted from the config's start and from its finer neighbour's estimate; "
                     "the lower cost is shown")
    if summary["failed"]:
        lines.append(f"  failed runs: {', '.join(f['run'] for f in summary['failed'])}")
    return "\n".join(lines)


def _sweep_figure(ok, pnames, truth, settle):
    plt = _pyplot()
    cols = 2
    nrow = math.ceil(len(pnames) / cols)
    fig, axes = plt.subplots(nrow, cols, figsize=(10, 3.4 * nrow), squeeze=False)
    n = np.array([r["n_elements"] for r in ok])
    for ax, p in zip(axes.flat, pnames):
        v = np.array([r["properties"][p] for r in ok])
        se = np.array([r["property_standard_errors"].get(p, np.nan) for r in ok], float)
        # A coarse chain can drive a coefficient to ~0 (a degenerate fit): keep the axis to
        # three decades around the median and mark such points at the edge.
        ref = [x for x in [truth.get(p)] if x] + list(v[np.isfinite(v)])
        med = float(np.median(np.abs(ref))) if ref else 1.0
        lo, hi = med / 1e3, med * 1e3
        inside = (v >= lo) & (v <= hi)
        ax.errorbar(n[inside], v[inside], yerr=1.96 * np.nan_to_num(se[inside]), fmt="o-", ms=4, capsize=2,
                    label="estimate (95 %)")
        if np.any(~inside):
            edge = np.where(v < lo, lo, hi)
            ax.plot(n[~inside], edge[~inside], "v", color="tab:orange", label="off scale (degenerate fit)")
        if p in truth:
            ax.axhline(truth[p], color="k", ls=":", lw=1, label="truth")
        if settle.get(p) is not None:
            ax.axvline(settle[p], color="tab:red", ls="--", lw=1, label=f"settles at n = {settle[p]}")
        ax.set_title(p)
        ax.set_xlabel("number of elements n")
        shown = np.concatenate([v[inside], [truth[p]] if p in truth else []])
        if shown.size and np.all(shown > 0) and shown.max() / shown.min() > 20 or np.any(~inside):
            ax.set_yscale("log")
            ax.set_ylim(min(shown.min(), lo if np.any(v < lo) else shown.min()) / 1.5,
                        max(shown.max(), hi if np.any(v > hi) else shown.max()) * 1.5)
        ax.legend(fontsize=8)
    for ax in list(axes.flat)[len(pnames):]:
        ax.axis("off")
    fig.suptitle("Material properties against the number of elements (Figs. 3.10-3.11)")
    fig.tight_layout()
    return fig


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


# ---------------------------------------------------------------------------------------
# Output helpers
# ---------------------------------------------------------------------------------------
def table_csv(rows: list[dict[str, Any]]) -> str:
    columns: list[str] = []
    for r in rows:
        columns += [k for k in r if k not in columns]
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: ("" if r.get(k) is None else (repr(float(r[k])) if isinstance(r.get(k), (float, np.floating)) else r[k]))
                    for k in columns})
    return buf.getvalue()


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save_figure(fig, path: Path) -> Path:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    _pyplot().close(fig)
    return atomic_write_bytes(path, buf.getvalue())
