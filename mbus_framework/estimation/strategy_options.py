"""Options of the global strategy (``solver.options.strategy``) and its CPU-time budget.

Kept apart from :mod:`mbus_framework.estimation.strategy` so that reading a solver's options
(``mbus-run --list-plugins``, config validation) does not import the search itself.
"""
from __future__ import annotations

import time

from pydantic import BaseModel, ConfigDict, Field

from mbus_framework.estimation.problem import Progress, SearchTimeout

#: Default bound on the whole search [s] (``solver.options.strategy.time_budget``).
BUDGET_S = 50.0
BUDGET_KEY = "solver.options.strategy.time_budget"
_now = time.process_time  # the search's clock: CPU time of this process, so a busy machine does not
#                           cut a search short (tests replace it)


class SearchClock:
    """The search's time budget in CPU seconds of this process (other processes on a busy
    machine do not count), checked before every model evaluation (a :attr:`FitProblem.monitor`),
    and the live progress note (at most every 0.5 s of CPU time)."""

    def __init__(self, budget: float, progress: Progress | None = None) -> None:
        self.t0, self.budget, self.progress = _now(), budget, progress
        self.evaluations = 0
        self.ran_out = False
        self._shown = self.t0

    def elapsed(self) -> float:
        return _now() - self.t0

    def out_of_time(self) -> bool:
        self.ran_out = self.ran_out or self.elapsed() > self.budget
        return self.ran_out

    def note(self) -> str:
        t = self.elapsed()
        left = max(self.budget - t, 0.0)
        return f"{self.evaluations} evaluations; {t:.0f} of {self.budget:g} CPU s, at most {left:.0f} s left"

    def __call__(self) -> None:
        if self.out_of_time():
            raise SearchTimeout(f"the time budget of {self.budget:g} s (CPU) ran out")
        self.evaluations += 1
        now = _now()
        if self.progress is not None and now - self._shown > 0.5:
            self._shown = now
            self.progress.advance(0, self.note())

    def verdict(self, starts: int) -> str:
        """The sentence a result carries when the budget stopped the search."""
        return (f"the time budget of {self.budget:g} s (CPU) ran out after {starts} local fit(s); "
                f"raise {BUDGET_KEY} to search longer, or fit a decimated or windowed record "
                f"(estimation.decimate, estimation.window)")


def _material_ranges() -> dict[str, tuple[float, float]]:
    from mbus_framework.estimation.global_search import MATERIAL_RANGES

    return dict(MATERIAL_RANGES)


