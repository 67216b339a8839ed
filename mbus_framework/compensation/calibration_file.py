"""The transducer calibration file: NPZ arrays plus a JSON sidecar (format ``mbus-calibration/1``)."""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mbus_framework.compensation.transfer import TransferEstimate, _TransducerResponse
from mbus_framework.errors import DataError

FORMAT = "mbus-calibration/1"

# ---------------------------------------------------------------------------------------------
# The calibration file
# ---------------------------------------------------------------------------------------------
@dataclass
class Calibration(_TransducerResponse):
    """A saved G_TR(f): what :mod:`mbus_plugins.compensators.transfer_function` loads by path."""

    f: np.ndarray
    log_G_TR: np.ndarray
    reliable: np.ndarray
    se_log_magnitude: np.ndarray
    se_phase: np.ndarray
    usable: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    path: Path | None = None


    def response(self, f: np.ndarray, band: tuple[float, float] | None = None, extend: bool = False) -> np.ndarray:
        """G_TR at frequencies f [Hz].

        Inside ``band`` (default: the reliable band; never wider) log-magnitude and unwrapped
        phase are interpolated linearly between reliable lines. Outside it the result is 0, or
        with ``extend`` the raw estimate, interpolated (real and imaginary parts) between the
        usable lines: noisy, but of the right size, which is what a filter needs where the rig
        still passes a little.
        """
        f = np.abs(np.asarray(f, dtype=float))
        lo, hi = band or self.reliable_band
        r0, r1 = self.reliable_band
        lo, hi = max(lo, r0), min(hi, r1)
        sel = self.reliable & (self.f >= lo) & (self.f <= hi)
        fs, lg = self.f[sel], self.log_G_TR[sel]
        if fs.size < 2:
            raise DataError(f"{self.path}: fewer than two reliable calibration lines in {lo:g}-{hi:g} Hz")
        inside = (f >= fs[0]) & (f <= fs[-1])
        out = np.zeros(f.shape, dtype=complex)
        out[inside] = np.exp(np.interp(f[inside], fs, lg.real) + 1j * np.interp(f[inside], fs, lg.imag))
        if extend:
            ok = self.usable if self.usable is not None else np.isfinite(self.log_G_TR)
            ok = ok & np.isfinite(self.log_G_TR)
            fu = np.r_[0.0, self.f[ok]]
            gu = np.r_[0.0, np.exp(self.log_G_TR[ok])]
            outside = ~inside & (f <= fu[-1])
            out[outside] = np.interp(f[outside], fu, gu.real) + 1j * np.interp(f[outside], fu, gu.imag)
        return out


def save_calibration(path: str | Path, est: TransferEstimate, meta: dict[str, Any]) -> tuple[Path, Path]:
    """Write ``path`` (.npz arrays) and its JSON sidecar atomically; returns both paths."""
    from mbus_framework.pipeline.storage import atomic_write_json, atomic_write_npz

    path = Path(path)
    if path.suffix.lower() != ".npz":
        path = path.with_suffix(".npz")
    atomic_write_npz(
        path,
        f=est.f,
        log_G_TR=est.log_G_TR,
        gamma=est.gamma,
        se_log_magnitude=est.se_log_magnitude,
        se_phase=est.se_phase,
        reliable=est.reliable,
        lengths=est.lengths,
        G_tot=est.G_tot,
        delays_s=est.delays_s,
        usable=est.usable,
    )
    sidecar = path.with_suffix(".json")
    atomic_write_json(sidecar, {"format": FORMAT, "arrays": path.name, **meta})
    return path, sidecar


def load_calibration(path: str | Path) -> Calibration:
    """Read a calibration written by :func:`save_calibration` (give the .npz or the .json)."""
    path = Path(path)
    npz, sidecar = path.with_suffix(".npz"), path.with_suffix(".json")
    if not npz.is_file():
        raise DataError(f"{npz}: calibration file not found (run the calibration config first)")
    meta: dict[str, Any] = {}
    if sidecar.is_file():
        try:
            meta = json.loads(sidecar.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise DataError(f"{sidecar}: unreadable calibration sidecar ({type(exc).__name__})") from None
        if meta.get("format") != FORMAT:
            raise DataError(f"{sidecar}: not an mbus calibration (format {meta.get('format')!r}, expected {FORMAT})")
    try:
        with np.load(npz, allow_pickle=False) as z:
            cal = Calibration(
                f=z["f"], log_G_TR=z["log_G_TR"], reliable=z["reliable"].astype(bool),
                se_log_magnitude=z["se_log_magnitude"], se_phase=z["se_phase"],
                usable=z["usable"].astype(bool) if "usable" in z.files else None, meta=meta, path=npz,
            )
    except (KeyError, ValueError, OSError) as exc:
        raise DataError(f"{npz}: not a readable calibration ({type(exc).__name__}: {exc})") from None
    if not cal.reliable.any():
        raise DataError(f"{npz}: calibration has no reliable frequency lines")
    return cal
