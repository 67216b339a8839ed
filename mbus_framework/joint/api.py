"""``mbus.fit([record_a, record_b], ...)``: a joint fit of records kept in memory."""
from __future__ import annotations

from typing import Any, Mapping, Sequence

from mbus_framework.errors import ConfigError
from mbus_framework.joint.result import JointResult


def is_record_list(t: Any, u: Any, y: Any) -> bool:
    """True for ``fit([rec, ...])``: a list of Records or (t, u, y) triples and no u, y."""
    if u is not None or y is not None or not isinstance(t, (list, tuple)) or not t:
        return False
    from mbus_framework.api.fitting import Record

    return all(isinstance(r, Record) or (isinstance(r, (list, tuple)) and len(r) == 3) for r in t)


def _geometry(sample: Any) -> dict[str, float]:
    if isinstance(sample, Mapping):
        return dict(sample)
    return {"length": sample.length, "diameter": sample.diameter, "density": sample.density}


def fit_records(records: Sequence[Any], *, sample: Any, model: str, model_options: Mapping[str, Any] | None,
                initial: Mapping[str, float] | None, hold: str, solver: str, solver_options: Mapping[str, Any] | None,
                config: Mapping[str, Any] | None, title: str | None, shared: Sequence[str] | None,
                per_record: Sequence[str] | None, labels: Sequence[str] | None, progress=None) -> JointResult:
    """Fit records jointly; ``sample`` one geometry for all or one per record (a list)."""
    from mbus_framework.api.fitting import ARRAYS
    from mbus_framework.interfaces.backend import check_record
    from mbus_framework.joint.run import RecordInput, check_records, merge_nuisance, run_records
    from mbus_framework.pipeline.run import designed_waveform, load_components

    n = len(records)
    samples = list(sample) if isinstance(sample, (list, tuple)) else [sample] * n
    if len(samples) != n:
        raise ConfigError(f"sample: {len(samples)} geometries for {n} records; give one, or one per record")
    labels = list(labels) if labels is not None else [f"record {i + 1}" for i in range(n)]
    if len(labels) != n or len(set(labels)) != n:
        raise ConfigError(f"labels: give {n} distinct labels, one per record")
    inputs = []
    for i, (rec, geometry, label) in enumerate(zip(records, samples, labels)):
        t, u, y = rec
        mapping: dict[str, Any] = {
            **dict(config or {}),
            "title": title,
            "sample": _geometry(geometry),
            "model": {"name": model, "options": dict(model_options or {}), "initial": dict(initial) if initial else None,
                      "hold": hold},
            "backend": {"name": "file", "options": {"path": "measurement.csv"}},
            "solver": {"name": solver, "options": dict(solver_options or {})},
        }
        c = load_components(merge_nuisance(mapping, per_record), source=f"records[{i}]")
        m = check_record(f"{ARRAYS} records[{i}]", t, u, y)
        m.meta.setdefault("source", label)
        inputs.append(RecordInput(label, c, m, designed_waveform(c)))
    check_records(labels, [r.components for r in inputs], shared, per_record, "<records>")
    outcome = run_records(inputs, shared, per_record, "<records>", title, progress)
    return JointResult(outcome.document, None, outcome)
