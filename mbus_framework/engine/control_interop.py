"""python-control interoperability: state-space export, frequency responses, Bode reports.

* :func:`to_control` exports a medium model at parameters theta as a ``control.StateSpace``,
  continuous (dz/dt = A z + B u, y = C z + D u) or discrete with zero-order hold at dt
  (z[k+1] = Phi z[k] + Gamma u[k], Phi = e^{A dt}, Gamma = int_0^dt e^{A s} ds B, the exact
  discretisation used by :mod:`mbus_framework.engine.simulation`).
* :func:`frequency_response` evaluates H(j 2 pi f) = C (j 2 pi f I - A)^-1 B + D, or the ZOH
  discrete H(e^{j 2 pi f dt}) when dt is given, at frequencies f [Hz] (output force per
  input force, dimensionless).
* :func:`transfer_function_estimate` is the H1 estimate H = P_uy / P_uu (Welch averaged
  cross/auto spectra) of a measured record, with the coherence gamma^2 = |P_uy|^2/(P_uu P_yy).
* :func:`bode_figure` / :func:`write_bode_plot` draw the fitted model's Bode diagram over
  the measured estimate (matplotlib Agg canvas; no GUI, no global backend switch).
"""
from __future__ import annotations

# The simulation engine (scipy.linalg) is imported where it is used: the run's figures need only
# the H1 estimate, and the figure helpers should not load scipy for it.
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from mbus_framework.interfaces.model import MediumModel


def to_control(model: MediumModel, theta, dt: float | None = None):
    """``control.StateSpace`` of ``model`` at ``theta``: continuous, or ZOH-discrete at ``dt`` [s]."""
    import control

    from mbus_framework.engine.simulation import as_float_ss, discretize

    A, B, C, D = as_float_ss(model.state_space(np.asarray(theta, dtype=float)))
    if dt is None:
        return control.ss(A, B, C, D)
    sys = discretize((A, B, C, D), float(dt), "zoh")
    return control.ss(sys.Phi, sys.Gamma.reshape(-1, 1), C, D, float(dt))


def frequency_response(model: MediumModel, theta, f, dt: float | None = None) -> np.ndarray:
    """Complex response H at frequencies ``f`` [Hz]: continuous, or ZOH-discrete at ``dt``.

    One batched direct solve (s I - A) x = B per frequency (fine up to a few hundred states).
    """
    from mbus_framework.engine.simulation import as_float_ss, discretize

    f = np.atleast_1d(np.asarray(f, dtype=float))
    A, B, C, D = as_float_ss(model.state_space(np.asarray(theta, dtype=float)))
    if dt is None:
        s = 2j * np.pi * f
    else:
        sys = discretize((A, B, C, D), float(dt), "zoh")
        A, B = sys.Phi, sys.Gamma.reshape(-1, 1)
        s = np.exp(2j * np.pi * f * float(dt))
    n = A.shape[0]
    eye = np.eye(n)
    # Batched solve (s_k I - A) x_k = B.
    M = s[:, None, None] * eye[None] - A[None]
    rhs = np.broadcast_to(B.astype(complex), (s.size, n, 1))
    x = np.linalg.solve(M, rhs)[..., 0]
    return x @ C[0].astype(complex) + D[0, 0]


@dataclass
class TransferEstimate:
    """Measured transfer-function estimate: f [Hz], H (complex), coherence in [0, 1]."""

    f: np.ndarray
    H: np.ndarray
    coherence: np.ndarray
    input_power: np.ndarray | None = None  # Welch P_uu [u^2/Hz] at f

    def within(self, lo: float, hi: float) -> "TransferEstimate":
        """The estimate at lo <= f <= hi."""
        k = (self.f >= lo) & (self.f <= hi)
        return TransferEstimate(self.f[k], self.H[k], self.coherence[k],
                                None if self.input_power is None else self.input_power[k])


