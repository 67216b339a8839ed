"""Exact discrete-time simulation of a medium model and its exact parameter sensitivities.

Problem
-------
A medium model gives a continuous single-input single-output system (time t [s], input force
u [N], output force y [N])

    dz/dt = A z + B u,      y = C z + D u,        z(0) = 0.

The input is known only at the samples u[k] = u(k h), h = ``dt`` [s]. Between samples it is
reconstructed by a hold:

* ``"zoh"`` (zero-order hold): u(t) = u[k] on [k h, (k+1) h). This is what a function
  generator playing a sampled waveform does, and what the dissertation's RK4 (eq. 3.22)
  approximates when the input is held over the step.
* ``"foh"`` (first-order hold): u linear between samples, starting at u[0] at t = 0. This is
  python-control's ``forced_response`` convention.

The engine returns y[k] = y(k h) of the *continuous* system for that input, exactly (to
round-off): no time-stepping error whatever the step, stiffness or damping.

Discretisation
--------------
With Phi = e^{A h} and the phi-functions phi_1(z) = (e^z - 1)/z, phi_2(z) = (e^z - 1 - z)/z^2,

    Gamma0 = int_0^h e^{A s} ds B        = h phi_1(A h) B,
    Gamma1 = int_0^h e^{A s} (1 - s/h) ds B = h phi_2(A h) B,

    ZOH:  x[k+1] = Phi x[k] + Gamma0 u[k]
    FOH:  x[k+1] = Phi x[k] + (Gamma0 - Gamma1) u[k] + Gamma1 u[k+1].

For FOH the state xi[k] = x[k] - Gamma1 u[k] obeys xi[k+1] = Phi xi[k] + Gamma_eff u[k],
Gamma_eff = Gamma0 - Gamma1 + Phi Gamma1, y[k] = C xi[k] + (D + C Gamma1) u[k], and from rest
xi[0] = -Gamma1 u[0]. Hence, for both holds, the response from rest is the causal convolution

    y[k] = sum_{j<=k} g[k-j] u[j]  -  u[0] c[k],                                         (1)

    ZOH: g[0] = D,            g[m] = C Phi^(m-1) Gamma0 (m >= 1),  c = 0
    FOH: g[0] = D + C Gamma1, g[m] = C Phi^(m-1) Gamma_eff,         c[k] = C Phi^k Gamma1.

How (1) is evaluated: ``simulate`` on the modal path uses a block recursion over the modal
states (:func:`~mbus_framework.engine.modal_response.modal_block_response`: blocks of 32
samples, a Toeplitz product inside each block, a prefix scan over block-start states; O(N)
and no FFT). Sensitivities and the doubling path convolve the kernels by FFT
(:mod:`mbus_framework.engine.causal_convolution`; O(N log N), the input spectrum is cached, so
refitting the same record costs one forward and one inverse transform per output).

Two ways to get the kernels g, c
--------------------------------
*Modal* (default when safe, :mod:`mbus_framework.engine.modal` and
:mod:`mbus_framework.engine.modal_response`): the balanced eigendecomposition of A makes every
kernel a sum of modes, O(n N) without forming Phi^k.

*Repeated doubling* (safe fallback, :mod:`mbus_framework.engine.doubling`): Phi, Gamma0,
Gamma1 from one matrix exponential (Van Loan) and the Krylov sequence by doubling; no
eigendecomposition, exact for defective models. Cost O(n^2 N).

Choosing the path (``method="auto"``): the modal path is tried when the eigenvector matrix
of the balanced A is well conditioned (kappa_1(V) <= ``MODAL_MAX_CONDITION``) and, for
sensitivities, no two eigenvalues (nearly) coincide (relative gap >=
``MODAL_MIN_SEPARATION``). Its result is kept only if the error estimate
kappa x amplification is at most ``MODAL_MAX_AMPLIFICATION``, where the round-off
amplification of the modal sums is sum_i max|term_i| ||u||_2 / max |output| (see
:func:`~mbus_framework.engine.modal_response.output_amplification`); that catches nearly
defective models (large, cancelling residues or partial fractions) and records that end before the wave arrives (an
output ~1e-20 of the modal terms). Otherwise the doubling path runs. Both paths stay far
below the 1e-9 target: the modal path's measured error is < 180 eps kappa amplification
(< ~2e-10 where accepted), the doubling path's ~1e-14 (tests/test_simulation.py, the
benchmark). Fits evaluate one record many times: when its last output took the doubling path,
the doubling y is computed first and the modal y only when the decision could go the other
way, and a Jacobian at a theta whose modal y was just rejected skips the modal kernels
(``_surely_rejected``: the same path and result, only the order differs).

Threading: the engine's matrices are small (tens of states). Products are arranged so that
no single BLAS call is large enough for a threaded BLAS to split it across cores, which on
a shared machine costs far more than it saves; LAPACK's ``geev`` and ``expm`` are left as
they are.

Sensitivities
-------------
dy/dtheta_p is the output of the forward-sensitivity system

    d/dt [z; z_p] = [[A, 0], [A_p, A]] [z; z_p] + [B; B_p] u,   y_p = C_p z + C z_p + D_p u

(A_p = dA/dtheta_p, ...), which is itself linear; its exact discretisation is the exact
derivative of the discretised model, so dy/dtheta is exact, not a finite difference.
A_p, B_p, C_p, D_p come from complex-step differentiation of the model's own
``state_space`` (exact to round-off, no model-specific code).

The modal path differentiates the modal sums (:mod:`mbus_framework.engine.modal_response`);
the doubling path discretises the 2n-state sensitivity system per parameter.

Units: ``dt`` in seconds, theta in the model's SI units, y in the model's output units,
dy/dtheta_p in output units per unit of theta_p.
"""
from __future__ import annotations

