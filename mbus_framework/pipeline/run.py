"""One identification run, flowing one way:

config -> components -> acquisition (saved to disk first) -> compensation -> estimation
-> result.json -> figures and report.html.

:func:`execute` does all of it into a run folder; :func:`load_components` and :func:`estimate`
are the steps without files (the Python API fits arrays with them).
"""
from __future__ import annotations

import datetime as _dt
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from mbus_framework.interfaces.backend import AcquisitionContext, Measurement
from mbus_framework.pipeline.config import RunConfig, apply_overrides, load_config, validate_structure
from mbus_framework.errors import ConfigError, EstimationError
from mbus_framework.interfaces.excitation import Waveform
from mbus_framework.estimation.nuisance import NuisanceSettings
from mbus_framework.interfaces.registry import Registry
from mbus_framework.pipeline.components import Components, build_components
from mbus_framework.pipeline.figures import FitData
from mbus_framework.pipeline.recorded_input import consistency_warnings, excitation_section
from mbus_framework.pipeline.results import build_result
from mbus_framework.pipeline.run_report import REPORT_FILE, write_report
from mbus_framework.estimation.problem import FitProblem, FitResult, Progress
from mbus_framework.pipeline.storage import atomic_write_json, atomic_write_text, write_waveforms

MEASUREMENT_FILE = "measurement.csv"


@dataclass
class RunOutcome:
    """Everything one run produced; ``run_dir`` is None for a fit kept in memory."""

    run_dir: Path | None
    components: Components
    measurement: Measurement
    fit: FitResult
    result: dict[str, Any]
    problem: FitProblem | None = None
    designed: Waveform | None = None

    def fit_data(self) -> FitData:
        """The arrays behind the figures (fitted record, prediction, trace, design)."""
        if self.problem is None:
            raise ValueError("this outcome has no fitting problem")
        return FitData.from_fit(self.problem, self.fit, self.designed, self.components.config.title or self.components.source)


def new_run_dir(config: RunConfig, source: str) -> Path:
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    name = re.sub(r"[^A-Za-z0-9_.-]+", "_", Path(source).stem).strip("_.") or "run"
    base = Path(config.output.directory) / f"{stamp}-{name}"
    path, k = base, 1
    while path.exists():
        k += 1
        path = base.with_name(f"{base.name}-{k}")
    return path


def acquire(c: Components, run_dir: Path, waveform: Waveform | None) -> Measurement:
    """Acquire and write the raw record (and its metadata) before anything is fitted;
    ``waveform`` is the designed excitation, or None when the backend reads the input."""
    context = AcquisitionContext(waveform, c.sample, c.model, c.registry, run_dir, c.source)
    m = c.backend.acquire(context)
    save_measurement(run_dir, m)
    return m


def nuisance_settings(config: RunConfig) -> NuisanceSettings:
    n = config.nuisance
    return NuisanceSettings(
        estimate_gain=n.input_gain.estimate,
        gain=1.0 if n.input_gain.value is None else n.input_gain.value,
        estimate_delay=n.delay.estimate,
        delay=0.0 if n.delay.value is None else n.delay.value,
        max_delay=n.max_delay,
    )


def make_problem(c: Components, m: Measurement) -> FitProblem:
    nuisance = nuisance_settings(c.config)
    initial = None
    if c.config.model.initial:
        initial = c.model.theta_from_mapping(c.config.model.initial, f"{c.source}: model.initial")
        if nuisance.active:
            initial = np.r_[initial, nuisance.gain, nuisance.delay]
    if nuisance.active and c.config.model.hold != "zoh":
        raise ConfigError(f"{c.source}: nuisance: an input gain or delay needs model.hold: zoh")
    return FitProblem(
        model=c.model,
        t=m.t,
        u=m.u,
        y=m.y,
        initial=initial,
        fixed=dict(c.config.model.fixed),
        hold=c.config.model.hold,
        output_filter=c.compensator.output_filter(),
        nuisance=nuisance,
        noise_filter=c.compensator.noise_filter(),
    )


def write_trace(path: Path, fit: FitResult) -> None:
    """Convergence trace (Fig. 3.8): iteration, stage, cost, then one column per parameter."""
    lines = [",".join(["iteration", "stage", "cost", *fit.names])]
    for rec in fit.trace:
        values = ",".join(f"{v:.17g}" for v in rec["theta"])
        lines.append(f"{rec['iteration']},{rec.get('stage', '')},{rec['cost']:.17g},{values}")
    atomic_write_text(path, "\n".join(lines) + "\n")


