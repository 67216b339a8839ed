"""One identification run, flowing one way:

config -> components -> acquisition (saved to disk first) -> compensation -> estimation
-> result.json -> figures and report.html.

:func:`execute` does all of it into a run folder; :func:`load_components` and :func:`estimate`
are the steps without files (the Python API fits arrays with them).
"""
from __future__ import annotations

from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import yaml

from mbus_framework.interfaces.backend import AcquisitionContext, Measurement
from mbus_framework.pipeline.config import RunConfig, apply_overrides, load_config, validate_structure
from mbus_framework.errors import ConfigError
from mbus_framework.interfaces.excitation import Waveform
from mbus_framework.estimation.nuisance import NuisanceSettings
from mbus_framework.interfaces.registry import Registry, default_registry
from mbus_framework.pipeline import figure_workers, interrupts, limits
from mbus_framework.pipeline.figure_workers import Helpers
from mbus_framework.pipeline.components import Components, build_components
from mbus_framework.pipeline.figures import FitData
from mbus_framework.pipeline.reduction import reduce_record
from mbus_framework.pipeline.recorded_input import consistency_warnings, excitation_section
from mbus_framework.pipeline.results import MEASUREMENT_WARNING, build_result
from mbus_framework.pipeline.run_folder import RunFolder, default_name
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
        return FitData.from_fit(self.problem, self.fit, self.designed, self.components.config.title or self.components.source,
                                self.result.get("dispersion"), self.result.get("record_units"))


def new_run_dir(config: RunConfig, source: str) -> Path:
    """A free default folder name (not reserved: runs reserve theirs with :class:`RunFolder`)."""
    base = Path(config.output.directory) / default_name(source)
    path, k = base, 1
    while path.exists():
        k += 1
        path = base.with_name(f"{base.name}-{k}")
    return path


def acquire(c: Components, run_dir: Path, waveform: Waveform | None) -> Measurement:
    """Acquire and write the raw record (and its metadata) before anything is fitted;
    ``waveform`` is the designed excitation, or None when the backend reads the input."""
    context = AcquisitionContext(waveform, c.sample, c.model, c.registry, run_dir, c.source)
    m = limits.checked_measurement(c.backend.acquire(context), c)
    from mbus_framework.pipeline.input_files import input_files

    save_measurement(run_dir, m, input_files(c.config.model_dump(mode="json")))
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
    stages, build the plugin instances and check initial values, parameter ranges and memory
    (:func:`~mbus_framework.pipeline.limits.check_run`); nothing is acquired."""
    if isinstance(config, Mapping):
        source = source or "<config>"
        run_config = validate_structure(apply_overrides(dict(config), overrides or []), source)
    else:
        source = source or str(config)
        run_config = load_config(config, overrides, check_files=True)
    registry = registry or default_registry()
    with limits.plugin_failures(registry, source):  # a third-party plugin's bug is one named line
        c = build_components(run_config, source, registry)
        limits.check_run(c)  # before anything is allocated or acquired
    return c


def designed_waveform(c: Components) -> Waveform | None:
    """The configured excitation's samples (checked), or None when the input comes from the record."""
    with limits.plugin_failures(c.registry, c.source):
        return limits.checked_waveform(c)


def input_warnings(m: Measurement, designed: Waveform | None) -> list[str]:
    """Where the design and the record disagree (:func:`~mbus_framework.pipeline.recorded_input.consistency_warnings`);
    the backend's own warnings (a partial acquisition) are in the result's ``measurement:`` lines."""
    return consistency_warnings(designed, m) if designed is not None else []


def estimate(c: Components, m: Measurement, designed: Waveform | None = None,
             progress: Progress | None = None,
             before_fit: Callable[[FitProblem], None] | None = None) -> RunOutcome:
    """Compensate, fit and build the result document; touches no file. Every stage is an
    interruption checkpoint (:mod:`~mbus_framework.pipeline.interrupts`); numeric failures inside
    the solver or the uncertainty analysis are one-line errors (:func:`~mbus_framework.pipeline.limits.estimation_boundary`).
    ``before_fit`` gets the fitting problem before the solver starts (a run sends the figures
    that need no fit to its figure helpers)."""
    recorded = m
    m, reduction = reduce_record(m, c.config.estimation, c.source)
    limits.check_memory(c, len(m.t), "the record (saved; not fitted)", float(m.t[1] - m.t[0]))
    with limits.plugin_failures(c.registry, c.source):
        compensated = c.compensator.apply(m)
        problem = make_problem(c, compensated)
    if before_fit is not None:
        before_fit(problem)
    interrupts.check()
    with limits.estimation_boundary(c):
        fit = c.solver.solve(problem, interrupts.CheckedProgress(progress))
    interrupts.check()
    with limits.estimation_boundary(c):  # the uncertainty analysis
        result = build_result(c, m, problem, fit, designed, compensated.meta.get("compensation"))
    result["excitation"] = excitation_section(c.config.excitation.name if c.config.excitation else None, designed,
                                              recorded)
    if reduction is not None:
        result["reduction"] = reduction  # the window and decimation actually fitted
    if isinstance(m.meta.get("pretrigger"), dict):
        result["pretrigger"] = m.meta["pretrigger"]  # what the file backend cut and subtracted
    measured = [w for w in result.get("warnings", []) if w.startswith(MEASUREMENT_WARNING)]
    others = [w for w in result.get("warnings", []) if not w.startswith(MEASUREMENT_WARNING)]
    result["warnings"] = measured + input_warnings(recorded, designed) + others
    return RunOutcome(None, c, m, fit, result, problem, designed)


