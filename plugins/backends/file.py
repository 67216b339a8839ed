"""``file`` backend: fit a recorded input/output pair.

Formats (chosen by extension):

* ``.csv``: header row ``t,u,y`` (any order, extra columns ignored), then one sample per row;
  t in seconds, u the input, y the output;
* ``.npz``: arrays ``t``, ``u``, ``y`` of equal length.

The record must be finite, at least 16 samples long, with a uniform, increasing time step
(relative jitter below 1e-6 of the step). Every problem is reported in one line that names
the file.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict

from mbus_framework.backend import AcquisitionContext, Backend, Measurement
from mbus_framework.errors import DataError
from mbus_framework.hookspecs import BackendSpec, hookimpl

REQUIRED = ("t", "u", "y")
MIN_SAMPLES = 16
STEP_TOLERANCE = 1e-6


class FileOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    path: str


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


def check_record(path, t, u, y) -> Measurement:
    """Validate lengths, finiteness and a uniform time step; return the measurement."""
    t, u, y = (np.asarray(a, dtype=float).ravel() for a in (t, u, y))
    if not (len(t) == len(u) == len(y)):
        raise DataError(f"{path}: length mismatch (t {len(t)}, u {len(u)}, y {len(y)} samples)")
    if len(t) < MIN_SAMPLES:
        raise DataError(f"{path}: only {len(t)} samples; need at least {MIN_SAMPLES}")
    for name, a in (("t", t), ("u", u), ("y", y)):
        bad = np.flatnonzero(~np.isfinite(a))
        if bad.size:
            raise DataError(f"{path}: column {name} has {bad.size} non-finite value(s) (first at row {bad[0] + 1})")
    steps = np.diff(t)
    dt = float(np.median(steps))
    if dt <= 0:
        raise DataError(f"{path}: time column t is not increasing")
    worst = int(np.argmax(np.abs(steps - dt)))
    if abs(steps[worst] - dt) > STEP_TOLERANCE * dt:
        raise DataError(
            f"{path}: non-uniform time step (step {steps[worst]:.6g} s at row {worst + 2}, median {dt:.6g} s)"
        )
    return Measurement(t - t[0], u, y, meta={"source": str(path)})


class FileBackend(Backend):
    """Recorded data from a file (no instruments)."""

    Options = FileOptions
    summary = "recorded t,u,y from a .csv or .npz file"

    def acquire(self, context: AcquisitionContext) -> Measurement:
        path = Path(self.options.path)
        if not path.is_absolute() and context.config_path not in ("", "<config>"):
            candidate = Path(context.config_path).parent / path
            if candidate.exists() and not path.exists():
                path = candidate
        return read_record(path)


@hookimpl
def mbus_backends():
    return [BackendSpec("file", FileBackend, FileBackend.summary)]
