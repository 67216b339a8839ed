"""One identification run, flowing one way:

config -> components -> acquisition (saved to disk first) -> compensation -> estimation
-> result.json -> report.
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
from mbus_framework.pipeline.results import build_result
from mbus_framework.estimation.problem import FitProblem, FitResult, Progress
from mbus_framework.pipeline.storage import atomic_write_json, atomic_write_text, write_waveforms

MEASUREMENT_FILE = "measurement.csv"


@dataclass
class RunOutcome:
    run_dir: Path
    components: Components
    measurement: Measurement
    fit: FitResult
    result: dict[str, Any]


def new_run_dir(config: RunConfig, source: str) -> Path:
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    name = re.sub(r"[^A-Za-z0-9_.-]+", "_", Path(source).stem).strip("_.") or "run"
    base = Path(config.output.directory) / f"{stamp}-{name}"
    path, k = base, 1
    while path.exists():
        k += 1
        path = base.with_name(f"{base.name}-{k}")
    return path


def acquire(c: Components, run_dir: Path, waveform: Waveform) -> Measurement:
    """Acquire and write the raw record (and its metadata) before anything is fitted."""
    context = AcquisitionContext(waveform, c.sample, c.model, c.registry, run_dir, c.source)
    m = c.backend.acquire(context)
    write_waveforms(run_dir / MEASUREMENT_FILE, m.t, m.u, m.y)
    atomic_write_json(run_dir / "measurement.json", {"truth": m.truth, "meta": m.meta, "n_samples": len(m.t), "dt_s": m.dt})
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


def execute(
    config_path: str | Path | Mapping[str, Any],
    overrides: list[str] | None = None,
    out_dir: str | Path | None = None,
    progress: Progress | None = None,
    registry: Registry | None = None,
    plots: bool | None = None,
    source: str | None = None,
) -> RunOutcome:
    """Run one identification from a config file, or from a config mapping (``source`` names
    it in error messages and the default run-folder name); returns everything it produced."""
    if isinstance(config_path, Mapping):
        source = source or "<config>"
        data = apply_overrides(dict(config_path), overrides or [])
        config = validate_structure(data, source)
    else:
        source = source or str(config_path)
        config = load_config(config_path, overrides)
    c = build_components(config, source, registry)
    if c.config.model.initial:  # fail on bad initial values before acquiring anything
        c.model.theta_from_mapping(c.config.model.initial, f"{source}: model.initial")
    waveform = c.excitation.waveform()
    run_dir = Path(out_dir) if out_dir else new_run_dir(config, source)
    run_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_text(run_dir / "config.yaml", yaml.safe_dump(config.model_dump(mode="json"), sort_keys=False))

    measurement = acquire(c, run_dir, waveform)
    compensated = c.compensator.apply(measurement)
    problem = make_problem(c, compensated)
    try:
        fit = c.solver.solve(problem, progress)
    except np.linalg.LinAlgError as exc:
        raise EstimationError(f"{source}: estimation failed: {exc}") from None
    result = build_result(c, measurement, problem, fit, waveform, compensated.meta.get("compensation"))
    if fit.trace:
        write_trace(run_dir / "trace.csv", fit)
        result["files"]["trace"] = "trace.csv"
    atomic_write_json(run_dir / "result.json", result)
    if plots if plots is not None else config.output.plots:
        from mbus_framework.pipeline.report import write_plots

        result["files"].update(write_plots(run_dir, c, problem, fit, waveform))
        atomic_write_json(run_dir / "result.json", result)
    return RunOutcome(run_dir, c, measurement, fit, result)
