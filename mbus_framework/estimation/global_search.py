"""Global search over a physical parameter box, in the frequency domain.

The output-error cost of a wave model is multimodal mostly along one direction: the time
scale. Scaling every parameter by c**e (e its ``time_exponent``) makes the model run c times
faster, G_c(f) = G(f / c), and a wrong c by a fraction of a period of the wave's transit
time is a local minimum (cycle skipping). So the search splits the log-parameter space into

* the **time scale** ln c along e, scanned densely (3 % steps over the whole box) at the cost
  of a shift on the log-frequency grid of :class:`~mbus_framework.estimation.spectral.RecordSpectrum`
  (one eigendecomposition serves every c), and
* the **shape** (the directions orthogonal to e: damping ratios, shear-to-normal ratios,
  relaxation-time products), sampled by a scrambled Sobol design over the box's projection.

The box comes from physics, not from a start: every property of the model within a plausible
material range (moduli 1e5-1e14 Pa, viscosities 1e-3-1e9 Pa s by default; the model's
``plausible_bounds``). The best (shape, scale) pairs are then fitted locally in the frequency
domain (Levenberg-Marquardt on Y - G X with the exact Jacobian of
:mod:`mbus_framework.engine.frequency`), and the distinct minima returned best first. A model
whose time scaling is not exact (fixed coefficients with a time exponent) is searched by a
plain Sobol design over the box instead.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from mbus_framework.engine.frequency import response, response_batch, response_with_jacobian, tail_basis
from mbus_framework.estimation.spectral import RecordSpectrum

#: Default plausible range of every property, by unit (see the module docstring).
MATERIAL_RANGES: dict[str, tuple[float, float]] = {"Pa": (1e5, 1e14), "Pa s": (1e-3, 1e9), "s": (1e-10, 1e-1)}
#: Span x/÷ around ``typical`` for parameters no range covers.
GENERIC_SPAN = 1e4


@dataclass
class Candidate:
    """A point of the search: the full parameter vector, its spectral cost and origin."""

    theta: np.ndarray
    cost: float
    origin: str
    amplitude: float = 1.0  # best output scale factor found with the amplitude left free
    as_given: bool = False  # the user's initial values as given (short trial, no full-precision solve)


@dataclass
class SearchSpace:
    """Which entries of theta the search moves and the box it moves them in.

    ``movable``: free, log-scale model parameters (searched in ln theta); ``gain`` / ``delay``:
    index of a free nuisance gain / delay or None; ``lo``/``hi``: the box (full vectors);
    ``scaled``: the exact time-scaling shortcut is valid.
    """

    movable: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    e: np.ndarray
    gain: int | None
    delay: int | None
    scaled: bool


def search_space(problem, ranges: dict[str, tuple[float, float]] | None = None) -> SearchSpace:
    """The physical box of ``problem`` (model's ``plausible_bounds`` within its hard bounds)."""
    from mbus_framework.estimation.nuisance import DELAY, GAIN

    model, n_model = problem.model, problem.n_model
    params = problem.parameters
    free = problem.free
    lo, hi = problem.lower.astype(float).copy(), problem.upper.astype(float).copy()
    plo, phi = plausible_bounds(model, ranges or MATERIAL_RANGES)
    lo[:n_model] = np.maximum(lo[:n_model], plo)
    hi[:n_model] = np.minimum(hi[:n_model], phi)
    movable = np.array([free[i] and params[i].log_scale and i < n_model for i in range(len(params))])
    e = np.array([p.time_exponent for p in params], dtype=float)
    held_scaling = any(e[i] != 0 and not movable[i] for i in range(n_model))
    scaled = bool(getattr(model, "exact_time_scaling", True) and not held_scaling and np.any(e[movable] != 0))
    names = problem.names
    gain = names.index(GAIN) if GAIN in names and free[names.index(GAIN)] else None
    delay = names.index(DELAY) if DELAY in names and free[names.index(DELAY)] else None
    if gain is not None:
        g0 = problem.fixed.get(GAIN, 1.0) if problem.initial is None else problem.initial[gain]
        lo[gain], hi[gain] = max(lo[gain], g0 / 1e3), min(hi[gain], g0 * 1e3)
    return SearchSpace(movable, lo, hi, e, gain, delay, scaled)


def plausible_bounds(model, ranges: dict[str, tuple[float, float]]) -> tuple[np.ndarray, np.ndarray]:
    """Per-parameter bounds that keep every property within ``ranges`` (by property unit).

    Uses the model's own ``plausible_bounds(ranges)`` when it has one; otherwise maps the
    property ranges through ``from_properties`` when properties and parameters correspond one
    to one and monotonically, else ``typical`` x/÷ GENERIC_SPAN.
    """
    own = getattr(model, "plausible_bounds", None)
    if callable(own):
        lo, hi = own(ranges)
        return np.asarray(lo, float), np.asarray(hi, float)
    params = list(model.parameters)
    typical = np.array([p.typical for p in params], dtype=float)
    lo, hi = typical / GENERIC_SPAN, typical * GENERIC_SPAN
    props = list(model.properties)
    if len(props) == len(params) and all(p.unit in ranges for p in props):
        try:
            plo = np.asarray(model.from_properties({p.name: ranges[p.unit][0] for p in props}), float)
            phi = np.asarray(model.from_properties({p.name: ranges[p.unit][1] for p in props}), float)
        except Exception:  # a model whose properties do not map one to one
            return lo, hi
        ok = np.isfinite(plo) & np.isfinite(phi) & (plo > 0) & (phi > plo)
        lo, hi = np.where(ok, plo, lo), np.where(ok, phi, hi)
    return lo, hi


# ---------------------------------------------------------------------------------------------
# Effective response on the spectrum's grid
# ---------------------------------------------------------------------------------------------
def _nuisance_factor(f: np.ndarray, theta, problem) -> np.ndarray:
    """g e^{-i 2 pi f tau}: the nuisance gain and delay of ``theta`` at frequencies f."""
    gain, delay = problem.split(theta)[1:]
    return gain * np.exp(-2j * np.pi * f * delay)


def spectral_cost(problem, spectrum: RecordSpectrum, theta, space: SearchSpace) -> float:
    """sum |Y - g e^{-i w tau} G(theta) X|^2 on the spectrum's grid."""
    theta = np.asarray(theta, float)
    G = response(problem.model, theta[: problem.n_model], spectrum.f)
    return spectrum.cost(G * _nuisance_factor(spectrum.f, theta, problem))


def sobol(d: int, n: int, seed: int) -> np.ndarray:
    """n points of a scrambled Sobol design in [0, 1)^d (the first n of the next power of 2)."""
    from scipy.stats import qmc  # here, not at the top: scipy.stats takes about 0.4 s to import

    return qmc.Sobol(d, scramble=True, seed=seed).random_base2(int(np.ceil(np.log2(max(n, 1)))))[:n]


# ---------------------------------------------------------------------------------------------
# Shape x scale scan
# ---------------------------------------------------------------------------------------------
def scan(problem, spectrum: RecordSpectrum, space: SearchSpace, template: np.ndarray, shapes: int = 256,
         seed: int = 0, per_shape: int = 2, amplitude_penalty: float | None = 0.0,
         around: list[np.ndarray] | None = None, halfwidth: float = 0.0) -> list[Candidate]:
    """Candidates best first (at most ``per_shape`` scales per shape): ``shapes`` Sobol shapes
    over the whole box, or, with ``around``, that many around each given parameter vector
    within ``halfwidth`` (natural-log units per shape coordinate).

    ``amplitude_penalty`` w: each scale gets its best output scale factor a, scored as
    cost + w E (ln a)^2 (E the record's spectral energy), so the shape of the response is
    matched before its level; None holds a = 1."""
    mv = np.flatnonzero(space.movable)
    if mv.size == 0:
        return []
    llo, lhi = np.log(space.lo[mv]), np.log(space.hi[mv])
    if not space.scaled:
        return _sobol_scan(problem, spectrum, space, template, mv, llo, lhi, shapes * 4, seed, around, halfwidth)
    e = space.e[mv]
    Q = np.linalg.svd(np.eye(mv.size) - np.outer(e, e) / (e @ e))[0][:, : mv.size - 1]
    # bounding box of the box's projection on the shape space (a linear map over a box)
    plo = np.minimum(Q * llo[:, None], Q * lhi[:, None]).sum(axis=0)
    phi = np.maximum(Q * llo[:, None], Q * lhi[:, None]).sum(axis=0)
    unit = sobol(max(mv.size - 1, 1), shapes, seed)[:, : mv.size - 1]
    if around:
        centres = [Q.T @ np.log(np.clip(th, space.lo, space.hi)[mv]) for th in around]
        psis = np.vstack([np.clip(c + (2 * unit - 1) * halfwidth, plo, phi) for c in centres])
    else:
        psis = plo + unit * (phi - plo)
    step, F = spectrum.step, spectrum.f.size
    nz = e != 0
    shapes_ok = []  # (theta0, j_lo, j_hi) of every shape with a scale range inside the box
    for psi in psis:
        base = Q @ psi
        if np.any((base[~nz] < llo[~nz]) | (base[~nz] > lhi[~nz])):
            continue
        a, b = (llo[nz] - base[nz]) / e[nz], (lhi[nz] - base[nz]) / e[nz]
        lnc_lo, lnc_hi = np.max(np.minimum(a, b)), np.min(np.maximum(a, b))
        j_lo, j_hi = int(np.ceil(lnc_lo / step)), int(np.floor(lnc_hi / step))
        if j_hi < j_lo:
            continue
        theta0 = template.copy()
        theta0[mv] = np.exp(base)
        shapes_ok.append((theta0, j_lo, j_hi))
    if not shapes_ok:
        return []
    # one batched evaluation of every shape on its own extended grid (padded to one length)
    lengths = [F + j_hi - j_lo for _, j_lo, j_hi in shapes_ok]
    width = max(lengths)
    grids = np.array([spectrum.f[0] * np.exp(step * np.minimum(np.arange(width), L - 1) - step * j_hi)
                      for (_, _, j_hi), L in zip(shapes_ok, lengths)])
    thetas = np.array([th[: problem.n_model] for th, _, _ in shapes_ok])
    Gs = response_batch(problem.model, thetas, grids)
    out: list[Candidate] = []
    for (theta0, j_lo, j_hi), G, L in zip(shapes_ok, Gs, lengths):
        out += _scale_scan(problem, spectrum, space, theta0, mv, e, j_lo, j_hi, per_shape, amplitude_penalty, G[:L])
    out.sort(key=lambda c: c.cost)
    return out


def _scale_scan(problem, spectrum, space, theta0, mv, e, j_lo, j_hi, per_shape, amplitude_penalty=None,
                G: np.ndarray | None = None) -> list[Candidate]:
    """Costs of theta0 * c**e for ln c = j step, j_lo..j_hi, from one response evaluation
    (``G``, when given, is that response on the extended grid below).

    G_c(f_i) = G(f_{i-j}); rows r of a sliding window over G on the extended grid
    f_lo e^{k step}, k = -j_hi..F-1-j_lo, are the scales j = j_hi - r."""
    step, F = spectrum.step, spectrum.f.size
    if G is None:
        k = np.arange(-j_hi, F - j_lo)
        G = response(problem.model, theta0[: problem.n_model], spectrum.f[0] * np.exp(step * k))
    if not np.all(np.isfinite(G)):
        return []
    W = np.lib.stride_tricks.sliding_window_view(G, F)  # (C, F): row r -> j = j_hi - r
    X = spectrum.X * _nuisance_factor(spectrum.f, theta0, problem)
    cross = np.real(W @ (X * np.conj(spectrum.Y)))  # Re sum G X conj(Y)
    power = (np.abs(W) ** 2) @ (np.abs(X) ** 2)  # sum |G X|^2
    energy = spectrum.energy
    free_amp = space.gain is None and amplitude_penalty is not None
    if space.gain is not None or free_amp:  # best real gain factor a >= 0 per scale
        a = np.clip(cross / np.where(power > 0, power, 1.0), 0.0, None)
    else:
        a = np.ones_like(power)
    cost = energy - 2 * a * cross + a * a * power
    if free_amp and amplitude_penalty:
        with np.errstate(divide="ignore"):
            cost = cost + amplitude_penalty * energy * np.log(np.where(a > 0, a, 1e-300)) ** 2
    C = cost.size
    is_min = np.ones(C, dtype=bool)
    is_min[1:] &= cost[1:] <= cost[:-1]
    is_min[:-1] &= cost[:-1] <= cost[1:]
    rows = np.flatnonzero(is_min)
    rows = rows[np.argsort(cost[rows])][:per_shape]
    out = []
    for r in rows:
        th = theta0.copy()
        th[mv] = theta0[mv] * np.exp(step * (j_hi - r) * e)
        amp = 1.0
        if space.gain is not None:
            th[space.gain] = th[space.gain] * a[r] if a[r] > 0 else th[space.gain]
        elif free_amp:
            amp = float(a[r]) if a[r] > 0 else 1.0
        out.append(Candidate(th, float(cost[r]), "scan", amp))
    return out


def _sobol_scan(problem, spectrum, space, template, mv, llo, lhi, points, seed, around=None, halfwidth=0.0):
    """Direct evaluation on a Sobol design over the box, or around given vectors (no
    time-scaling shortcut)."""
    unit = sobol(mv.size, points, seed)
    if around:
        rows = [np.clip(np.log(np.clip(th, space.lo, space.hi)[mv]) + (2 * unit - 1) * halfwidth, llo, lhi)
                for th in around]
        logs = np.vstack(rows)
    else:
        logs = llo + unit * (lhi - llo)
    out = []
    for row in logs:
        th = template.copy()
        th[mv] = np.exp(row)
        c = spectral_cost(problem, spectrum, th, space)
        if np.isfinite(c):
            out.append(Candidate(th, c, "scan"))
    out.sort(key=lambda c: c.cost)
    return out


def align(problem, spectrum: RecordSpectrum, theta: np.ndarray, space: SearchSpace, origin: str,
          amplitude_penalty: float | None = 1e-3) -> Candidate:
    """The best time scale for the shape of ``theta`` within the box (a 1-D scale scan, scored
    as :func:`scan` scores, the unmoved start included)."""
    mv = np.flatnonzero(space.movable)
    theta = np.clip(np.asarray(theta, float), space.lo, space.hi)
    if mv.size == 0 or not space.scaled:
        return Candidate(theta, spectral_cost(problem, spectrum, theta, space), origin)
    e = space.e[mv]
    nz = e != 0
    llo, lhi, base = np.log(space.lo[mv]), np.log(space.hi[mv]), np.log(theta[mv])
    a, b = (llo[nz] - base[nz]) / e[nz], (lhi[nz] - base[nz]) / e[nz]
    lo, hi = np.max(np.minimum(a, b)), np.min(np.maximum(a, b))
    j_lo, j_hi = int(np.ceil(lo / spectrum.step)), int(np.floor(hi / spectrum.step))
    found = (_scale_scan(problem, spectrum, space, theta, mv, e, min(j_lo, 0), max(j_hi, 0), 1, amplitude_penalty)
             if j_hi >= j_lo else [])
    if not found:
        return Candidate(theta, spectral_cost(problem, spectrum, theta, space), origin)
    return Candidate(found[0].theta, found[0].cost, origin, found[0].amplitude)


# ---------------------------------------------------------------------------------------------
# Local fits in the frequency domain
# ---------------------------------------------------------------------------------------------
def refine(problem, spectrum: RecordSpectrum, cand: Candidate, space: SearchSpace, max_nfev: int = 40,
           amplitude_free: bool = False, amplitude_weight: float = 0.0, transient: bool = True) -> Candidate:
    """Levenberg-Marquardt on the spectral residual from ``cand``: movable entries in ln theta,
    a free gain in ln g, a free delay in units of dt; exact Jacobian; clipped to the box.

    ``transient``: the record's unfinished tail (:func:`~mbus_framework.engine.frequency.tail_basis`)
    is projected out of the residual (variable projection with Kaufman's Jacobian), so the fit
    sees the finite record exactly. ``amplitude_free`` adds an output scale factor a (in ln a,
    started at ``cand.amplitude``) when the problem has no free gain: the shape and time scale
    then fit before the level; ``amplitude_weight`` w adds the residual sqrt(w) ln a, pulling
    a towards 1."""
    fit = _SpectralFit(problem, spectrum, space, cand.theta, amplitude_free, amplitude_weight, transient)
    if fit.nvar == 0:
        return cand
    z0 = fit.z_of(np.clip(cand.theta, space.lo, space.hi), cand.amplitude)
    res = least_squares(fit.residual, z0, jac=fit.jacobian, method="lm", max_nfev=max_nfev, xtol=1e-6, ftol=1e-8)
    th, amp = fit.unpack(res.x)
    pull = amplitude_weight * np.log(amp) ** 2 if fit.extra else 0.0
    return Candidate(th, float(2 * res.cost - pull), cand.origin, amp)


class _SpectralFit:
    """Residual and Jacobian of :func:`refine` in its coordinates z."""

    def __init__(self, problem, spectrum, space, theta, amplitude_free, amplitude_weight, transient):
        self.problem, self.spectrum, self.space = problem, spectrum, space
        self.theta0 = np.clip(np.asarray(theta, float), space.lo, space.hi)
        self.logs = list(np.flatnonzero(space.movable)) + ([space.gain] if space.gain is not None else [])
        self.lin = [space.delay] if space.delay is not None else []
        self.extra = bool(amplitude_free and space.gain is None)
        self.weight, self.transient = amplitude_weight, transient
        self.nl, self.nd = len(self.logs), len(self.lin)
        self.nvar = self.nl + self.nd + self.extra
        dt = problem.dt
        self.zlo = np.r_[np.log(space.lo[self.logs]), space.lo[self.lin] / dt, [-700.0] * self.extra]
        self.zhi = np.r_[np.log(space.hi[self.logs]), space.hi[self.lin] / dt, [700.0] * self.extra]
        self._basis_at: tuple | None = None

    def z_of(self, theta, amplitude) -> np.ndarray:
        dt = self.problem.dt
        return np.r_[np.log(theta[self.logs]), theta[self.lin] / dt, [np.log(max(amplitude, 1e-300))] * self.extra]

    def unpack(self, z):
        z = np.clip(z, self.zlo, self.zhi)
        th = self.theta0.copy()
        th[self.logs] = np.exp(z[: self.nl])
        th[self.lin] = z[self.nl : self.nl + self.nd] * self.problem.dt
        return th, (float(np.exp(z[-1])) if self.extra else 1.0)

    def _projector(self, th):
        """Orthonormal basis (2F, r) of the real-stacked tail transforms, or None."""
        lines = self.spectrum.lines
        if not (self.transient and lines.transient):
            return None
        key = tuple(th[: self.problem.n_model])
        if self._basis_at is None or self._basis_at[0] != key:
            B = tail_basis(self.problem.model, th[: self.problem.n_model], lines.f, self.problem.dt,
                           lines.tail_shift) * lines.output_response[:, None]
            B = np.vstack([B.real, B.imag])
            Q = None
            if np.all(np.isfinite(B)) and B.size:
                U, s, _ = np.linalg.svd(B, full_matrices=False)
                keep = s > 1e-10 * s.max(initial=0.0)
                Q = U[:, keep] if keep.any() else None
            self._basis_at = (key, Q)
        return self._basis_at[1]

    def _model(self, th, amp, jac: bool):
        lines, p = self.spectrum.lines, self.problem
        base = _nuisance_factor(lines.f, th, p) * lines.X * amp
        if not jac:
            return response(p.model, th[: p.n_model], lines.f, lines.dt), None, base
        G, Jm = response_with_jacobian(p.model, th[: p.n_model], lines.f, lines.dt)
        return G, Jm, base

    def residual(self, z):
        th, amp = self.unpack(z)
        G, _, base = self._model(th, amp, False)
        with np.errstate(over="ignore", invalid="ignore"):  # an overflowing trial point is caught below
            r = G * base - self.spectrum.lines.Y
        if not np.all(np.isfinite(r)):
            return np.full(2 * r.size + self.extra, 1e3 * np.sqrt(self.spectrum.lines.energy / r.size))
        r = np.concatenate([r.real, r.imag])
        Q = self._projector(th)
        if Q is not None:
            r = r - Q @ (Q.T @ r)
        pull = [np.sqrt(self.weight) * np.log(amp)] if self.extra else []
        return np.concatenate([r, pull])

    def jacobian(self, z):
        th, amp = self.unpack(z)
        G, Jm, base = self._model(th, amp, True)
        sp, dt = self.spectrum.lines, self.problem.dt
        J = np.empty((sp.f.size, self.nvar), dtype=complex)
        for c, i in enumerate(self.logs):
            J[:, c] = (Jm[:, i] * th[i] if i < self.problem.n_model else G) * base  # d/d ln theta_i
        for c, _ in enumerate(self.lin):
            J[:, self.nl + c] = G * base * (-2j * np.pi * sp.f) * dt
        if self.extra:
            J[:, -1] = G * base
        if not np.all(np.isfinite(J)):
            J = np.zeros_like(J)
        Jr = np.vstack([J.real, J.imag])
        Q = self._projector(th)
        if Q is not None:
            Jr = Jr - Q @ (Q.T @ Jr)
        if self.extra:
            Jr = np.vstack([Jr, np.r_[np.zeros(self.nl + self.nd), np.sqrt(self.weight)][None, :]])
        return Jr


def homotopy(problem, spectrum: RecordSpectrum, cand: Candidate, space: SearchSpace,
             weights: tuple[float, ...] = (1.0, 100.0), max_nfev: int = 25) -> Candidate:
    """Frequency-domain fit from a scan candidate, level last.

    First the response's shape and time scale with a free output scale a (started at the
    scan's), then a pulled towards 1 by the residual sqrt(w C) ln a for each w in
    ``weights`` (C the cost after the first stage), then a = 1 exactly. The response level of
    a heavily attenuating chain changes by decades with its shape; fitting it last keeps the
    fit out of the flat region where the model explains nothing."""
    if space.gain is not None:  # a free input gain already carries the level
        return refine(problem, spectrum, cand, space, 2 * max_nfev)
    c = refine(problem, spectrum, cand, space, max_nfev, amplitude_free=True)
    scale = max(c.cost, 1e-300)
    for w in weights:
        c = refine(problem, spectrum, c, space, max(max_nfev // 2, 5), amplitude_free=True, amplitude_weight=w * scale)
    c = Candidate(c.theta, c.cost, c.origin, 1.0)
    return refine(problem, spectrum, c, space, max_nfev)


def distinct(cands: list[Candidate], rtol: float = 0.05, limit: int | None = None) -> list[Candidate]:
    """Candidates best first, dropping any within ``rtol`` (max |ln ratio| over the positive
    entries) of a better one; at most ``limit``."""
    out: list[Candidate] = []
    kept: list[np.ndarray] = []
    for c in sorted(cands, key=lambda c: c.cost):
        if not np.isfinite(c.cost):
            continue
        if limit is not None and len(out) >= limit:
            break
        pos = c.theta > 0
        logs = np.log(np.where(pos, c.theta, 1.0))
        if kept:
            K = np.array(kept)
            if np.any(np.max(np.abs(K - logs)[:, pos], axis=1) <= rtol):
                continue
        out.append(c)
        kept.append(logs)
    return out