from typing import Literal, Sequence

import numpy as np

from mbus_framework.engine.causal_convolution import causal_convolve, respond
from mbus_framework.engine.doubling import (
    DiscreteSystem,
    Hold,
    as_float_ss,
    check_hold,
    discretize,
    doubling_kernels,
    markov_parameters,
)
from mbus_framework.engine.modal import ModalForm, modal_form, phi_functions
from mbus_framework.engine.modal_response import (
    modal_block_response,
    modal_kernels,
    modal_y_bounds,
    output_amplification,
)
from mbus_framework.interfaces.model import MediumModel, StateSpace

Method = Literal["auto", "modal", "doubling"]

#: Largest kappa_1(V) (eigenvectors of the balanced A) for which the modal path is used.
MODAL_MAX_CONDITION = 5.0e3
#: Smallest relative eigenvalue separation for which modal *sensitivities* are tried.
MODAL_MIN_SEPARATION = 1.0e-8
#: Largest error estimate kappa * amplification accepted from the modal path: kappa is the
#: eigenvector conditioning, amplification the round-off amplification of the modal sums in
#: the outputs (see ``output_amplification``). Over random Kelvin-Voigt chains (n 1-40,
#: parameters x0.03-30, 2-25 MHz, records 60-20000 samples, ZOH and FOH, y and dy/dtheta)
#: the modal path's relative error stayed below 180 eps kappa amplification, so 5e3 keeps it
#: below ~2e-10 (observed: < 5e-12 where accepted); the doubling path, used otherwise, is
#: good to ~1e-14. Table 3.1 (n = 10, 6200 samples): kappa 23, estimate 27.
MODAL_MAX_AMPLIFICATION = 5.0e3


def _modal_ok(mf: ModalForm | None, dt: float, sensitivities: bool) -> bool:
    if mf is None or not mf.paired or mf.kappa > MODAL_MAX_CONDITION:
        return False
    if np.any(mf.lam.real * dt > 700.0):  # e^{lambda h} would overflow the power table
        return False
    return not sensitivities or mf.separation(dt) >= MODAL_MIN_SEPARATION


_REJECTED: list = []  # (modal form, dt, hold, u, amplification) of recent rejected outputs y
_LAST_Y_PATH: list = []  # [(dt, hold, u, path)] of the last output y computed by method 'auto'


