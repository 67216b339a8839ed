"""What a Dask worker does with one :class:`SampleTask`: the single-run pipeline
(:func:`mbus_framework.pipeline.run.execute`) into the sample's run folder, then its table row.

Replicates (``average``, ``joint``, ``auto``): each replicate record is acquired through its own run config and saved
(``replicates/r<k>/measurement.csv``) before anything is fitted; their mean is written to
``replicates/averaged.csv`` and fitted, with the ``file`` backend reading that file in the run
folder's config.yaml, so the folder re-runs on its own; or the records are fitted jointly
(:mod:`.joint_replicates`; ``auto`` chooses by :mod:`.replicate_choice`). (The replicates are staged next to the
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

from mbus_framework.campaigns.attempt import is_current
from mbus_framework.campaigns.hashing import digest
from mbus_framework.campaigns.joint_replicates import joint_result
from mbus_framework.campaigns.plan import AUTO, AVERAGED, JOINT, SampleTask
from mbus_framework.campaigns.replicate_choice import choose
from mbus_framework.campaigns.replicates import average_records
from mbus_framework.campaigns.rows import failed_row, result_row
from mbus_framework.errors import DataError, MbusError
from mbus_framework.pipeline.components import build_components
from mbus_framework.pipeline.config import validate_structure
from mbus_framework.pipeline.run import acquire, designed_waveform, execute
from mbus_framework.pipeline.storage import atomic_write_json, atomic_write_text, write_waveforms

#: Written last into a finished run folder: the content key and the table row (for resuming).
MARKER = "campaign_row.json"
AVERAGED_FILE = "averaged.csv"


def run_task(task: SampleTask) -> dict[str, Any]:
    """Fit one sample; returns ``{"row": ..., "cacheable": bool, "seconds": float, "stale": bool}``.

    The fit is written into a work folder (``runs/.<label>.<attempt>``) and committed by renaming
    it to ``runs/<label>`` only while ``task.attempt`` is still the campaign's current attempt
    (:mod:`~mbus_framework.campaigns.attempt`); a stale fit is discarded (``stale`` True). Every
    input file is checked against the hash the client planned with before it is read, and the
    absolute path and SHA-256 of each are recorded in the run's ``measurement.json``.
    """
    os.environ.setdefault("MPLBACKEND", "Agg")
    t0 = time.perf_counter()
    run_dir = Path(task.run_dir)
    out = run_dir.parent.parent
    rel = str(Path("runs") / run_dir.name)
    if not is_current(out, task.attempt):
        return {"row": None, "cacheable": False, "seconds": 0.0, "stale": True}
    work = run_dir.parent / f".{run_dir.name}.{task.attempt[:12] or 'work'}"
    for stale in (work, _staging(work)):  # an unfinished fit of this attempt: start clean
        if stale.exists():
            shutil.rmtree(stale)
    work.mkdir(parents=True)
    cacheable = True
    try:
        problem = _check_inputs(task)
        if problem:
            cacheable = False  # the worker's view of the files, not the data: retried on the next run
            raise DataError(problem)
        result, truth = _fit(task, work, run_dir)
        row = result_row(task, result, rel, truth)
    except MbusError as exc:
        row = failed_row(task, str(exc), rel, _recorded_truth(work))
    except Exception as exc:  # noqa: BLE001 - isolate the failure in its row, keep the traceback
        atomic_write_text(work / "error.txt", traceback.format_exc())
        row = failed_row(task, f"internal error ({type(exc).__name__}: {exc}); traceback in {rel}/error.txt",
                         rel, _recorded_truth(work))
        cacheable = False
    seconds = time.perf_counter() - t0
    _record_inputs(work, task)
    if cacheable:
        worker = {"host": socket.gethostname(), "pid": os.getpid()}
        atomic_write_json(work / MARKER, {"key": task.key, "row": row, "seconds": seconds, "worker": worker,
                                          "attempt": task.attempt})
    if not _commit(work, run_dir, out, task.attempt):
        return {"row": None, "cacheable": False, "seconds": seconds, "stale": True}
    return {"row": row, "cacheable": cacheable, "seconds": seconds, "stale": False}


def _check_inputs(task: SampleTask) -> str | None:
    """A one-line problem when an input file is missing here or differs from the client's."""
    host = socket.gethostname()
    for path, expected in task.inputs:
        found = digest(path)
        if found == expected:
            continue
        if found == "missing":
            return (f"{path}: not found on the worker host {host}; workers must see the campaign's files at the "
                    f"same paths (a shared file system)")
        return f"{path}: differs on the worker host {host} from the file the campaign was planned with"
    return None


