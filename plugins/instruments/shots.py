"""Shots on disk and shot processing, shared by the ``lab`` backend and the ``file`` backend.

Run-directory layout written by the ``lab`` backend (all files written atomically)::

    <run_dir>/shots/acquisition.json   format, status, instrument identities and settings,
                                       processing options, shots requested/saved, error if any
    <run_dir>/shots/excitation.npz     designed excitation (t [s], u) and the uploaded generator
                                       points with the generator's actual sample rate
    <run_dir>/shots/shot_0001.npz      one per shot, written as it arrives

A shot file holds ``dt`` [s] (scope sample interval), ``u_raw`` / ``y_raw`` (int16 scope codes of
the excitation and response channels), ``u`` / ``y`` [V] and ``meta`` (a JSON string: channel
numbers, V/div, counts per division, block details, time stamp). Volts are
``raw * (V/div) / counts_per_division`` (25 for the GDS-2000).

Processing (:func:`combine`) turns shots into one ``t, u, y`` record: each shot's excitation
channel is aligned with the reference (the waveform the generator actually played) by
cross-correlation; both channels are cut from the burst start (minus nothing: t = 0 is the first
sample of the burst), optionally baseline-corrected with the pre-burst samples, averaged over
shots and scaled by the gains. Without a reference (no designed excitation anywhere), the burst
start is where the excitation channel leaves its pre-burst rest (:func:`burst_start`) and the
record is kept to its end.
"""
from __future__ import annotations

import datetime as _dt
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from mbus_framework.engine.physics import onset_index
from mbus_framework.errors import DataError
from mbus_framework.pipeline.storage import atomic_write_json, atomic_write_npz, read_npz, read_regular_file, to_jsonable

FORMAT = "mbus-lab-shots/1"
SHOT_DIR = "shots"
ACQUISITION_FILE = "acquisition.json"
EXCITATION_FILE = "excitation.npz"
MIN_SAMPLES = 16
MAX_SHOTS = 10_000
"""The lab backend saves at most this many shots."""
DT_RANGE = (1e-12, 100.0)
"""Plausible scope sample interval [s]."""
MAX_REFERENCE_SAMPLES = 50_000_000
"""Longest played excitation on the scope's grid [samples]."""


class AlignOptions(BaseModel):
    """How the recorded excitation is matched to the designed one."""

    model_config = ConfigDict(extra="forbid")
    enabled: bool = Field(True, description="align each shot with the reference by cross-correlation")
    min_correlation: float = Field(
        0.8, ge=0, le=1, description="smallest acceptable normalised correlation (miswiring check)")
    remove_baseline: bool = Field(True, description="subtract each channel's pre-burst mean")
    window: Literal["excitation", "record"] = Field(
        "excitation", description="keep the excitation's duration, or everything up to the record end")


class ProcessingOptions(BaseModel):
    """From shots to the fitted record (``backend.options.processing``)."""

    model_config = ConfigDict(extra="forbid")
    align: AlignOptions = Field(default_factory=AlignOptions)
    input: Literal["recorded", "designed"] = Field(
        "recorded", description="u is the recorded excitation channel, or the designed waveform "
                                "scaled to it by least squares")
    u_gain: float = Field(1.0, description="model input per recorded volt on the excitation channel [N/V]")
    y_gain: float = Field(1.0, description="model output per recorded volt on the response channel [N/V]")


@dataclass
class Shot:
    """One two-channel record from the scope (volts and raw codes)."""

    dt: float
    u: np.ndarray
    y: np.ndarray
    u_raw: np.ndarray | None = None
    y_raw: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)


@dataclass
class Reference:
    """What the generator played: ``values`` at ``rate`` [Hz], repeated ``repeats`` times."""

    values: np.ndarray
    rate: float
    repeats: int = 1

    def on_grid(self, dt: float) -> np.ndarray:
        """Zero-order-hold resampling onto a grid of step ``dt`` [s] (the whole burst)."""
        total = self.values.size * self.repeats
        span = total / (self.rate * dt)
        if not np.isfinite(span) or span > MAX_REFERENCE_SAMPLES:
            raise DataError(f"the played excitation ({total} points at {self.rate:g} Hz) spans {span:.3g} samples of "
                            f"{dt:g} s, more than {MAX_REFERENCE_SAMPLES:,} (wrong point rate or sample interval?)")
        n = int(np.floor(span + 1e-6))
        idx = np.floor(np.arange(n) * dt * self.rate + 1e-6).astype(np.int64)
        return np.asarray(self.values, dtype=float)[idx % self.values.size]