def load_components(
    config: str | Path | Mapping[str, Any],
    overrides: list[str] | None = None,
    source: str | None = None,
    registry: Registry | None = None,
) -> Components:
    """Read (a file) or take (a mapping) a run config, apply ``--set`` overrides, validate both
    stages and the initial values, and build the plugin instances; nothing is acquired."""
    if isinstance(config, Mapping):
        source = source or "<config>"
        run_config = validate_structure(apply_overrides(dict(config), overrides or []), source)
    else:
        source = source or str(config)
        run_config = load_config(config, overrides)
    c = build_components(run_config, source, registry)
    if c.config.model.initial:  # fail on bad initial values before acquiring anything
        c.model.theta_from_mapping(c.config.model.initial, f"{source}: model.initial")
    return c


def designed_waveform(c: Components) -> Waveform | None:
    """The configured excitation's samples, or None when the input comes from the record."""
    return c.excitation.waveform() if c.excitation is not None else None


def input_warnings(m: Measurement, designed: Waveform | None) -> list[str]:
    """The backend's own warnings (e.g. a partial acquisition) and, with a design, where the
    design and the record disagree (:func:`~mbus_framework.pipeline.recorded_input.consistency_warnings`)."""
    out = [str(w) for w in m.meta.get("warnings", [])]
    if designed is not None:
        out += consistency_warnings(designed, m)
    return out


def estimate(c: Components, m: Measurement, designed: Waveform | None = None,
             progress: Progress | None = None) -> RunOutcome:
    """Compensate, fit and build the result document; touches no file."""
    compensated = c.compensator.apply(m)
    problem = make_problem(c, compensated)
    try:
        fit = c.solver.solve(problem, progress)
    except np.linalg.LinAlgError as exc:
        raise EstimationError(f"{c.source}: estimation failed: {exc}") from None
    result = build_result(c, m, problem, fit, designed, compensated.meta.get("compensation"))
    result["excitation"] = excitation_section(c.config.excitation.name if c.config.excitation else None, designed, m)
    result["warnings"] = input_warnings(m, designed) + list(result.get("warnings", []))
    return RunOutcome(None, c, m, fit, result, problem, designed)


def write_outputs(run_dir: Path, outcome: RunOutcome, plots: bool = True) -> None:
    """trace.csv and result.json, then the figures (PNG) and report.html; result.json is written
    before any figure is drawn, so a plotting failure cannot lose the estimates."""
    result, fit = outcome.result, outcome.fit
    if fit.trace:
        write_trace(run_dir / "trace.csv", fit)
        result["files"]["trace"] = "trace.csv"
    atomic_write_json(run_dir / "result.json", result)
    pngs = None
    if plots:
        from mbus_framework.pipeline.report import write_figures

        files, pngs = write_figures(run_dir, outcome.fit_data())
        result["files"].update(files)
    result["files"]["report"] = REPORT_FILE
    atomic_write_json(run_dir / "result.json", result)
    write_report(run_dir, result, pngs)


def write_config(run_dir: Path, config: RunConfig) -> None:
    atomic_write_text(run_dir / "config.yaml", yaml.safe_dump(config.model_dump(mode="json"), sort_keys=False))


def save_measurement(run_dir: Path, m: Measurement) -> None:
    """The record and its metadata, written before anything is fitted."""
    write_waveforms(run_dir / MEASUREMENT_FILE, m.t, m.u, m.y)
    atomic_write_json(run_dir / "measurement.json", {"truth": m.truth, "meta": m.meta, "n_samples": len(m.t), "dt_s": m.dt})


def execute(
    config_path: str | Path | Mapping[str, Any],
    overrides: list[str] | None = None,
    out_dir: str | Path | None = None,
    progress: Progress | None = None,
    registry: Registry | None = None,
    plots: bool | None = None,
    source: str | None = None,
    measurement: Measurement | None = None,
) -> RunOutcome:
    """Run one identification from a config file, or from a config mapping (``source`` names
    it in error messages and the default run-folder name), into a run folder; returns everything
    it produced. With ``measurement`` the backend is not asked: that record is saved and fitted."""
    c = load_components(config_path, overrides, source, registry)
    designed = designed_waveform(c)
    run_dir = Path(out_dir) if out_dir else new_run_dir(c.config, c.source)
    run_dir.mkdir(parents=True, exist_ok=True)
    write_config(run_dir, c.config)
    if measurement is None:
        measurement = acquire(c, run_dir, designed)
    else:
        save_measurement(run_dir, measurement)
    outcome = estimate(c, measurement, designed, progress)
    outcome.run_dir = run_dir
    write_outputs(run_dir, outcome, plots if plots is not None else c.config.output.plots)
    return outcome
