"""Global estimation strategy: where to start, where to search, and when to stop.

The output-error cost of a wave model is multimodal (cycle skipping along the time scale) and,
for heavily damped media, nearly flat wherever the model explains nothing. The strategy works
for lightly damped slices and for stiff, heavily damped liquids and tissues alike, for any
medium model and any local solver (``local_fit``):

1. **Physical search region.** Every property within a plausible material range (moduli
   1e5-1e14 Pa, viscosities 1e-3-1e9 Pa s by default, ``material_ranges``); not a box around
   a possibly wrong start. An estimate that ends on the region's edge widens it (x/÷ 100 on
   that side) and is fitted again (``widen`` times).
2. **Starts from physics, then from the whole region.** First the user's initial values as
   given, then they and the model's own ``initial_guess`` (for chains: first arrival -> sound
   speed) fitted in the frequency domain, then the
   frequency-domain shape x time-scale scan over the whole region
   (:mod:`mbus_framework.estimation.global_search`). Each start is fitted in the frequency
   domain (shape and time scale first, response level last, the record's unfinished tail
   projected out), so candidates arrive ranked by an exact spectral cost.
3. **Time-domain local fits** from the candidates, best first, at most ``n_starts`` of them;
   when none is accepted, up to ``pole_starts`` more from parameters whose poles match the
   record's subspace-identified poles (:mod:`mbus_framework.estimation.poles`): a lightly
   damped chain rings in lines narrower than the scan's grid. These are fitted on the record's
   first N/16 ... N/2 samples before the whole record (``pole_windows``, time continuation).
4. **Acceptance by the noise level, not by whiteness alone** (:mod:`mbus_framework.estimation.acceptance`):
   a minimum is accepted when no input-related structure is left in its residual (an F test
   of a model-free FIR fit), its variance agrees with the repeated periods' noise when the
   record is periodic, and its residual is white. Otherwise the search goes on; when the
   candidates are spent, a multi-start around the best distinct minima in turn follows
   (``fallback_starts``, ``fallback_anchors``; time-scale alignment and band continuation in
   the time domain), and a minimum that is still not accepted is reported as such
   (result.json warns).
5. The best minimum is refined on the full record.

The whole search, refinement included, is bounded by ``time_budget`` (CPU seconds of the
process, so the load of other processes does not cut a search short): the budget is checked
before every model evaluation (:class:`SearchClock`), a local fit under way when it runs out
is abandoned, and the best minimum found so far is reported with a verdict that names the
budget and how to raise it. On an interactive terminal the progress line shows the
evaluations, the time spent and the time left of the budget.

The phases run in the order above (:func:`mbus_framework.estimation.phases.explore`).
Everything tried is reported (:class:`SearchReport`), so result.json says what won and why.
"""
from __future__ import annotations

import dataclasses
import time
from typing import Callable

import numpy as np

from mbus_framework.estimation import global_search as gs
from mbus_framework.estimation.acceptance import Verdict, estimate_noise, judge, residual_input_test
from mbus_framework.estimation.exploration import (  # noqa: F401  (re-exported names)
    BandFilter,
    align_time_scale,
    coordinate_scan,
    record_windows,
    residual_autocorrelation,
    residual_whiteness,
    signal_bandwidth,
    time_exponents,
)
from mbus_framework.estimation.local import LocalResult
from mbus_framework.estimation.minima import near, region_around
from mbus_framework.estimation.phases import explore
from mbus_framework.estimation.poles import identified_poles, pole_candidates
from mbus_framework.estimation.problem import FitProblem, Progress, SearchTimeout
from mbus_framework.estimation.routing import all_null, noise_dominated, null_cost, record_damping
from mbus_framework.estimation.search_report import SearchReport, at_box_edge, stage_trace  # noqa: F401  (at_box_edge re-exported)
from mbus_framework.estimation.spectral import record_spectrum
from mbus_framework.estimation.strategy_options import (  # noqa: F401  (re-exported: the solvers' options)
    BUDGET_KEY, BUDGET_S, SearchClock, StrategyOptions)


#: A local solver: (problem, start, band filter or None, max_nfev, final) -> LocalResult
LocalFit = Callable[[FitProblem, np.ndarray, "BandFilter | None", int, bool], LocalResult]


