"""Frequency response of the input hold between samples (interval h [s])."""
from __future__ import annotations

import numpy as np


def hold_response(f: np.ndarray, dt: float, hold: str = "zoh") -> np.ndarray:
    """Frequency response of the input hold: ZOH e^{-i pi f h} sinc(f h), FOH sinc^2(f h)."""
    x = np.asarray(f, dtype=float) * dt
    if hold == "zoh":
        return np.exp(-1j * np.pi * x) * np.sinc(x)
    if hold == "foh":
        return np.sinc(x) ** 2 + 0j
    raise ValueError(f"hold must be 'zoh' or 'foh', not {hold!r}")
