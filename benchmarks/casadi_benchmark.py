"""Benchmark of the ``casadi_collocation`` solver on the Table 3.1 case (issue 6 targets).

    python benchmarks/casadi_benchmark.py [--out benchmarks/results/casadi.json] [--skip-variants]

Data: the record of ``configs/table3_1_casadi.yaml`` (rho 1000, L 0.05 m, D 0.0254 m, n 10,
6200 samples at 6.25 MS/s, PRBS 2.5 us bits, Gaussian noise std 10 % of the noise-free RMS,
seed 1), acquired through the framework's own pipeline (simulated backend), 20 states.

1. **Convergence** from the two dissertation initial sets (+100/+150 % and -35/-50 %) and from
   (x0.1, x10, x10, x0.1), with the default options (global strategy + collocation NLP):
   estimate, error, |theta - theta_scipy| / theta_scipy (target <= 1e-3), wall time (target
   < 60 s), IPOPT iterations (final solve and all local solves), NLP size.
   The reference is ``scipy_lm`` with its default strategy from initial set 1.
2. **Local solve only** (``global_search: false``) from the same starts: where the
   simultaneous NLP alone ends when its states are warm-started from a simulation at the
   start (then its first step is the single-shooting Gauss-Newton step).
3. **Variants** from initial set 2 with ``global_search: false`` (a start inside the basin):
   samples_per_node 1 / 4 / auto / 64, Radau and trapezoidal schemes, exact and L-BFGS
   Hessians, and the textbook full formulation (every sample and collocation-point state an
   NLP variable) on the first 1500 samples (the record DESIGN.md section 3 reports a naive
   trapezoidal NLP taking 50-250 s and failing on). Each row: time, iterations, NLP size,
   difference from the exact ZOH model (discretisation error) and from scipy.
4. ``search_samples: 2000`` from the (x0.1, x10, x10, x0.1) start: the global search on the
   first 2000 samples, the final solve on the whole record.

Writes ``--out`` (JSON: settings, machine, rows) and prints one line per run.
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))  # this checkout's mbus_framework and plugins, whatever is installed
CONFIG = ROOT / "configs" / "table3_1_casadi.yaml"
DEFAULT_OUT = HERE / "results" / "casadi.json"
TRUTH = np.array([3.0e8, 15.0, 5.0e7, 12.0])
STARTS = {
    "set 1 (+100/+150 %)": np.array([2.0, 2.5, 2.0, 2.5]),
    "set 2 (-35/-50 %)": np.array([0.65, 0.5, 0.65, 0.5]),
    "(x0.1, x10, x10, x0.1)": np.array([0.1, 10.0, 10.0, 0.1]),
}
AGREEMENT_TARGET = 1e-3
TIME_TARGET_S = 60.0


def table_3_1_problem(tmp: Path):
    """The config's FitProblem (data acquired by the simulated backend) and its solver options."""
    from mbus_framework.pipeline.config import load_config
    from mbus_framework.pipeline.run import acquire, build_components, make_problem

    config = load_config(CONFIG)
    c = build_components(config, str(CONFIG))
    measurement = acquire(c, tmp, c.excitation.waveform())
    return make_problem(c, c.compensator.apply(measurement)), config.solver.options


def casadi_fit(problem, base: dict, **overrides):
    from mbus_plugins.solvers.casadi_collocation import CasadiCollocation, CasadiCollocationOptions

    opts = CasadiCollocationOptions.model_validate({**base, **overrides})
    t0 = time.perf_counter()
    fit = CasadiCollocation(opts).solve(problem)
    return fit, time.perf_counter() - t0


