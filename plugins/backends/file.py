"""``file`` backend: fit a recorded input/output pair.

Formats (``format: auto`` picks by what ``path`` is):

* ``.csv``/``.tsv``/``.txt`` with header row ``t,u,y`` (any order, extra columns ignored), then
  one sample per row; t in seconds, u the input, y the output; other layouts with the reader
  options of :mod:`mbus_plugins.backends.text_table` (``columns``, ``delimiter``, ``decimal``,
  ``skip_rows``, ``units_row``, ``comment``); with ``response_path``, two ``time,value`` files;
* ``.npz`` with arrays ``t``, ``u``, ``y`` of equal length (or named by ``columns``);
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
they are unpacked; the size limit of a compressed .mat file applies to the file, not its
unpacked arrays); text may be UTF-8 (with or without BOM), UTF-16 with BOM, or any 8-bit
encoding (header names are ASCII; numbers are numbers).

Text, NPZ and .mat records start at the onset of the earlier channel, with the pre-trigger
offsets removed (:mod:`mbus_plugins.backends.pretrigger`; ``pretrigger: false`` opts out).

The t,u,y record must be finite, at least 16 samples long, with a uniform, increasing time
step (relative jitter below 1e-6 of the step). Every problem is reported in one line that
names the file.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import ConfigDict, Field

from mbus_framework.interfaces.backend import AcquisitionContext, Backend, Measurement, check_record
from mbus_framework.errors import DataError
from mbus_framework.interfaces.hookspecs import BackendSpec, hookimpl
from mbus_framework.pipeline import run_folder
from mbus_framework.pipeline.storage import read_npz, read_regular_file
from mbus_framework.pipeline.units import record_units

from mbus_plugins.backends.mat_file import MatVariables, read_mat
from mbus_plugins.backends.pretrigger import remove_pretrigger
from mbus_plugins.backends.text_table import TABLE_KEYS, TEXT_SUFFIXES, TableOptions, read_pair, read_table
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


class FileOptions(TableOptions):
    """Where the record is and how to read it; the text reader's options are
    :class:`~mbus_plugins.backends.text_table.TableOptions` (columns, delimiter, ...)."""

    model_config = ConfigDict(extra="forbid")
    path: str = Field(description="t,u,y .csv/.tsv/.txt/.npz, a .mat file, a GDS-2000 CSV (excitation channel) or a lab run directory")
    response_path: str | None = Field(None, description="GDS-2000 CSV of the response channel")
    format: Literal["auto", "tuy", "gds_csv", "lab_run", "run", "mat"] = Field(
        "auto", description="how to read path ('run': a run folder's measurement.csv; 'mat': MATLAB file)")
    pretrigger: bool = Field(
        True, description="t,u,y and .mat records: cut samples before the onset and subtract their mean (DC offset)")
    variables: MatVariables | None = Field(
        None, description=".mat files: which variable is input, output, time, ... (default u, y, t)")
    processing: ProcessingOptions | None = Field(
        None, description="alignment/averaging/gains for GDS CSV pairs and lab runs (default: as saved)")
    counts_per_division: float | None = Field(
        None, gt=0, description="lab runs: rescale the saved raw codes with this factor (default: as saved)")
    units: dict[Literal["u", "y"], str] | None = Field(
        None, description="units of the record's input and output (e.g. {u: V, y: V}); overrides the file's")


def read_record(path: str | Path, table: TableOptions | None = None) -> Measurement:
    """Read and check a ``t,u,y`` record from delimited text (.csv/.tsv/.txt, with the reader
    options ``table``) or NPZ (``table.columns`` may name its arrays)."""
    path = Path(path)
    suffix = path.suffix.lower()
    meta: dict = {}
    if suffix in TEXT_SUFFIXES:
        columns, meta = read_table(path, read_text(path), table)
    elif suffix == ".npz":
        columns = _read_npz(path, table.columns if table is not None else None)
    elif not path.exists():
        raise DataError(f"{path}: file not found")
    else:
        raise DataError(f"{path}: unsupported file type '{suffix[:20]}' (use .csv/.tsv/.txt, .npz or .mat; "
                        f"set format if the content is one of these)")
    m = check_record(path, columns["t"], columns["u"], columns["y"])
    m.meta.update(meta)
    return m


def read_text_pair(u_path: Path, y_path: Path, table: TableOptions) -> Measurement:
    """Two single-channel text files (``time,value``): u from ``u_path``, y from ``y_path``."""
    for p in (u_path, y_path):
        if p.suffix.lower() not in TEXT_SUFFIXES:
            raise DataError(f"{p}: a response_path pair must be GDS-2000 CSV exports or time,value text files "
                            f"(.csv/.tsv/.txt)")
    columns, meta = read_pair(u_path, read_text(u_path), y_path, read_text(y_path), table)
    m = check_record(u_path, columns["t"], columns["u"], columns["y"])
    m.meta.update(meta, response_source=str(y_path))
    return m


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


def _read_npz(path: Path, names: dict | None = None) -> dict[str, np.ndarray]:
    arrays = read_npz(path)
    names = {c: str((names or {}).get(c, c)) for c in REQUIRED}
    missing = [c if names[c] == c else f"{c} ('{names[c]}')" for c in REQUIRED if names[c] not in arrays]
    if missing:
        raise DataError(f"{path}: missing array(s) {', '.join(missing)} (has {', '.join(arrays)[:120] or 'none'}); "
                        f"name them with backend.options.columns: {{t: ..., u: ..., y: ...}}")
    out = {}
    for c in REQUIRED:
        a = arrays[names[c]]
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
                  record_units=record_units(meta), warnings=[str(w) for w in warnings_saved])
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
    given = processing.model_fields_set  # a gain given converts its channel to newtons
    units = {c: "N" if f"{c}_gain" in given else _vertical_units(trace.header)
             for c, trace in (("u", u), ("y", y))}
    if any(units.values()):
        m.meta["units"] = {c: v or "N" for c, v in units.items()}
        m.meta["units_source"] = f"the scope files' Vertical Units ({u_path.name}, {y_path.name})"
    return m


def _vertical_units(header: dict[str, str]) -> str | None:
    for key, value in header.items():
        if key.strip().lower() == "vertical units" and value.strip():
            return value.strip()
    return None


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
        if fmt != "tuy":
            self._no_table_options(path, fmt)
        if fmt in ("gds_csv", "lab_run", "run") and "pretrigger" in o.model_fields_set:
            raise DataError(f"{path}: backend.options.pretrigger applies to t,u,y and .mat files; a {fmt} record "
                            f"is aligned by backend.options.processing.align")
        return self._with_units(self._read(path, fmt, reference, context))

    def _with_units(self, m: Measurement) -> Measurement:
        """``meta.units`` of u and y: the file's (a units row, ``t [s]``-style headers, a scope's
        ``Vertical Units`` unless a gain converts the channel to newtons), then ``units``."""
        units = {k: v for k, v in (m.meta.get("units") or {}).items()}
        if self.options.units:
            units.update(self.options.units)
            m.meta["units_source"] = "backend.options.units"
        elif units:
            m.meta.setdefault("units_source", str(m.meta.get("source") or "the record"))
        if units:
            m.meta["units"] = units
        return m

    def _read(self, path: Path, fmt: str, reference: Reference | None, context) -> Measurement:
        o = self.options
        if fmt == "gds_csv":
            y_path = self._resolve(o.response_path, context) if o.response_path else None
            return read_gds_pair(path, y_path, reference, o.processing or ProcessingOptions())
        if fmt == "lab_run":
            return read_lab_run(path, reference, o.processing, o.counts_per_division)
        if fmt == "run":
            return read_run_folder(path)
        if fmt == "mat":
            m = read_mat(path, o.variables)
        elif o.variables is not None:
            raise DataError(f"{path}: backend.options.variables applies to MATLAB .mat files only "
                            f"(set format: mat if this is one)")
        else:
            table = TableOptions.model_validate(o.model_dump(include=set(TABLE_KEYS)))
            if o.response_path is not None:
                m = read_text_pair(path, self._resolve(o.response_path, context), table)
            else:
                m = read_record(path, table)
        return remove_pretrigger(m, str(path)) if o.pretrigger else m

    def _no_table_options(self, path: Path, fmt: str) -> None:
        given = sorted(set(TABLE_KEYS) & self.options.model_fields_set)
        if given:
            raise DataError(f"{path}: backend.options.{given[0]} applies to t,u,y text files, not to a {fmt} record")

    @staticmethod
    def _resolve(name: str, context: AcquisitionContext | None) -> Path:
        """A config's paths arrive absolute (:mod:`mbus_framework.pipeline.config_paths`); a
        relative one (from Python) is taken from the config's folder when known, else as given."""
        path = Path(name)
        if not path.is_absolute() and context is not None and context.config_path not in ("", "<config>"):
            return Path(context.config_path).parent / path
        return path


@hookimpl
def mbus_backends():
    return [BackendSpec("file", FileBackend, FileBackend.summary)]
