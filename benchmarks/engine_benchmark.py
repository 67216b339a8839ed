"""Benchmark: the mbus simulation engine against the dissertation's method (Table 3.1 case).

Run on demand (not part of the test suite):

    python benchmarks/engine_benchmark.py [--quick] [--out benchmarks/results/engine.json]
                                          [--blas-threads N|default]

In one process and one run it times, for the Table 3.1 case (rho 1000 kg/m^3, L 0.05 m,
D 0.0254 m, n = 10, 6200 samples of a PRBS (order 9, bit 2.5 us) at 6.25 MS/s, truth
k_sigma 3e8 N/m, b_sigma 15 N s/m, k_tau 5e7 N/m, b_tau 12 N s/m):

(a) the engine: exact ZOH simulation (``mbus_framework.engine.simulation.simulate``) and exact
    sensitivities (``simulate_with_sensitivities``);
(b) the dissertation's method (``benchmarks/dissertation_method.py``): RK4 at the sample
    rate (eq. 3.22) with the input held over each step, and a 1 % forward-difference
    Jacobian (p = 4 extra RK4 runs, the base run reused);

and reports simulations/s, Jacobians/s, full identifications/s (the same Levenberg-
Marquardt iteration, eq. 3.25 with Marquardt's lambda update, from the dissertation's
second initial set -35 %, -50 %, -35 %, -50 %, on data with 10 % noise), the accuracy of each
against an exact reference, the speed-up ratios with the issue's targets as pass/fail, and a
table of engine cost for n in {5, 10, 20, 40} x N in {1k, 6k, 25k, 100k}. It also reports
the bias of each method (noise-free data) and how often plain LM from the second set lands
in the truth's basin over several noise draws (information, not a target).

Clocks: the two methods are timed round by round, interleaved, and medians are reported.
Ratios are of CPU time (``time.process_time``): on a shared machine the wall clock also
counts time spent waiting for a core while other processes run, which says nothing about
either method; wall-clock ratios are reported alongside. Both methods run on one BLAS
thread by default (``--blas-threads``, set before numpy loads), so neither gains from the
second core and the ratios compare algorithms.

"Exact" reference: the Van Loan exponential of the balanced system in 30-digit mpmath,
then the per-sample state recursion in 80-bit extended precision (numpy longdouble); for
the Jacobian the same on the 2n-state sensitivity system (``--quick``: the engine's
eigen-free doubling path instead).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path


def _blas_threads_from_argv(argv: list[str]) -> str:
    """--blas-threads must act before numpy loads its BLAS, so it is read here."""
    for i, a in enumerate(argv):
        if a == "--blas-threads" and i + 1 < len(argv):
            return argv[i + 1]
        if a.startswith("--blas-threads="):
            return a.split("=", 1)[1]
    return "1"


if __name__ == "__main__":
    _threads = _blas_threads_from_argv(sys.argv[1:])
    if _threads != "default":
        for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ[_var] = _threads

import numpy as np  # noqa: E402
import scipy  # noqa: E402
from scipy.linalg import matrix_balance  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

from dissertation_method import (  # noqa: E402
    EngineForwardDifference,
    ExactEngine,
    Rk4ForwardDifference,
    levenberg_marquardt,
)

from mbus_framework.engine import simulation as sim  # noqa: E402
from mbus_framework.interfaces.sample import Sample  # noqa: E402
from mbus_plugins.excitations.prbs import Prbs, PrbsOptions  # noqa: E402
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions  # noqa: E402

TRUTH = np.array([3.0e8, 15.0, 5.0e7, 12.0])  # k_sigma, b_sigma, k_tau, b_tau (Table 3.1)
SECOND_SET = np.array([0.65, 0.5, 0.65, 0.5])  # -35 %, -50 %, -35 %, -50 %
SAMPLE = Sample(length=0.05, diameter=0.0254, density=1000.0)
NOISE_FRACTION = 0.10  # std of Gaussian noise / RMS of the noise-free output
NOISE_SEED = 2009
TARGETS = {"simulation_speedup": 100.0, "jacobian_speedup": 50.0, "identification_speedup": 30.0}


# ---------------------------------------------------------------------------------------
# Machine and case
# ---------------------------------------------------------------------------------------
def machine_info() -> dict:
    cpu = platform.processor() or ""
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    blas = {}
    try:
        cfg = np.show_config(mode="dicts")
        blas = {k: cfg["Build Dependencies"][k].get("name") for k in ("blas", "lapack")}
    except Exception:  # pragma: no cover - older numpy
        pass
    return {
        "platform": platform.platform(),
        "cpu": cpu,
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "blas": blas,
        "thread_env": {k: os.environ.get(k) for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")},
        "load_average_start": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
    }


def kv(n: int) -> KelvinVoigtChain:
    return KelvinVoigtChain(SAMPLE, KelvinVoigtOptions(n_elements=n))


def prbs(n_samples: int):
    return Prbs(PrbsOptions(order=9, bit_width=2.5e-6, sample_rate=6.25e6, n_samples=n_samples)).waveform()


# ---------------------------------------------------------------------------------------
# Exact reference (independent of the engine's kernels)
# ---------------------------------------------------------------------------------------
def _mp_zoh_matrices(A: np.ndarray, B: np.ndarray, dt: float, dps: int = 30):
    """Phi, Gamma of a ZOH discretisation as longdouble arrays, via a 30-digit Van Loan expm.

    A is balanced first (exact power-of-two scaling) so the exponential is well scaled."""
    import mpmath as mp

    n = A.shape[0]
    Ab, (s, _) = matrix_balance(A, permute=False, separate=True)
    Bb = B[:, 0] / s
    with mp.workdps(dps):
        M = mp.zeros(n + 1, n + 1)
        for i in range(n):
            for j in range(n):
                if Ab[i, j] != 0.0:
                    M[i, j] = mp.mpf(Ab[i, j]) * mp.mpf(dt)
            M[i, n] = mp.mpf(Bb[i]) * mp.mpf(dt)
        E = mp.expm(M)
        to_ld = np.vectorize(lambda v: np.longdouble(mp.nstr(v, 25, strip_zeros=False)))
        Phi = to_ld(np.array(E[:n, :n].tolist(), dtype=object))
        Gam = to_ld(np.array(E[:n, n].tolist(), dtype=object)).reshape(-1)
    return Phi.astype(np.longdouble), Gam.astype(np.longdouble), s


def _ld_recursion(Phi, Gam, c, d, u) -> np.ndarray:
    x = np.zeros(Phi.shape[0], dtype=np.longdouble)
    y = np.empty(u.size, dtype=np.longdouble)
    uu = u.astype(np.longdouble)
    for k in range(u.size):
        y[k] = c @ x + d * uu[k]
        x = Phi @ x + Gam * uu[k]
    return y.astype(float)


def exact_reference(model, theta, u, dt, jacobian: bool):
    """y (N,) and, if asked, dy/dtheta (N, p) from mpmath discretisation + longdouble recursion."""
    A, B, C, D = sim.as_float_ss(model.state_space(theta))
    Phi, Gam, s = _mp_zoh_matrices(A, B, dt)
    c = (C[0] * s).astype(np.longdouble)
    y = _ld_recursion(Phi, Gam, c, np.longdouble(D[0, 0]), u)
    if not jacobian:
        return y, None
    n = A.shape[0]
    cols = []
    for d in sim.state_space_derivatives(model, theta):
        Aa = np.block([[A, np.zeros((n, n))], [d.A, A]])
        Ba = np.vstack([B, d.B])
        Ca = np.hstack([d.C, C])
        Phi_a, Gam_a, s_a = _mp_zoh_matrices(Aa, Ba, dt)
        cols.append(_ld_recursion(Phi_a, Gam_a, (Ca[0] * s_a).astype(np.longdouble), np.longdouble(d.D[0, 0]), u))
    return y, np.stack(cols, axis=1)


def rel_err(a, ref) -> float:
    return float(np.max(np.abs(np.asarray(a) - ref)) / np.max(np.abs(ref)))


def col_rel_err(a, ref) -> float:
    return max(rel_err(a[:, i], ref[:, i]) for i in range(ref.shape[1]))


# ---------------------------------------------------------------------------------------
# Timing helpers
# ---------------------------------------------------------------------------------------
def _per_call(fn, calls: int) -> tuple[float, float]:
    """(wall, CPU) seconds per call of ``fn`` over ``calls`` calls."""
    c0, t0 = time.process_time(), time.perf_counter()
    for _ in range(calls):
        fn()
    return (time.perf_counter() - t0) / calls, (time.process_time() - c0) / calls


def interleaved(slow, fast, rounds: int, fast_calls: int) -> dict:
    """Time ``slow`` once and ``fast`` ``fast_calls`` times per round; medians over rounds.

    Both wall-clock and CPU time (``time.process_time``) are recorded. On a shared machine
    the wall clock also counts the time the process waited for a core while other processes
    ran; CPU time does not, so the CPU-time ratio is the one the targets are judged on. With
    one BLAS thread (the default here) the two agree on an idle machine.
    """
    fast()  # warm caches (input spectrum, imports)
    ws, cs, wf, cf = [], [], [], []
    for _ in range(rounds):
        w, c = _per_call(slow, 1)
        ws.append(w)
        cs.append(c)
        w, c = _per_call(fast, fast_calls)
        wf.append(w)
        cf.append(c)
    return {
        "dissertation_s": statistics.median(cs),
        "engine_s": statistics.median(cf),
        "speedup": statistics.median(a / b for a, b in zip(cs, cf)),
        "dissertation_wall_s": statistics.median(ws),
        "engine_wall_s": statistics.median(wf),
        "speedup_wall": statistics.median(a / b for a, b in zip(ws, wf)),
        "rounds": rounds,
        "clock": "CPU time (process_time); *_wall_* = wall clock",
    }


def timed_lm(fm, y, theta0):
    """levenberg_marquardt with its CPU time attached (``cpu_time_s``)."""
    c0 = time.process_time()
    res = levenberg_marquardt(fm, y, theta0)
    res.cpu_time_s = time.process_time() - c0
    return res


# ---------------------------------------------------------------------------------------
# Sections
# ---------------------------------------------------------------------------------------
def table_3_1_simulation_and_jacobian(quick: bool) -> dict:
    model = kv(10)
    w = prbs(6200)
    u, dt = w.u, w.dt
    engine = ExactEngine(model, u, dt)
    diss = Rk4ForwardDifference(model, u, dt)
    out: dict = {"n_elements": 10, "n_samples": int(u.size), "sample_rate_hz": 1 / dt}
    ss = model.state_space(TRUTH)
    out["engine_path"] = {
        "simulation": sim.engine_path(ss, dt, False, u),
        "sensitivities": sim.engine_path(ss, dt, True, u, derivatives=sim.state_space_derivatives(model, TRUTH)),
    }

    # --- accuracy against the exact reference
    t0 = time.perf_counter()
    y_ref, J_ref = exact_reference(model, TRUTH, u, dt, jacobian=not quick)
    ref_time = time.perf_counter() - t0
    y_eng = engine.simulate(TRUTH)
    y_rk4 = diss.simulate(TRUTH)
    _, J_eng = sim.simulate_with_sensitivities(model, TRUTH, u, dt)
    J_fd = diss.jacobian(TRUTH, y_rk4)
    if J_ref is None:  # quick: the eigen-free doubling path stands in for the exact Jacobian
        J_ref = sim.simulate_with_sensitivities(model, TRUTH, u, dt, method="doubling")[1]
        jac_ref_name = "engine doubling path (Van Loan + repeated doubling)"
    else:
        jac_ref_name = "30-digit Van Loan of the sensitivity system + extended-precision recursion"
    out["accuracy"] = {
        "reference": "30-digit Van Loan expm + 80-bit per-sample recursion (ZOH)",
        "jacobian_reference": jac_ref_name,
        "reference_time_s": ref_time,
        "engine_simulation_rel_error": rel_err(y_eng, y_ref),
        "dissertation_simulation_rel_error": rel_err(y_rk4, y_ref),
        "engine_jacobian_rel_error": col_rel_err(J_eng, J_ref),
        "dissertation_jacobian_rel_error": col_rel_err(J_fd, J_ref),
        "measure": "max_k |y[k] - y_ref[k]| / max_k |y_ref[k]| (per Jacobian column, worst column)",
    }

    # --- speed
    rounds = 3 if quick else 7
    sim_t = interleaved(lambda: diss.simulate(TRUTH), lambda: engine.simulate(TRUTH), rounds, 40)
    jac_t = interleaved(
        lambda: diss.jacobian(TRUTH, y_rk4),
        lambda: sim.simulate_with_sensitivities(model, TRUTH, u, dt),
        max(2, rounds // 2),
        20,
    )
    out["simulation"] = {
        **sim_t,
        "engine_per_s": 1 / sim_t["engine_s"],
        "dissertation_per_s": 1 / sim_t["dissertation_s"],
    }
    out["jacobian"] = {
        **jac_t,
        "engine_per_s": 1 / jac_t["engine_s"],
        "dissertation_per_s": 1 / jac_t["dissertation_s"],
        "engine_definition": "simulate_with_sensitivities: y and the exact 4-column Jacobian",
        "dissertation_definition": "4 RK4 runs at +1 % per parameter (base run y(theta) given)",
    }
    return out


def _noisy_data(model, u, dt, noise: float, seed: int = NOISE_SEED):
    y0 = sim.simulate(model, TRUTH, u, dt)
    rng = np.random.default_rng(seed)
    return y0 + noise * np.sqrt(np.mean(y0**2)) * rng.standard_normal(y0.size)


def _lm_summary(res, model, u, dt, y_meas) -> dict:
    r_exact = y_meas - sim.simulate(model, res.theta, u, dt)
    return {
        "theta": res.theta.tolist(),
        "relative_error_percent": (100 * (res.theta / TRUTH - 1)).tolist(),
        "max_abs_relative_error_percent": float(np.max(np.abs(100 * (res.theta / TRUTH - 1)))),
        "cost_exact_model": 0.5 * float(r_exact @ r_exact),
        "iterations": res.iterations,
        "simulations": res.n_simulations,
        "jacobians": res.n_jacobians,
        "converged": res.converged,
        "message": res.message,
        "wall_time_s": res.wall_time_s,
    }


def _recovered(theta) -> bool:
    """Landed in the truth's basin (every parameter within 5 %), not in a far local minimum."""
    return bool(np.max(np.abs(np.asarray(theta) / TRUTH - 1)) < 0.05)


