"""Global estimation strategy for output-error fits of lightly damped chains.

The output-error cost of a wave-propagation model is multimodal: a model whose wave arrives
a few periods early or late matches the data at a wrong phase (cycle skipping). The strategy
removes that ambiguity before any local fit, for any medium model:

1. **Physics-based start.** The user's initial values, or the model's own
   ``initial_guess`` (for the chains: first arrival -> sound speed -> stiffness, Sec. 3.5.1).
2. **Time-scale alignment.** Every parameter declares a ``time_exponent`` e (stiffness 2,
   damping 1, relaxation time -1). Scaling theta_i by c**e_i makes all the model's dynamics
   run c times faster, i.e. moves its arrival time by 1/c without changing its shape. A 1-D
   grid over c (with the best amplitude factor per point) puts the model's arrival on the
   measured one.
3. **Band continuation.** Each local fit first matches a low-passed residual (cut-off a
   fraction of the record's signal bandwidth, where the cost has few local minima), then
   widens the band to the full record.
4. **Budgeted multi-start.** Further starts spread log-uniformly (Sobol) around the aligned
   start, each aligned and band-continued; the search stops once ``confirm`` starts reach
   the same best minimum, or the budget is spent. The best is refined on the full record.

Everything tried is reported (``SearchReport``), so result.json says what won.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy import fft as sfft
from scipy.stats import qmc

from mbus_framework.estimation.problem import FitProblem, Progress


class StrategyOptions(BaseModel):
    """Options of the global strategy (the ``solver.options.strategy`` config section)."""

    model_config = ConfigDict(extra="forbid")
    time_scale: bool = Field(True, description="align the arrival time by a 1-D time-scale search")
    time_scale_range: float = Field(4.0, gt=1, description="search time scales c in [1/r, r]")
    time_scale_points: int = Field(40, ge=3, description="grid points of the time-scale search")
    bands: list[float] = Field(
        default_factory=lambda: [0.15, 0.3, 0.6],
        description="low-pass cut-offs of the continuation, as fractions of the signal bandwidth; "
        "the full band always follows",
    )
    n_starts: int = Field(12, ge=1, description="maximum number of starts (the first is the physics/user start)")
    spread: float = Field(4.0, ge=1, description="extra starts are drawn log-uniformly within x/÷ spread")
    confirm: int = Field(
        0,
        ge=0,
        description="also stop when this many starts reach the best minimum although its residuals are "
        "not white (0: never; agreeing starts can share a local minimum)",
    )
    stage_max_nfev: int = Field(60, ge=5, description="function-evaluation budget of each continuation stage")
    seed: int = Field(0, description="seed of the multi-start design")
    search_box: float = Field(
        1e3, gt=1, description="log-scale estimates stay within x/÷ this factor of the initial values"
    )
    accept_white: bool = Field(
        True,
        description="accept a minimum at once when its residuals are white (no structure left to fit)",
    )
    whiteness_threshold: float = Field(
        0.1, gt=0, description="largest mean |autocorrelation| of residuals at lags 1-10 counted as white"
    )
    coordinate_scan: int = Field(
        1, ge=0, description="sweeps of a per-parameter log-grid scan after alignment (0 = off)"
    )


@dataclass
class LocalResult:
    """Outcome of one local least-squares solve (log-parameter space)."""

    theta: np.ndarray
    cost: float
    nfev: int
    njev: int
    status: int
    message: str
    iterations: int
    trace: list[dict] = field(default_factory=list)


#: A local solver: (problem, start, band filter or None, max_nfev, final) -> LocalResult
LocalFit = Callable[[FitProblem, np.ndarray, "BandFilter | None", int, bool], LocalResult]


@dataclass
class SearchReport:
    """What the strategy tried and what won (written to result.json ``strategy``)."""

    initial_source: str
    initial: dict[str, float]
    aligned: dict[str, float] | None = None
    time_scale: float | None = None
    signal_bandwidth_hz: float | None = None
    bands_hz: list[float] = field(default_factory=list)
    starts: list[dict] = field(default_factory=list)
    winner: int | None = None
    confirmed_by: int = 0
    accepted_because: str = ""
    box: dict | None = None
    wall_time_s: float = 0.0

    def as_dict(self) -> dict:
        return dict(self.__dict__)


class BandFilter:
    """Zero-phase low-pass |H(f)| = 1 / sqrt(1 + (f/fc)^8) applied along axis 0 by FFT.

    The record is zero-padded to twice its length, so the filter is a linear convolution
    (no wrap-around). Being linear, it applies to residuals and Jacobians alike.
    """

    def __init__(self, cutoff_hz: float, n: int, dt: float):
        self.cutoff_hz = float(cutoff_hz)
        self.n = n
        self.nfft = sfft.next_fast_len(2 * n, real=True)
        f = sfft.rfftfreq(self.nfft, dt)
        self.gain = 1.0 / np.sqrt(1.0 + (f / cutoff_hz) ** 8)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        X = sfft.rfft(x, self.nfft, axis=0)
        g = self.gain if x.ndim == 1 else self.gain[:, None]
        return sfft.irfft(X * g, self.nfft, axis=0)[: self.n]


def signal_bandwidth(y: np.ndarray, dt: float, fraction: float = 0.99) -> float:
    """Frequency [Hz] below which ``fraction`` of the record's power lies."""
    Y = np.abs(np.fft.rfft(y - np.mean(y))) ** 2
    f = np.fft.rfftfreq(len(y), dt)
    cum = np.cumsum(Y)
    if cum[-1] <= 0:
        return float(f[-1])
    return float(f[min(np.searchsorted(cum, fraction * cum[-1]), len(f) - 1)])


