"""``file`` backend: fit a recorded input/output pair.

Formats (``format: auto`` picks by what ``path`` is):

* ``.csv`` with header row ``t,u,y`` (any order, extra columns ignored), then one sample per
  row; t in seconds, u the input, y the output;
* ``.npz`` with arrays ``t``, ``u``, ``y`` of equal length;
* a GDS-2000 CSV export (``key,value`` header rows such as ``Vertical Scale`` and
  ``Sampling Period``, then raw codes or ``time,value`` rows; see
  :mod:`mbus_plugins.instruments.gds_csv`): ``path`` is the excitation channel's file and
  ``response_path`` the response channel's; the excitation channel is aligned with the designed
  excitation of the config and both are cut at the burst start (``processing``); without an
  excitation in the config the burst start is where the excitation channel leaves its rest;
* a MATLAB ``.mat`` file (level 5, or v7.3 with h5py installed): ``variables`` names the input,
  output and time variables, the column of a 2-D output and optional sample thickness, density
  and fluid temperature (:mod:`mbus_plugins.backends.mat_file`);
* a run directory (or its ``shots/`` folder) written by the ``lab`` backend: every saved
  shot is re-processed with the processing options saved with it (or ``processing``), so a
  run can be re-fitted without the instruments, also after an acquisition that failed
  part-way (the result then carries a warning);
* the run directory of any other run (simulated, file, ...): its ``measurement.csv``, the
  record exactly as that run fitted it, with the warnings saved in its ``measurement.json``.
  So ``mbus-run <run>/config.yaml --set 'backend={name: file, options: {path: <run>}}'``
  re-fits every run folder.

Files are read with limits (regular files only, at most 512 MiB; NPZ arrays checked before
they are unpacked); text may be UTF-8 (with or without BOM), UTF-16 with BOM, or any 8-bit
encoding (header names are ASCII; numbers are numbers).

The t,u,y record must be finite, at least 16 samples long, with a uniform, increasing time
step (relative jitter below 1e-6 of the step). Every problem is reported in one line that
names the file.
"""
from __future__ import annotations

import io
import json
import warnings
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from mbus_framework.interfaces.backend import AcquisitionContext, Backend, Measurement, check_record
from mbus_framework.errors import DataError
from mbus_framework.interfaces.hookspecs import BackendSpec, hookimpl
from mbus_framework.pipeline import run_folder
from mbus_framework.pipeline.storage import read_npz, read_regular_file

from mbus_plugins.backends.mat_file import MatVariables, read_mat
from mbus_plugins.instruments.gds_csv import read_gds_csv
from mbus_plugins.instruments.shots import (
    SHOT_DIR,
    ProcessingOptions,
    Reference,
    Shot,
    combine,
    find_shot_dir,
    load_run,
    rescale,
)

REQUIRED = ("t", "u", "y")
RUN_RECORD = "measurement.csv"
"""The record every run saves before fitting (``mbus_framework.pipeline.run.MEASUREMENT_FILE``)."""


GDS_HEADER_KEYS = ("memory length", "sampling period", "vertical scale", "source", "firmwave", "format")


class FileOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    path: str = Field(description="t,u,y .csv/.npz, a GDS-2000 CSV (excitation channel) or a lab run directory")
    response_path: str | None = Field(None, description="GDS-2000 CSV of the response channel")
    format: Literal["auto", "tuy", "gds_csv", "lab_run", "run", "mat"] = Field(
        "auto", description="how to read path ('run': a run folder's measurement.csv; 'mat': MATLAB file)")
    variables: MatVariables | None = Field(
        None, description=".mat files: which variable is input, output, time, ... (default u, y, t)")
    processing: ProcessingOptions | None = Field(
        None, description="alignment/averaging/gains for GDS CSV pairs and lab runs (default: as saved)")
    counts_per_division: float | None = Field(
        None, gt=0, description="lab runs: rescale the saved raw codes with this factor (default: as saved)")


def read_record(path: str | Path) -> Measurement:
    """Read and check a ``t,u,y`` record from CSV or NPZ."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".csv":
        columns = _read_csv(path)
    elif suffix == ".npz":
        columns = _read_npz(path)
    elif not path.exists():
        raise DataError(f"{path}: file not found")
    else:
        raise DataError(f"{path}: unsupported file type '{suffix[:20]}' (use .csv with header t,u,y or .npz)")
    return check_record(path, columns["t"], columns["u"], columns["y"])


def read_text(path: Path, what: str = "data file") -> str:
    """A data file's text: UTF-8 (BOM or not), UTF-16 with BOM, else Latin-1 (every byte decodes)."""
    data = read_regular_file(path, what)
    if data[:2] in (b"\xff\xfe", b"\xfe\xff"):
        try:
            return data.decode("utf-16")
        except UnicodeDecodeError:
            raise DataError(f"{path}: starts with a UTF-16 byte-order mark but is not UTF-16 text") from None
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        return data.decode("latin-1")


