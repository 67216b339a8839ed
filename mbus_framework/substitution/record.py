"""A substitution record: reference shot r(t) (water only), sample shot s(t) (plate in the
path), sample interval dt [s], plate thickness h [m] and density rho [kg/m^3], water temperature
[deg C] and the number of passes through the plate."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: Variables read from a MATLAB file by default (the layout of Poudrel et al. 2024).
DEFAULT_VARIABLES = {
    "reference": "s_ref",
    "sample": "s",
    "time": "t",
    "thickness": "h",
    "density": "rho",
    "temperature": "Temp",
}


@dataclass
class SubstitutionRecord:
    reference: np.ndarray
    sample: np.ndarray
    dt: float
    thickness: float
    density: float
    temperature_C: float
    passes: int = 2
    source: str = ""
    notes: list[str] = field(default_factory=list)

    def __post_init__(self):
        self.reference = np.asarray(self.reference, dtype=float).ravel()
        self.sample = np.asarray(self.sample, dtype=float).ravel()
        for name, value in (("thickness", self.thickness), ("density", self.density), ("sample interval", self.dt)):
            if not np.isfinite(value) or value <= 0:
                raise ValueError(f"{self.source or 'record'}: {name} must be positive, got {value}")
        if self.reference.size != self.sample.size or self.reference.size < 16:
            raise ValueError(
                f"{self.source or 'record'}: reference ({self.reference.size}) and sample ({self.sample.size}) "
                "shots must have the same length (16 samples at least)"
            )
        if not (np.all(np.isfinite(self.reference)) and np.all(np.isfinite(self.sample))):
            raise ValueError(f"{self.source or 'record'}: the shots hold NaN or infinite values")


def read_mat(
    path: str | Path,
    *,
    column: int = 0,
    variables: dict[str, str] | None = None,
    overrides: dict[str, float] | None = None,
    passes: int = 2,
) -> SubstitutionRecord:
    """Read a MATLAB file (level 5, or v7.3 with h5py: :mod:`mbus_framework.pipeline.matlab`, the
    reader the file backend uses). ``variables`` maps record fields to the file's variable names
    (defaults :data:`DEFAULT_VARIABLES`); ``column`` picks the column of a 2-D sample variable;
    ``overrides`` gives thickness/density/temperature_C/dt instead of reading them. Errors are
    one line naming the file and the variable (ValueError)."""
    from mbus_framework.errors import DataError
    from mbus_framework.pipeline.matlab import load_mat

    path = Path(path)
    names = {**DEFAULT_VARIABLES, **(variables or {})}
    overrides = dict(overrides or {})
    if not path.is_file():
        raise ValueError(f"{path}: file not found")
    try:
        data = load_mat(path)
    except DataError as exc:
        raise ValueError(str(exc)) from None

    def get(field_name: str) -> np.ndarray:
        var = names[field_name]
        if var not in data:
            present = ", ".join(sorted(data))
            raise ValueError(f"{path}: no variable {var!r} for the {field_name} (variables: {present})")
        try:
            return np.asarray(data[var], dtype=float)
        except (TypeError, ValueError):
            raise ValueError(f"{path}: variable {var!r} ({field_name}) does not hold real numbers") from None

    def scalar(field_name: str, key: str) -> float:
        if key in overrides:
            return float(overrides[key])
        value = get(field_name)
        if value.size != 1:
            raise ValueError(f"{path}: variable {names[field_name]!r} ({field_name}) must be a scalar, has shape {value.shape}")
        return float(value.ravel()[0])

    reference = get("reference")
    sample = get("sample")
    if sample.ndim == 2 and min(sample.shape) > 1:
        if sample.shape[0] != reference.size and sample.shape[1] == reference.size:
            sample = sample.T
        if not -sample.shape[1] <= column < sample.shape[1]:
            raise ValueError(
                f"{path}: column {column} of {names['sample']!r} is out of range (it has {sample.shape[1]} columns)"
            )
        sample = sample[:, column]
    if "dt" in overrides:
        dt = float(overrides["dt"])
    else:
        t = get("time").ravel()
        if t.size != reference.size:
            raise ValueError(f"{path}: time {names['time']!r} has {t.size} samples, the shots {reference.size}")
        steps = np.diff(t)
        dt = float(np.median(steps))
        if dt <= 0 or np.max(np.abs(steps - dt)) > 1e-3 * dt:
            raise ValueError(f"{path}: time {names['time']!r} is not uniformly sampled")
    return SubstitutionRecord(
        reference=reference,
        sample=sample,
        dt=dt,
        thickness=scalar("thickness", "thickness"),
        density=scalar("density", "density"),
        temperature_C=scalar("temperature", "temperature_C"),
        passes=passes,
        source=str(path),
    )