class _Search:
    """State of one search: the boxed problem, the spectrum, the best minimum so far."""

    def __init__(self, problem: FitProblem, local_fit: LocalFit, options: StrategyOptions, progress,
                 clock: SearchClock | None = None):
        self.options, self.local_fit, self.progress = options, local_fit, progress
        self.clock = clock or SearchClock(options.time_budget, progress)
        self.space = gs.search_space(problem, options.material_ranges)
        lo, hi = self.space.lo.copy(), self.space.hi.copy()
        if problem.initial is not None and options.search_box:
            lo, hi = region_around(problem, np.asarray(problem.initial, float), options.search_box, lo, hi)
            self.space = dataclasses.replace(self.space, lo=lo, hi=hi)
        self.problem = dataclasses.replace(problem, lower=lo, upper=hi, monitor=self.clock)
        self._hard = (problem.lower.astype(float), problem.upper.astype(float))
        self.names = problem.names
        self.noise = estimate_noise(problem.t, problem.u, problem.y)
        f_sig = signal_bandwidth(problem.y, problem.dt)
        self.filters = [BandFilter(fr * f_sig, len(problem.y), problem.dt) for fr in options.bands if fr * f_sig > 0]
        self.floor = 1e-14 * 0.5 * float(problem.y @ problem.y)  # round-off level of the cost
        self.best: LocalResult | None = None
        self.stopped_short: tuple[LocalResult, int] | None = None  # the last start's, if a short trial
        self.minima: list[LocalResult] = []  # every time-domain fit's end point
        self.verdict: Verdict | None = None
        self.nfev = self.njev = 0
        self._spectrum = None
        self._poles: np.ndarray | None = None
        self.routing: dict | None = None
        self.report = SearchReport("", {}, signal_bandwidth_hz=f_sig, bands_hz=[b.cutoff_hz for b in self.filters])
        self.report.noise = self.noise.as_dict()
        self.report.box = self._box_dict()

    @property
    def spectrum(self):
        if self._spectrum is None:
            self._spectrum = record_spectrum(self.problem)
        return self._spectrum

    def _box_dict(self) -> dict:
        return {"lower": dict(zip(self.names, map(float, self.problem.lower))),
                "upper": dict(zip(self.names, map(float, self.problem.upper)))}

    def seeds(self) -> list[tuple[str, np.ndarray]]:
        p = self.problem
        out = []
        if p.initial is not None:
            out.append(("config", p.full(np.asarray(p.initial, float)[p.free], p.initial)))
        guess = p.default_initial()
        out.append(("model.initial_guess", p.full(np.asarray(guess, float)[p.free], guess)))
        return [(s, np.clip(th, p.lower, p.upper)) for s, th in out]

    def candidates_from(self, starts: list[gs.Candidate], limit: int) -> list[gs.Candidate]:
        """Frequency-domain fits of ``starts`` (at most ``limit``), distinct, best first."""
        fitted = []
        for c in starts[:limit]:
            try:
                fitted.append(gs.homotopy(self.problem, self.spectrum, c, self.space))
            except (np.linalg.LinAlgError, ValueError, FloatingPointError):
                continue
        return gs.distinct(fitted, rtol=0.02)

    def seed_candidates(self, seeds: list[tuple[str, np.ndarray]]):
        """Each physics-based start fitted in the frequency domain twice: as it is (its level
        trusted) and after a shape-first time-scale alignment; best first per seed, in the
        seeds' order (the user's values before the model's guess), each seed's fits made only
        when the earlier seeds' were not accepted (a generator); distinct."""
        p, sp, space = self.problem, self.spectrum, self.space
        done: list[gs.Candidate] = []
        for origin, th in seeds:
            out = []
            try:
                out.append(gs.refine(p, sp, gs.Candidate(th, np.nan, origin), space))
            except (np.linalg.LinAlgError, ValueError, FloatingPointError):
                pass
            out += self.candidates_from([gs.align(p, sp, th, space, origin)], 1)
            for c in gs.distinct(out, rtol=0.02):
                if not any(near(c.theta, d.theta) for d in done):
                    done.append(c)
                    yield c

    def scan(self) -> list[gs.Candidate]:
        """The multi-level shape x scale scan over the whole region (best distinct first)."""
        o, p, sp = self.options, self.problem, self.spectrum
        template = self.template()
        kw = dict(amplitude_penalty=o.amplitude_penalty)
        level1 = gs.scan(p, sp, self.space, template, shapes=o.shapes, seed=o.seed, **kw)
        centres = [c.theta for c in gs.distinct(level1, 0.5, 5)] + [th for _, th in self.seeds()]
        if self.best is not None:
            centres.append(self.best.theta)
        level2 = gs.scan(p, sp, self.space, template, shapes=o.local_shapes, seed=o.seed + 1, around=centres,
                         halfwidth=1.5, **kw)
        centres = [c.theta for c in gs.distinct(level1 + level2, 0.3, 5)]
        level3 = gs.scan(p, sp, self.space, template, shapes=o.local_shapes, seed=o.seed + 2, around=centres,
                         halfwidth=0.5, **kw)
        found = gs.distinct(level1 + level2 + level3, 0.2)
        self.report.scan = {"shapes": o.shapes + o.local_shapes * 10, "candidates": len(found),
                            "best": [dict(zip(self.names, map(float, c.theta))) for c in found[:3]]}
        return found

    def template(self) -> np.ndarray:
        """Typical values (the model's guess for parameters without one), within the box."""
        p = self.problem
        return np.clip(p.full(np.array([q.typical for q in p.parameters])[p.free], p.default_initial()),
                       p.lower, p.upper)

    def pole_candidates(self) -> list[gs.Candidate]:
        """Starts matched to the record's subspace-identified poles (:mod:`.poles`)."""
        o = self.options
        found = pole_candidates(self.problem, self.space, self.template(), limit=o.pole_starts, seed=o.seed,
                                identify=lambda _: self.record_poles())
        self.report.poles = {"candidates": [dict(zip(self.names, map(float, c.theta))) for c in found]}
        return found

    def record_poles(self) -> np.ndarray:
        """The record's subspace-identified poles (:func:`.poles.identified_poles`), identified
        once per search: routing and the pole starts both use them."""
        if self._poles is None:
            self._poles = identified_poles(self.problem)
        return self._poles

    def rings_unexplained(self) -> bool:
        """Every end so far null and the record's poles ring: pole starts first (:mod:`.routing`)."""
        o, p, null = self.options, self.problem, null_cost(self.problem.y)
        noise_var = self.noise.periods if self.noise.periods is not None else self.noise.out_of_band
        costs = [float(e["cost"]) for e in self.report.starts if "cost" in e]
        if not all_null(costs, null, o.null_fraction) or noise_dominated(null, p.y.size, noise_var):
            return False
        zeta = record_damping(p, self.record_poles())
        self.routing = {"null_cost": null, "least_damping_ratio": zeta, "before_scan": zeta < o.light_damping}
        return zeta < o.light_damping

    def expect(self, more: int) -> None:
        """Raise the progress total to the starts done plus ``more``: the later phases (record
        poles, fallback) add starts beyond ``n_starts``, so the counter never passes its total."""
        set_total = getattr(self.progress, "set_total", None)
        if set_total is not None and more > 0:
            set_total(len(self.report.starts) + more)

    def try_start(self, theta: np.ndarray, origin: str, spectral_cost: float | None = None,
                  explore: bool = False, windows: int = 0, max_nfev: int | None = None,
                  trial: bool = False, as_given: bool = False) -> bool:
        """One time-domain local fit (band stages or ``windows`` record windows, then the full
        record); True when accepted. ``max_nfev`` bounds the full-band fit; with ``trial`` a fit
        that runs out of it before converging is a short trial (:attr:`stopped_short` then holds
        its end and the rest of the start's budget, and it is not counted a minimum). ``as_given``
        marks the user's values as given (not next to a minimum: no full-precision solve);
        ``origin`` is the report's label only. A start the
        time budget stops is recorded as stopped and the :class:`SearchTimeout` passed on."""
        entry: dict = {"index": len(self.report.starts), "origin": origin,
                       "start": dict(zip(self.names, map(float, theta)))}
        if spectral_cost is not None:
            entry["spectral_cost"] = spectral_cost
        before = self.clock.evaluations
        self.stopped_short = None
        try:
            return self._fit_start(theta, entry, explore, windows, max_nfev, trial, as_given)
        except SearchTimeout:
            entry.update(stopped="time budget ran out", evaluations=self.clock.evaluations - before)
            self.nfev += self.clock.evaluations - before  # the abandoned fit's model evaluations
            self.report.starts.append(entry)
            raise

    def _fit_start(self, theta: np.ndarray, entry: dict, explore: bool, windows: int,
                   max_nfev: int | None = None, trial: bool = False, as_given: bool = False) -> bool:
        o, p = self.options, self.problem
        if explore:
            if o.time_scale:
                theta, c, n = align_time_scale(p, theta, o, points=max(11, o.time_scale_points // 2))
                self.nfev += n
                entry["time_scale"] = c
            if o.coordinate_scan:
                theta, n = coordinate_scan(p, theta, o)
                self.nfev += n
        path: list[dict] = []
        for bf in self.filters if explore else []:
            res = self.local_fit(p, theta, bf, o.stage_max_nfev, False)
            self.nfev, self.njev, theta = self.nfev + res.nfev, self.njev + res.njev, res.theta
            path += stage_trace(res, f"band {bf.cutoff_hz:.4g} Hz")
        for n, window in record_windows(p, windows):
            res = self.local_fit(window, theta, None, o.stage_max_nfev, False)
            self.nfev, self.njev, theta = self.nfev + res.nfev, self.njev + res.njev, res.theta
            path += stage_trace(res, f"first {n} samples")
        # a start fitted in the frequency domain is next to its minimum: solve to full precision
        precise = not explore and not as_given
        budget = (10 if precise else 2) * o.stage_max_nfev
        res = self.local_fit(p, theta, None, min(budget, max_nfev or budget), precise)
        self.nfev, self.njev = self.nfev + res.nfev, self.njev + res.njev
        res.trace = path + stage_trace(res, "full band")
        verdict = self.judge(res)
        entry.update(end=dict(zip(self.names, map(float, res.theta))), cost=res.cost, verdict=verdict.as_dict(),
                     residual_autocorrelation=verdict.whiteness)
        short = trial and res.nfev < budget and res.status == 0 and not verdict.accepted
        if short:  # stopped by the trial's bound, not at a minimum: resumed later if still needed
            entry["stopped"] = f"short trial: {res.nfev} evaluations without converging"
            self.stopped_short = (res, budget - res.nfev)
        self.report.starts.append(entry)
        if not short:
            self.minima.append(res)
        if self.best is None or res.cost < self.best.cost * (1 - 1e-9) - self.floor:
            self.best, self.verdict, self.report.winner = res, verdict, entry["index"]
        if self.progress:
            self.progress.advance(1, f"best cost {self.best.cost:.4g}")
        return verdict.accepted and self.best is res

    def judge(self, res: LocalResult) -> Verdict:
        p, o = dataclasses.replace(self.problem, monitor=None), self.options
        with np.errstate(over="ignore", invalid="ignore"):
            r = p.y - p.predict(res.theta)
        if res.cost <= self.floor:
            v = judge(r, p.u, int(p.free.sum()), self.noise, significance=o.significance, lags=o.residual_lags)
            return dataclasses.replace(v, accepted=True, reason="exact fit (cost at round-off level)")
        return judge(r, p.u, int(p.free.sum()), self.noise, significance=o.significance,
                     whiteness_threshold=o.whiteness_threshold if o.accept_white else np.inf,
                     white_noise=p.noise_filter is None, lags=o.residual_lags, min_excess=o.min_excess)

    def anchors(self) -> list[np.ndarray]:
        """The ``fallback_anchors`` lowest-cost minima found, distinct (2 % in every parameter)."""
        out: list[np.ndarray] = []
        for res in sorted(self.minima, key=lambda r: r.cost):
            if len(out) < self.options.fallback_anchors and not any(near(res.theta, a) for a in out):
                out.append(res.theta)
        return out

    def fallback(self, out_of_time=lambda: False) -> bool:
        """Sobol starts around the best minima (in turn), aligned and scanned in the time domain."""
        o, p = self.options, self.problem
        if not o.fallback_starts or self.best is None:
            return False
        free = p.free & np.array([q.log_scale for q in p.parameters])
        design = gs.sobol(max(int(free.sum()), 1), o.fallback_starts, o.seed)
        anchors = self.anchors()
        self.expect(len(design))
        for i, row in enumerate(design):
            if out_of_time():
                break
            anchor = anchors[i % len(anchors)]
            th = anchor.copy()
            th[free] = anchor[free] * np.exp((2 * row[: free.sum()] - 1) * np.log(o.spread))
            if self.try_start(np.clip(th, p.lower, p.upper), "fallback multi-start", explore=True):
                return True
        return False

    def widen_if_on_edge(self, final: LocalResult) -> LocalResult:
        """Refit with the region widened x/÷ 100 on every side an estimate ended on; stops when
        nothing can widen (the hard bounds) or a refit does not lower the cost."""
        o = self.options
        for _ in range(o.widen):
            lo, hi = self.problem.lower.copy(), self.problem.upper.copy()
            movable = self.space.movable
            low = movable & (final.theta <= lo * (1 + 1e-6))
            high = movable & (final.theta >= hi * (1 - 1e-6))
            if not (low.any() or high.any()):
                break
            lo[low], hi[high] = lo[low] / 100.0, hi[high] * 100.0
            lo, hi = np.maximum(lo, self._hard[0]), np.minimum(hi, self._hard[1])
            if np.array_equal(lo, self.problem.lower) and np.array_equal(hi, self.problem.upper):
                break  # on the hard bounds already: nothing to widen, a refit would repeat the last
            self.report.widened += [n for n, f in zip(self.names, low | high) if f]
            self.problem = dataclasses.replace(self.problem, lower=lo, upper=hi)
            self.space = dataclasses.replace(self.space, lo=lo, hi=hi)
            again = self.local_fit(self.problem, final.theta, None, 10 * o.stage_max_nfev, True)
            self.nfev, self.njev = self.nfev + again.nfev, self.njev + again.njev
            if again.cost > final.cost:
                break  # the wider region holds nothing better: the estimate stays where it was
            again.trace = final.trace + stage_trace(again, "widened region")
            final = again
        self.report.box = self._box_dict()
        return final


def search(
    problem: FitProblem,
    local_fit: LocalFit,
    options: StrategyOptions,
    progress: Progress | None = None,
) -> tuple[LocalResult, SearchReport, int, int]:
    """Run the strategy within ``options.time_budget``; returns (best refined result, report,
    total nfev, total njev)."""
    t0 = time.perf_counter()
    clock = SearchClock(options.time_budget, progress)
    s = _Search(problem, local_fit, options, progress, clock)
    o = options
    seeds = s.seeds()
    silent = residual_input_test(problem.y - problem.y.mean(), problem.u, 0).p_value > o.significance
    if silent:  # no response to the input in the record: nothing a wider search could find
        o = options.model_copy(update={"n_starts": 1, "global_search": False, "pole_starts": 0, "fallback_starts": 0,
                                       "widen": 0})
        s.options = o
        s.report.scan = {"skipped": "no response to the input is detectable in the record"}
    s.report.initial_source, s.report.initial = seeds[0][0], dict(zip(s.names, map(float, seeds[0][1])))
    if progress:
        progress.start("global search (starts)", total=o.n_starts)
    try:
        accepted = explore(s, o, seeds)
    except SearchTimeout:
        accepted = False
    if progress:
        progress.stop()
    if s.best is None:  # the budget ran out before any local fit ended: the best seed as it is
        s.best = _evaluated(s, seeds)
        s.verdict = s.judge(s.best)
    best, v = s.best, s.verdict
    s.report.accepted = bool(accepted)
    s.report.verdict = v.as_dict() if v is not None else None
    if clock.ran_out:
        s.report.stopped_by_budget = clock.verdict(sum("end" in e for e in s.report.starts))
    s.report.accepted_because = v.reason if accepted and v is not None else (
        "not confirmed: " + (f"{s.report.stopped_by_budget}; " if clock.ran_out else "")
        + f"best of {len(s.report.starts)} starts; {v.reason if v is not None else 'no start'}")
    final = best
    try:
        if not clock.ran_out:
            final = local_fit(s.problem, best.theta, None, 10 * o.stage_max_nfev, True)
            s.nfev, s.njev = s.nfev + final.nfev, s.njev + final.njev
            if final.cost > best.cost:  # refinement never makes things worse
                final = best
            else:
                final.trace = best.trace + stage_trace(final, "refinement")
            final = s.widen_if_on_edge(final)
    except SearchTimeout:
        s.report.stopped_by_budget = s.report.stopped_by_budget or clock.verdict(
            sum("end" in e for e in s.report.starts))
    if not accepted and final is not best:  # the refinement went on to a lower minimum: judge that one
        v = s.judge(final)
        if v.accepted:
            s.report.accepted, s.report.verdict = True, v.as_dict()
            s.report.accepted_because = f"{v.reason}; reached by refining the best of {len(s.report.starts)} starts"
    for i, rec in enumerate(final.trace):
        rec["iteration"] = i
    s.report.wall_time_s = time.perf_counter() - t0
    s.report.cpu_time_s = clock.elapsed()
    return final, s.report, s.nfev, s.njev


def _evaluated(s: _Search, seeds: list[tuple[str, np.ndarray]]) -> LocalResult:
    """The first seed, evaluated once (no local fit ended within the budget)."""
    p = dataclasses.replace(s.problem, monitor=None)
    theta = seeds[0][1]
    with np.errstate(over="ignore", invalid="ignore"):
        r = p.y - p.predict(theta)
    cost = 0.5 * float(r @ r) if np.all(np.isfinite(r)) else np.inf
    return LocalResult(theta, cost, 1, 0, 0, "the time budget ran out before any local fit ended", 0,
                       [{"cost": cost, "theta": theta.tolist(), "stage": "start"}])