def write_outputs(run_dir: Path, outcome: RunOutcome, plots: bool = True, helpers: Helpers | None = None,
                  fmt: str | None = None) -> None:
    """trace.csv and result.json, then the figures (``fmt``, default the config's
    ``output.figures``: SVG drawn here, or PNG drawn by ``helpers`` when given, which get the data
    first and draw while this process writes) and report.html; result.json is written before any
    figure is drawn, so a plotting failure cannot lose the estimates."""
    fmt = fmt or outcome.components.config.output.figures
    result, fit = outcome.result, outcome.fit
    data = outcome.fit_data() if plots else None
    if data is not None and helpers is not None:
        helpers.submit(data)
    if fit.trace:
        write_trace(run_dir / "trace.csv", fit)
        result["files"]["trace"] = "trace.csv"
    atomic_write_json(run_dir / "result.json", result)
    pngs = None
    if data is not None:
        from mbus_framework.pipeline.report import write_figures

        files, pngs = write_figures(run_dir, data, helpers=helpers, fmt=fmt)
        result["files"].update(files)
    result["files"]["report"] = REPORT_FILE
    atomic_write_json(run_dir / "result.json", result)
    write_report(run_dir, result, pngs)


def write_config(run_dir: Path, config: RunConfig) -> None:
    atomic_write_text(run_dir / "config.yaml", yaml.safe_dump(config.model_dump(mode="json"), sort_keys=False))


def save_measurement(run_dir: Path, m: Measurement, inputs: list | None = None) -> None:
    """The record and its metadata, written before anything is fitted; ``inputs``: the files the
    config names, [{key, path, sha256}] (:mod:`~mbus_framework.pipeline.input_files`)."""
    write_waveforms(run_dir / MEASUREMENT_FILE, m.t, m.u, m.y)
    doc = {"truth": m.truth, "meta": m.meta, "n_samples": len(m.t), "dt_s": m.dt}
    if inputs:
        doc["inputs"] = inputs
    atomic_write_json(run_dir / "measurement.json", doc)


def execute(
    config_path: str | Path | Mapping[str, Any],
    overrides: list[str] | None = None,
    out_dir: str | Path | None = None,
    progress: Progress | None = None,
    registry: Registry | None = None,
    plots: bool | None = None,
    source: str | None = None,
    measurement: Measurement | None = None,
    overwrite: bool = False,
) -> RunOutcome:
    """Run one identification from a config file, or from a config mapping (``source`` names
    it in error messages and the default run-folder name), into a run folder; returns everything
    it produced. With ``measurement`` the backend is not asked: that record is saved and fitted.

    The run folder (``out_dir``, default a new ``<output.directory>/<date-time>-<config>``) is
    reserved exclusively (:class:`~mbus_framework.pipeline.run_folder.RunFolder`); a folder that
    already holds a run is replaced only with ``overwrite``."""
    c = load_components(config_path, overrides, source, registry)
    designed = designed_waveform(c)
    plots = plots if plots is not None else c.config.output.plots
    # PNG figures: forked now (before the folder's lock is taken), the figure helpers import
    # matplotlib while this process acquires and fits; closing them ends them if the run stops early
    png = plots and c.config.output.figures == "png"
    with (figure_workers.start() if png else None) or nullcontext() as helpers:
        folder = RunFolder.create(out_dir, parent=c.config.output.directory, source=c.source, overwrite=overwrite)
        with folder, limits.plugin_failures(c.registry, c.source):
            run_dir = folder.path
            write_config(run_dir, c.config)
            if measurement is None:
                measurement = acquire(c, run_dir, designed)
            else:
                save_measurement(run_dir, limits.checked_measurement(measurement, c))
            interrupts.check()
            early = None if helpers is None else (lambda p: helpers.draw_early(FitData.before_fit(p, designed)))
            outcome = estimate(c, measurement, designed, progress, early)
            outcome.run_dir = run_dir
            write_outputs(run_dir, outcome, plots, helpers)
            return outcome
