"""What every study shares: the result record, the member-run context, table and figure output."""
from __future__ import annotations

import csv
import io
import math
import os
import platform
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import yaml

from mbus_framework.errors import EstimationError
from mbus_framework.estimation.problem import Progress
from mbus_framework.pipeline.config import load_config
from mbus_framework.pipeline.storage import atomic_write_bytes


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

def _max_rel_diff(a: dict, b: dict) -> float | None:
    common = [k for k in a if k in b and b[k]]
    if not common:
        return None
    return float(max(abs(a[k] / b[k] - 1.0) for k in common))


def _g(x, fmt=".4g", width=11) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return f"{'-':>{width}}"
    return f"{x:>{width}{fmt}}"



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
