"""``file`` backend: fit a recorded input/output pair.

Formats (``format: auto`` picks by what ``path`` is):

* ``.csv`` with header row ``t,u,y`` (any order, extra columns ignored), then one sample per
  row; t in seconds, u the input, y the output;
* ``.npz`` with arrays ``t``, ``u``, ``y`` of equal length;
* a GDS-2000 CSV export (``key,value`` header rows such as ``Vertical Scale`` and
  ``Sampling Period``, then raw codes or ``time,value`` rows; see
  :mod:`plugins.instruments.gds_csv`): ``path`` is the excitation channel's file and
  ``response_path`` the response channel's; the excitation channel is aligned with the designed
  excitation of the config and both are cut at the burst start (``processing``); without an
  excitation in the config the burst start is where the excitation channel leaves its rest;
* a run directory (or its ``shots/`` folder) written by the ``lab`` backend: every saved
  shot is re-processed with the processing options saved with it (or ``processing``), so a
  run can be re-fitted without the instruments, also after an acquisition that failed
  part-way.

The t,u,y record must be finite, at least 16 samples long, with a uniform, increasing time
step (relative jitter below 1e-6 of the step). Every problem is reported in one line that
names the file.
"""
from __future__ import annotations

import warnings
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from mbus_framework.interfaces.backend import AcquisitionContext, Backend, Measurement, check_record
from mbus_framework.errors import DataError
from mbus_framework.interfaces.hookspecs import BackendSpec, hookimpl

from plugins.instruments.gds_csv import read_gds_csv
from plugins.instruments.shots import ProcessingOptions, Reference, Shot, combine, load_run, rescale

REQUIRED = ("t", "u", "y")


GDS_HEADER_KEYS = ("memory length", "sampling period", "vertical scale", "source", "firmwave", "format")


class FileOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    path: str = Field(description="t,u,y .csv/.npz, a GDS-2000 CSV (excitation channel) or a lab run directory")
    response_path: str | None = Field(None, description="GDS-2000 CSV of the response channel")
    format: Literal["auto", "tuy", "gds_csv", "lab_run"] = Field("auto", description="how to read path")
    processing: ProcessingOptions | None = Field(
        None, description="alignment/averaging/gains for GDS CSV pairs and lab runs (default: as saved)")
    counts_per_division: float | None = Field(
        None, gt=0, description="lab runs: rescale the saved raw codes with this factor (default: as saved)")


def read_record(path: str | Path) -> Measurement:
    """Read and check a ``t,u,y`` record from CSV or NPZ."""
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path}: file not found")
    suffix = path.suffix.lower()
    if suffix == ".csv":
        columns = _read_csv(path)
    elif suffix == ".npz":
        columns = _read_npz(path)
    else:
        raise DataError(f"{path}: unsupported file type '{suffix}' (use .csv with header t,u,y or .npz)")
    return check_record(path, columns["t"], columns["u"], columns["y"])


def _read_csv(path: Path) -> dict[str, np.ndarray]:
    with open(path, encoding="utf-8-sig") as fh:
        header = fh.readline().strip()
    names = [h.strip().lower() for h in header.split(",")]
    missing = [c for c in REQUIRED if c not in names]
    if missing:
        raise DataError(f"{path}: missing column(s) {', '.join(missing)} in header '{header}' (expected t,u,y)")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # an empty body is reported below, in one line
            data = np.genfromtxt(path, delimiter=",", skip_header=1, dtype=float, invalid_raise=True)
    except ValueError as exc:
        raise DataError(f"{path}: malformed row ({str(exc).splitlines()[-1].strip()})") from None
    data = np.atleast_2d(data)
    if data.size == 0:
        raise DataError(f"{path}: no data rows")
    if data.shape[1] != len(names):
        raise DataError(f"{path}: rows have {data.shape[1]} values but the header has {len(names)} columns")
    return {c: data[:, names.index(c)] for c in REQUIRED}


def _read_npz(path: Path) -> dict[str, np.ndarray]:
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [c for c in REQUIRED if c not in z.files]
            if missing:
                raise DataError(f"{path}: missing array(s) {', '.join(missing)} (has {', '.join(z.files) or 'none'})")
            return {c: np.asarray(z[c], dtype=float).ravel() for c in REQUIRED}
    except DataError:
        raise
    except Exception as exc:  # noqa: BLE001 - numpy raises several kinds for corrupt files
        raise DataError(f"{path}: not a readable .npz file ({type(exc).__name__})") from None


def sniff_format(path: Path) -> str:
    """'lab_run' for a folder, 'gds_csv' for a CSV with GDS-2000 header rows, else 'tuy'."""
    if path.is_dir():
        return "lab_run"
    if path.suffix.lower() == ".csv" and path.is_file():
        with open(path, encoding="utf-8-sig", errors="replace") as fh:
            for _, line in zip(range(40), fh):
                if line.split(",")[0].strip().lower() in GDS_HEADER_KEYS:
                    return "gds_csv"
    return "tuy"


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
    run = load_run(path)
    if processing is None:
        saved = run.acquisition.get("processing")
        try:
            processing = ProcessingOptions(**saved) if saved else ProcessingOptions()
        except Exception as exc:  # noqa: BLE001 - pydantic ValidationError
            raise DataError(f"{run.shot_dir}: saved processing options are invalid ({exc})") from None
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
    summary = "recorded t,u,y (.csv/.npz), GDS-2000 CSV exports, or a lab run directory"
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
