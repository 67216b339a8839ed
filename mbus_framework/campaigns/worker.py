"""What a Dask worker does with one :class:`SampleTask`: the single-run pipeline
(:func:`mbus_framework.pipeline.run.execute`) into the sample's run folder, then its table row.

Averaged replicates: each replicate record is acquired through its own run config and saved
(``replicates/r<k>/measurement.csv``) before anything is fitted; their mean is written to
``replicates/averaged.csv`` and fitted, with the ``file`` backend reading that file in the run
folder's config.yaml, so the folder re-runs on its own. (The replicates are staged next to the
run folder and moved into it once the run has reserved it: a run folder starts empty.) A failure never escapes: a data or fit error (``MbusError``) becomes a row
with its error and is remembered for resuming (the same data fail the same way); any other
exception becomes a row too, with the traceback in ``error.txt``, and is retried on a re-run.
"""
from __future__ import annotations

import copy
import json
import os
import shutil
import socket
import time
import traceback
from pathlib import Path
from typing import Any

from mbus_framework.campaigns.plan import SampleTask
from mbus_framework.campaigns.replicates import average_records
from mbus_framework.campaigns.rows import failed_row, result_row
from mbus_framework.errors import MbusError
from mbus_framework.pipeline.components import build_components
from mbus_framework.pipeline.config import validate_structure
from mbus_framework.pipeline.run import acquire, designed_waveform, execute
from mbus_framework.pipeline.storage import atomic_write_json, atomic_write_text, write_waveforms

#: Written last into a finished run folder: the content key and the table row (for resuming).
MARKER = "campaign_row.json"
AVERAGED_FILE = "averaged.csv"


def run_task(task: SampleTask) -> dict[str, Any]:
    """Fit one sample; returns ``{"row": ..., "cacheable": bool, "seconds": float}``."""
    os.environ.setdefault("MPLBACKEND", "Agg")
    t0 = time.perf_counter()
    run_dir = Path(task.run_dir)
    rel = str(Path("runs") / run_dir.name)
    for stale in (run_dir, _staging(run_dir)):  # an unfinished or outdated run of this sample: start clean
        if stale.exists():
            shutil.rmtree(stale)
    run_dir.mkdir(parents=True)
    cacheable = True
    try:
        result, truth = _fit(task, run_dir)
        row = result_row(task, result, rel, truth)
    except MbusError as exc:
        row = failed_row(task, str(exc), rel, _recorded_truth(run_dir))
    except Exception as exc:  # noqa: BLE001 - isolate the failure in its row, keep the traceback
        atomic_write_text(run_dir / "error.txt", traceback.format_exc())
        row = failed_row(task, f"internal error ({type(exc).__name__}: {exc}); traceback in {rel}/error.txt",
                         rel, _recorded_truth(run_dir))
        cacheable = False
    seconds = time.perf_counter() - t0
    if cacheable:
        worker = {"host": socket.gethostname(), "pid": os.getpid()}
        atomic_write_json(run_dir / MARKER, {"key": task.key, "row": row, "seconds": seconds, "worker": worker})
    return {"row": row, "cacheable": cacheable, "seconds": seconds}


def read_marker(run_dir: str | Path, key: str) -> dict[str, Any] | None:
    """The stored row of a finished run whose content key is ``key``, else None."""
    path = Path(run_dir) / MARKER
    try:
        stored = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return stored.get("row") if isinstance(stored, dict) and stored.get("key") == key else None


def _fit(task: SampleTask, run_dir: Path) -> tuple[dict[str, Any], dict[str, float] | None]:
    if len(task.configs) == 1:
        outcome = execute(task.configs[0], [], run_dir, plots=task.plots, source=task.source)
        return outcome.result, None
    staging = _staging(run_dir)
    try:
        mean = _average(task, staging)
        config = copy.deepcopy(task.configs[0])
        config["backend"] = {"name": "file", "options": {"path": str(run_dir / "replicates" / AVERAGED_FILE)}}
        outcome = execute(config, [], run_dir, plots=task.plots, source=task.source, measurement=mean)
    finally:  # the saved replicates belong to the run folder, whatever happened
        if staging.exists():
            run_dir.mkdir(parents=True, exist_ok=True)
            staging.rename(run_dir / "replicates")
    result = outcome.result
    result["replicates"] = {"averaged": [f"r{n}" for n in task.replicate_numbers], "file": f"replicates/{AVERAGED_FILE}"}
    atomic_write_json(run_dir / "result.json", result)
    truth = {**(mean.truth or {}), **(mean.meta.get("true_properties") or {})}
    return result, truth


def _staging(run_dir: Path) -> Path:
    return run_dir.parent / f".{run_dir.name}.replicates"


def _average(task: SampleTask, folder: Path):
    """Acquire (and save) every replicate record into ``folder``, then write their sample-wise
    mean there; returns the mean."""
    records, names = [], []
    for number, config in zip(task.replicate_numbers, task.configs):
        c = build_components(validate_structure(config, task.source), task.source)
        rep_dir = folder / f"r{number}"
        rep_dir.mkdir(parents=True, exist_ok=True)
        records.append(acquire(c, rep_dir, designed_waveform(c)))
        names.append(f"r{number}")
    mean = average_records(records, names, task.source)
    write_waveforms(folder / AVERAGED_FILE, mean.t, mean.u, mean.y)
    atomic_write_json(folder / "averaged.json", {"truth": mean.truth, "meta": mean.meta})
    return mean


def _recorded_truth(run_dir: Path) -> dict[str, float]:
    """The truth a simulated record saved before its fit failed (empty for recorded data)."""
    for meta_file in [run_dir / "measurement.json", run_dir / "replicates" / "averaged.json"]:
        try:
            saved = json.loads(meta_file.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        meta = saved.get("meta") or {}
        return {**(saved.get("truth") or {}), **(meta.get("true_properties") or {})}
    return {}
