"""Model comparison: fit several medium models to the same record and rank them.

For each model the solver minimises cost = 1/2 RSS, RSS = sum_k (y_k - yhat_k)^2 over the
record (N samples, p free parameters). The table reports

    sigma^2 = RSS / (N - p)                               residual variance
    AIC = N ln(RSS/N) + 2 p                               (Gaussian errors, constants dropped)
    BIC = N ln(RSS/N) + p ln N
    SE_i = sqrt([sigma^2 (J^T J)^-1]_ii)                  J = d yhat/d theta at the optimum
    Q_LB = N (N+2) sum_{k=1}^{h} r_k^2 / (N - k)          Ljung-Box on the residual
                                                          autocorrelation r_k, p = P(chi2_h > Q)

and marks the model with the smallest criterion (BIC by default) as best. A model that
captures the dynamics leaves white residuals (large Ljung-Box p-value); a wrong structure
leaves coloured residuals.

Entry points: :func:`compare_models` (data + models + solver -> :class:`ComparisonTable`),
:func:`render_table` (text), and :func:`run_comparison` (a config file -> acquisition saved
to the run folder -> comparison.txt / comparison.json), which ``mbus-run --compare-models``
calls.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
from scipy import stats

from mbus_framework.estimation.problem import FitProblem, FitResult, Solver
from mbus_framework.estimation.uncertainty import from_jacobian
from mbus_framework.interfaces.model import MediumModel

CRITERIA = ("bic", "aic")


@dataclass
class ComparisonData:
    """The shared record: t [s] (uniform), input u, output y; hold and output filter as in
    :class:`~mbus_framework.estimation.problem.FitProblem`."""

    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    hold: str = "zoh"
    output_filter: Any = None

    @classmethod
    def from_any(cls, data) -> "ComparisonData":
        """From a ComparisonData, FitProblem, Measurement or any object with t, u, y."""
        if isinstance(data, cls):
            return data
        return cls(np.asarray(data.t, float), np.asarray(data.u, float), np.asarray(data.y, float),
                   getattr(data, "hold", "zoh"), getattr(data, "output_filter", None))


@dataclass
class Candidate:
    """A model to compare: display name, model instance, optional start and fixed values."""

    name: str
    model: MediumModel
    initial: np.ndarray | None = None
    fixed: dict[str, float] = field(default_factory=dict)


@dataclass
class ModelRow:
    """One row of the comparison table."""

    name: str
    n_params: int
    n_obs: int
    cost: float = np.nan
    rss: float = np.nan
    residual_std: float = np.nan
    aic: float = np.nan
    bic: float = np.nan
    delta: float = np.nan
    parameters: dict[str, float] = field(default_factory=dict)
    standard_errors: dict[str, float] = field(default_factory=dict)
    properties: dict[str, float] = field(default_factory=dict)
    property_units: dict[str, str] = field(default_factory=dict)
    property_standard_errors: dict[str, float] = field(default_factory=dict)
    parameter_units: dict[str, str] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    ljung_box_q: float = np.nan
    ljung_box_p: float = np.nan
    ljung_box_lags: int = 0
    success: bool = False
    message: str = ""
    wall_time_s: float = 0.0
    best: bool = False
    error: str | None = None
    fit: FitResult | None = field(default=None, repr=False)
    model: MediumModel | None = field(default=None, repr=False)
    problem: FitProblem | None = field(default=None, repr=False)

    @property
    def white(self) -> bool:
        """Residuals pass the Ljung-Box test at the 1 % level."""
        return bool(np.isfinite(self.ljung_box_p) and self.ljung_box_p >= 0.01)

    def relative_standard_errors(self) -> dict[str, float]:
        return {k: self.standard_errors[k] / abs(v) if v else np.inf
                for k, v in self.parameters.items() if k in self.standard_errors}

    def as_dict(self) -> dict[str, Any]:
        out = {k: v for k, v in self.__dict__.items() if k not in ("fit", "model", "problem")}
        out["white"] = self.white
        out["relative_standard_errors"] = self.relative_standard_errors()
        return _jsonable(out)


@dataclass
class ComparisonTable:
    """Rows in the order given; ``best`` is the name of the model with the smallest criterion."""

    rows: list[ModelRow]
    criterion: str
    n_obs: int
    best: str | None

    def row(self, name: str) -> ModelRow:
        for r in self.rows:
            if r.name == name:
                return r
        raise KeyError(name)

    def as_dict(self) -> dict[str, Any]:
        return {"criterion": self.criterion, "n_obs": self.n_obs, "best": self.best,
                "models": [r.as_dict() for r in self.rows]}


def ljung_box(residuals: np.ndarray, lags: int | None = None) -> tuple[float, float, int]:
    """Ljung-Box statistic Q, its p-value (chi-square, ``lags`` dof) and the lags used.

    Default lags: min(20, N // 5).
    """
    e = np.asarray(residuals, dtype=float)
    e = e - e.mean()
    n = e.size
    h = int(lags or min(20, max(1, n // 5)))
    denom = float(e @ e)
    if denom <= 0 or n < 3:
        return np.nan, np.nan, h
    r = np.array([float(e[:-k] @ e[k:]) / denom for k in range(1, h + 1)])
    q = float(n * (n + 2) * np.sum(r**2 / (n - np.arange(1, h + 1))))
    return q, float(stats.chi2.sf(q, h)), h


def information_criteria(rss: float, n: int, p: int) -> tuple[float, float]:
    """(AIC, BIC) of a Gaussian least-squares fit with RSS, N observations, p parameters."""
    if not (rss > 0 and np.isfinite(rss)):
        return np.nan, np.nan
    base = n * np.log(rss / n)
    return float(base + 2 * p), float(base + p * np.log(n))


def _candidates(models) -> list[Candidate]:
    if isinstance(models, Mapping):
        return [Candidate(str(k), v) for k, v in models.items()]
    out = []
    for m in models:
        if isinstance(m, Candidate):
            out.append(m)
        elif isinstance(m, MediumModel):
            out.append(Candidate(type(m).__name__, m))
        else:
            name, model, *rest = m
            out.append(Candidate(str(name), model, *rest))
    names = [c.name for c in out]
    if len(set(names)) != len(names):
        raise ValueError(f"model names must be unique, got {names}")
    return out


def compare_models(
    problem_data,
    model_specs: Mapping[str, MediumModel] | Iterable,
    solver: Solver,
    criterion: str = "bic",
    lags: int | None = None,
    progress=None,
) -> ComparisonTable:
    """Fit every model to the same record with ``solver`` and tabulate the statistics.

    ``problem_data``: ComparisonData, FitProblem, Measurement (anything with t, u, y).
    ``model_specs``: mapping name -> model, or a sequence of :class:`Candidate` /
    (name, model[, initial[, fixed]]) tuples. A model whose fit raises is reported with its
    error instead of taking the comparison down.
    """
    if criterion not in CRITERIA:
        raise ValueError(f"criterion must be one of {CRITERIA}, not {criterion!r}")
    data = ComparisonData.from_any(problem_data)
    n = int(data.y.size)
    rows = []
    for cand in _candidates(model_specs):
        problem = FitProblem(cand.model, data.t, data.u, data.y, initial=cand.initial, fixed=dict(cand.fixed),
                             hold=data.hold, output_filter=data.output_filter)
        p = int(problem.free.sum())
        row = ModelRow(cand.name, p, n, model=cand.model, problem=problem,
                       parameter_units={q.name: q.unit for q in problem.parameters},
                       property_units={q.name: q.unit for q in cand.model.properties})
        t0 = time.perf_counter()
        try:
            fit = solver.solve(problem, progress)
        except Exception as exc:  # noqa: BLE001 - one failing model must not hide the others
            row.error = f"{type(exc).__name__}: {exc}"
            row.wall_time_s = time.perf_counter() - t0
            rows.append(row)
            continue
        row.wall_time_s = time.perf_counter() - t0
        _fill_row(row, problem, fit, lags)
        rows.append(row)
    key = "bic" if criterion == "bic" else "aic"
    scored = [r for r in rows if np.isfinite(getattr(r, key))]
    best = min(scored, key=lambda r: getattr(r, key)) if scored else None
    for r in rows:
        if best is not None and np.isfinite(getattr(r, key)):
            r.delta = getattr(r, key) - getattr(best, key)
        r.best = r is best
    return ComparisonTable(rows, criterion, n, best.name if best else None)


def _fill_row(row: ModelRow, problem: FitProblem, fit: FitResult, lags: int | None) -> None:
    theta = np.asarray(fit.theta, dtype=float)
    residuals = np.asarray(fit.residuals, dtype=float)
    free = problem.free
    names = [nm for nm, f in zip(problem.names, free) if f]
    rss = float(residuals @ residuals)
    row.fit, row.cost, row.rss = fit, 0.5 * rss, rss
    row.success, row.message = bool(fit.success), str(fit.message)
    row.parameters = {nm: float(v) for nm, v in zip(problem.names, theta)}
    try:
        row.properties = {k: float(v) for k, v in problem.model.to_properties(theta).items()}
    except Exception:  # noqa: BLE001 - properties are informative only
        row.properties = {}
    row.aic, row.bic = information_criteria(rss, row.n_obs, row.n_params)
    J = fit.jacobian
    if J is None or J.shape != (residuals.size, int(free.sum())):
        J = problem.predict_with_jacobian(theta)[1][:, free]
    unc = from_jacobian(names, J, 0.5 * rss)
    row.residual_std = unc.residual_std
    row.standard_errors = {nm: float(se) for nm, se in zip(names, unc.standard_errors)}
    row.ljung_box_q, row.ljung_box_p, row.ljung_box_lags = ljung_box(residuals, lags)


def review_row(row: ModelRow, c, measurement, waveform, compensation) -> None:
    """Properties with their standard errors, and the warnings, of ``row``'s fit as a single run
    of that model reports them (:func:`~mbus_framework.pipeline.results.build_result`)."""
    from mbus_framework.pipeline.results import build_result

    if measurement.truth and set(measurement.truth) != set(c.model.parameter_names):
        measurement = replace(measurement, truth=None)  # the truth is another model's parameters
    doc = build_result(c, measurement, row.problem, row.fit, waveform, compensation)
    unc = doc.get("uncertainty") or {}
    row.properties = dict(doc["properties"])
    row.property_units = dict(doc["property_units"])
    row.property_standard_errors = {k: float(v) for k, v in (unc.get("property_standard_errors") or {}).items()}
    if unc.get("standard_errors"):  # the sandwich estimate when the output is compensated, as a single run
        row.standard_errors = {k: float(v) for k, v in unc["standard_errors"].items()}
    row.warnings = list(doc.get("warnings") or [])


def render_table(table: ComparisonTable, parameters: bool = True) -> str:
    """Plain-text table: one line per model (best marked '*'), then each model's parameter and
    property estimates with standard errors and units, and its warnings."""
    crit = table.criterion.upper()
    head = (f"{'':1} {'model':<22} {'p':>3} {'cost':>12} {'AIC':>12} {'BIC':>12} {'d' + crit:>10} "
            f"{'LB Q':>9} {'LB p':>8} {'white':>5}  status")
    lines = [f"model comparison on {table.n_obs} samples (best = smallest {crit}, marked *)", head,
             "-" * len(head)]
    for r in table.rows:
        if r.error:
            lines.append(f"  {r.name:<22} {r.n_params:>3} {'-':>12} {'-':>12} {'-':>12} {'-':>10} "
                         f"{'-':>9} {'-':>8} {'-':>5}  failed: {r.error}")
            continue
        lines.append(
            f"{'*' if r.best else ' '} {r.name:<22} {r.n_params:>3} {r.cost:>12.5g} {r.aic:>12.6g} {r.bic:>12.6g} "
            f"{r.delta:>10.4g} {r.ljung_box_q:>9.4g} {r.ljung_box_p:>8.3g} {'yes' if r.white else 'no':>5}  "
            f"{'converged' if r.success else 'not converged'} ({r.wall_time_s:.1f} s)"
        )
    if parameters:
        for r in table.rows:
            if r.error or not r.parameters:
                continue
            lines.append("")
            lines.append(f"{r.name}{'  (best)' if r.best else ''}: residual std {r.residual_std:.4g}")
            rel = r.relative_standard_errors()
            for nm, v in r.parameters.items():
                unit = r.parameter_units.get(nm, "")
                if nm in r.standard_errors:
                    lines.append(f"    {nm:<18} {v:>13.6g} +- {r.standard_errors[nm]:<11.4g} {unit:<8} "
                                 f"({100 * rel[nm]:.3g} %)")
                else:
                    lines.append(f"    {nm:<18} {v:>13.6g} {'':<14} {unit:<8} (fixed)")
            for nm, v in r.properties.items():
                se = r.property_standard_errors.get(nm)
                unit = r.property_units.get(nm, "")
                rse = f" ({100 * se / abs(v):.3g} %)" if se is not None and np.isfinite(se) and v else ""
                spread = f"+- {se:<11.4g}" if se is not None and np.isfinite(se) else f"{'':<14}"
                lines.append(f"    {nm:<18} {v:>13.6g} {spread} {unit:<8}{rse}")
            lines += [f"    warning: {w}" for w in r.warnings]
    return "\n".join(lines)


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if np.isfinite(v) else None
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


# --------------------------------------------------------------------------------------
# From a config file (what ``mbus-run CONFIG --compare-models a,b,c`` calls)
# --------------------------------------------------------------------------------------


def build_candidate(registry, name: str, sample, base_options: Mapping[str, Any], source: str = "<config>") -> MediumModel:
    """Model ``name`` for ``sample``; options of the configured model that the other model
    also has (e.g. ``n_elements``) carry over, the rest take that model's defaults."""
    from mbus_framework.pipeline.config import validate_options

    spec = registry.get("model", name)
    opts_cls = spec.implementation.Options
    fields = getattr(opts_cls, "model_fields", {})
    carried = {k: v for k, v in dict(base_options).items() if k in fields}
    options = validate_options(opts_cls, carried, f"model.options (for '{name}')", source)
    return spec.implementation(sample, options)


def run_comparison(
    config_path: str | Path,
    model_names: Sequence[str],
    overrides: Sequence[str] | None = None,
    out_dir: str | Path | None = None,
    registry=None,
    progress=None,
    plots: bool | None = None,
) -> tuple[ComparisonTable, str]:
    """Acquire once (as the config says; the record is saved first), then fit each named
    model with the configured solver and compensator. The configured model keeps its
    options, initial and fixed values; the others carry over shared options. Writes
    comparison.txt, comparison.json (and comparison_bode.png) into the run folder."""
    import yaml

    from mbus_framework.engine.control_interop import write_bode_plot
    from mbus_framework.estimation.spectral import excited_band
    from mbus_framework.pipeline.units import record_units
    from mbus_framework.interfaces.registry import default_registry
    from mbus_framework.pipeline.config import load_config
    from mbus_framework.pipeline.run import acquire, build_components, designed_waveform, new_run_dir
    from mbus_framework.pipeline.folder_report import write_folder_report
    from mbus_framework.pipeline.storage import atomic_write_json, atomic_write_text

    source = str(config_path)
    names = [n.strip() for n in model_names if n.strip()]
    if not names:
        from mbus_framework.errors import ConfigError

        raise ConfigError("--compare-models: give at least one model name")
    config = load_config(config_path, list(overrides or []))
    registry = registry or default_registry()
    c = build_components(config, source, registry)
    candidates = []
    for name in names:
        if name == config.model.name:
            initial = None
            if config.model.initial:
                initial = c.model.theta_from_mapping(config.model.initial, f"{source}: model.initial")
            candidates.append(Candidate(name, c.model, initial, dict(c.config.model.fixed)))
        else:
            candidates.append(Candidate(name, build_candidate(registry, name, c.sample, config.model.options, source)))
    waveform = designed_waveform(c)
    run_dir = Path(out_dir) if out_dir else new_run_dir(config, source)
    run_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_text(run_dir / "config.yaml", yaml.safe_dump(config.model_dump(mode="json"), sort_keys=False))
    measurement = acquire(c, run_dir, waveform)
    data = c.compensator.apply(measurement)
    cdata = ComparisonData(data.t, data.u, data.y, config.model.hold, c.compensator.output_filter())
    table = compare_models(cdata, candidates, c.solver, progress=progress)
    for row in table.rows:
        if row.fit is not None:
            review_row(row, replace(c, model=row.model), measurement, waveform, data.meta.get("compensation"))
    text = render_table(table)
    atomic_write_text(run_dir / "comparison.txt", text + "\n")
    atomic_write_json(run_dir / "comparison.json", {"config": source, "run_dir": str(run_dir), **table.as_dict()})
    if (plots if plots is not None else config.output.plots) and table.best is not None:
        best = table.row(table.best)
        others = [(r.name, r.model, r.fit.theta) for r in table.rows if r is not best and r.fit is not None]
        units = record_units(measurement.meta, data.meta.get("compensation"))
        write_bode_plot(run_dir / "comparison_bode.png", best.model, best.fit.theta, data.u, data.y, data.dt,
                        label=f"{best.name} (best)", extra_models=others,
                        title="model comparison over the record's excited band",
                        units=(units["u"], units["y"]), band=excited_band(data.u, data.dt))
    write_folder_report(run_dir, "mbus model comparison", text, source)
    return table, text
