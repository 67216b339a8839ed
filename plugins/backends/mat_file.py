"""MATLAB ``.mat`` records for the ``file`` backend: named variables -> t, u, y (+ sample data).

Level-5 files (MATLAB 5 ... 7.2, the default ``save`` format) are read with
:func:`scipy.io.loadmat`; v7.3 files are HDF5 and are read with ``h5py`` when it is installed.

:class:`MatVariables` maps the file's variables to the record:

* ``input`` (u) and ``output`` (y): vectors of N samples, or N x M matrices (one signal per
  column: MATLAB's layout), of which ``column`` (0-based) is taken;
* ``time`` (t, seconds, N samples), or instead ``sample_interval`` dt [s] or ``sample_rate``
  f_s [Hz] (then t_k = k dt = k / f_s);
* optional scalars ``thickness`` [m], ``density`` [kg/m^3] and ``temperature`` (of the coupling
  fluid) [deg C], reported in ``meta["sample_from_file"] = {"length", "density"}`` and
  ``meta["fluid_from_file"] = {"temperature_C"}``.

Every problem is one line naming the file and the variable or option.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from mbus_framework.errors import DataError
from mbus_framework.interfaces.backend import Measurement, check_record
from mbus_framework.pipeline.matlab import load_mat

OPTION = "backend.options.variables"


class MatVariables(BaseModel):
    """Which variable of a ``.mat`` file is what."""

    model_config = ConfigDict(extra="forbid")
    input: str = Field("u", description="variable holding the input u (vector, or N x M: see column)")
    output: str = Field("y", description="variable holding the output y (vector, or N x M: see column)")
    column: int = Field(0, ge=0, description="0-based column of a 2-D input/output (one signal per column)")
    time: str | None = Field("t", description="variable holding t [s]; unused when sample_interval or sample_rate is set")
    sample_interval: float | None = Field(None, gt=0, description="time step dt [s] when the file holds no time vector")
    sample_rate: float | None = Field(None, gt=0, description="sample rate [Hz] when the file holds no time vector")
    thickness: str | None = Field(None, description="variable holding the sample thickness [m] (optional)")
    density: str | None = Field(None, description="variable holding the sample density [kg/m^3] (optional)")
    temperature: str | None = Field(None, description="variable holding the fluid temperature [deg C] (optional)")

    @model_validator(mode="after")
    def _one_clock(self) -> "MatVariables":
        if self.sample_interval is not None and self.sample_rate is not None:
            raise ValueError("give sample_interval or sample_rate, not both")
        return self


def _numeric(path: Path, name: str, role: str, value: Any) -> np.ndarray:
    a = np.asarray(value)
    if not (np.issubdtype(a.dtype, np.number) or a.dtype == bool) or np.iscomplexobj(a):
        raise DataError(f"{path}: variable '{name}' ({OPTION}.{role}) holds {a.dtype} values, not real numbers")
    return a.astype(float)


def _get(path: Path, arrays: dict[str, np.ndarray], name: str, role: str) -> np.ndarray:
    if name not in arrays:
        have = ", ".join(sorted(arrays))[:120] or "none"
        raise DataError(f"{path}: no variable '{name}' ({OPTION}.{role}); the file has: {have}")
    return _numeric(path, name, role, arrays[name])


def _signal(path: Path, a: np.ndarray, name: str, role: str, column: int) -> np.ndarray:
    """A vector as is; an N x M matrix's ``column``; anything else is an error."""
    if a.ndim == 1 or (a.ndim == 2 and 1 in a.shape):
        return a.ravel()
    if a.ndim != 2:
        raise DataError(f"{path}: variable '{name}' ({OPTION}.{role}) has {a.ndim} dimensions "
                        f"{'x'.join(map(str, a.shape))}; expected a vector or an N x M matrix")
    if column >= a.shape[1]:
        raise DataError(f"{path}: {OPTION}.column = {column} is out of range: variable '{name}' has "
                        f"{a.shape[1]} columns (0 ... {a.shape[1] - 1})")
    return a[:, column]


def _scalar(path: Path, arrays: dict[str, np.ndarray], name: str, role: str) -> float:
    a = _get(path, arrays, name, role)
    if a.size != 1:
        raise DataError(f"{path}: variable '{name}' ({OPTION}.{role}) has {a.size} values; expected one number")
    value = float(a.ravel()[0])
    if not np.isfinite(value) or (role != "temperature" and value <= 0):
        raise DataError(f"{path}: variable '{name}' ({OPTION}.{role}) is {value:g}; expected a positive number")
    return value


def read_mat(path: Path, v: MatVariables | None = None) -> Measurement:
    """A checked t, u, y record from the variables of a ``.mat`` file (see the module docstring)."""
    v = v or MatVariables()
    arrays = load_mat(path)
    u = _signal(path, _get(path, arrays, v.input, "input"), v.input, "input", v.column)
    y = _signal(path, _get(path, arrays, v.output, "output"), v.output, "output", v.column)
    if u.size != y.size:
        raise DataError(f"{path}: input '{v.input}' has {u.size} samples but output '{v.output}' has {y.size} "
                        f"(one signal per column expected)")
    step = v.sample_interval or (1.0 / v.sample_rate if v.sample_rate else None)
    used = {"input": v.input, "output": v.output}
    if step is not None:
        t = np.arange(u.size) * step
    elif v.time is None:
        raise DataError(f"{path}: no time base: set {OPTION}.time (a variable) or sample_interval / sample_rate")
    else:
        if v.time not in arrays:
            have = ", ".join(sorted(arrays))[:120] or "none"
            raise DataError(f"{path}: no variable '{v.time}' ({OPTION}.time); the file has: {have}; "
                            f"name the time variable or set {OPTION}.sample_interval")
        t = _signal(path, _numeric(path, v.time, "time", arrays[v.time]), v.time, "time", 0)
        if t.size != u.size:
            raise DataError(f"{path}: time '{v.time}' has {t.size} samples but input '{v.input}' has {u.size}")
        used["time"] = v.time
    m = check_record(path, t, u, y)
    sample = {}
    for role, key in (("thickness", "length"), ("density", "density")):
        name = getattr(v, role)
        if name is not None:
            sample[key] = _scalar(path, arrays, name, role)
            used[role] = name
    m.meta["time_start_s"] = float(t[0])
    if sample:
        m.meta["sample_from_file"] = sample
    if v.temperature is not None:
        m.meta["fluid_from_file"] = {"temperature_C": _scalar(path, arrays, v.temperature, "temperature")}
        used["temperature"] = v.temperature
    m.meta["variables"] = used
    if any(_signal_is_matrix(arrays[n]) for n in (v.input, v.output)):
        m.meta["column"] = v.column
    return m


def _signal_is_matrix(a: np.ndarray) -> bool:
    return np.asarray(a).ndim == 2 and min(np.asarray(a).shape) > 1
