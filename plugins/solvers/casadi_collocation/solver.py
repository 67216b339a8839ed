"""The ``casadi_collocation`` solver: local solves of the collocation NLP inside the global strategy."""
from __future__ import annotations

import time
from dataclasses import replace
from typing import Any

import numpy as np
from mbus_plugins.solvers.casadi_collocation.band_filter import (
    butterworth_ss,
    filter_data,
    filter_states,
)
from mbus_plugins.solvers.casadi_collocation.nlp import CollocationNLP, StageData
from mbus_plugins.solvers.casadi_collocation.options import (
    IPOPT_STATUS,
    CasadiCollocationOptions,
)

from mbus_framework.engine.simulation import as_float_ss, discretize
from mbus_framework.errors import EstimationError
from mbus_framework.estimation.nuisance import DELAY
from mbus_framework.estimation.problem import FitProblem, FitResult, Progress, Solver
from mbus_framework.estimation.strategy import BandFilter, LocalResult, search


# ---------------------------------------------------------------------------------------------
# the solver
# ---------------------------------------------------------------------------------------------
def _stats_summary(stats: dict) -> dict:
    """IPOPT statistics as plain JSON-able values (the per-iteration arrays summarised)."""
    out = {k: (v if isinstance(v, (bool, str)) else float(v) if isinstance(v, float) else int(v))
           for k, v in stats.items() if isinstance(v, (bool, str, int, float))}
    it = stats.get("iterations") or {}
    if it.get("obj"):
        out["final_inf_pr"] = float(it["inf_pr"][-1])
        out["final_inf_du"] = float(it["inf_du"][-1])
    return out


