"""``from_file`` excitation: a user's arbitrary waveform, played point by point.

The file holds the generator's points u_j at a point rate r (from a time column, or from
``file_sample_rate``). As a generator plays them, each point is held for 1/r (zero-order hold):

    u(t) = a * u_floor(t r)      for 0 <= t < periods * J / r, zero afterwards,

looping ``periods`` times over the J points; a = amplitude / max|u_j| when ``amplitude`` is
given, else 1. The record samples u(t) at ``sample_rate`` (default: r) for ``n_samples``
(default: the whole played waveform).

Formats (by suffix): ``.npy`` (1-D array), ``.npz`` (array ``u``, optional ``t``), ``.csv``,
``.txt``, ``.dat`` (comma or whitespace separated numbers; an optional header row of names;
the column named ``t``/``time`` gives the times, ``column`` picks the values, by name or
0-based index; without a header, one column is u and with two or more the first is t and
``column`` defaults to 1). In a config file a relative path is taken from the config's folder
(:mod:`mbus_framework.pipeline.config_paths`); given directly, from the current directory.
"""
from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from pydantic import Field, model_validator

from mbus_framework.errors import DataError
from mbus_framework.interfaces.excitation import DesignedExcitation, ExcitationOptions
from mbus_framework.interfaces.hookspecs import ExcitationSpec, hookimpl
from mbus_framework.pipeline.storage import read_npz, read_regular_file
from mbus_plugins.excitations.bounds import SAMPLE_RATE_RANGE, Amplitude, RecordSamples, SampleRate, samples


class FromFileOptions(ExcitationOptions):
    path: str = Field(description="waveform file (.npy, .npz, .csv, .txt, .dat)")
    column: str | int | None = Field(None, description="column of the values (name or 0-based index)")
    file_sample_rate: SampleRate | None = Field(None, description="point rate of the file [Hz] (no time column)")
    sample_rate: SampleRate | None = Field(None, description="record sampling rate [Hz] (default: the point rate)")
    amplitude: Amplitude | None = Field(None, description="rescale so the peak |u| is this [N or V]")
    periods: int = Field(1, ge=1, le=1000, description="play the file this many times in a row")
    n_samples: RecordSamples | None = Field(None, description="record length [samples]")
    duration: float | None = Field(None, gt=0, description="record length [s] (alternative to n_samples)")

    @model_validator(mode="after")
    def _length(self):
        if self.n_samples is not None and self.duration is not None:
            raise ValueError("give n_samples or duration, not both")
        return self


def read_points(path: Path, column: str | int | None) -> tuple[np.ndarray, np.ndarray | None]:
    """(values, times or None) from a waveform file; DataError naming the file when unusable."""
    if not path.exists():
        raise DataError(f"{path}: waveform file not found")
    suffix = path.suffix.lower()
    try:
        if suffix == ".npy":
            u, t = np.load(io.BytesIO(read_regular_file(path, "waveform file")), allow_pickle=False), None
        elif suffix == ".npz":
            z = read_npz(path, "waveform file")
            if "u" not in z:
                raise DataError(f"{path}: no array 'u' (arrays: {', '.join(z)[:120]})")
            u, t = z["u"], z.get("t")
        elif suffix in (".csv", ".txt", ".dat"):
            u, t = _read_text(path, column)
        else:
            raise DataError(f"{path}: unknown waveform format '{suffix}' (use .npy, .npz, .csv, .txt or .dat)")
    except DataError:
        raise
    except (ValueError, OSError) as exc:
        raise DataError(f"{path}: cannot read waveform ({type(exc).__name__}: {str(exc).splitlines()[0]})") from None
    try:
        u = np.asarray(u, dtype=float)
        t = None if t is None else np.asarray(t, dtype=float)
    except (ValueError, TypeError) as exc:
        raise DataError(f"{path}: waveform values are not real numbers ({type(exc).__name__})") from None
    if u.ndim != 1 or u.size < 2:
        raise DataError(f"{path}: expected a 1-D waveform of at least 2 points, got shape {u.shape}")
    if not np.all(np.isfinite(u)):
        raise DataError(f"{path}: waveform has non-finite values")
    if t is not None:
        t = np.asarray(t, dtype=float)
        if t.shape != u.shape:
            raise DataError(f"{path}: time and value columns differ in length")
    return u, t