def time_exponents(problem: FitProblem) -> np.ndarray:
    return np.array([p.time_exponent for p in problem.parameters], dtype=float)


def align_time_scale(problem: FitProblem, theta: np.ndarray, options: StrategyOptions, points: int | None = None):
    """Best time scale c for ``theta`` (free parameters scaled by c**e); returns (theta_c, c, nfev).

    Each grid point is scored by the residual after the best amplitude factor a:
    min_a ||a yhat - y||^2 = ||y||^2 - (yhat.y)^2 / ||yhat||^2.
    """
    e = time_exponents(problem) * problem.free
    if not np.any(e):
        return theta, 1.0, 0
    points = points or options.time_scale_points
    r = options.time_scale_range
    scales = np.exp(np.linspace(-np.log(r), np.log(r), points))
    lo, hi = problem.lower, problem.upper
    best, best_c, nfev = _explained_energy(problem, theta), 1.0, 1  # the start itself competes
    for c in scales:
        th = theta * c**e
        if np.any(th < lo) or np.any(th > hi):
            continue
        score = _explained_energy(problem, th)
        nfev += 1
        if score > best:
            best, best_c = score, float(c)
    return theta * best_c**e, best_c, nfev


def _explained_energy(problem: FitProblem, theta: np.ndarray) -> float:
    """(yhat . y)^2 / ||yhat||^2: the data energy a scaled model output explains."""
    with np.errstate(over="ignore", invalid="ignore"):
        yhat = problem.predict(theta)
    denom = float(yhat @ yhat)
    if not np.isfinite(denom) or denom <= 0:
        return -np.inf
    return float(yhat @ problem.y) ** 2 / denom


def coordinate_scan(problem: FitProblem, theta: np.ndarray, options: StrategyOptions, points: int = 16):
    """Per-parameter log-grid scan (x/÷ spread) keeping each best point; returns (theta, nfev)."""
    theta = theta.copy()
    nfev = 0
    factors = np.exp(np.linspace(-np.log(options.spread), np.log(options.spread), points))
    best = _explained_energy(problem, theta)
    for _ in range(options.coordinate_scan):
        for i in np.flatnonzero(problem.free):
            for f in factors:
                trial = theta.copy()
                trial[i] = theta[i] * f
                if not (problem.lower[i] <= trial[i] <= problem.upper[i]):
                    continue
                score = _explained_energy(problem, trial)
                nfev += 1
                if score > best:
                    best, theta = score, trial
    return theta, nfev