class _Session:
    """Everything one ``solve`` shares between its local solves (NLPs are built once)."""

    def __init__(self, problem: FitProblem, opts: CasadiCollocationOptions):
        from mbus_framework.estimation.nuisance import _split_delay

        self.problem, self.opts = problem, opts
        self.h = problem.dt
        delay = float(problem.fixed.get(DELAY, 0.0)) if DELAY in problem.names else 0.0
        self.shift, self.step = _split_delay(delay, self.h) if delay > 0 else (0, None)
        self.n_pred = problem.y.size - self.shift
        if self.n_pred < 2:
            raise EstimationError("casadi_collocation: the delay leaves fewer than 2 samples to fit")
        self.u = problem.u[: self.n_pred]
        self.s_y = float(np.sqrt(np.mean(problem.y**2))) or 1.0
        self.nlps: dict[bool, CollocationNLP] = {}
        self.m: int | None = None
        self.nfev = self.njev = 0
        self.last: dict[str, Any] = {}
        self.log: list[dict[str, Any]] = []  # one entry per local solve
        self.results: list[np.ndarray] = []  # estimates of earlier local solves (warm starts)

    # -- structure --------------------------------------------------------------------------------
    def samples_per_node(self, theta: np.ndarray) -> int:
        o = self.opts
        if o.samples_per_node != "auto":
            return int(min(o.samples_per_node, self.n_pred))
        A = as_float_ss(self.problem.model.state_space(theta[: self.problem.n_model])).A
        rate = float(np.max(np.abs(np.linalg.eigvals(A)))) * self.h
        m = int(o.node_phase / rate) if rate > 0 else 64
        return int(np.clip(m, 1, min(64, self.n_pred)))

    def nlp(self, band: bool, theta: np.ndarray) -> CollocationNLP:
        if band not in self.nlps:
            if self.m is None:
                self.m = self.samples_per_node(theta)
            self.nlps[band] = CollocationNLP(self.problem, self.opts, self.u, self.h, self.m, self.step, band)
        return self.nlps[band]

    # -- scaling --------------------------------------------------------------------------------
    def state_scales(self, theta: np.ndarray) -> np.ndarray:
        """max_k |x_i(t_k)| of a simulation (exact discretisation) at ``theta``."""
        p = self.problem
        model_theta, gain, _ = p.split(theta)
        sys_d = discretize(p.model.state_space(model_theta), self.h, p.hold)
        x = np.zeros(sys_d.Phi.shape[0])
        peak = np.zeros_like(x)
        Gu = np.outer(sys_d.Gamma, gain * self.u)
        for k in range(self.n_pred - 1):
            x = sys_d.Phi @ x + Gu[:, k]
            np.maximum(peak, np.abs(x), out=peak)
        good = np.isfinite(peak) & (peak > 0)
        if not good.any():
            return np.ones_like(peak)
        peak[~good] = float(np.exp(np.mean(np.log(peak[good]))))
        return peak

    # -- one local solve -------------------------------------------------------------------------
    def local_fit(self, problem: FitProblem, theta0: np.ndarray, band: BandFilter | None, max_nfev: int,
                  final: bool) -> LocalResult:
        p, o = self.problem, self.opts
        theta0 = np.clip(np.asarray(theta0, dtype=float), problem.lower, problem.upper)
        typical = np.array([q.typical for q in p.parameters], dtype=float)
        # free parameters are scaled by their start (by ``typical`` when the start is zero);
        # fixed ones enter with their value
        zero = p.free & ~(np.abs(theta0) > 0)
        ref = np.where(zero, np.where(typical != 0, typical, 1.0), theta0)
        nlp = self.nlp(band is not None, ref)
        y = p.y
        filt = None
        if band is not None:
            Af, Bf, Cf, Df = butterworth_ss(band.cutoff_hz, self.h)
            s_z = np.max(np.abs(filter_states(Af, Bf, y / self.s_y)), axis=1)
            s_z[~(s_z > 0)] = 1.0
            filt = (Af * np.outer(1 / s_z, s_z), Bf / s_z, Cf * s_z, Df)
            y = filter_data(Af, Bf, Cf, Df, y / self.s_y) * self.s_y
        with np.errstate(over="ignore", invalid="ignore"):
            sd = StageData(ref, self.state_scales(ref), self.s_y, y[self.shift:], filt)
            sd.x0 = nlp.warm_start(ref, sd)
        if not np.all(np.isfinite(sd.x0)):  # the model cannot be simulated here: a failed stage
            self.log.append({"band_hz": None if band is None else band.cutoff_hz, "final": final,
                             "iterations": 0, "status": "simulation at the start is not finite",
                             "cost": np.inf, "wall_time_s": 0.0})
            return LocalResult(theta=theta0, cost=np.inf, nfev=0, njev=0, status=-1,
                               message="casadi_collocation: the start cannot be simulated (non-finite states)",
                               iterations=0, trace=[])
        max_iter = o.max_iter if final else max_nfev
        # the refinement of an earlier local solve's result starts at or next to a minimum
        warm = final and any(np.array_equal(theta0, r) for r in self.results)
        t0 = time.perf_counter()
        # the problem's own bounds (the user's), not the strategy's search region: finite region
        # bounds on the NLP variables make IPOPT's barrier creep along flat valleys (a Maxwell
        # series spring running to the bound); the region bounds the starts only
        theta, stats, w, fobj, records, reason = nlp.solve(sd, p.lower, p.upper, max_iter,
                                                           *((o.xtol, o.ftol) if final else (o.stage_xtol, o.stage_ftol)),
                                                           warm=warm)
        self.results.append(theta)
        wall = time.perf_counter() - t0
        ret = str(stats.get("return_status"))
        if ret == "User_Requested_Stop":
            status, message = (4 if reason.startswith("relative") else 0), f"IPOPT stopped: {reason}"
        else:
            status, message = IPOPT_STATUS.get(ret, -1), f"IPOPT: {ret}"
        if band is None:
            with np.errstate(over="ignore", invalid="ignore"):
                r = p.y - p.predict(theta)
            cost = 0.5 * float(r @ r) if np.all(np.isfinite(r)) else np.inf
        else:
            cost = fobj
        nfev, njev = int(stats.get("n_call_nlp_f", 0)), int(stats.get("n_call_nlp_jac_g", 0))
        self.nfev, self.njev = self.nfev + nfev, self.njev + njev
        trace = [{"iteration": i, "cost": c, "theta": th.tolist()} for i, (c, th) in enumerate(records)]
        self.last = {"nlp": nlp, "stage_data": sd, "w": w, "stats": stats, "objective": fobj,
                     "solve_time_s": wall, "band": band is not None, "theta": theta}
        self.log.append({"band_hz": None if band is None else band.cutoff_hz, "final": final, "warm": warm,
                         "iterations": int(stats.get("iter_count", 0)), "status": ret if not reason else reason,
                         "cost": cost, "wall_time_s": wall})
        return LocalResult(theta=theta, cost=cost, nfev=nfev, njev=njev, status=status, message=message,
                           iterations=int(stats.get("iter_count", 0)), trace=trace)

    def start(self) -> tuple[np.ndarray, str]:
        p = self.problem
        if p.initial is not None:
            theta0, source = p.full(np.asarray(p.initial, float)[p.free], p.initial), "config"
        else:
            guess = p.default_initial()
            theta0, source = p.full(np.asarray(guess, float)[p.free], guess), "model.initial_guess"
        return np.clip(theta0, p.lower, p.upper), source