def identification(quick: bool) -> dict:
    """Table 3.1 identification: speed and accuracy, bias, and robustness over noise draws.

    * ``table_3_1``: data with 10 % noise (seed ``NOISE_SEED``), both methods from the second
      initial set with the same LM; wall time end to end (engine: median of 10 runs, before
      and after the slow run). Accuracy: the cost of each estimate under the exact model (the
      engine's estimate is the exact least-squares solution, so it cannot fit worse) and the
      parameter errors, also in Cramer-Rao standard errors.
    * ``bias``: noise-free data, LM started at each method's own Table 3.1 estimate: what is
      left is the method's own error (RK4 truncation and stopping), not noise.
    * ``robustness``: from the second set over several noise draws. Plain LM on this lightly
      damped chain is a lottery (DESIGN.md section 3): some draws send it to a far local
      region, for either Jacobian. Reported, not a target.
    """
    model = kv(10)
    w = prbs(6200)
    u, dt = w.u, w.dt
    theta0 = TRUTH * SECOND_SET
    out: dict = {
        "initial": theta0.tolist(),
        "noise": f"Gaussian, std = {NOISE_FRACTION:.0%} of the RMS noise-free output, seed {NOISE_SEED}",
        "lm": "eq. 3.25 in parameters normalised by the initial values, Marquardt lambda update (x10 / /10)",
    }
    engine, diss = ExactEngine(model, u, dt), Rk4ForwardDifference(model, u, dt)

    # --- Table 3.1 (10 % noise) from the second initial set
    y_meas = _noisy_data(model, u, dt, NOISE_FRACTION)
    eng_runs = [timed_lm(engine, y_meas, theta0) for _ in range(3 if quick else 5)]
    d_res = timed_lm(diss, y_meas, theta0)
    eng_runs += [timed_lm(engine, y_meas, theta0) for _ in range(2 if quick else 5)]
    e_time = statistics.median(r.cpu_time_s for r in eng_runs)
    e_res = eng_runs[0]
    e_sum = _lm_summary(e_res, model, u, dt, y_meas)
    e_sum["cpu_time_s"] = e_time
    e_sum["wall_time_s"] = statistics.median(r.wall_time_s for r in eng_runs)
    d_sum = _lm_summary(d_res, model, u, dt, y_meas)
    d_sum["cpu_time_s"] = d_res.cpu_time_s
    _, J = sim.simulate_with_sensitivities(model, e_res.theta, u, dt)
    sigma2 = 2 * e_sum["cost_exact_model"] / (u.size - TRUTH.size)
    se = np.sqrt(np.diag(np.linalg.inv(J.T @ J)) * sigma2) / TRUTH * 100
    t31 = {
        "engine": e_sum,
        "dissertation": d_sum,
        "engine_per_s": 1 / e_time,
        "dissertation_per_s": 1 / d_res.cpu_time_s,
        "speedup": d_res.cpu_time_s / e_time,
        "speedup_wall": d_res.wall_time_s / e_sum["wall_time_s"],
        "clock": "CPU time (process_time); wall_time_s = wall clock",
        "cramer_rao_se_percent": se.tolist(),
        "engine_error_in_se": (np.array(e_sum["relative_error_percent"]) / se).tolist(),
        "dissertation_error_in_se": (np.array(d_sum["relative_error_percent"]) / se).tolist(),
        "both_recovered": _recovered(e_res.theta) and _recovered(d_res.theta),
    }
    out["table_3_1"] = t31
    out["speedup"] = t31["speedup"]

    # --- method bias: noise-free data, started at each method's own estimate
    y_clean = _noisy_data(model, u, dt, 0.0)
    b_eng = levenberg_marquardt(engine, y_clean, e_res.theta)
    b_diss = levenberg_marquardt(diss, y_clean, d_res.theta)
    bias = {
        "engine": _lm_summary(b_eng, model, u, dt, y_clean),
        "dissertation": _lm_summary(b_diss, model, u, dt, y_clean),
    }
    out["bias"] = bias

    # --- robustness over noise draws (same draws for both methods)
    seeds = list(range(3 if quick else 20))
    diss_seeds = [] if quick else seeds[:3]
    rob = {"seeds": seeds, "engine": [], "engine_fd_jacobian": [], "dissertation": []}
    eng_fd = EngineForwardDifference(model, u, dt)
    for sd in seeds:
        y_sd = _noisy_data(model, u, dt, NOISE_FRACTION, seed=sd)
        for key, fm in (("engine", engine), ("engine_fd_jacobian", eng_fd)):
            r = levenberg_marquardt(fm, y_sd, theta0)
            rob[key].append({"seed": sd, "recovered": _recovered(r.theta), "iterations": r.iterations,
                             "max_abs_relative_error_percent": float(np.max(np.abs(100 * (r.theta / TRUTH - 1))))})
        if sd in diss_seeds:
            r = levenberg_marquardt(diss, y_sd, theta0)
            rob["dissertation"].append({"seed": sd, "recovered": _recovered(r.theta), "iterations": r.iterations,
                                        "wall_time_s": r.wall_time_s,
                                        "max_abs_relative_error_percent": float(np.max(np.abs(100 * (r.theta / TRUTH - 1))))})
    rob["engine_recovered"] = f"{sum(x['recovered'] for x in rob['engine'])}/{len(seeds)}"
    rob["engine_fd_jacobian_recovered"] = f"{sum(x['recovered'] for x in rob['engine_fd_jacobian'])}/{len(seeds)}"
    rob["engine_recovered_on_dissertation_seeds"] = (
        f"{sum(x['recovered'] for x in rob['engine'] if x['seed'] in diss_seeds)}/{len(diss_seeds)}"
    )
    rob["note"] = (
        "recovered = every parameter within 5 % of the truth. Plain LM from the second set is "
        "sensitive to Jacobian details on this multimodal cost: the same engine simulation with a "
        "1 % forward-difference Jacobian lands in the truth's basin more often than with the exact "
        "Jacobian; neither is a global strategy (DESIGN.md section 3)."
    )
    rob["dissertation_recovered"] = f"{sum(x['recovered'] for x in rob['dissertation'])}/{len(diss_seeds)}"
    out["robustness"] = rob

    acc = {
        "both_recovered_table_3_1": t31["both_recovered"],
        "fit_cost_engine_le_dissertation": e_sum["cost_exact_model"] <= d_sum["cost_exact_model"] * (1 + 1e-12),
        "bias_engine_le_dissertation": bias["engine"]["max_abs_relative_error_percent"]
        <= bias["dissertation"]["max_abs_relative_error_percent"],
    }
    out["accuracy_equal_or_better"] = all(acc.values())
    out["accuracy_checks"] = acc
    return out