def now() -> str:
    return _dt.datetime.now().astimezone().isoformat(timespec="seconds")


# -- writing ---------------------------------------------------------------------------------
def shot_path(shot_dir: Path, index: int) -> Path:
    return Path(shot_dir) / f"shot_{index:04d}.npz"


def save_shot(shot_dir: Path, index: int, shot: Shot) -> Path:
    """Write one shot atomically (``shot_<index:04d>.npz``)."""
    arrays = {"dt": np.float64(shot.dt), "u": np.asarray(shot.u, float), "y": np.asarray(shot.y, float),
              "meta": np.array(json.dumps(to_jsonable(shot.meta)))}
    if shot.u_raw is not None:
        arrays["u_raw"] = np.asarray(shot.u_raw, np.int16)
    if shot.y_raw is not None:
        arrays["y_raw"] = np.asarray(shot.y_raw, np.int16)
    return atomic_write_npz(shot_path(shot_dir, index), **arrays)


def save_excitation(shot_dir: Path, t, u, points=None, points_rate: float | None = None, repeats: int = 1) -> Path:
    arrays = {"t": np.asarray(t, float), "u": np.asarray(u, float)}
    if points is not None:
        arrays["points"] = np.asarray(points, np.int16)
        arrays["points_rate_hz"] = np.float64(points_rate)
        arrays["repeats"] = np.int64(repeats)
    return atomic_write_npz(Path(shot_dir) / EXCITATION_FILE, **arrays)


def write_acquisition(shot_dir: Path, record: dict[str, Any]) -> Path:
    record = dict(record, format=FORMAT, updated=now())
    return atomic_write_json(Path(shot_dir) / ACQUISITION_FILE, record)


# -- reading ---------------------------------------------------------------------------------
def find_shot_dir(path: Path) -> Path | None:
    """The shot folder for a run directory or a shot folder, or None."""
    path = Path(path)
    for candidate in (path, path / SHOT_DIR):
        if (candidate / ACQUISITION_FILE).is_file() or any(candidate.glob("shot_*.npz")):
            return candidate
    return None


def load_shot(path: Path) -> Shot:
    """One saved shot, checked: dt plausible, u and y equally long, finite, real."""
    try:
        z = read_npz(path, "shot file")
    except DataError as exc:
        raise DataError(f"{path}: unreadable shot file ({str(exc).partition(': ')[2]})") from None
    missing = [k for k in ("dt", "u", "y") if k not in z]
    if missing:
        raise DataError(f"{path}: not a shot file (missing {', '.join(missing)})")
    try:
        meta = json.loads(str(z["meta"])) if "meta" in z else {}
        dt = float(np.asarray(z["dt"], float).reshape(-1)[0]) if np.asarray(z["dt"]).size == 1 else float("nan")
        u, y = np.asarray(z["u"], float), np.asarray(z["y"], float)
        u_raw, y_raw = (np.asarray(z[k], np.int16) if k in z else None for k in ("u_raw", "y_raw"))
    except (ValueError, TypeError, OverflowError) as exc:  # bad JSON, strings or complex numbers
        raise DataError(f"{path}: unreadable shot file ({type(exc).__name__}: {str(exc)[:100]})") from None
    if not isinstance(meta, dict):
        raise DataError(f"{path}: shot meta must be a JSON object, not {type(meta).__name__}")
    if u.shape != y.shape or u.ndim != 1:
        raise DataError(f"{path}: channels u and y differ in length or are not 1-D ({u.shape} vs {y.shape})")
    if not (np.isfinite(dt) and DT_RANGE[0] <= dt <= DT_RANGE[1]):
        raise DataError(f"{path}: sample interval dt = {dt!r} s is not within {DT_RANGE[0]:g}-{DT_RANGE[1]:g} s")
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(y))):
        raise DataError(f"{path}: channel u or y has non-finite samples")
    for name, raw, volts in (("u_raw", u_raw, u), ("y_raw", y_raw, y)):
        if raw is not None and raw.shape != volts.shape:
            raise DataError(f"{path}: {name} has {raw.size} codes but the channel {volts.size} samples")
    return Shot(dt, u, y, u_raw, y_raw, meta)


