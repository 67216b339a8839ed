"""``mbus-run joint.yaml``: acquire every record into a run folder, fit jointly, write result.json.

The run folder holds config.yaml (the joint config as run), ``records/<k>/`` per record (its
config.yaml, measurement.csv and measurement.json, written before anything is fitted) and
result.json (:mod:`~mbus_framework.joint.run`).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import yaml

from mbus_framework.joint.config import split
from mbus_framework.joint.result import JointResult
from mbus_framework.joint.run import RecordInput, check_records, merge_nuisance, run_records


def load_joint(config: str | Path | Mapping[str, Any], overrides: list[str] | None = None):
    """(source, joint section, title, output directory, [(label, record config)]) with paths resolved."""
    from mbus_framework.pipeline.config import apply_overrides, read_yaml
    from mbus_framework.pipeline.config_paths import resolve

    if isinstance(config, Mapping):
        source, written, path = "<joint config>", dict(config), None
    else:
        source, path = str(config), Path(config)
        written = read_yaml(path)
    data = apply_overrides(written, overrides or [])
    section, base, records = split(data, source)
    out = []
    for i, (label, rec) in enumerate(records):
        rec = merge_nuisance(rec, section.per_record)
        if path is not None:
            rec = resolve(rec, rec, path, f"{source}: joint.records[{i}]", True)
        out.append((label, rec))
    output = (base.get("output") or {}).get("directory", "runs") if isinstance(base.get("output"), dict) else "runs"
    return source, section, base.get("title"), output, out


def run_joint_config(config: str | Path | Mapping[str, Any], overrides: list[str] | None = None,
                     out_dir: str | Path | None = None, progress=None, overwrite: bool = False) -> JointResult:
    """Run a joint config into a run folder (default ``<output.directory>/<time>-<config>``)."""
    from mbus_framework.pipeline import interrupts
    from mbus_framework.pipeline.run import acquire, designed_waveform, load_components
    from mbus_framework.pipeline.run_folder import RunFolder
    from mbus_framework.pipeline.storage import atomic_write_json, atomic_write_text

    source, section, title, output, records = load_joint(config, overrides)
    built = [(label, load_components(rec, source=f"{source}: joint.records[{i}]"))
             for i, (label, rec) in enumerate(records)]
    check_records([lab for lab, _ in built], [c for _, c in built], section.shared, section.per_record, source)
    folder = RunFolder.create(out_dir, parent=output, source=source, overwrite=overwrite)
    with folder:
        run_dir = folder.path
        raw = config if isinstance(config, Mapping) else yaml.safe_load(Path(config).read_text(encoding="utf-8"))
        atomic_write_text(run_dir / "config.yaml", yaml.safe_dump(dict(raw), sort_keys=False))
        inputs = []
        for k, (label, c) in enumerate(built):
            rec_dir = run_dir / "records" / f"{k + 1}"
            rec_dir.mkdir(parents=True, exist_ok=True)
            atomic_write_text(rec_dir / "config.yaml", yaml.safe_dump(c.config.model_dump(mode="json"), sort_keys=False))
            designed = designed_waveform(c)
            m = acquire(c, rec_dir, designed)
            m.meta.setdefault("source", f"records/{k + 1}/measurement.csv")
            inputs.append(RecordInput(label, c, m, designed))
            interrupts.check()
        outcome = run_records(inputs, section.shared, section.per_record, source, title, progress)
        outcome.document["files"] = {"records": [f"records/{k + 1}" for k in range(len(inputs))]}
        atomic_write_json(run_dir / "result.json", outcome.document)
        return JointResult(outcome.document, run_dir, outcome)