def _surely_rejected(amp: float, kappa: float, u: np.ndarray) -> bool:
    """True when a modal output whose amplification, measured on *another* computation of the
    same y (block recursion, FFT convolution or the doubling path), is ``amp`` would be
    rejected however the round-off falls.

    Two computations of y differ by at most ~c eps kappa B ||u||_1 (B the termwise bound,
    c = 1e3 generous), so the modal amplification B ||u||_2 / peak is at least
    1 / (1/amp + c eps kappa ||u||_1 / ||u||_2) >= 1 / (1/amp + c eps kappa sqrt(N)); the
    decision is taken only when that exceeds the threshold by 1e-6."""
    if not np.isfinite(amp) or amp <= 0.0:
        return False
    slack = 1e3 * np.finfo(float).eps * kappa * np.sqrt(max(u.shape[-1], 1))
    return kappa / (1.0 / amp + slack) > MODAL_MAX_AMPLIFICATION * (1.0 + 1e-6)


def _note_rejection(mf: ModalForm, dt: float, hold: Hold, u: np.ndarray, amp: float) -> None:
    """Remember that the modal output y of this system was rejected (amplification ``amp``)."""
    if np.isfinite(amp):
        _REJECTED.insert(0, (mf, dt, hold, np.array(u, copy=True), amp))
        del _REJECTED[4:]


def _rejected_before(mf: ModalForm, dt: float, hold: Hold, u: np.ndarray) -> bool:
    """True when the modal y of the same system, step, hold and input was rejected by a margin
    (:func:`_surely_rejected`).

    The sensitivity path's amplification is a maximum over rows whose first row is y itself,
    with the same termwise bound B (to a few ulp), so it would reject too: the modal kernels
    are skipped (the doubling path runs, as it would). A local fit evaluates y and then
    dy/dtheta at the same theta, so this saves one modal attempt per Jacobian on records
    where the modal path is not accepted.
    """
    for mf0, dt0, hold0, u0, amp in _REJECTED:
        if mf0 is mf and dt0 == dt and hold0 == hold and u0.shape == u.shape and np.array_equal(u0, u):
            return _surely_rejected(amp, mf.kappa, u)
    return False


def _expect_doubling(dt: float, hold: Hold, u: np.ndarray) -> bool:
    """True when the last output y computed for this record (step, hold, input) took the doubling path."""
    if not _LAST_Y_PATH:
        return False
    dt0, hold0, u0, path = _LAST_Y_PATH[0]
    return path == "doubling" and dt0 == dt and hold0 == hold and u0.shape == u.shape and np.array_equal(u0, u)


def _note_path(dt: float, hold: Hold, u: np.ndarray, path: str) -> None:
    if _LAST_Y_PATH and _LAST_Y_PATH[0][0] == dt and _LAST_Y_PATH[0][1] == hold and np.array_equal(_LAST_Y_PATH[0][2], u):
        _LAST_Y_PATH[0] = (dt, hold, _LAST_Y_PATH[0][2], path)
    else:
        _LAST_Y_PATH[:] = [(dt, hold, np.array(u, copy=True), path)]


def _doubling_y(ss: StateSpace, u: np.ndarray, dt: float, hold: Hold) -> np.ndarray:
    g, corr = doubling_kernels(ss, dt, hold, u.shape[-1])
    return respond(g[0], None if corr is None else corr[0], u)


def _simulate_y(ss: StateSpace, u: np.ndarray, dt: float, hold: Hold, method: Method) -> tuple[np.ndarray, str]:
    """Output y of eq. (1) and the path used (modal block recursion, or doubling + FFT).

    With ``method='auto'``, when the last y of the same record took the doubling path, the
    doubling y is computed first; if its amplification shows the modal y would surely be
    rejected (:func:`_surely_rejected`), it is returned without forming the modal y. Otherwise
    the modal y decides as usual. The result is the same either way; only the order differs.
    """
    _check_method(hold, method)
    if method != "doubling":
        mf = modal_form(ss)
        if method == "modal" and mf is None:
            raise ValueError("the modal path needs a diagonalisable A with finite eigenvectors")
        if method == "modal" or _modal_ok(mf, dt, False):
            yd = None
            if method == "auto" and u.shape[-1] and _expect_doubling(dt, hold, u):
                yd = _doubling_y(ss, u, dt, hold)
                with np.errstate(over="ignore", invalid="ignore", under="ignore", divide="ignore"):
                    amp_d = output_amplification(yd, *modal_y_bounds(mf, dt, hold, u.shape[-1]), u)
                if _surely_rejected(amp_d, mf.kappa, u):
                    _note_rejection(mf, dt, hold, u, amp_d)
                    return yd, "doubling"
            with np.errstate(over="ignore", invalid="ignore", under="ignore", divide="ignore"):
                y, amp = modal_block_response(mf, dt, hold, u)
            if method == "modal" or amp * mf.kappa <= MODAL_MAX_AMPLIFICATION:
                if method == "auto":
                    _note_path(dt, hold, u, "modal")
                return y, "modal"
            _note_rejection(mf, dt, hold, u, amp)
            _note_path(dt, hold, u, "doubling")
            if yd is not None:
                return yd, "doubling"
    return _doubling_y(ss, u, dt, hold), "doubling"