def _read_text(path: Path, column: str | int | None):
    data = read_regular_file(path, "waveform file")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = data.decode("latin-1")
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise DataError(f"{path}: no data")
    delim = "," if "," in lines[0] else None
    first = [c.strip() for c in (lines[0].split(delim))]
    try:
        [float(c) for c in first]
        names = None
    except ValueError:
        names = [c.lower() for c in first]
        lines = lines[1:]
    data = np.loadtxt(io.StringIO("\n".join(lines)), delimiter=delim, ndmin=2)
    ncol = data.shape[1]
    tcol = None
    if names is not None:
        if len(names) != ncol:
            raise DataError(f"{path}: header has {len(names)} names for {ncol} columns")
        tcol = next((i for i, n in enumerate(names) if n in ("t", "time", "time_s")), None)
        if column is None:
            col = names.index("u") if "u" in names else next(i for i in range(ncol) if i != tcol) if ncol > 1 else 0
        elif isinstance(column, str):
            if column.lower() not in names:
                raise DataError(f"{path}: no column '{column}' (columns: {', '.join(names)})")
            col = names.index(column.lower())
        else:
            col = column
    else:
        if ncol > 1:
            tcol = 0
        col = (1 if ncol > 1 else 0) if column is None else column
        if isinstance(col, str):
            raise DataError(f"{path}: column '{col}' given by name but the file has no header")
    if not 0 <= col < ncol:
        raise DataError(f"{path}: column {col} out of range (the file has {ncol} columns)")
    return data[:, col], (data[:, tcol] if tcol is not None and tcol != col else None)


class FromFile(DesignedExcitation):
    """A waveform read from a file, held point by point like a generator plays it."""

    Options = FromFileOptions
    summary = "user's arbitrary waveform from a file (.npy/.npz/.csv), zero-order hold"

    def __init__(self, options):
        super().__init__(options)
        o = self.options
        self.path = Path(o.path)
        points, t = read_points(self.path, o.column)
        if t is not None:
            steps = np.diff(t)
            dt = float(np.mean(steps))
            if not dt > 0 or np.max(np.abs(steps - dt)) > 1e-6 * dt:
                raise DataError(f"{self.path}: time column is not uniform and increasing")
            rate = 1.0 / dt
            lo, hi = SAMPLE_RATE_RANGE
            if not lo <= rate <= hi:
                raise DataError(f"{self.path}: time column gives a point rate of {rate:g} Hz, outside {lo:g}-{hi:g} Hz "
                                f"(times must be in seconds)")
            if o.file_sample_rate is not None and abs(o.file_sample_rate - rate) > 1e-6 * rate:
                raise DataError(
                    f"{self.path}: time column gives {rate:g} Hz but file_sample_rate is {o.file_sample_rate:g} Hz"
                )
        elif o.file_sample_rate is not None:
            rate = o.file_sample_rate
        else:
            raise DataError(f"{self.path}: no time column; set excitation.options.file_sample_rate")
        peak = float(np.max(np.abs(points)))
        if peak == 0:
            raise DataError(f"{self.path}: waveform is all zero")
        self.points = points * (o.amplitude / peak if o.amplitude else 1.0)
        self.point_rate = rate
        # Resolve the record grid (the options stay as the user gave them).
        self.sample_rate = o.sample_rate or rate
        played = o.periods * points.size / rate
        try:
            if o.n_samples is not None:
                self.n_samples = o.n_samples
            elif o.duration is not None:
                self.n_samples = samples(o.duration * self.sample_rate, "record (duration x sample_rate)")
            else:
                self.n_samples = samples(played * self.sample_rate, "played waveform")
        except ValueError as exc:
            raise DataError(f"{self.path}: {exc}") from None
        if self.n_samples < 16:
            raise DataError(f"{self.path}: record of {self.n_samples} samples is too short (at least 16)")

    def signal(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        j = np.floor(t * self.point_rate + 1e-9).astype(np.int64)
        J = self.points.size
        inside = (j >= 0) & (j < J * self.options.periods)
        u = np.zeros_like(t)
        u[inside] = self.points[j[inside] % J]
        return u

    def grid(self) -> tuple[int, float]:
        return self.n_samples, self.sample_rate

    def describe(self) -> dict:
        return {
            "path": str(self.path),
            "n_points": int(self.points.size),
            "point_rate_hz": self.point_rate,
            "periods": self.options.periods,
            "period_s": self.points.size / self.point_rate,
            "period_samples": self.points.size / self.point_rate * self.sample_rate,
        }


@hookimpl
def mbus_excitations():
    return [ExcitationSpec("from_file", FromFile, FromFile.summary)]