def _read_csv(path: Path) -> dict[str, np.ndarray]:
    text = read_text(path)
    header, _, body = text.partition("\n")
    header = header.strip()
    names = [h.strip().lower() for h in header.split(",")]
    missing = [c for c in REQUIRED if c not in names]
    if missing:
        raise DataError(f"{path}: missing column(s) {', '.join(missing)} in header {header[:60]!r} (expected t,u,y)")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # an empty body is reported below, in one line
            data = np.genfromtxt(io.StringIO(body), delimiter=",", dtype=float, invalid_raise=True)
    except ValueError as exc:
        raise DataError(f"{path}: malformed row ({str(exc).splitlines()[-1].strip()[:120]})") from None
    data = np.atleast_2d(data)
    if data.size == 0:
        raise DataError(f"{path}: no data rows")
    if data.shape[1] != len(names):
        raise DataError(f"{path}: rows have {data.shape[1]} values but the header has {len(names)} columns")
    return {c: data[:, names.index(c)] for c in REQUIRED}


def _read_npz(path: Path) -> dict[str, np.ndarray]:
    arrays = read_npz(path)
    missing = [c for c in REQUIRED if c not in arrays]
    if missing:
        raise DataError(f"{path}: missing array(s) {', '.join(missing)} (has {', '.join(arrays)[:120] or 'none'})")
    out = {}
    for c in REQUIRED:
        a = arrays[c]
        if not (np.issubdtype(a.dtype, np.number) or a.dtype == bool) or np.iscomplexobj(a):
            raise DataError(f"{path}: array {c} holds {a.dtype} values, not real numbers")
        out[c] = np.asarray(a, dtype=float).ravel()
    return out


def sniff_format(path: Path) -> str:
    """'lab_run' for a folder with saved shots, 'run' for another run folder, 'mat' for a ``.mat``
    file, 'gds_csv' for a CSV with GDS-2000 header rows, else 'tuy'."""
    if path.is_dir():
        if find_shot_dir(path) is None and (path / RUN_RECORD).is_file():
            return "run"
        return "lab_run"
    if path.suffix.lower() == ".mat":
        return "mat"
    if path.suffix.lower() == ".csv" and path.is_file():
        try:
            head = read_text(path)[:8192]
        except DataError:
            return "tuy"  # read_record reports the problem
        for line in head.splitlines()[:40]:
            if line.split(",")[0].strip().lower() in GDS_HEADER_KEYS:
                return "gds_csv"
    return "tuy"


def read_run_folder(path: Path) -> Measurement:
    """The record a finished (or stopped) run fitted: ``measurement.csv`` and the warnings of its
    ``measurement.json``."""
    check_not_running(path)
    m = read_record(path / RUN_RECORD)
    saved = {}
    meta_file = path / "measurement.json"
    if meta_file.is_file():
        try:
            saved = json.loads(read_text(meta_file, "measurement record"))
        except ValueError as exc:
            raise DataError(f"{meta_file}: not valid JSON ({str(exc)[:80]})") from None
    meta = saved.get("meta") if isinstance(saved, dict) else None
    meta = meta if isinstance(meta, dict) else {}
    warnings_saved = meta.get("warnings") if isinstance(meta.get("warnings"), list) else []
    m.meta.update(source=str(path / RUN_RECORD), refit_of=str(path), original_source=str(meta.get("source")),
                  warnings=[str(w) for w in warnings_saved])
    return m


def check_not_running(path: Path) -> None:
    """DataError if a live run is still writing the folder; an abandoned one is marked interrupted."""
    folder = path if (path / run_folder.STATUS_FILE).is_file() else path.parent
    status = run_folder.read_status(folder) or {}
    if status.get("status") != run_folder.RUNNING:
        return
    if run_folder.is_active(folder):
        raise DataError(f"{path}: the run is still in progress (pid {status.get('pid')}); wait for it to finish")
    run_folder.recover(folder)


