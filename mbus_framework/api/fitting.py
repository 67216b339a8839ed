"""Run a config, fit arrays, read a record: the three entry points of the Python API."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterator, Mapping, Sequence

import numpy as np

from mbus_framework.api.result import Result
from mbus_framework.interfaces.backend import AcquisitionContext, check_record

if TYPE_CHECKING:  # pragma: no cover
    from mbus_framework.estimation.problem import Progress
    from mbus_framework.joint.result import JointResult
    from mbus_framework.interfaces.registry import Registry
    from mbus_framework.interfaces.sample import Sample

ARRAYS = "<arrays>"


@dataclass
class Record:
    """A recorded input/output pair: t [s] from 0, input u, output y, and what the reader knows
    about it (``meta``: source files, alignment, instruments). Unpacks as ``t, u, y = record``."""

    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    meta: dict[str, Any] = field(default_factory=dict)

    def __iter__(self) -> Iterator[np.ndarray]:
        return iter((self.t, self.u, self.y))

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])


def _progress(progress: "bool | Progress | None") -> "Progress | None":
    from mbus_framework.pipeline.progress import make_progress

    if progress is None or isinstance(progress, bool):
        return make_progress(progress)
    return progress


def _override_list(overrides: Mapping[str, Any] | Sequence[str] | None) -> list[str]:
    """``{"a.b": 4}`` or ``["a.b=4"]`` -> ``["a.b=4"]`` (values written as YAML)."""
    import yaml

    if overrides is None:
        return []
    if isinstance(overrides, Mapping):
        out = []
        for key, value in overrides.items():
            text = value if isinstance(value, str) else yaml.safe_dump(value, default_flow_style=True).strip()
            if text.endswith("\n..."):
                text = text[: -len("\n...")]
            out.append(f"{key}={text}")
        return out
    if isinstance(overrides, str):
        return [overrides]
    return list(overrides)


def run_config(
    config: str | Path | Mapping[str, Any],
    overrides: Mapping[str, Any] | Sequence[str] | None = None,
    out_dir: str | Path | None = None,
    *,
    plots: bool | None = None,
    progress: "bool | Progress | None" = None,
    source: str | None = None,
    registry: "Registry | None" = None,
    overwrite: bool = False,
) -> Result:
    """Run one identification from a YAML config file or a config mapping, as ``mbus-run``
    does: acquire (the record is saved first), fit, and write a run folder (``out_dir``, default
    ``runs/<time>-<name>/``) with result.json, figures and report.html.

    ``overrides`` are dotted keys, ``{"solver.options.strategy.n_starts": 4}`` or
    ``["solver.options.strategy.n_starts=4"]``; ``plots`` None follows ``output.plots``;
    ``progress`` None shows a bar on an interactive terminal only; an ``out_dir`` that already
    holds a run is replaced only with ``overwrite``.
    """
    from mbus_framework.pipeline.run import execute

    outcome = execute(config, _override_list(overrides), out_dir, progress=_progress(progress), registry=registry,
                      plots=plots, source=source, overwrite=overwrite)
    return Result.from_outcome(outcome)


def fit(
    t: Any,
    u: Any = None,
    y: Any = None,
    *,
    sample: "Mapping[str, float] | Sample | Sequence[Mapping[str, float] | Sample]",
    model: str = "kelvin_voigt",
    model_options: Mapping[str, Any] | None = None,
    initial: Mapping[str, float] | None = None,
    fixed: Mapping[str, float] | None = None,
    hold: str = "zoh",
    solver: str = "scipy_lm",
    solver_options: Mapping[str, Any] | None = None,
    config: Mapping[str, Any] | None = None,
    title: str | None = None,
    out_dir: str | Path | None = None,
    plots: bool = True,
    progress: "bool | Progress | None" = False,
    shared: Sequence[str] | None = None,
    per_record: Sequence[str] | None = None,
    labels: Sequence[str] | None = None,
) -> "Result | JointResult":
    """Fit a medium model to arrays: t [s] (uniform), input u, output y.

    Joint fit: ``fit([record_a, record_b], sample=[geom_a, geom_b], shared=[...],
    per_record=["input_gain"])`` (Records or (t, u, y) triples; ``sample`` one geometry or one
    per record) fits the records jointly, the ``shared`` properties (default: all not per record)
    common to all, and returns a :class:`~mbus_framework.joint.result.JointResult`
    (:mod:`mbus_framework.joint`; ``fixed`` and ``out_dir`` are for single records).

    ``sample`` is the geometry, ``{"length": L [m], "diameter": D [m], "density": rho [kg/m^3]}``
    (or a :class:`~mbus_framework.plugins.Sample`); ``model`` a registered medium model with its
    ``model_options``; ``initial`` and ``fixed`` parameters (or properties) as in a config's
    ``model`` section. ``config`` adds further config sections (``nuisance``, ``compensator``,
    ``identifiability``). Nothing is written unless ``out_dir`` is given; then it becomes a run
    folder whose config.yaml re-fits the saved measurement.csv with ``mbus-run``.
    """
    from mbus_framework.joint.api import fit_records, is_record_list

    if is_record_list(t, u, y):
        if fixed or out_dir is not None:
            from mbus_framework.errors import ConfigError

            raise ConfigError("fit: fixed and out_dir are for one record; a joint fit takes neither")
        return fit_records(t, sample=sample, model=model, model_options=model_options, initial=initial, hold=hold,
                           solver=solver, solver_options=solver_options, config=config, title=title, shared=shared,
                           per_record=per_record, labels=labels, progress=_progress(progress))
    if u is None or y is None:
        raise TypeError("fit: give t, u, y arrays, or a list of records for a joint fit")
    if shared is not None or per_record is not None:
        from mbus_framework.errors import ConfigError

        raise ConfigError("fit: shared and per_record need a list of records (a joint fit)")
    geometry = sample if isinstance(sample, Mapping) else {
        "length": sample.length, "diameter": sample.diameter, "density": sample.density}
    mapping: dict[str, Any] = {
        **dict(config or {}),
        "title": title,
        "sample": dict(geometry),
        "model": {"name": model, "options": dict(model_options or {}), "initial": dict(initial) if initial else None,
                  "fixed": dict(fixed or {}), "hold": hold},
        "backend": {"name": "file", "options": {"path": "measurement.csv"}},
        "solver": {"name": solver, "options": dict(solver_options or {})},
    }
    measurement = check_record(ARRAYS, t, u, y)
    if out_dir is not None:
        from mbus_framework.pipeline.run import execute

        outcome = execute(mapping, None, out_dir, progress=_progress(progress), plots=plots, source=title or "arrays",
                          measurement=measurement)
        return Result.from_outcome(outcome)
    from mbus_framework.pipeline.run import designed_waveform, estimate, load_components

    c = load_components(mapping, source=ARRAYS)
    return Result.from_outcome(estimate(c, measurement, designed_waveform(c), _progress(progress)))


def load_record(path: str | Path, response_path: str | Path | None = None, **options: Any) -> Record:
    """Read a record the way the ``file`` backend does: a t,u,y ``.csv``/``.tsv``/``.txt``/``.npz``,
    a MATLAB ``.mat`` file, a GDS-2000 CSV export pair (``path`` the excitation channel,
    ``response_path`` the response), or a ``lab`` run folder. ``options`` are further
    ``backend.options`` of the file backend (reader options such as ``columns``, ``delimiter``,
    ``decimal``; ``variables`` for .mat files; ``processing``, ``format``, ``counts_per_division``)."""
    from mbus_framework.interfaces.registry import default_registry
    from mbus_framework.pipeline.config import validate_options

    registry = default_registry()
    spec = registry.get("backend", "file")
    raw = {"path": str(path), **options}
    if response_path is not None:
        raw["response_path"] = str(response_path)
    backend = spec.implementation(validate_options(spec.implementation.Options, raw, "load_record"))
    m = backend.acquire(AcquisitionContext(None, None, None, registry))  # type: ignore[arg-type]
    return Record(m.t, m.u, m.y, m.meta)
