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
import uuid
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
    """What a study uses to run its member runs: in this process, or on Dask with ``client``.

    On Dask, :meth:`plan_ahead` first runs the study once with placeholder (failed) records to
    learn which runs it asks for before it has any result, and submits them all at once; the
    real pass then collects them (and runs on demand whatever depends on earlier results, such
    as the element sweep's warm starts). The numbers are the same as in-process.
    """

    kind: str
    config_path: str
    overrides: list[str]
    out_dir: Path
    progress: Progress | None
    options: Any
    client: Any = None
    _planning: bool = False
    _requests: list = field(default_factory=list)
    _pending: dict = field(default_factory=dict)

    def run(self, label: str, extra: list[str], keep_outcome: Callable | None = None) -> dict[str, Any]:
        """One identification with ``extra`` overrides; returns its compact record.

        ``keep_outcome(outcome, record)`` may add to the record while the outcome is alive.
        An :class:`EstimationError` is recorded (``ok: false``), not raised.
        """
        if self._planning:
            self._requests.append((label, tuple(extra)))
            return {"label": label, "overrides": list(extra), "ok": False, "error": "planning", "wall_time_s": 0.0}
        dest = self.out_dir / "runs" / label
        if self.client is None:
            return run_member(self.config_path, self.config_path, self.overrides, extra, dest, self.options.keep_runs,
                              keep_outcome)
        future = self._pending.pop((label, tuple(extra)), None) or self._submit(label, extra)
        record, shipped = future.result()
        if keep_outcome is not None and shipped is not None:
            keep_outcome(self._outcome(extra, dest, *shipped), record)
        return record

    def plan_ahead(self, study: Callable) -> None:
        """Submit every run ``study`` asks for before seeing a result (see the class docstring)."""
        self._planning = True
        try:
            study(self)
        except Exception:  # noqa: BLE001 - the placeholders make a study give up; its real pass reports
            pass
        finally:
            self._planning = False
        for label, extra in dict.fromkeys(self._requests):
            self._pending[label, extra] = self._submit(label, list(extra))
        self._requests.clear()

    def cancel_pending(self) -> None:
        """Cancel submitted runs the study did not collect (after an error or Ctrl-C)."""
        if self._pending and self.client is not None:
            self.client.cancel(list(self._pending.values()), force=True)
        self._pending.clear()

    def _submit(self, label: str, extra: list[str]):
        from mbus_framework.pipeline.config import read_yaml

        dest = self.out_dir / "runs" / label
        mapping = read_yaml(self.config_path)
        return self.client.submit(run_member, mapping, self.config_path, self.overrides, list(extra), dest,
                                  self.options.keep_runs, None, True, key=f"mbus-study-{label}-{uuid.uuid4().hex[:8]}",
                                  pure=False)

    def _outcome(self, extra: list[str], dest: Path, measurement, fit, result):
        """The run's outcome rebuilt here from what the worker sent (for ``keep_outcome``)."""
        from mbus_framework.pipeline.components import build_components
        from mbus_framework.pipeline.run import RunOutcome

        config = load_config(self.config_path, self.overrides + list(extra))
        return RunOutcome(dest, build_components(config, self.config_path), measurement, fit, result)

    def start(self, total: int) -> None:
        if self.progress and not self._planning:
            self.progress.start(f"study {self.kind}", total=total)

    def advance(self, note: str) -> None:
        if self.progress and not self._planning:
            self.progress.advance(1, note)

    def stop(self) -> None:
        if self.progress and not self._planning:
            self.progress.stop()


def run_member(config, source: str, overrides: list[str], extra: list[str], dest: Path, keep_runs: bool,
               keep_outcome: Callable | None = None, ship: bool = False):
    """One member run of a study (here or on a Dask worker) into ``dest``; returns its compact
    record, or ``(record, (measurement, fit, result))`` with ``ship`` (None for a failed run).

    ``config`` is the base config file or its mapping (``source`` names it); ``keep_runs``
    keeps the whole run folder, otherwise only result.json and config.yaml.
    """
    from mbus_framework.pipeline.run import execute

    record: dict[str, Any] = {"label": dest.name, "overrides": list(extra)}
    shipped = None
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="mbus-study-") as tmp:
        run_dir = dest if keep_runs else Path(tmp) / dest.name
        if dest.exists() and keep_runs:
            shutil.rmtree(dest)
        try:
            outcome = execute(config, overrides + list(extra), run_dir, progress=None, plots=False, source=source)
        except EstimationError as exc:
            record.update(ok=False, error=str(exc), wall_time_s=time.perf_counter() - t0)
            return (record, None) if ship else record
        record.update(ok=True, **compact_record(outcome.result))
        record["wall_time_s"] = time.perf_counter() - t0
        if keep_outcome is not None:
            keep_outcome(outcome, record)
        if ship:
            shipped = (outcome.measurement, outcome.fit, outcome.result)
        if not keep_runs:
            dest.mkdir(parents=True, exist_ok=True)
            for name in ("result.json", "config.yaml"):
                if (run_dir / name).exists():
                    shutil.copyfile(run_dir / name, dest / name)
    return (record, shipped) if ship else record


def compact_record(result: dict[str, Any]) -> dict[str, Any]:
    """The numbers a study needs from one result.json."""
    unc = result.get("uncertainty", {}) or {}
    rec = {
        "parameters": dict(result["parameters"]),
        "properties": dict(result["properties"]),
        "property_units": dict(result.get("property_units") or {}),
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