def transfer_function_estimate(u, y, dt: float, nperseg: int | None = None) -> TransferEstimate:
    """H1 estimate P_uy / P_uu (Welch, Hann window, 50 % overlap) and coherence.

    Segments must outlast the impulse response of the medium (lightly damped chains ring
    for hundreds of samples); the default is a quarter of the record.
    """
    from mbus_framework.engine.welch import cross_spectral_density, power_spectral_density

    u = np.asarray(u, dtype=float)
    y = np.asarray(y, dtype=float)
    nperseg = int(nperseg or min(len(u), max(256, len(u) // 4)))
    f, Puu = power_spectral_density(u, dt, nperseg)
    _, Pyy = power_spectral_density(y, dt, nperseg)
    _, Puy = cross_spectral_density(u, y, dt, nperseg)
    with np.errstate(divide="ignore", invalid="ignore"):
        H = Puy / Puu
        coh = np.abs(Puy) ** 2 / (Puu * Pyy)
    keep = f > 0
    return TransferEstimate(f[keep], H[keep], np.nan_to_num(coh[keep]), Puu[keep])


def bode_figure(model: MediumModel, theta, u=None, y=None, dt: float | None = None, f=None,
                title: str | None = None, label: str = "fitted model", extra_models=(),
                units: tuple[str, str] | None = None, band: tuple[float, float] | None = None):
    """Bode diagram (magnitude in dB and unwrapped phase in degrees) of the model.

    With a record (u, y, dt) the measured H1 estimate is drawn underneath (points with
    coherence < 0.5 faded, and said so in the legend) and the model is evaluated ZOH-discretely
    at dt, which is the like-for-like comparison for sampled data. ``band`` (f_lo, f_hi) [Hz]
    limits the frequency axis, e.g. to the record's excited band
    (:func:`mbus_framework.estimation.spectral.excited_band`): outside it neither the H1 estimate
    nor the fit says anything. ``extra_models`` is a sequence of
    (label, model, theta) drawn in addition (e.g. the other models of a comparison);
    ``units`` the (input, output) units for the magnitude label.
    Returns a matplotlib ``Figure`` on an Agg canvas.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    est = None
    if u is not None and y is not None and dt is not None:
        est = transfer_function_estimate(u, y, dt)
        if band is not None:
            est = est.within(*band)
    if f is None:
        if est is not None:
            f = est.f
        else:
            f = np.logspace(3, 7, 400)
    f = np.asarray(f, dtype=float)
    if band is not None:
        f = f[(f >= band[0]) & (f <= band[1])]
    fig = Figure(figsize=(7.0, 6.0))
    FigureCanvasAgg(fig)
    ax_m, ax_p = fig.subplots(2, 1, sharex=True)
    if est is not None:
        good = est.coherence >= 0.5
        for mask, alpha, lab in ((good, 0.9, "measured (H1 estimate)"), (~good, 0.25, "measured, coherence < 0.5")):
            if np.any(mask):
                ax_m.semilogx(est.f[mask] / 1e6, 20 * np.log10(np.abs(est.H[mask])), ".", ms=3, color="0.35",
                              alpha=alpha, label=lab)
                ax_p.semilogx(est.f[mask] / 1e6, np.degrees(np.unwrap(np.angle(est.H)))[mask], ".", ms=3,
                              color="0.35", alpha=alpha)
    curves = [(label, model, theta), *extra_models]
    for lab, m, th in curves:
        H = frequency_response(m, th, f, dt)
        ax_m.semilogx(f / 1e6, 20 * np.log10(np.abs(H)), lw=1.4, label=lab)
        ax_p.semilogx(f / 1e6, np.degrees(np.unwrap(np.angle(H))), lw=1.4)
    known = units is not None and "recorded units" not in units
    ax_m.set_ylabel(f"|H| [dB re 1 {units[1]}/{units[0]}]" if known else "|H| [dB]")
    ax_p.set_ylabel("phase [deg]")
    ax_p.set_xlabel("frequency [MHz]")
    ax_m.grid(True, which="both", alpha=0.3)
    ax_p.grid(True, which="both", alpha=0.3)
    ax_m.legend(loc="best", fontsize=8)
    if title:
        ax_m.set_title(title)
    fig.tight_layout()
    return fig


def write_bode_plot(path: str | Path, model: MediumModel, theta, u=None, y=None, dt: float | None = None,
                    **kwargs) -> Path:
    """Write :func:`bode_figure` to ``path`` (PNG); returns the path."""
    path = Path(path)
    fig = bode_figure(model, theta, u, y, dt, **kwargs)
    fig.savefig(path, dpi=110)
    return path
