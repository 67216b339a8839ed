"""Synthetic conventional records from known properties (tests and virtual campaigns).

Cyclic compression (eq. 6.14 driven in displacement): with a preload offset, a linear creep of
the displacement and a linear relaxation of the force,

    x(t) = x_0 + A_x cos(w t + theta) + v t
    u(t) = F_0 + k (x(t) - x_0) + b dx/dt + r t  (+ Gaussian noise on both channels)

which the compression fit (degree-1 drift) recovers exactly without noise. A shear sweep is a
power law around the reference frequency f0,

    E'(f) = E'_0 (f / f0)^n_E,   eta'(f) = eta'_0 (f / f0)^n_eta,   E''(f) = 2 pi f eta'(f)

with optional multiplicative Gaussian scatter per point.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np


def compression_record(k: float, b: float, *, frequency: float = 1.0, amplitude: float = 0.2e-3,
                       sample_rate: float = 400.0, cycles: float = 5.0, phase: float = 0.0,
                       preload: float = 0.0, offset: float = 0.0, creep: float = 0.0, relaxation: float = 0.0,
                       force_noise: float = 0.0, displacement_noise: float = 0.0,
                       rng: np.random.Generator | None = None) -> dict[str, np.ndarray]:
    """{time [s], force [N], displacement [m]} of a test at ``frequency`` [Hz] (see module).

    ``amplitude`` [m], ``preload`` F_0 [N], ``offset`` x_0 [m], ``creep`` v [m/s],
    ``relaxation`` r [N/s], noise standard deviations in N and m.
    """
    omega = 2.0 * math.pi * frequency
    t = np.arange(int(round(cycles * sample_rate / frequency)) + 1) / sample_rate
    wave = amplitude * np.cos(omega * t + phase)
    rate = -amplitude * omega * np.sin(omega * t + phase)
    x = offset + wave + creep * t
    u = preload + k * (wave + creep * t) + b * (rate + creep) + relaxation * t
    if force_noise or displacement_noise:
        rng = rng if rng is not None else np.random.default_rng()
        u = u + force_noise * rng.standard_normal(t.size)
        x = x + displacement_noise * rng.standard_normal(t.size)
    return {"time": t, "force": u, "displacement": x}


def rheometer_sweep(storage_modulus: float, dynamic_viscosity: float, *, f0: float = 10.0,
                    frequencies: np.ndarray | None = None, storage_exponent: float = 0.05,
                    viscosity_exponent: float = -0.1, scatter: float = 0.0,
                    rng: np.random.Generator | None = None) -> dict[str, np.ndarray]:
    """{frequency [Hz], storage [Pa], loss [Pa], viscosity [Pa s]} of a power-law sweep.

    ``frequencies`` default: 20 points log-spaced over 0.1-100 rad/s, the dissertation's sweep.
    ``scatter`` is the relative standard deviation of each point's multiplicative noise.
    """
    if frequencies is None:
        frequencies = np.logspace(-1, 2, 20) / (2.0 * math.pi)
    f = np.asarray(frequencies, dtype=float)
    storage = storage_modulus * (f / f0) ** storage_exponent
    viscosity = dynamic_viscosity * (f / f0) ** viscosity_exponent
    if scatter:
        rng = rng if rng is not None else np.random.default_rng()
        storage = storage * (1.0 + scatter * rng.standard_normal(f.size))
        viscosity = viscosity * (1.0 + scatter * rng.standard_normal(f.size))
    return {"frequency": f, "storage": storage, "loss": 2.0 * math.pi * f * viscosity, "viscosity": viscosity}


def write_compression_csv(path: str | Path, record: dict[str, np.ndarray]) -> Path:
    """Write a record as a texture-analyser-like export: ``time [s], force [N], displacement [mm]``."""
    import pandas as pd

    frame = pd.DataFrame({"time [s]": record["time"], "force [N]": record["force"],
                          "displacement [mm]": record["displacement"] * 1e3})
    path = Path(path)
    frame.to_csv(path, index=False, float_format="%.7g")
    return path


def write_sweep_csv(path: str | Path, sweep: dict[str, np.ndarray]) -> Path:
    """Write a sweep as a rheometer-like export: ``omega [rad/s], G' [Pa], G'' [Pa], eta' [Pa s]``."""
    import pandas as pd

    frame = pd.DataFrame({"omega [rad/s]": 2.0 * math.pi * sweep["frequency"], "G' [Pa]": sweep["storage"],
                          "G'' [Pa]": sweep["loss"], "eta' [Pa s]": sweep["viscosity"]})
    path = Path(path)
    frame.to_csv(path, index=False, float_format="%.7g")
    return path