def _check_method(hold, method) -> None:
    check_hold(hold)
    if method not in ("auto", "modal", "doubling"):
        raise ValueError(f"method must be 'auto', 'modal' or 'doubling', not {method!r}")


def _simulate_sens(ss: StateSpace, derivs, u: np.ndarray, dt: float, hold: Hold, method: Method):
    """[y; dy/dtheta_1; ...] (1+p, N) of eq. (1) and the path used ('modal' or 'doubling')."""
    _check_method(hold, method)
    N = u.shape[-1]
    if method != "doubling":
        mf = modal_form(ss)
        if method == "modal" and mf is None:
            raise ValueError("the modal path needs a diagonalisable A with finite eigenvectors")
        if method == "modal" or (_modal_ok(mf, dt, True) and not _rejected_before(mf, dt, hold, u)):
            with np.errstate(over="ignore", invalid="ignore", under="ignore", divide="ignore"):
                g, corr, gb, cb = modal_kernels(mf, dt, hold, N, derivs)
                out = respond(g, corr, u)
                amp = output_amplification(out, gb, cb, u)
            if method == "modal" or amp * mf.kappa <= MODAL_MAX_AMPLIFICATION:
                return out, "modal"
    g, corr = doubling_kernels(ss, dt, hold, N, derivs)
    return respond(g, corr, u), "doubling"


def engine_path(
    ss: StateSpace,
    dt: float,
    sensitivities: bool = False,
    u: np.ndarray | None = None,
    hold: Hold = "zoh",
    derivatives: Sequence[StateSpace] | None = None,
) -> str:
    """Which path ``method='auto'`` takes: 'modal' or 'doubling'.

    Without ``u`` only the a-priori checks (conditioning, eigenvalue separation) are
    applied. With the input record ``u`` the outputs are computed and the error estimate
    decides too, as in a real call; sensitivities then need ``derivatives`` (from
    :func:`state_space_derivatives`).
    """
    ss = as_float_ss(ss)
    if u is None:
        return "modal" if _modal_ok(modal_form(ss), dt, sensitivities) else "doubling"
    u = np.asarray(u, dtype=float)
    if not sensitivities:
        return _simulate_y(ss, u, float(dt), hold, "auto")[1]
    if derivatives is None:
        raise ValueError("pass derivatives=state_space_derivatives(model, theta) with u")
    return _simulate_sens(ss, derivatives, u, float(dt), hold, "auto")[1]


# ---------------------------------------------------------------------------------------
# Public entry points
# ---------------------------------------------------------------------------------------
def simulate_ss(
    ss: StateSpace, u: np.ndarray, dt: float, hold: Hold = "zoh", *, method: Method = "auto"
) -> np.ndarray:
    """Output y (N,) from rest of a continuous SISO system for samples ``u`` at ``dt`` [s]."""
    u = np.asarray(u, dtype=float)
    return _simulate_y(as_float_ss(ss), u, float(dt), hold, method)[0]


def simulate(
    model: MediumModel, theta, u: np.ndarray, dt: float, hold: Hold = "zoh", *, method: Method = "auto"
) -> np.ndarray:
    """Model output y [N] (shape (N,)) for input force u [N] sampled at ``dt`` [s], from rest."""
    if not getattr(model, "has_state_space", True):
        from mbus_framework.engine.convolution import simulate_response

        check_hold(hold)
        return simulate_response(model, theta, u, dt, hold)
    return simulate_ss(model.state_space(np.asarray(theta, dtype=float)), u, dt, hold, method=method)