def summary(fit, wall: float, ref: np.ndarray, se: np.ndarray) -> dict:
    ex = fit.extras
    solves = ex.get("local_solves", [])
    rel_scipy = np.abs(fit.theta / ref - 1)
    return {
        "estimate": dict(zip(fit.names, map(float, fit.theta))),
        "error_percent": dict(zip(fit.names, map(float, 100 * (fit.theta / TRUTH - 1)))),
        "error_over_se": dict(zip(fit.names, map(float, np.abs(fit.theta - TRUTH) / se))),
        "relative_difference_from_scipy": dict(zip(fit.names, map(float, rel_scipy))),
        "max_relative_difference_from_scipy": float(rel_scipy.max()),
        "cost": float(fit.cost),
        "success": bool(fit.success),
        "message": fit.message,
        "wall_time_s": wall,
        "final_ipopt_iterations": int(fit.iterations),
        "local_solves": len(solves),
        "ipopt_iterations_all_solves": int(sum(s["iterations"] for s in solves)),
        "ipopt_time_all_solves_s": float(sum(s["wall_time_s"] for s in solves)),
        "nlp_size": ex.get("nlp_size"),
        "nlp_build_time_s": ex.get("nlp_build_time_s"),
        "discretisation_error": ex.get("discretisation_error"),
        "ipopt_final": {k: ex.get("ipopt", {}).get(k) for k in ("return_status", "iter_count", "n_call_nlp_f",
                                                               "n_call_nlp_jac_g", "n_call_nlp_hess_l")},
        "strategy_accepted_because": fit.strategy.get("accepted_because"),
        "strategy_starts_tried": len(fit.strategy.get("starts", [])),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    ap.add_argument("--skip-variants", action="store_true", help="only the convergence targets")
    args = ap.parse_args(argv)

    import casadi

    from mbus_framework.studies.common import machine_info
    from mbus_framework.estimation.uncertainty import from_jacobian
    from mbus_plugins.solvers.scipy_lm import ScipyLM, ScipyLMOptions

    load_before = machine_info()["load_average_1min"]
    with tempfile.TemporaryDirectory() as tmp:
        problem, base = table_3_1_problem(Path(tmp))
    base = dict(base)
    base["print_level"] = 0

    # reference: scipy_lm, default strategy, initial set 1
    problem.initial = TRUTH * STARTS["set 1 (+100/+150 %)"]
    t0 = time.perf_counter()
    ref_fit = ScipyLM(ScipyLMOptions()).solve(problem)
    scipy_time = time.perf_counter() - t0
    ref = ref_fit.theta
    se = from_jacobian(problem.names, ref_fit.jacobian, ref_fit.cost).standard_errors
    doc: dict = {
        "benchmark": "casadi_collocation",
        "command": "python benchmarks/casadi_benchmark.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "settings": {"config": str(CONFIG.relative_to(ROOT)), "n_samples": int(problem.y.size),
                     "states": 2 * problem.model.options.n_elements, "truth": dict(zip(problem.names, TRUTH)),
                     "solver_options": base, "casadi": casadi.__version__,
                     "targets": {"max_relative_difference_from_scipy": AGREEMENT_TARGET,
                                 "wall_time_s": TIME_TARGET_S}},
        "scipy_reference": {"estimate": dict(zip(problem.names, map(float, ref))), "cost": float(ref_fit.cost),
                            "wall_time_s": scipy_time,
                            "standard_errors": dict(zip(problem.names, map(float, se)))},
    }
    print(f"scipy_lm reference (set 1): {ref} in {scipy_time:.1f} s")

    conv = {}
    for name, factors in STARTS.items():
        problem.initial = TRUTH * factors
        fit, wall = casadi_fit(problem, base)
        row = summary(fit, wall, ref, se)
        row["initial"] = dict(zip(problem.names, map(float, TRUTH * factors)))
        row["passed"] = bool(row["max_relative_difference_from_scipy"] <= AGREEMENT_TARGET and wall < TIME_TARGET_S)
        conv[name] = row
        print(f"{name:<24} global: max |rel diff vs scipy| {row['max_relative_difference_from_scipy']:.2e}, "
              f"{wall:5.1f} s, final IPOPT iterations {row['final_ipopt_iterations']}, "
              f"{row['ipopt_iterations_all_solves']} in {row['local_solves']} local solves -> "
              f"{'PASS' if row['passed'] else 'FAIL'}")
    doc["convergence"] = conv

    local = {}
    for name, factors in STARTS.items():
        problem.initial = TRUTH * factors
        fit, wall = casadi_fit(problem, base, global_search=False)
        row = summary(fit, wall, ref, se)
        row["reached_scipy_minimum"] = bool(row["max_relative_difference_from_scipy"] <= AGREEMENT_TARGET)
        local[name] = row
        print(f"{name:<24} local only: {'reached' if row['reached_scipy_minimum'] else 'MISSED'} the minimum "
              f"(max rel diff {row['max_relative_difference_from_scipy']:.2e}), errors % "
              f"{np.round(list(row['error_percent'].values()), 2)}, {wall:.1f} s, {row['final_ipopt_iterations']} it")
    doc["local_only"] = local

    if not args.skip_variants:
        variants = {}
        problem.initial = TRUTH * STARTS["set 2 (-35/-50 %)"]
        cases = {
            "default (legendre 3, condensed, auto nodes, gauss-newton)": {},
            "samples_per_node 1": {"samples_per_node": 1},
            "samples_per_node 4": {"samples_per_node": 4},
            "samples_per_node 64": {"samples_per_node": 64},
            "radau 3": {"scheme": "radau"},
            "legendre 2": {"degree": 2},
            "trapezoidal": {"scheme": "trapezoidal"},
            "exact hessian": {"hessian": "exact"},
            "limited-memory hessian": {"hessian": "limited-memory"},
        }
        for name, over in cases.items():
            fit, wall = casadi_fit(problem, base, global_search=False, **over)
            variants[name] = summary(fit, wall, ref, se)
            print(f"variant {name:<58} {wall:6.1f} s, {fit.iterations:3d} it, "
                  f"{variants[name]['nlp_size']['variables']:7d} variables, disc. error "
                  f"{variants[name]['discretisation_error']:.1e}, vs scipy "
                  f"{variants[name]['max_relative_difference_from_scipy']:.1e}")
        # full formulation on the first 1500 samples, against scipy on the same window
        short = replace(problem, t=problem.t[:1500], u=problem.u[:1500], y=problem.y[:1500])
        short.initial = TRUTH * STARTS["set 2 (-35/-50 %)"]
        ref_short = ScipyLM(ScipyLMOptions()).solve(short).theta
        for name, over in {"full, legendre 3, 1500 samples": {"formulation": "full"},
                           "full, trapezoidal, 1500 samples": {"formulation": "full", "scheme": "trapezoidal"},
                           "condensed, legendre 3, 1500 samples": {}}.items():
            fit, wall = casadi_fit(short, base, global_search=False, **over)
            variants[name] = summary(fit, wall, ref_short, se)
            print(f"variant {name:<58} {wall:6.1f} s, {fit.iterations:3d} it, "
                  f"{variants[name]['nlp_size']['variables']:7d} variables, disc. error "
                  f"{variants[name]['discretisation_error']:.1e}, vs scipy (1500) "
                  f"{variants[name]['max_relative_difference_from_scipy']:.1e}")
        doc["variants_from_set_2_local"] = variants

        problem.initial = TRUTH * STARTS["(x0.1, x10, x10, x0.1)"]
        fit, wall = casadi_fit(problem, base, search_samples=2000)
        doc["search_on_2000_samples_from_x0.1_x10"] = summary(fit, wall, ref, se)
        print(f"search_samples 2000 from (x0.1, x10, x10, x0.1): max rel diff vs scipy "
              f"{doc['search_on_2000_samples_from_x0.1_x10']['max_relative_difference_from_scipy']:.1e}, {wall:.1f} s")

    doc["machine"] = {**machine_info(), "load_average_1min_before": load_before}
    doc["all_targets_passed"] = all(r["passed"] for r in conv.values())
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1, allow_nan=True) + "\n")
    print(f"targets: {'PASS' if doc['all_targets_passed'] else 'FAIL'}; written {args.out}")
    return 0 if doc["all_targets_passed"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