def search(
    problem: FitProblem,
    local_fit: LocalFit,
    options: StrategyOptions,
    progress: Progress | None = None,
) -> tuple[LocalResult, SearchReport, int, int]:
    """Run the strategy; returns (best refined result, report, total nfev, total njev)."""
    t0 = time.perf_counter()
    names = problem.names
    if problem.initial is not None:
        theta0, source = problem.full(np.asarray(problem.initial, float)[problem.free], problem.initial), "config"
    else:
        guess = problem.default_initial()
        theta0, source = problem.full(np.asarray(guess, float)[problem.free], guess), "model.initial_guess"
    theta0 = np.clip(theta0, problem.lower, problem.upper)
    report = SearchReport(source, dict(zip(names, map(float, theta0))))
    problem = boxed(problem, theta0, options.search_box)
    report.box = {"lower": dict(zip(names, map(float, problem.lower))), "upper": dict(zip(names, map(float, problem.upper)))}

    f_sig = signal_bandwidth(problem.y, problem.dt)
    report.signal_bandwidth_hz = f_sig
    filters = [BandFilter(fr * f_sig, len(problem.y), problem.dt) for fr in options.bands if fr * f_sig > 0]
    report.bands_hz = [bf.cutoff_hz for bf in filters]

    nfev = njev = 0
    anchor = theta0
    if options.time_scale:
        anchor, c, n = align_time_scale(problem, theta0, options)
        nfev += n
        report.aligned, report.time_scale = dict(zip(names, map(float, anchor))), c

    starts = [anchor]
    if options.n_starts > 1:
        free = problem.free
        sampler = qmc.Sobol(d=int(free.sum()), scramble=True, seed=options.seed)
        design = sampler.random(int(2 ** np.ceil(np.log2(max(options.n_starts - 1, 1)))))[: options.n_starts - 1]
        for row in design:
            th = anchor.copy()
            th[free] = anchor[free] * np.exp((2 * row - 1) * np.log(options.spread))
            starts.append(np.clip(th, problem.lower, problem.upper))

    if progress:
        progress.start("global search (starts)", total=len(starts))
    best: LocalResult | None = None
    confirmations = 0
    floor = 1e-14 * 0.5 * float(problem.y @ problem.y)  # round-off level of the cost
    for k, start in enumerate(starts):
        entry = {"index": k, "start": dict(zip(names, map(float, start)))}
        if k > 0 and options.time_scale:
            start, c, n = align_time_scale(problem, start, options, points=max(11, options.time_scale_points // 2))
            nfev += n
            entry["time_scale"] = c
        if options.coordinate_scan:
            start, n = coordinate_scan(problem, start, options)
            nfev += n
            entry["scanned"] = dict(zip(names, map(float, start)))
        res = None
        theta = start
        path: list[dict] = []
        for bf in filters:
            res = local_fit(problem, theta, bf, options.stage_max_nfev, False)
            nfev, njev, theta = nfev + res.nfev, njev + res.njev, res.theta
            path += _stage_trace(res, f"band {bf.cutoff_hz:.4g} Hz")
        res = local_fit(problem, theta, None, 2 * options.stage_max_nfev, False)
        nfev, njev = nfev + res.nfev, njev + res.njev
        res.trace = path + _stage_trace(res, "full band")
        entry.update(end=dict(zip(names, map(float, res.theta))), cost=res.cost)
        report.starts.append(entry)
        if best is None or res.cost < best.cost * (1 - 1e-9) - floor:
            same = best is not None and _same_minimum(best, res, floor)
            best, report.winner = res, k
            confirmations = 2 if same else 1
        elif _same_minimum(best, res, floor):
            confirmations += 1
        entry["residual_autocorrelation"] = res_white = residual_whiteness(problem, res.theta)
        if progress:
            progress.advance(1, f"best cost {best.cost:.4g}")
        if options.confirm and confirmations >= options.confirm:
            report.accepted_because = f"{confirmations} starts reached the same minimum"
            break
        if options.accept_white and best is res and res_white < options.whiteness_threshold:
            report.accepted_because = f"white residuals (mean |autocorrelation| {res_white:.3g})"
            break
        if best is res and res.cost <= floor:
            report.accepted_because = "exact fit (cost at round-off level)"
            break
    else:
        report.accepted_because = f"best of {len(starts)} starts (budget spent)"
    report.confirmed_by = confirmations
    if progress:
        progress.stop()

    final = local_fit(problem, best.theta, None, 50 * options.stage_max_nfev, True)
    nfev, njev = nfev + final.nfev, njev + final.njev
    if final.cost > best.cost:  # refinement never makes things worse
        final = best
    else:
        final.trace = best.trace + _stage_trace(final, "refinement")
    for i, rec in enumerate(final.trace):
        rec["iteration"] = i
    report.wall_time_s = time.perf_counter() - t0
    return final, report, nfev, njev


def boxed(problem: FitProblem, theta0: np.ndarray, factor: float) -> FitProblem:
    """The problem with log-scale parameters confined to theta0 x/÷ factor (within its bounds).

    A parameter the data barely see can otherwise run away by many decades during a local
    solve and drag the fit into a remote, flat region."""
    lower, upper = problem.lower.copy(), problem.upper.copy()
    for i, p in enumerate(problem.parameters):
        if p.log_scale and theta0[i] > 0:
            lower[i] = max(lower[i], theta0[i] / factor)
            upper[i] = min(upper[i], theta0[i] * factor)
    return dataclasses.replace(problem, lower=lower, upper=upper)


def at_box_edge(report: dict, theta: dict[str, float], rtol: float = 1e-3) -> list[str]:
    """Names of parameters that ended on the edge of the search box."""
    box = report.get("box") or {}
    out = []
    for name, value in theta.items():
        lo, hi = box.get("lower", {}).get(name), box.get("upper", {}).get(name)
        for edge in (lo, hi):
            if edge not in (None, 0.0) and np.isfinite(edge) and abs(value - edge) <= rtol * abs(edge):
                out.append(name)
                break
    return out


def _stage_trace(res: LocalResult, stage: str) -> list[dict]:
    """The Jacobian-evaluation records of one local solve, labelled with their stage.

    Costs of band stages are those of the band-limited residual."""
    return [dict(rec, stage=stage) for rec in res.trace]


def residual_whiteness(problem: FitProblem, theta: np.ndarray, lags: int = 10) -> float:
    """Mean |normalised autocorrelation| of the residual y - yhat at lags 1..``lags``.

    About 0.8/sqrt(N) for white noise; near 1 when a structured misfit is left (a local
    minimum of a wave model leaves a delayed or mistuned copy of the signal).
    """
    with np.errstate(over="ignore", invalid="ignore"):
        r = problem.y - problem.predict(theta)
    if not np.all(np.isfinite(r)):
        return np.inf
    return residual_autocorrelation(r, lags)


def residual_autocorrelation(r: np.ndarray, lags: int = 10) -> float:
    """Mean |normalised autocorrelation| of residuals r at lags 1..``lags``."""
    r = np.asarray(r, dtype=float) - np.mean(r)
    denom = float(r @ r)
    if denom <= 0 or not np.isfinite(denom):
        return 0.0
    return float(np.mean([abs(r[:-k] @ r[k:]) / denom for k in range(1, lags + 1)]))


def _same_minimum(a: LocalResult, b: LocalResult, floor: float = 0.0, rtol: float = 1e-3) -> bool:
    """Two local results are the same minimum when costs and parameters agree to ``rtol``.

    ``floor`` is a cost below which differences are round-off (noise-free data)."""
    if not (np.isfinite(a.cost) and np.isfinite(b.cost)):
        return False
    cost_ok = abs(a.cost - b.cost) <= rtol * max(a.cost, b.cost) + floor
    return bool(cost_ok and np.allclose(a.theta, b.theta, rtol=10 * rtol, atol=0))