def simulate_batch(
    model: MediumModel,
    thetas,
    u: np.ndarray,
    dt: float,
    hold: Hold = "zoh",
    *,
    method: Method = "auto",
) -> np.ndarray:
    """Outputs (B, N) for a batch of parameter vectors ``thetas`` (B, p) and one input u (N,)."""
    thetas = np.atleast_2d(np.asarray(thetas, dtype=float))
    u = np.asarray(u, dtype=float)
    if not getattr(model, "has_state_space", True):
        return np.array([simulate(model, th, u, dt, hold) for th in thetas]).reshape(len(thetas), u.shape[-1])
    out = np.empty((thetas.shape[0], u.shape[-1]))
    for b, th in enumerate(thetas):
        out[b] = _simulate_y(as_float_ss(model.state_space(th)), u, float(dt), hold, method)[0]
    return out


def state_space_derivatives(model: MediumModel, theta) -> list[StateSpace]:
    """dA/dtheta_i, dB/dtheta_i, dC/dtheta_i, dD/dtheta_i by complex step (exact to round-off).

    M'(theta) = Im M(theta + i s e_i) / s with s = 1e-20 |theta_i| (1e-20 when theta_i = 0):
    no subtraction, so no cancellation; the truncation error O(s^2) is far below round-off.
    Requires the model to be written with analytic arithmetic (see :mod:`mbus_framework.engine.arrays`).
    """
    theta = np.asarray(theta, dtype=float)
    out = []
    for i in range(theta.size):
        step = 1e-20 * (abs(theta[i]) if theta[i] != 0.0 else 1.0)
        tc = theta.astype(complex)
        tc[i] += 1j * step
        ss = model.state_space(tc)
        out.append(StateSpace(*(np.atleast_2d(np.imag(np.asarray(m, dtype=complex))) / step for m in ss)))
    return out


def simulate_with_sensitivities(
    model: MediumModel, theta, u: np.ndarray, dt: float, hold: Hold = "zoh", *, method: Method = "auto"
) -> tuple[np.ndarray, np.ndarray]:
    """Output y (N,) and exact sensitivities dy/dtheta (N, p) of the sampled model output."""
    theta = np.asarray(theta, dtype=float)
    u = np.asarray(u, dtype=float)
    if not getattr(model, "has_state_space", True):
        from mbus_framework.engine.convolution import simulate_response_with_sensitivities

        check_hold(hold)
        return simulate_response_with_sensitivities(model, theta, u, dt, hold)
    ss = as_float_ss(model.state_space(theta))
    derivs = state_space_derivatives(model, theta)
    out, _ = _simulate_sens(ss, derivs, u, float(dt), hold, method)
    return out[0], np.ascontiguousarray(out[1:].T)


def simulate_with_sensitivities_batch(
    model: MediumModel,
    thetas,
    u: np.ndarray,
    dt: float,
    hold: Hold = "zoh",
    *,
    method: Method = "auto",
) -> tuple[np.ndarray, np.ndarray]:
    """Outputs (B, N) and sensitivities (B, N, p) for parameter vectors ``thetas`` (B, p)."""
    thetas = np.atleast_2d(np.asarray(thetas, dtype=float))
    u = np.asarray(u, dtype=float)
    N, nb, p = u.shape[-1], thetas.shape[0], thetas.shape[1]
    if not getattr(model, "has_state_space", True):
        pairs = [simulate_with_sensitivities(model, th, u, dt, hold) for th in thetas]
        return np.array([y for y, _ in pairs]).reshape(nb, N), np.array([J for _, J in pairs]).reshape(nb, N, p)
    out = np.empty((nb, 1 + p, N))
    for b, th in enumerate(thetas):
        ss = as_float_ss(model.state_space(th))
        out[b] = _simulate_sens(ss, state_space_derivatives(model, th), u, float(dt), hold, method)[0]
    return out[:, 0], np.ascontiguousarray(out[:, 1:].transpose(0, 2, 1))


__all__: Sequence[str] = (
    "DiscreteSystem",
    "Hold",
    "Method",
    "ModalForm",
    "as_float_ss",
    "causal_convolve",
    "discretize",
    "engine_path",
    "markov_parameters",
    "modal_form",
    "phi_functions",
    "simulate",
    "simulate_batch",
    "simulate_ss",
    "simulate_with_sensitivities",
    "simulate_with_sensitivities_batch",
    "state_space_derivatives",
)