def read_gds_pair(u_path: Path, y_path: Path | None, reference: Reference | None,
                  processing: ProcessingOptions) -> Measurement:
    """Excitation and response channel files from a GDS-2000 -> aligned t, u, y."""
    if y_path is None:
        raise DataError(f"{u_path}: a GDS-2000 CSV holds one channel; give backend.options.response_path "
                        f"(the response channel's file)")
    u, y = read_gds_csv(u_path), read_gds_csv(y_path)
    if u.volts.size != y.volts.size or abs(u.dt - y.dt) > 1e-6 * u.dt:
        raise DataError(f"{y_path}: {y.volts.size} samples of {y.dt:.6g} s but {u_path.name} has "
                        f"{u.volts.size} of {u.dt:.6g} s (not the same acquisition?)")
    if abs(u.t[0] - y.t[0]) > 0.5 * u.dt:
        raise DataError(f"{y_path}: starts at {y.t[0]:.6g} s but {u_path.name} at {u.t[0]:.6g} s")
    shot = Shot(u.dt, u.volts, y.volts, meta={"u_file": str(u_path), "y_file": str(y_path)})
    t, uu, yy, meta = combine([shot], reference, processing, str(u_path))
    m = check_record(u_path, t, uu, yy)
    m.meta.update(meta, source=str(u_path), response_source=str(y_path), layout=u.layout,
                  u_header=u.header, y_header=y.header)
    return m


def read_lab_run(path: Path, context_reference: Reference | None, processing: ProcessingOptions | None,
                 counts_per_division: float | None = None) -> Measurement:
    """Shots saved by the ``lab`` backend -> the same t, u, y it produced (or would have)."""
    if path.is_dir():
        check_not_running(path if path.name != SHOT_DIR else path.parent)
    run = load_run(path)
    if processing is None:
        saved = run.acquisition.get("processing")
        try:
            processing = ProcessingOptions.model_validate(saved) if saved else ProcessingOptions()
        except Exception as exc:  # noqa: BLE001 - pydantic ValidationError
            first = str(exc).splitlines()
            raise DataError(f"{run.shot_dir}: saved processing options are invalid "
                            f"({' '.join(first[:3])[:160]})") from None
    shots = run.shots
    if counts_per_division is not None:
        shots = [rescale(s, counts_per_division) for s in shots]
    reference = run.reference
    if reference is None and run.designed_u is not None and run.designed_t is not None and run.designed_t.size > 1:
        reference = Reference(run.designed_u, 1.0 / float(run.designed_t[1] - run.designed_t[0]))
    if reference is None:
        reference = context_reference
    t, u, y, meta = combine(shots, reference, processing, str(run.shot_dir))
    m = check_record(run.shot_dir, t, u, y)
    status = run.acquisition.get("status", "unknown")
    warnings = list(meta.pop("warnings", []))
    if status != "complete":
        warnings.append(f"acquisition {status}: {len(shots)} of {run.acquisition.get('shots_requested', '?')} "
                        f"shots saved ({run.acquisition.get('error') or 'no error recorded'})")
    m.meta.update(meta, source=str(run.shot_dir), shot_files=[f.name for f in run.files],
                  acquisition_status=status, instruments=run.acquisition.get("instruments", {}),
                  warnings=warnings)
    return m


class FileBackend(Backend):
    """Recorded data from files (no instruments)."""

    Options = FileOptions
    summary = "recorded t,u,y (.csv/.npz/.mat), GDS-2000 CSV exports, or a lab run directory"
    needs_excitation = False  # the record holds the input

    def acquire(self, context: AcquisitionContext) -> Measurement:
        o = self.options
        path = self._resolve(o.path, context)
        fmt = o.format if o.format != "auto" else sniff_format(path)
        if not path.exists():
            raise DataError(f"{path}: file not found")
        wave = context.excitation if context is not None else None
        reference = Reference(np.asarray(wave.u, float), wave.sample_rate) if wave is not None else None
        if fmt == "gds_csv":
            y_path = self._resolve(o.response_path, context) if o.response_path else None
            return read_gds_pair(path, y_path, reference, o.processing or ProcessingOptions())
        if fmt == "lab_run":
            return read_lab_run(path, reference, o.processing, o.counts_per_division)
        if fmt == "run":
            return read_run_folder(path)
        if fmt == "mat":
            return read_mat(path, o.variables)
        if o.variables is not None:
            raise DataError(f"{path}: backend.options.variables applies to MATLAB .mat files only "
                            f"(set format: mat if this is one)")
        return read_record(path)

    @staticmethod
    def _resolve(name: str, context: AcquisitionContext | None) -> Path:
        path = Path(name)
        if not path.is_absolute() and context is not None and context.config_path not in ("", "<config>"):
            candidate = Path(context.config_path).parent / path
            if candidate.exists() and not path.exists():
                path = candidate
        return path


@hookimpl
def mbus_backends():
    return [BackendSpec("file", FileBackend, FileBackend.summary)]
