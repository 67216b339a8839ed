"""Shear frequency sweep (Section 6.2.3.3): E' and eta' at one chosen frequency.

A rheometer sweep table has a frequency column (``frequency [Hz]`` or ``omega [rad/s]``), the
storage modulus ``E'`` (or ``G'``) [Pa] and the dynamic viscosity ``eta'`` [Pa s]; when
``eta'`` is absent it is computed from the loss modulus as ``eta' = E'' / w``. The dissertation
compares the MBUS shear properties with E' and eta' "around 10 Hz", where potato's values
hardly depend on frequency:

    E_tau  <->  E'(f0),      eta_tau  <->  eta'(f0)       (f0 = 10 Hz by default)

A value at f0 is interpolated between the two neighbouring sweep points linearly in
(log f, log value), which is exact for a power law ``value ~ f^n`` (the usual shape of a
sweep); a quantity with non-positive values is interpolated linearly in log f instead.
f0 outside the sweep is an error (no extrapolation).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from mbus_framework.errors import DataError
from mbus_framework.analysis.conventional.columns import Quantity, read_export

_ANGULAR = (("omega", "rad/s"), ("ω", "rad/s"), ("angular frequency", "rad/s"), ("angular_frequency", "rad/s"))

#: Columns of a sweep table (headers may carry units, e.g. ``E' [kPa]``).
SWEEP_COLUMNS = (
    Quantity("frequency", ("frequency", "f", "freq", "omega", "ω", "angular frequency", "angular_frequency"),
             "frequency", implied_units=_ANGULAR),
    Quantity("storage", ("E'", "G'", "storage modulus", "storage_modulus", "E_prime", "G_prime"), "modulus"),
    Quantity("loss", ("E''", "G''", "loss modulus", "loss_modulus", "E_double_prime", "G_double_prime"),
             "modulus", required=False),
    Quantity("viscosity", ("eta'", "η'", "dynamic viscosity", "dynamic_viscosity", "eta_prime"),
             "viscosity", required=False),
)


@dataclass(frozen=True)
class SweepValue:
    """E' [Pa] and eta' [Pa s] of one sweep at ``frequency`` [Hz]."""

    source: str
    frequency: float
    storage_modulus: float
    dynamic_viscosity: float

    def as_dict(self) -> dict:
        return asdict(self)


def interpolate_at(frequencies: np.ndarray, values: np.ndarray, f0: float) -> float:
    """Value at ``f0`` between sorted ``frequencies`` (power-law interpolation, see module)."""
    i = int(np.clip(np.searchsorted(frequencies, f0), 1, frequencies.size - 1))
    f_lo, f_hi = frequencies[i - 1], frequencies[i]
    v_lo, v_hi = values[i - 1], values[i]
    w = (math.log(f0) - math.log(f_lo)) / (math.log(f_hi) - math.log(f_lo))
    if np.all(values > 0):
        return float(math.exp((1 - w) * math.log(v_lo) + w * math.log(v_hi)))
    return float((1 - w) * v_lo + w * v_hi)


def analyse_sweep(frequency, storage, *, viscosity=None, loss=None, f0: float = 10.0,
                  source: str = "<sweep>") -> SweepValue:
    """E'(f0) and eta'(f0) from sweep arrays in SI (frequency in Hz)."""
    f = np.asarray(frequency, dtype=float)
    if viscosity is None:
        if loss is None:
            raise DataError(f"{source}: needs a dynamic viscosity (eta') or a loss modulus (E'') column")
        viscosity = np.asarray(loss, dtype=float) / (2.0 * math.pi * f)
    order = np.argsort(f)
    f = f[order]
    storage = np.asarray(storage, dtype=float)[order]
    viscosity = np.asarray(viscosity, dtype=float)[order]
    if f.size < 2 or np.any(f <= 0):
        raise DataError(f"{source}: a sweep needs at least two positive frequencies")
    if np.any(np.diff(f) == 0):
        raise DataError(f"{source}: frequency {f[np.flatnonzero(np.diff(f) == 0)[0]]:g} Hz appears twice")
    if not (f[0] <= f0 <= f[-1]):
        raise DataError(f"{source}: {f0:g} Hz is outside the sweep ({f[0]:.3g}-{f[-1]:.3g} Hz); "
                        "choose another --shear-frequency")
    return SweepValue(source, float(f0), interpolate_at(f, storage, f0), interpolate_at(f, viscosity, f0))


def analyse_sweep_file(path: str | Path, *, f0: float = 10.0) -> SweepValue:
    """:func:`analyse_sweep` of a sweep table file (CSV/TSV, optionally gzipped)."""
    cols = read_export(path, SWEEP_COLUMNS)
    return analyse_sweep(cols["frequency"], cols["storage"], viscosity=cols.get("viscosity"),
                         loss=cols.get("loss"), f0=f0, source=str(path))