class StrategyOptions(BaseModel):
    """Options of the global strategy (the ``solver.options.strategy`` config section)."""

    model_config = ConfigDict(extra="forbid")
    material_ranges: dict[str, tuple[float, float]] = Field(
        default_factory=_material_ranges,
        description="plausible range of every property, by its unit ('Pa', 'Pa s', 's'): the search region",
    )
    widen: int = Field(2, ge=0, description="times the region is widened (x/÷ 100) when an estimate ends on its edge")
    global_search: bool = Field(True, description="scan the whole region in the frequency domain when the "
                                                  "physics-based starts are not accepted")
    shapes: int = Field(128, ge=8, description="Sobol shapes of the first scan level")
    local_shapes: int = Field(24, ge=4, description="shapes around each of the best points at the finer levels")
    spectral_candidates: int = Field(4, ge=1, description="scan candidates fitted in the frequency domain")
    amplitude_penalty: float = Field(1e-3, ge=0, description="weight of the response-level mismatch in the scan")
    n_starts: int = Field(6, ge=1, description="maximum number of time-domain local fits from the candidates")
    pole_starts: int = Field(3, ge=0, description="time-domain fits from starts whose poles match the record's "
                                                  "subspace-identified poles (lightly damped chains), when the "
                                                  "scan's were not accepted")
    poles_first: bool = Field(True, description="try the pole starts before the scan when every time-domain end "
                              "so far explains less than null_fraction of the record (a zero-output cost) and "
                              "the record's identified poles ring (least damping ratio < light_damping)")
    null_fraction: float = Field(0.05, gt=0, lt=1, description="poles_first: an end whose cost is at least "
                                 "(1 - null_fraction) x 0.5 sum(y^2) explains (almost) none of the record")
    light_damping: float = Field(2e-3, gt=0, lt=1, description="poles_first: the record rings when its least "
                                 "damping ratio -Re(s)/|s| (s = ln z / dt of its identified poles) is below this")
    pole_windows: int = Field(4, ge=0, description="pole starts: first fitted on the record's first N/2^k "
                                                   "samples, k = pole_windows..1, then on the whole record "
                                                   "(time continuation for ringing chains; 0 = off)")
    fallback_starts: int = Field(6, ge=0, description="multi-start around the best minima when none was accepted")
    fallback_anchors: int = Field(2, ge=1, description="fallback starts are shared in turn among this many of the "
                                                       "best distinct minima found")
    bands: list[float] = Field(
        default_factory=lambda: [0.3],
        description="fallback starts: low-pass stages before the full-band local fit, as fractions of the "
        "signal bandwidth (starts fitted in the frequency domain go straight to the full band)",
    )
    trial_nfev: int | None = Field(15, ge=1, description="a start not fitted in the frequency domain (the "
                                   "initial values as given) is first fitted in the time domain with at most this "
                                   "many evaluations; one that has not converged by then waits behind the "
                                   "frequency-domain starts and is resumed only if none of them is accepted "
                                   "(null: fitted at once)")
    spectral_trial_nfev: int | None = Field(60, ge=1, description="a start fitted in the frequency domain is "
                                            "next to its minimum: one whose time-domain fit has not converged "
                                            "within this many evaluations waits until the other starts of its "
                                            "phase are tried, then goes on (null: fitted at once) if its cost is "
                                            "still the lowest found (see resume_above_best)")
    resume_above_best: bool = Field(False, description="also resume a frequency-domain start's short trial that "
                                    "stopped above the lowest cost found so far (off: such a trial is crawling "
                                    "along a valley above a known minimum; the later phases search on instead)")
    stage_max_nfev: int = Field(60, ge=5, description="function-evaluation budget of each local-fit stage")
    significance: float = Field(1e-3, gt=0, lt=1, description="p-value below which input-related structure "
                                                              "in the residual rejects a minimum")
    min_excess: float = Field(0.03, ge=0, lt=1, description="input-related residual structure rejects a minimum "
                              "only when it is also this large: its excess over the noise, as a fraction of the "
                              "residual energy (significance is not size)")
    residual_lags: int | None = Field(None, ge=1, description="lags of the residual-input test (default N/16, <= 400)")
    accept_white: bool = Field(True, description="also require white residuals to accept a minimum")
    whiteness_threshold: float = Field(
        0.1, gt=0, description="largest mean |autocorrelation| of residuals at lags 1-10 counted as white"
    )
    seed: int = Field(0, description="seed of the Sobol designs")
    # the time-domain exploration of the fallback multi-start
    time_scale: bool = Field(True, description="fallback starts: align the arrival by a 1-D time-scale search")
    time_scale_range: float = Field(4.0, gt=1, description="fallback: time scales c in [1/r, r]")
    time_scale_points: int = Field(40, ge=3, description="fallback: grid points of the time-scale search")
    spread: float = Field(4.0, ge=1, description="fallback starts are drawn log-uniformly within x/÷ spread")
    coordinate_scan: int = Field(1, ge=0, description="fallback: sweeps of a per-parameter log-grid scan (0 = off)")
    search_box: float | None = Field(
        None, gt=1, description="also confine log-scale parameters to x/÷ this factor of the initial values"
    )
    time_budget: float = Field(BUDGET_S, gt=0, description="bound on the whole search [CPU s], checked before "
                               "every model evaluation; when it runs out the best minimum so far is reported "
                               "as not confirmed")
