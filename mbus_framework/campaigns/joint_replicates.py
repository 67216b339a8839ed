"""A sample's replicates fitted jointly (``campaign.replicates: joint``, or ``auto`` when they
differ in gain or delay): one material shared by every replicate record, each with its own
input gain g_r and delay tau_r (y_r(t) = g_r * y(t - tau_r)), by the joint estimator of
:mod:`mbus_framework.joint` (per-record fits first, then the joint maximum-likelihood fit, and
the likelihood-ratio test of agreement).

:func:`joint_result` gives the run's result.json (the joint document plus what the campaign
table reads: ``parameters``, ``fit.nrmse``, ``replicates``); :func:`replicate_rows` the rows of
``replicates.csv``: per replicate its joint gain and delay and its own single-record fit.
"""
from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any, Sequence

from mbus_framework.interfaces.backend import Measurement
from mbus_framework.joint.spec import NUISANCE

#: what each replicate keeps to itself in a joint fit
PER_REPLICATE = list(NUISANCE)  # input_gain, delay


def joint_result(configs: Sequence[dict[str, Any]], records: Sequence[Measurement], names: Sequence[str],
                 source: str, title: str | None, reason: str) -> dict[str, Any]:
    """Fit ``records`` (one per replicate run config ``configs``, labelled ``names``) jointly."""
    from mbus_framework.joint.run import RecordInput, merge_nuisance, run_records
    from mbus_framework.pipeline.components import build_components
    from mbus_framework.pipeline.config import validate_structure
    from mbus_framework.pipeline.run import designed_waveform

    inputs = []
    for name, config, m in zip(names, configs, records):
        where = f"{source}: {name}"
        c = build_components(validate_structure(merge_nuisance(dict(config), PER_REPLICATE), where), where)
        inputs.append(RecordInput(name, c, m, designed_waveform(c)))
    t0 = time.perf_counter()
    outcome = run_records(inputs, None, PER_REPLICATE, source, title)
    doc = outcome.document
    doc["solver"]["wall_time_s"] = time.perf_counter() - t0
    model = inputs[0].components.model
    theta = model.from_properties(doc["properties"])
    doc["parameters"] = dict(zip(model.parameter_names, map(float, theta)))
    nrmse = [r["fit"]["nrmse"] for r in doc["records"]]
    doc["fit"] = {"nrmse": math.sqrt(sum(v * v for v in nrmse) / len(nrmse))}
    doc["replicates"] = {"mode": "joint", "reason": reason, "records": list(names),
                         "agreement_p_value": doc["agreement"]["p_value"]}
    return doc


def replicate_rows(table, out_dir: str | Path) -> list[dict[str, Any]]:
    """Per replicate of each jointly fitted sample of ``table``: sample_id, replicate, its length [m], the joint
    fit's input gain and delay (with SE, truth when simulated), nrmse and verdict, and the
    replicate's own single-record properties (with SE); read from the run folders' result.json."""
    rows = []
    if "replicates" not in table:
        return rows
    for _, r in table[table["replicates"] == "joint"].iterrows():
        try:
            doc = json.loads((Path(out_dir) / str(r["run_dir"]) / "result.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        for rec in doc.get("records", []):
            row: dict[str, Any] = {"sample_id": r["sample_id"], "replicate": rec["label"],
                                   "sample_length": rec["sample"]["length"]}
            for name in PER_REPLICATE:
                row[f"joint_{name}"] = rec["per_record"].get(name, math.nan)
                row[f"joint_{name}_se"] = rec["per_record_standard_errors"].get(name, math.nan)
                row[f"true_{name}"] = (rec.get("truth_nuisance") or {}).get(name, math.nan)
            row["joint_nrmse"] = rec["fit"]["nrmse"]
            row["joint_accepted"] = bool(rec["verdict"]["accepted"])
            own = rec.get("own_fit") or {}
            for name, value in (own.get("properties") or {}).items():
                row[name] = value
                row[f"{name}_se"] = (own.get("property_standard_errors") or {}).get(name, math.nan)
            row["agreement_p_value"] = doc["agreement"]["p_value"]
            rows.append(row)
    return rows