def _truncated(problem: FitProblem, n: int) -> FitProblem:
    """The same problem on the first ``n`` samples (the dynamics still start from rest)."""
    return replace(problem, t=problem.t[:n], u=problem.u[:n], y=problem.y[:n],
                   lower=problem.lower, upper=problem.upper)


class CasadiCollocation(Solver):
    """Direct collocation (states as NLP variables) solved by IPOPT, inside the global strategy."""

    Options = CasadiCollocationOptions
    summary = "CasADi direct collocation (Legendre/Radau/trapezoidal) solved by IPOPT, Gauss-Newton Hessian"

    def solve(self, problem: FitProblem, progress: Progress | None = None) -> FitResult:
        import casadi as ca

        t0 = time.perf_counter()
        o = self.options
        _check_supported(problem)
        session = _Session(problem, o)
        nfev = njev = 0
        search_log: list[dict[str, Any]] = []
        if o.global_search:
            n_search = o.search_samples
            if n_search is not None and n_search < problem.y.size:
                sproblem = _truncated(problem, n_search)
                ssession = _Session(sproblem, o)
                found, report, nfev, njev = search(sproblem, ssession.local_fit, o.strategy, progress)
                search_log = [dict(r, samples=n_search) for r in ssession.log]
                session.results.append(np.clip(found.theta, problem.lower, problem.upper))  # a warm start
                best = session.local_fit(problem, found.theta, None, o.max_iter, True)
                best.trace = found.trace + [dict(r, stage="refinement (whole record)") for r in best.trace]
                nfev, njev = nfev + best.nfev, njev + best.njev
            else:
                best, report, nfev, njev = search(problem, session.local_fit, o.strategy, progress)
            strategy = report.as_dict()
        else:
            theta0, source = session.start()
            if progress:
                progress.start("IPOPT", total=1)
            best = session.local_fit(problem, theta0, None, o.max_iter, True)
            if progress:
                progress.advance(1, f"cost {best.cost:.4g}")
                progress.stop()
            nfev, njev = best.nfev, best.njev
            strategy = {"initial_source": source, "initial": dict(zip(problem.names, map(float, theta0))),
                        "global_search": False}
        last = session.last
        extras = {"method": "ipopt", "scheme": o.scheme, "degree": 1 if o.scheme == "trapezoidal" else o.degree,
                  "formulation": o.formulation, "coordinates": o.coordinates, "hessian": o.hessian}
        result = FitResult.at_estimate(problem, best, nfev=nfev, njev=njev, wall_time_s=0.0,
                                       strategy=strategy, extras=extras)
        yhat = problem.y - result.residuals
        nlp = session.nlps.get(False)
        if nlp is not None and last and not last["band"]:
            sd = replace(last["stage_data"], s_x=session.state_scales(best.theta))
            ycoll = nlp.simulate_output(best.theta, sd)
            yex = yhat[session.shift:]
            extras.update(
                nlp_size=nlp.size,
                nlp_build_time_s=nlp.build_time_s,
                ipopt=_stats_summary(last["stats"]),
                ipopt_solve_time_s=last["solve_time_s"],
                collocation_cost=0.5 * float(np.sum((problem.y[session.shift:] - ycoll) ** 2)
                                             + np.sum(problem.y[: session.shift] ** 2)),
                discretisation_error=float(np.linalg.norm(ycoll - yex) / max(np.linalg.norm(yex), 1e-300)),
            )
        if last and not np.array_equal(last["theta"], best.theta):
            # the strategy keeps a search-stage result when the refinement did not lower the cost
            extras["note"] = "the refinement did not lower the cost; IPOPT figures describe the refinement"
        extras["local_solves"] = search_log + session.log
        extras["casadi_version"] = ca.__version__
        result.wall_time_s = time.perf_counter() - t0
        return result


def _check_supported(problem: FitProblem) -> None:
    if not getattr(problem.model, "has_state_space", True):
        raise EstimationError(
            "casadi_collocation: the model is defined by its frequency response only (no states to "
            "collocate); use solver scipy_lm or frequency_domain"
        )
    if problem.output_filter is not None:
        raise EstimationError(
            "casadi_collocation: a compensator with a model-side output filter (a spectral filter of the "
            "prediction) cannot enter the collocation NLP; use solver scipy_lm for this compensator"
        )
    if DELAY in problem.names and problem.free[problem.names.index(DELAY)]:
        raise EstimationError(
            "casadi_collocation: estimating a delay is not supported (its whole-sample part is not "
            "differentiable); fix nuisance.delay or use solver scipy_lm"
        )
    if problem.hold not in ("zoh", "foh"):
        raise EstimationError(f"casadi_collocation: unknown hold {problem.hold!r}")