def rescale(shot: Shot, counts_per_division: float) -> Shot:
    """Recompute volts from raw codes with a different counts-per-division factor."""
    if shot.u_raw is None or shot.y_raw is None:
        return shot
    m = shot.meta
    try:
        u_vdiv, y_vdiv = float(m["u_volts_per_div"]), float(m["y_volts_per_div"])
    except (KeyError, TypeError, ValueError):
        raise DataError(f"shot {m.get('index', '?')}: no usable u_volts_per_div / y_volts_per_div in its meta "
                        f"(cannot rescale the raw codes)") from None
    if not (np.isfinite(u_vdiv) and np.isfinite(y_vdiv) and u_vdiv > 0 and y_vdiv > 0):
        raise DataError(f"shot {m.get('index', '?')}: V/div {u_vdiv:g} / {y_vdiv:g} must be positive")
    u = shot.u_raw.astype(float) * u_vdiv / counts_per_division
    y = shot.y_raw.astype(float) * y_vdiv / counts_per_division
    return Shot(shot.dt, u, y, shot.u_raw, shot.y_raw, dict(m, counts_per_division=counts_per_division))


@dataclass
class SavedRun:
    shot_dir: Path
    acquisition: dict[str, Any]
    shots: list[Shot]
    files: list[Path]
    reference: Reference | None
    designed_t: np.ndarray | None
    designed_u: np.ndarray | None


def load_run(path: Path) -> SavedRun:
    """Read a shot folder (or the run directory holding ``shots/``)."""
    shot_dir = find_shot_dir(path)
    if shot_dir is None:
        raise DataError(f"{path}: no saved shots (expected {SHOT_DIR}/{ACQUISITION_FILE} and shot_*.npz)")
    acq_file = shot_dir / ACQUISITION_FILE
    acquisition: dict[str, Any] = {}
    if acq_file.exists():
        acquisition = _read_acquisition(acq_file)
    files = sorted(shot_dir.glob("shot_*.npz"))
    if not files:
        raise DataError(f"{shot_dir}: no shot_*.npz files (the acquisition saved no shot)")
    if len(files) > MAX_SHOTS:
        raise DataError(f"{shot_dir}: {len(files)} shot files, more than a lab run saves ({MAX_SHOTS})")
    shots = [load_shot(f) for f in files]
    reference, designed_t, designed_u = _read_excitation(shot_dir / EXCITATION_FILE)
    return SavedRun(shot_dir, acquisition, shots, files, reference, designed_t, designed_u)