def _record_inputs(work: Path, task: SampleTask) -> None:
    """Add ``inputs: [{path, sha256}]`` (absolute paths) to the run's measurement.json."""
    meta_file = work / "measurement.json"
    if not task.inputs or not meta_file.is_file():
        return
    try:
        saved = json.loads(meta_file.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return
    saved["inputs"] = [{"path": p, "sha256": h} for p, h in task.inputs]
    atomic_write_json(meta_file, saved)


def _commit(work: Path, run_dir: Path, out: Path, attempt: str) -> bool:
    """Replace ``run_dir`` by ``work`` if ``attempt`` is still current; else discard ``work``."""
    if not is_current(out, attempt):
        shutil.rmtree(work, ignore_errors=True)
        return False
    old = run_dir.parent / f".{run_dir.name}.old-{os.getpid()}"
    if run_dir.exists():
        os.rename(run_dir, old)
    os.rename(work, run_dir)
    shutil.rmtree(old, ignore_errors=True)
    return True


def read_marker(run_dir: str | Path, key: str) -> dict[str, Any] | None:
    """The stored row of a finished run whose content key is ``key``, else None."""
    path = Path(run_dir) / MARKER
    try:
        stored = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return stored.get("row") if isinstance(stored, dict) and stored.get("key") == key else None


def _fit(task: SampleTask, work: Path, run_dir: Path) -> tuple[dict[str, Any], dict[str, float] | None]:
    """Fit into ``work``; ``run_dir`` is where the folder will be (the averaged record's path)."""
    if len(task.configs) == 1:
        outcome = execute(task.configs[0], [], work, plots=task.plots, source=task.source)
        result = outcome.result
        if task.replicates in (JOINT, AUTO):  # one record: the joint fit is the single fit
            result["replicates"] = {"mode": AVERAGED if task.replicates == AUTO else JOINT,
                                    "reason": "one replicate", "records": [f"r{task.replicate_numbers[0]}"]}
            atomic_write_json(work / "result.json", result)
        return result, None
    staging = _staging(work)
    try:
        records, names = _acquire_all(task, staging)
        mode, reason = task.replicates, None
        if mode == AUTO:
            choice = choose(records)
            mode, reason = (JOINT if choice.mode == "joint" else AVERAGED), choice.reason
        if mode == JOINT:
            result = joint_result(task.configs, records, names, task.source, task.configs[0].get("title"),
                                  reason or "campaign.replicates: joint")
            result["replicates"]["files"] = [f"replicates/{n}/measurement.csv" for n in names]
            atomic_write_json(work / "result.json", result)
            return result, None
        mean = _average(records, names, task.source, staging)
        config = copy.deepcopy(task.configs[0])
        config["backend"] = {"name": "file", "options": {"path": str(run_dir / "replicates" / AVERAGED_FILE)}}
        outcome = execute(config, [], work, plots=task.plots, source=task.source, measurement=mean)
    finally:  # the saved replicates belong to the run folder, whatever happened
        if staging.exists():
            work.mkdir(parents=True, exist_ok=True)
            staging.rename(work / "replicates")
    result = outcome.result
    result["replicates"] = {"averaged": [f"r{n}" for n in task.replicate_numbers], "file": f"replicates/{AVERAGED_FILE}"}
    if reason is not None:
        result["replicates"].update(mode=AVERAGED, reason=reason)
    atomic_write_json(work / "result.json", result)
    truth = {**(mean.truth or {}), **(mean.meta.get("true_properties") or {})}
    return result, truth


def _staging(run_dir: Path) -> Path:
    return run_dir.parent / f".{run_dir.name}.replicates"


def _acquire_all(task: SampleTask, folder: Path):
    """Acquire (and save) every replicate record into ``folder/r<k>/``; returns (records, names)."""
    records, names = [], []
    for number, config in zip(task.replicate_numbers, task.configs):
        c = build_components(validate_structure(config, task.source), task.source)
        rep_dir = folder / f"r{number}"
        rep_dir.mkdir(parents=True, exist_ok=True)
        records.append(acquire(c, rep_dir, designed_waveform(c)))
        names.append(f"r{number}")
    return records, names


def _average(records, names, source: str, folder: Path):
    """Write the sample-wise mean of ``records`` into ``folder``; returns the mean."""
    mean = average_records(records, names, source)
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
