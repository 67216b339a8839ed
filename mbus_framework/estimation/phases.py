"""The strategy's phases in order (:mod:`.strategy`, steps 1-4): the physics-based starts, the
record's poles when every end so far explains nothing and the record rings, the whole-region
scan, the record's poles, and the fallback multi-start; True as soon as a minimum is accepted."""
from __future__ import annotations

import numpy as np

from mbus_framework.estimation import global_search as gs
from mbus_framework.estimation.local import LocalResult
from mbus_framework.estimation.minima import near
from mbus_framework.estimation.strategy_options import StrategyOptions


def explore(s, o: StrategyOptions, seeds: list[tuple[str, np.ndarray]]) -> bool:
    """Steps 1-4 of :mod:`.strategy`'s docstring on the search state ``s`` (the strategy's
    ``_Search``); True when a minimum was accepted. Raises
    :class:`SearchTimeout` when the budget runs out during a model evaluation."""
    out_of_time = s.clock.out_of_time
    spectral_ok = s.space.movable.any()
    # 1. the physics-based starts, fitted in the frequency domain first
    given = [gs.Candidate(th, np.nan, "config (as given)", as_given=True) for origin, th in seeds if origin == "config"]
    raw = [gs.Candidate(th, np.nan, origin) for origin, th in seeds if origin != "config"]

    def queue():  # lazily: the spectral fits of the seeds only when the start as given is not accepted
        yield from given
        if not getattr(s.problem.model, "has_state_space", True):
            # no states: the spectral stage cannot model the record's unfinished tail, so a
            # frequency-response model's own physics-based start is fitted in the time domain first
            yield from raw
            yield from (s.seed_candidates(seeds) if spectral_ok else [])
        elif spectral_ok:
            yield from s.seed_candidates(seeds)
        else:
            yield from raw

    tried = 0
    waiting: list[tuple[str, bool, int, LocalResult, int]] = []  # short trials that did not converge

    def lowest(res: LocalResult) -> bool:
        """``res`` ends at the lowest cost found so far (within round-off)."""
        return res.cost <= s.best.cost * (1 + 1e-9) + s.floor

    def attempt(c: gs.Candidate, origin: str) -> bool:
        """One start with a short trial: the start as given ``trial_nfev``, a frequency-domain
        candidate ``spectral_trial_nfev`` evaluations (it should be next to its minimum); one
        that has not converged by then waits until its phase's other starts are tried."""
        bound = o.trial_nfev if c.as_given else o.spectral_trial_nfev
        bound = bound if (spectral_ok and (c.as_given or np.isfinite(c.cost))) else None
        if s.try_start(c.theta, origin, c.cost, max_nfev=bound, trial=bound is not None, as_given=c.as_given):
            return True
        if s.stopped_short is not None:
            waiting.append((origin, c.as_given, len(s.report.starts) - 1, *s.stopped_short))
        return False

    def resume() -> bool:
        """The waiting trials, from where each stopped, with the rest of its budget; a
        frequency-domain start's only while its cost is the lowest found so far (unless
        ``resume_above_best``). A frequency-domain start is next to its minimum; one that has
        not converged in its trial crawls along a valley, and one that stopped above a minimum
        already found is left to the later phases (the record's poles, the fallback around the
        best minima): resumed, such trials took ~540 evaluations each and none was accepted or
        became the estimate in the convergence benchmark."""
        while waiting and not out_of_time():
            origin, as_given, index, res, left = waiting.pop(0)
            if not (as_given or o.resume_above_best or lowest(res)):
                s.report.starts[index]["not_resumed"] = (
                    f"stopped at cost {res.cost:.6g}, above the best found ({s.best.cost:.6g})")
                continue
            label = origin.replace("(as given)", "(as given, resumed)") if as_given else f"{origin} (resumed)"
            if s.try_start(res.theta, label, max_nfev=left, as_given=as_given):
                return True
        return False

    for c in queue():
        if tried >= o.n_starts or (tried and out_of_time()):
            break
        tried += 1
        if attempt(c, c.origin):
            return True
    if resume():
        return True
    poles_done = False
    def pole_phase() -> bool:
        """3. the record's poles: lightly damped chains, whose cost basin is narrower than the scan's
        grid; before 2. when every end so far explains nothing and the record rings (:mod:`.routing`)."""
        nonlocal poles_done
        poles_done = True
        poles = s.pole_candidates()
        s.report.poles.update({"routing": s.routing} if s.routing else {})
        s.expect(len(poles))
        for c in poles:
            if out_of_time():
                break
            if s.best is not None and near(c.theta, s.best.theta, 1e-3):
                continue
            if s.try_start(c.theta, "record poles", windows=o.pole_windows):
                return True
        return False

    pole_ok = o.global_search and o.pole_starts and spectral_ok
    if pole_ok and o.poles_first and not out_of_time() and s.rings_unexplained() and pole_phase():
        return True
    # 2. the whole region
    if o.global_search and spectral_ok and tried < o.n_starts and not out_of_time():
        for c in scan_candidates(s, o.spectral_candidates):
            if tried >= o.n_starts or out_of_time():
                break
            if s.best is not None and near(c.theta, s.best.theta):
                continue
            tried += 1
            if attempt(c, "scan"):
                return True
        if resume():
            return True
    if pole_ok and not poles_done and not out_of_time() and pole_phase():
        return True
    # 4. last resort: around the best minimum
    return not out_of_time() and s.fallback(out_of_time)


def scan_candidates(s, limit: int):
    """The scan's candidates fitted in the frequency domain, lazily (a generator): first the
    scan's best point alone, so it is tried in the time domain before any other is fitted (it
    is usually the one accepted, and each fit costs a four-stage homotopy); then the rest of
    the ``limit`` best, distinct (2 %) from it and from each other, best fitted cost first."""
    ranked = s.scan()
    first = s.candidates_from(ranked[:1], 1)
    yield from first
    if limit > 1:
        yield from (c for c in s.candidates_from(ranked[1:], limit - 1)
                    if not any(near(c.theta, f.theta) for f in first))
