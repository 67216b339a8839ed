"""Recorded data from an independent simulator, and the files a lab would hand over.

The Kelvin-Voigt chain is rebuilt here from the dissertation's equations (3.8-3.21: masses
m/2, m, ..., m, m/2 with m = rho (pi D^2/4) L / n; K = k_sigma T + k_tau I and B likewise,
T = tridiag(-1, 2, -1) with T[0,0] = 1; y = k_sigma x_n + b_sigma x_n') and simulated with
scipy.signal (exact ZOH discretisation, ``dlsim``), without any mbus code. The PRBS is scipy's
maximal-length sequence.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import signal


@dataclass(frozen=True)
class Material:
    """A sample and its true material properties (SI), with a record design."""

    name: str
    length: float
    diameter: float
    density: float
    properties: dict[str, float]
    sample_rate: float
    bit_width: float
    order: int
    n_samples: int
    noise: float
    n_elements: int = 10

    @property
    def sample(self) -> dict[str, float]:
        return {"length": self.length, "diameter": self.diameter, "density": self.density}

    def parameters(self) -> dict[str, float]:
        """Eqs. 3.32-3.38 inverted: k = E (pi D^2/4)/(L/n), k_tau = E_tau pi D, likewise b."""
        g_sigma = (self.length / self.n_elements) / (math.pi * self.diameter**2 / 4)
        g_tau = 1.0 / (math.pi * self.diameter)
        p = self.properties
        return {"k_sigma": p["E_sigma"] / g_sigma, "b_sigma": p["eta_sigma"] / g_sigma,
                "k_tau": p["E_tau"] / g_tau, "b_tau": p["eta_tau"] / g_tau}


POTATO = Material("potato", 0.03, 0.0254, 1080.0,
                  {"E_sigma": 2.42e10, "eta_sigma": 7.18e3, "E_tau": 6.56e9, "eta_tau": 5.14e3},
                  25.0e6, 0.4e-6, 8, 3000, 0.03)
# Table 3.1's medium (k 3e8 / b 15 / k_tau 5e7 / b_tau 12 at L 0.05 m, n 10) as properties.
TABLE_3_1 = Material("table3_1", 0.05, 0.0254, 1000.0,
                     {"E_sigma": 3.0e8 * 0.005 / (math.pi * 0.0254**2 / 4),
                      "eta_sigma": 15.0 * 0.005 / (math.pi * 0.0254**2 / 4),
                      "E_tau": 5.0e7 / (math.pi * 0.0254), "eta_tau": 12.0 / (math.pi * 0.0254)},
                     6.25e6, 2.5e-6, 8, 4000, 0.10)


def state_space(mat: Material) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    n = mat.n_elements
    p = mat.parameters()
    m = mat.density * (math.pi * mat.diameter**2 / 4) * mat.length / n
    masses = np.full(n, m)
    masses[0] = masses[-1] = m / 2
    T = 2.0 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1)
    T[0, 0] = 1.0
    K = p["k_sigma"] * T + p["k_tau"] * np.eye(n)
    Bd = p["b_sigma"] * T + p["b_tau"] * np.eye(n)
    Minv = np.diag(1.0 / masses)
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-Minv @ K, -Minv @ Bd]])
    B = np.zeros((2 * n, 1))
    B[n, 0] = 1.0 / masses[0]
    C = np.zeros((1, 2 * n))
    C[0, n - 1] = p["k_sigma"]
    C[0, 2 * n - 1] = p["b_sigma"]
    return A, B, C, np.zeros((1, 1))


def prbs_burst(mat: Material, n: int, start: int = 0) -> np.ndarray:
    """One period of scipy's maximal-length sequence as +-1 bits held for bit_width, from
    sample ``start``, zeros elsewhere (n samples)."""
    bits = 2.0 * signal.max_len_seq(mat.order)[0] - 1.0
    per_bit = mat.bit_width * mat.sample_rate
    k = np.arange(n - start)
    idx = np.floor(k / per_bit + 1e-9).astype(int)
    u = np.zeros(n)
    inside = idx < bits.size
    u[start:][inside] = bits[idx[inside]]
    return u


def simulate(mat: Material, u: np.ndarray, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(t, y): the exact ZOH response to u plus Gaussian noise of ``noise`` x its RMS."""
    dt = 1.0 / mat.sample_rate
    Phi, Gamma, C, D, _ = signal.cont2discrete(state_space(mat), dt, method="zoh")
    t = np.arange(u.size) * dt
    _, y, _ = signal.dlsim((Phi, Gamma, C, D, dt), u, t)
    y = y[:, 0]
    rng = np.random.default_rng(seed)
    return t, y + rng.normal(0.0, mat.noise * float(np.sqrt(np.mean(y**2))), y.size)


def write_tuy(path: Path, t: np.ndarray, u: np.ndarray, y: np.ndarray) -> Path:
    np.savetxt(path, np.column_stack([t, u, y]), delimiter=",", header="t,u,y", comments="", fmt="%.12g")
    return path


def write_gds_raw(path: Path, volts: np.ndarray, volts_per_div: float, period: float, source: str) -> np.ndarray:
    """One channel in the GDS-2000 raw layout: header rows, then 8-bit codes (V/div / 25 each)."""
    codes = np.clip(np.round(volts / volts_per_div * 25), -127, 127).astype(int)
    header = [f"Memory Length,{codes.size},", f"Source,{source},", "Vertical Units,V,",
              f"Vertical Scale,{volts_per_div:.3E},", f"Sampling Period,{period:.4E},", "Firmwave,V1.12,"]
    path.write_text("\r\n".join(header + [f"{c}," for c in codes]) + "\r\n")
    return codes