def scaling_table(quick: bool) -> dict:
    """Engine cost for n x N, material fixed at the Table 3.1 properties (k, b scale with n)."""
    props = kv(10).to_properties(TRUTH)
    ns, Ns = (5, 10, 20, 40), (1000, 6000, 25000, 100000)
    rows = []
    for n in ns:
        model = kv(n)
        theta = model.from_properties(props)
        ss = model.state_space(theta)
        for N in Ns:
            w = prbs(N)
            u, dt = w.u, w.dt
            reps = min(10 if quick else 30, max(3, int(2e5 // N)))
            sim.simulate(model, theta, u, dt)
            t_sim = statistics.median(_per_call(lambda: sim.simulate(model, theta, u, dt), 1)[1] for _ in range(reps))
            sim.simulate_with_sensitivities(model, theta, u, dt)
            t_jac = statistics.median(
                _per_call(lambda: sim.simulate_with_sensitivities(model, theta, u, dt), 1)[1]
                for _ in range(max(2, reps // 2))
            )
            rows.append(
                {
                    "n_elements": n,
                    "n_samples": N,
                    "simulation_ms": 1e3 * t_sim,
                    "jacobian_ms": 1e3 * t_jac,
                    "path": sim.engine_path(ss, dt, False, u)
                    + "/"
                    + sim.engine_path(ss, dt, True, u, derivatives=sim.state_space_derivatives(model, theta)),
                }
            )

    def slope(xs, ys):
        return float(np.polyfit(np.log(xs), np.log(ys), 1)[0])

    exps_N = {}
    exps_n = {}
    for key in ("simulation_ms", "jacobian_ms"):
        exps_N[key] = max(slope(Ns, [r[key] for r in rows if r["n_elements"] == n]) for n in ns)
        exps_n[key] = max(slope(ns, [r[key] for r in rows if r["n_samples"] == N]) for N in Ns)
    return {
        "rows": rows,
        "material": "Table 3.1 properties held fixed; theta = from_properties for each n",
        "max_exponent_in_N": exps_N,
        "max_exponent_in_n": exps_n,
        "linear_in_N": all(v <= 1.2 for v in exps_N.values()),
        "at_most_quadratic_in_n": all(v <= 2.0 for v in exps_n.values()),
        "exponent_definition": "least-squares slope of log(time) on log(N) (per n) or log(n) (per N); worst case",
        "clock": "CPU time (process_time), median of repeats",
    }


# ---------------------------------------------------------------------------------------
# Main
# ---------------------------------------------------------------------------------------
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer repeats, no noise-free identification")
    ap.add_argument("--out", default=str(HERE / "results" / "engine.json"), help="JSON output path")
    ap.add_argument(
        "--blas-threads",
        default="1",
        help="BLAS/OpenMP threads for both methods (default 1: every method on one core, so the "
        "ratios compare algorithms; 'default' leaves the environment alone)",
    )
    args = ap.parse_args(argv)
    t_start = time.perf_counter()
    result: dict = {"benchmark": "mbus engine vs dissertation method", "quick": args.quick, "machine": machine_info()}
    print(f"machine: {result['machine']['cpu']} x{result['machine']['cpu_count']}, "
          f"numpy {np.__version__}, scipy {scipy.__version__}, load {result['machine']['load_average_start']}")

    print("\n[1/3] Table 3.1 case: accuracy, simulation and Jacobian speed ...", flush=True)
    t31 = table_3_1_simulation_and_jacobian(args.quick)
    result["table_3_1"] = t31
    a = t31["accuracy"]
    print(f"  engine path: {t31['engine_path']}")
    print(f"  simulation error vs exact: engine {a['engine_simulation_rel_error']:.1e}, "
          f"RK4 {a['dissertation_simulation_rel_error']:.1e}")
    print(f"  Jacobian error vs exact:   engine {a['engine_jacobian_rel_error']:.1e}, "
          f"1% FD on RK4 {a['dissertation_jacobian_rel_error']:.1e}")
    s, j = t31["simulation"], t31["jacobian"]
    print("  (CPU time per call; wall-clock ratio in brackets)")
    print(f"  simulation: engine {1e3 * s['engine_s']:.3f} ms ({s['engine_per_s']:.0f}/s), "
          f"RK4 {1e3 * s['dissertation_s']:.1f} ms ({s['dissertation_per_s']:.1f}/s) -> {s['speedup']:.0f}x "
          f"({s['speedup_wall']:.0f}x)")
    print(f"  Jacobian:   engine {1e3 * j['engine_s']:.3f} ms ({j['engine_per_s']:.0f}/s), "
          f"FD-RK4 {1e3 * j['dissertation_s']:.1f} ms ({j['dissertation_per_s']:.2f}/s) -> {j['speedup']:.0f}x "
          f"({j['speedup_wall']:.0f}x)")

    print("\n[2/3] Table 3.1 identification from the second initial set ...", flush=True)
    ident = identification(args.quick)
    result["identification"] = ident
    r = ident["table_3_1"]
    print(f"  10 % noise: engine {r['engine']['cpu_time_s']:.3f} s ({r['engine']['iterations']} it), "
          f"dissertation {r['dissertation']['cpu_time_s']:.2f} s ({r['dissertation']['iterations']} it) "
          f"-> {r['speedup']:.0f}x (wall clock {r['speedup_wall']:.0f}x)")
    for who in ("engine", "dissertation"):
        errs = ", ".join(f"{e:+.4f}" for e in r[who]["relative_error_percent"])
        print(f"    {who:12s} error % [{errs}]  cost(exact model) {r[who]['cost_exact_model']:.8g}")
    print("    Cramer-Rao SE % [" + ", ".join(f"{v:.4f}" for v in r["cramer_rao_se_percent"]) + "]")
    b = ident["bias"]
    print(f"  bias (noise-free data, from own estimate): engine {b['engine']['max_abs_relative_error_percent']:.1e} %, "
          f"dissertation {b['dissertation']['max_abs_relative_error_percent']:.1e} %")
    rob = ident["robustness"]
    print(f"  robustness from set 2 over noise draws (in truth's basin): engine (exact J) {rob['engine_recovered']}, "
          f"engine with 1% FD J {rob['engine_fd_jacobian_recovered']}, dissertation {rob['dissertation_recovered']} "
          f"(engine on those draws {rob['engine_recovered_on_dissertation_seeds']})")

    print("\n[3/3] engine cost table (CPU ms: simulation / simulation + Jacobian) ...", flush=True)
    sc = scaling_table(args.quick)
    result["scaling"] = sc
    Ns = sorted({r["n_samples"] for r in sc["rows"]})
    print("  n \\ N " + "".join(f"{N:>20d}" for N in Ns))
    for n in sorted({r["n_elements"] for r in sc["rows"]}):
        cells = [r for r in sc["rows"] if r["n_elements"] == n]
        print(f"  {n:5d} " + "".join(f"{c['simulation_ms']:>9.2f} / {c['jacobian_ms']:>7.2f}" for c in cells))
    print(f"  worst exponent in N: {sc['max_exponent_in_N']}, in n: {sc['max_exponent_in_n']}")

    checks = {
        "simulation >= 100x faster than RK4": s["speedup"] >= TARGETS["simulation_speedup"],
        "simulation exact to 1e-9 (RK4 ~1e-5)": a["engine_simulation_rel_error"] <= 1e-9,
        "Jacobian >= 50x faster than 1% FD on RK4": j["speedup"] >= TARGETS["jacobian_speedup"],
        "identification >= 30x faster end to end": ident["speedup"] >= TARGETS["identification_speedup"],
        "identification accuracy equal or better": ident["accuracy_equal_or_better"],
        "cost linear in N": sc["linear_in_N"],
        "cost at most quadratic in n": sc["at_most_quadratic_in_n"],
    }
    result["targets"] = {k: {"pass": bool(v)} for k, v in checks.items()}
    result["targets_values"] = {
        "simulation_speedup": s["speedup"],
        "jacobian_speedup": j["speedup"],
        "identification_speedup": ident["speedup"],
        "simulation_speedup_wall": s["speedup_wall"],
        "jacobian_speedup_wall": j["speedup_wall"],
        "identification_speedup_wall": ident["table_3_1"]["speedup_wall"],
        "clock": "CPU time (process_time); *_wall = wall clock",
    }
    result["machine"]["load_average_end"] = list(os.getloadavg()) if hasattr(os, "getloadavg") else None
    result["total_time_s"] = time.perf_counter() - t_start
    print("\nTargets:")
    for k, v in checks.items():
        print(f"  [{'PASS' if v else 'FAIL'}] {k}")

    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2, default=float) + "\n")
    print(f"\nwrote {out} ({result['total_time_s']:.0f} s)")
    return 0 if all(checks.values()) else 1


if __name__ == "__main__":
    raise SystemExit(main())