def _read_acquisition(path: Path) -> dict[str, Any]:
    """``acquisition.json``: a JSON object of the expected format with sensibly typed fields."""
    try:
        acquisition = json.loads(read_regular_file(path, "acquisition record", 16 * 2**20).decode("utf-8"))
    except (ValueError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: not valid JSON ({str(exc)[:100]})") from None
    if not isinstance(acquisition, dict):
        raise DataError(f"{path}: must be a JSON object, not {type(acquisition).__name__}")
    if acquisition.get("format") != FORMAT:
        raise DataError(f"{path}: unknown format {str(acquisition.get('format'))[:40]!r} (expected {FORMAT})")
    for key, kinds in (("status", str), ("error", (str, type(None))), ("processing", (dict, type(None))),
                       ("instruments", dict), ("shots_requested", int), ("shots_saved", int)):
        if key in acquisition and not isinstance(acquisition[key], kinds):
            raise DataError(f"{path}: field {key!r} has the wrong type ({type(acquisition[key]).__name__})")
    return acquisition


def _read_excitation(path: Path) -> tuple[Reference | None, np.ndarray | None, np.ndarray | None]:
    """``excitation.npz``: (what the generator played, designed t, designed u), each checked."""
    if not path.exists():
        return None, None, None
    z = read_npz(path, "excitation file")
    try:
        t, u = np.asarray(z["t"], float), np.asarray(z["u"], float)
        reference = None
        if "points" in z:
            points = np.asarray(z["points"], float)
            rate = float(np.asarray(z["points_rate_hz"], float).reshape(-1)[0])
            repeats = int(np.asarray(z["repeats"]).reshape(-1)[0]) if "repeats" in z else 1
            if points.ndim != 1 or not points.size or not np.all(np.isfinite(points)):
                raise DataError(f"{path}: points must be a non-empty 1-D array of finite codes")
            if not (np.isfinite(rate) and rate > 0) or not 1 <= repeats <= 1_000_000:
                raise DataError(f"{path}: points_rate_hz {rate!r} must be positive and repeats {repeats} >= 1")
            reference = Reference(points, rate, repeats)
    except DataError:
        raise
    except (KeyError, ValueError, TypeError, IndexError, OverflowError) as exc:
        raise DataError(f"{path}: unreadable ({type(exc).__name__}: {str(exc)[:100]})") from None
    if t.ndim != 1 or t.shape != u.shape or t.size < 2 or not (np.all(np.isfinite(t)) and np.all(np.isfinite(u))):
        raise DataError(f"{path}: designed t and u must be equally long, finite 1-D arrays")
    if not t[1] > t[0]:
        raise DataError(f"{path}: designed time t does not increase")
    return reference, t, u


# -- processing ------------------------------------------------------------------------------
def find_lag(recorded: np.ndarray, reference: np.ndarray) -> tuple[int, float, float]:
    """Lag [samples] of ``reference`` inside ``recorded`` (may be negative), the normalised
    correlation there and the most negative normalised correlation (inverted-channel check)."""
    from scipy import signal  # on use: scipy.signal imports scipy.stats (about 0.5 s)

    a = recorded - recorded.mean()
    b = reference - reference.mean()
    corr = signal.correlate(a, b, mode="full", method="fft")
    lags = signal.correlation_lags(a.size, b.size, mode="full")
    # Normalise by the energy of the overlapping parts so partial overlaps are not favoured.
    a2 = np.concatenate([[0.0], np.cumsum(a * a)])
    b2 = np.concatenate([[0.0], np.cumsum(b * b)])
    lo_a = np.clip(lags, 0, a.size)
    hi_a = np.clip(lags + b.size, 0, a.size)
    lo_b = np.clip(-lags, 0, b.size)
    hi_b = np.clip(a.size - lags, 0, b.size)
    energy = np.sqrt((a2[hi_a] - a2[lo_a]) * (b2[hi_b] - b2[lo_b]))
    overlap = hi_a - lo_a
    usable = (energy > 0) & (overlap >= min(b.size, a.size) // 2)
    rho = np.where(usable, corr / np.where(energy > 0, energy, 1.0), 0.0)
    best = int(np.argmax(rho))
    return int(lags[best]), float(rho[best]), float(rho.min())


def burst_start(u: np.ndarray, where: str) -> int:
    """First sample of the burst on an excitation channel, found without the designed waveform.

    The onset is the first sample deviating from the first sample's level by more than 10 % of
    the largest deviation; it is then moved back while the samples before it still stand out of
    the pre-burst noise (3 robust standard deviations, 1.4826 x MAD, of the samples before the
    onset), so a slowly rising burst keeps its start. A record whose first sample is not at the
    rest level (further than a quarter of the half-range from the channel's mid-range: a record
    that starts inside the burst) starts at 0.
    """
    u = np.asarray(u, dtype=float)
    i = onset_index(u - u[0], 0.1)
    if i is None:
        raise DataError(f"{where}: the excitation channel is flat (no burst recorded)")
    mid, half = (u.max() + u.min()) / 2, (u.max() - u.min()) / 2
    if abs(u[0] - mid) > 0.25 * half:  # the first sample is at a burst level, not at rest
        return 0
    pre = u[:i]
    base = float(np.median(pre)) if pre.size else float(u[0])
    noise = 1.4826 * float(np.median(np.abs(pre - base))) if pre.size >= 8 else 0.0
    while i > 0 and abs(u[i - 1] - base) > 3.0 * noise:
        i -= 1
    return int(i)


def cut_at(shots: list[Shot], starts: list[int], n: int, remove_baseline: bool,
           source: str) -> list[tuple[np.ndarray, np.ndarray]]:
    """Both channels of each shot from its burst start, ``n`` samples, minus the pre-burst mean
    (when asked and at least 8 samples precede the burst)."""
    if n < MIN_SAMPLES:
        raise DataError(f"{source}: only {n} samples after the burst start; widen the timebase")
    cuts = []
    for s, i in zip(shots, starts):
        u, y = s.u.astype(float), s.y.astype(float)
        if remove_baseline and i >= 8:
            u, y = u - u[:i].mean(), y - y[:i].mean()
        cuts.append((u[i:i + n], y[i:i + n]))
    return cuts


def combine(shots: list[Shot], reference: Reference | None, options: ProcessingOptions,
            source: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
    """Align, cut, baseline-correct, average and scale shots; returns t [s], u, y and meta."""
    if not shots:
        raise DataError(f"{source}: no shots to process")
    dt = shots[0].dt
    for k, s in enumerate(shots[1:], start=2):
        if abs(s.dt - dt) > 1e-6 * dt or s.u.size != shots[0].u.size:
            raise DataError(f"{source}: shot {k} has dt {s.dt:.6g} s / {s.u.size} samples, shot 1 has "
                            f"{dt:.6g} s / {shots[0].u.size}; cannot average shots with different settings")
    align = options.align
    meta: dict[str, Any] = {"shots_averaged": len(shots), "dt_s": dt, "input": options.input,
                            "u_gain": options.u_gain, "y_gain": options.y_gain}
    try:
        ref = reference.on_grid(dt) if reference is not None else None
    except DataError as exc:
        raise DataError(f"{source}: {exc}") from None
    cuts = []
    if align.enabled and ref is not None:
        if ref.size < MIN_SAMPLES:
            raise DataError(f"{source}: the excitation covers only {ref.size} scope samples of {dt:.3g} s")
        lags, rhos = [], []
        for k, s in enumerate(shots, start=1):
            lag, rho, rho_min = find_lag(s.u, ref)
            if rho < align.min_correlation:
                hint = " (the channel looks inverted)" if -rho_min >= align.min_correlation else ""
                raise DataError(
                    f"{source}: shot {k}: the excitation channel does not match the designed excitation "
                    f"(best normalised correlation {rho:.2f} < {align.min_correlation}){hint}; check the "
                    f"channel mapping, the trigger and the generator output")
            if lag < 0:
                raise DataError(f"{source}: shot {k}: the record starts {-lag} samples after the excitation "
                                f"began; move the trigger point (timebase delay) so the burst start is recorded")
            lags.append(lag)
            rhos.append(rho)
        available = min(s.u.size - lag for s, lag in zip(shots, lags))
        n = min(ref.size, available) if align.window == "excitation" else available
        cuts = cut_at(shots, lags, n, align.remove_baseline, source)
        meta.update(lags_samples=lags, correlations=[round(r, 4) for r in rhos], window=align.window,
                    excitation_samples_on_grid=int(ref.size), truncated=bool(n < ref.size))
    elif align.enabled:  # no designed waveform: the burst starts where the excitation channel leaves its rest
        starts = [burst_start(s.u, f"{source}: shot {k}") for k, s in enumerate(shots, start=1)]
        n = min(s.u.size - i for s, i in zip(shots, starts))
        cuts = cut_at(shots, starts, n, align.remove_baseline, source)
        meta.update(aligned="burst onset (no designed excitation)", burst_starts_samples=starts, window="record")
        if 0 in starts:
            meta["warnings"] = [f"{source}: the excitation channel is not at rest at the start of the record "
                                f"(the burst began before it): fitted from the first sample, as if at rest"]
    else:
        n = shots[0].u.size
        cuts = [(s.u.astype(float), s.y.astype(float)) for s in shots]
        meta["aligned"] = False
    u = np.mean([c[0] for c in cuts], axis=0)
    y = np.mean([c[1] for c in cuts], axis=0)
    if options.input == "designed":
        if ref is None:
            raise DataError(f"{source}: processing.input 'designed' needs the designed excitation "
                            f"(an excitation section in the config)")
        r = ref[:n] if ref.size >= n else np.concatenate([ref, np.zeros(n - ref.size)])
        r = r / float(np.max(np.abs(ref)))
        gain = float(np.dot(u, r) / np.dot(r, r))
        meta["designed_peak_v"] = gain  # recorded volts at the designed waveform's peak
        u = gain * r
    t = np.arange(n) * dt
    return t, options.u_gain * u, options.y_gain * y, meta
