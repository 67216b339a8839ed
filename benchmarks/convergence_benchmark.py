"""Global-convergence benchmark of the ``scipy_lm`` solver (issue 4, first target).

    python benchmarks/convergence_benchmark.py [--n-cases 200] [--seed 0] [--workers 2]
                                               [--out benchmarks/results/convergence.json]

Each case is a simulated Table-3.1-style identification of a Kelvin-Voigt chain (n = 10
elements, D = 25.4 mm, the dissertation's transducers) whose true material properties are
drawn log-uniformly from one of five boxes that cover the dissertation's tables, converted to
model parameters for that table's geometry (eqs. 3.32, 3.36-3.38):

=====================  ======  ============  =========================================
group                  L [m]   rho [kg/m^3]  E_sigma, eta_sigma, E_tau, eta_tau
=====================  ======  ============  =========================================
table3_1               0.05    1000          Table 3.1 truth x/÷ 2 (2.96e9, 148, 6.27e8, 150)
liquids (Table 4.2)    0.05    998-1307      Table 4.2 min..max, widened x/÷ 1.25
tissues (Table 4.3)    0.05    920-1070      Table 4.3 min..max, widened x/÷ 1.25
potato_compensated     0.03    1080          Table 6.2 "MBUS after compensation" min..max
potato_uncompensated   0.03    1080          Table 6.2 "MBUS before compensation" min..max
=====================  ======  ============  =========================================

The liquids and tissues were measured 5 cm apart (Section 4.2.1), the potato slices were
3 cm thick (Section 6.2.1). The "conventionally measured" rows of Table 6.2 are not covered:
they come from 1 Hz compression and 0.1-100 rad/s rheometry, not from the ultrasound model
(as chain parameters they would be media with a 30-70 m/s sound speed). The groups take
turns, so 200 cases are 40 per group. Each property is drawn independently in its box.

Record ("Table 3.1-like, adapted so the excitation covers the medium's band"): the band
f99 of the true medium is the frequency below which 99 % of its white-input output power
lies (|G(j 2 pi f)|^2 integrated over f). Table 3.1 plays a PRBS whose -3 dB bandwidth,
0.443 / 2.5 us = 177 kHz, is 1.715 f99 of its medium (103 kHz), sampled with 15.625 samples per bit
(6.25 MS/s), 6200 samples, order 9. Every case keeps those ratios: bit width
T_b = 0.443 / (1.715 f99), sample rate 15.625 / T_b, 6200 samples, so the Table 3.1 truth
gets exactly the Table 3.1 record. Noise: Gaussian, std 10 % of the RMS of the noise-free
output (Table 3.1 "noise 10 %", as the simulated backend reads it).

Start: initial values drawn log-uniformly in [0.2, 5] x truth per parameter; the solver is
``scipy_lm`` with its default (full) strategy, called directly on a ``FitProblem``.

Counted per case:

* ``within_3se``: every parameter ends within 3 of the run's own standard errors
  (s^2 (J^T J)^-1 with the residual variance, as in result.json) of the truth;
* ``within_3se_untruncated``: the same with the run's covariance computed without the
  pseudo-inverse cut-off of ``uncertainty.from_jacobian`` (``pinv(J^T J)`` silently drops a
  direction whose singular-value ratio is below ~3e-8 and then reports a small standard error
  for a parameter that is not identifiable at all, e.g. the overall scale of an inertia-free,
  overdamped medium);
* ``global_minimum``: the final cost is not above the cost at the truth (relative slack
  1e-9): the estimator found a minimum at least as deep as the true parameters' (the global
  minimum, up to noise);
* the Cramer-Rao standard errors at the truth (sigma^2 (J^T J)^-1, known sigma, of ln theta by
  an SVD without truncation), to tell well-identified cases from practically unidentifiable
  ones (largest relative CRB > 0.5).

Writes ``--out`` (JSON: settings, machine, summary, every case) and prints the summary line
``N/200 within 3 SE (xx.x %)``. Target: >= 95 %.
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one BLAS thread per worker: at most 2 cores in all

import argparse  # noqa: E402
import json  # noqa: E402
import multiprocessing as mp  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE / "results" / "convergence.json"

N_ELEMENTS = 10
DIAMETER = 0.0254
NOISE = 0.10
N_SAMPLES = 6200
ORDER = 9
SAMPLES_PER_BIT = 6.25e6 * 2.5e-6  # Table 3.1: 15.625
INIT_LOW, INIT_HIGH = 0.2, 5.0
PROPS = ("E_sigma", "eta_sigma", "E_tau", "eta_tau")
T31 = {"E_sigma": 2.960287862e9, "eta_sigma": 148.0143931, "E_tau": 6.265942641e8, "eta_tau": 150.3826234}

#: group -> (length [m], density range [kg/m^3], {property: (low, high)})
GROUPS: dict[str, tuple[float, tuple[float, float], dict[str, tuple[float, float]]]] = {
    "table3_1": (0.05, (1000.0, 1000.0), {p: (v / 2.0, v * 2.0) for p, v in T31.items()}),
    "liquids": (0.05, (998.0, 1307.0), {
        "E_sigma": (3.22e12 / 1.25, 4.60e12 * 1.25), "eta_sigma": (3.07e5 / 1.25, 7.24e5 * 1.25),
        "E_tau": (2.11e12 / 1.25, 3.11e12 * 1.25), "eta_tau": (5.18e5 / 1.25, 7.21e5 * 1.25)}),
    "tissues": (0.05, (919.6, 1070.0), {
        "E_sigma": (1.37e12 / 1.25, 2.92e12 * 1.25), "eta_sigma": (1.92e5 / 1.25, 5.26e5 * 1.25),
        "E_tau": (2.03e12 / 1.25, 3.05e12 * 1.25), "eta_tau": (4.56e5 / 1.25, 6.14e5 * 1.25)}),
    "potato_compensated": (0.03, (1080.0, 1080.0), {
        "E_sigma": (4.84e9, 7.41e10), "eta_sigma": (4.87e2, 3.83e4),
        "E_tau": (1.30e9, 2.26e10), "eta_tau": (5.14e3, 1.07e5)}),
    "potato_uncompensated": (0.03, (1080.0, 1080.0), {
        "E_sigma": (7.39e9, 3.84e11), "eta_sigma": (1.56e4, 2.90e6),
        "E_tau": (1.94e10, 3.12e11), "eta_tau": (3.63e7, 5.06e8)}),
}


# ---------------------------------------------------------------------------------------
def make_model(length: float, density: float):
    from mbus_framework.interfaces.sample import Sample
    from plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions

    return KelvinVoigtChain(Sample(length, DIAMETER, density), KelvinVoigtOptions(n_elements=N_ELEMENTS))


def medium_band(model, theta: np.ndarray, fraction: float = 0.99) -> float:
    """f99 [Hz]: 99 % of the white-input output power int |G(j 2 pi f)|^2 df lies below it."""
    A, B, C, D = (np.asarray(x, float) for x in model.state_space(theta))
    lam, V = np.linalg.eig(A)
    b = np.linalg.solve(V, B).ravel()
    c = (C @ V).ravel()
    res = c * b  # G(s) = sum r_i / (s - lambda_i) + D
    f = np.logspace(0, 10, 6000)
    s = 2j * np.pi * f
    G = (res[None, :] / (s[:, None] - lam[None, :])).sum(axis=1) + D.item()
    P = np.abs(G) ** 2
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (P[1:] + P[:-1]) * np.diff(f))])
    return float(f[min(np.searchsorted(cum, fraction * cum[-1]), f.size - 1)])


def log_crb(J: np.ndarray, theta: np.ndarray, sigma: float) -> tuple[np.ndarray, float]:
    """Cramer-Rao standard errors of ln(theta) (~ relative SEs) by SVD, without truncation.

    Returns (SE of each ln theta_i, smallest / largest singular value of the column-scaled
    log-parameter Jacobian). A flat direction (ratio ~ 1e-9: e.g. the overall scale of a
    quasi-static, inertia-free medium) gives a huge SE instead of being dropped, as a
    pseudo-inverse of J^T J with the default cut-off would do.
    """
    Jl = J * theta
    norms = np.linalg.norm(Jl, axis=0)
    norms[norms == 0] = 1.0
    _, sv, Vt = np.linalg.svd(Jl / norms, full_matrices=False)
    with np.errstate(divide="ignore"):
        var = (sigma**2) * np.sum((Vt / np.where(sv > 0, sv, 0.0)[:, None]) ** 2, axis=0) / norms**2
    return np.sqrt(var), float(sv[-1] / sv[0]) if sv[0] > 0 else 0.0


_BAND_RATIO: list[float] = []


def band_ratio() -> float:
    """PRBS -3 dB bandwidth / medium f99 of Table 3.1 (0.443 / 2.5 us over f99 of its truth)."""
    if not _BAND_RATIO:
        model = make_model(0.05, 1000.0)
        _BAND_RATIO.append((0.443 / 2.5e-6) / medium_band(model, np.array([3.0e8, 15.0, 5.0e7, 12.0])))
    return _BAND_RATIO[0]


def draw_case(seed: int, index: int, groups: tuple[str, ...] = tuple(GROUPS)) -> dict:
    """The case ``index`` of benchmark ``seed`` (independent of the worker that runs it)."""
    rng = np.random.default_rng([seed, index])
    group = groups[index % len(groups)]
    length, (rho_lo, rho_hi), box = GROUPS[group]
    density = float(np.exp(rng.uniform(np.log(rho_lo), np.log(rho_hi))))
    props = {p: float(np.exp(rng.uniform(np.log(box[p][0]), np.log(box[p][1])))) for p in PROPS}
    factors = np.exp(rng.uniform(np.log(INIT_LOW), np.log(INIT_HIGH), len(PROPS)))
    noise_seed = int(rng.integers(2**31))
    return {"index": index, "group": group, "length": length, "density": density, "properties": props,
            "initial_factors": factors.tolist(), "noise_seed": noise_seed}


def run_case(args: tuple) -> dict:
    seed, index = args[0], args[1]
    groups = tuple(args[2]) if len(args) > 2 else tuple(GROUPS)
    from mbus_framework.interfaces.registry import default_registry
    from mbus_framework.engine.simulation import simulate
    from mbus_framework.estimation.problem import FitProblem
    from mbus_framework.estimation.uncertainty import from_jacobian
    from plugins.excitations.prbs import Prbs, PrbsOptions

    case = draw_case(seed, index, groups)
    model = make_model(case["length"], case["density"])
    names = model.parameter_names
    theta = np.asarray(model.from_properties(case["properties"]), float)
    f99 = medium_band(model, theta)
    bit_width = 0.443 / (band_ratio() * f99)
    rate = SAMPLES_PER_BIT / bit_width
    wave = Prbs(PrbsOptions(order=ORDER, bit_width=bit_width, amplitude=1.0, sample_rate=rate,
                            n_samples=N_SAMPLES)).waveform()
    t, u = wave.t, wave.u
    dt = float(t[1] - t[0])
    y_true = simulate(model, theta, u, dt)
    sigma = NOISE * float(np.sqrt(np.mean(y_true**2)))
    y = y_true + np.random.default_rng(case["noise_seed"]).normal(0.0, sigma, y_true.shape)
    initial = theta * np.asarray(case["initial_factors"])

    spec = default_registry().get("solver", "scipy_lm")
    solver = spec.implementation(spec.implementation.Options())
    problem = FitProblem(model=model, t=t, u=u, y=y, initial=initial)
    yhat0, J0 = problem.predict_with_jacobian(theta)
    r0 = y - yhat0
    cost_truth = 0.5 * float(r0 @ r0)
    crb_log, sv_ratio = log_crb(J0, theta, sigma)

    t0 = time.perf_counter()
    error = None
    try:
        fit = solver.solve(problem)
    except Exception as exc:  # a crash is a failed case, recorded with its parameters
        fit, error = None, f"{type(exc).__name__}: {exc}"
    wall = time.perf_counter() - t0
    out = {
        **case,
        "parameters_true": dict(zip(names, theta.tolist())),
        "initial": dict(zip(names, initial.tolist())),
        "record": {"bit_width_s": bit_width, "sample_rate_hz": rate, "n_samples": N_SAMPLES,
                   "medium_f99_hz": f99, "noise_std": sigma},
        "cost_truth": cost_truth,
        "crb_relative": dict(zip(names, crb_log.tolist())),
        "jacobian_sv_ratio": sv_ratio,
        "wall_time_s": wall,
        "error": error,
    }
    if fit is None:
        out.update(within_3se=False, within_3se_untruncated=False, global_minimum=False)
        return out
    from mbus_framework.studies.monte_carlo import covariance_from_jacobian

    unc = from_jacobian(names, fit.jacobian, fit.cost)
    se = unc.standard_errors
    # the same covariance without the pseudo-inverse cut-off (see the module docstring)
    se_full = np.sqrt(np.diag(covariance_from_jacobian(fit.jacobian, 2.0 * fit.cost / max(len(y) - len(names), 1))))
    z = np.abs(fit.theta - theta) / np.where(se > 0, se, np.nan)
    out.update(
        estimate=dict(zip(names, fit.theta.tolist())),
        error_percent=dict(zip(names, (100.0 * (fit.theta / theta - 1.0)).tolist())),
        se_relative=dict(zip(names, (se / fit.theta).tolist())),
        z=dict(zip(names, np.nan_to_num(z, nan=np.inf).tolist())),
        within_3se=bool(np.all(np.abs(fit.theta - theta) <= 3.0 * se)),
        se_relative_untruncated=dict(zip(names, (se_full / fit.theta).tolist())),
        within_3se_untruncated=bool(np.all(np.abs(fit.theta - theta) <= 3.0 * se_full)),
        cost=float(fit.cost),
        global_minimum=bool(fit.cost <= cost_truth * (1.0 + 1e-9)),
        nfev=int(fit.nfev),
        accepted_because=fit.strategy.get("accepted_because"),
        n_starts_tried=len(fit.strategy.get("starts", [])),
    )
    return out


def summarise(cases: list[dict], wall: float, workers: int) -> dict:
    n = len(cases)
    within = sum(c["within_3se"] for c in cases)
    glob = sum(c["global_minimum"] for c in cases)
    untr = sum(c["within_3se_untruncated"] for c in cases)
    both = sum(c["within_3se"] and c["global_minimum"] for c in cases)
    others = [c for c in cases if c["group"] != "potato_uncompensated"]
    others_within = sum(c["within_3se"] for c in others)
    ident = [c for c in cases if max(c["crb_relative"].values()) <= 0.5]
    ident_within = sum(c["within_3se"] for c in ident)
    times = np.array([c["wall_time_s"] for c in cases])
    by_group = {}
    for g in GROUPS:
        cs = [c for c in cases if c["group"] == g]
        if cs:
            by_group[g] = {
                "cases": len(cs),
                "within_3se": sum(c["within_3se"] for c in cs),
                "within_3se_untruncated": sum(c["within_3se_untruncated"] for c in cs),
                "global_minimum": sum(c["global_minimum"] for c in cs),
                "unidentifiable": sum(max(c["crb_relative"].values()) > 0.5 for c in cs),
                "median_time_s": float(np.median([c["wall_time_s"] for c in cs])),
            }
    return {
        "cases": n,
        "within_3se": within,
        "within_3se_percent": 100.0 * within / n if n else float("nan"),
        "global_minimum": glob,
        "global_minimum_percent": 100.0 * glob / n if n else float("nan"),
        "within_3se_untruncated": untr,
        "within_3se_and_global_minimum": both,
        "without_potato_uncompensated": {"cases": len(others), "within_3se": others_within},
        "identifiable_cases": len(ident),
        "identifiable_within_3se": ident_within,
        "errors": sum(c["error"] is not None for c in cases),
        "practically_unidentifiable": sum(max(c["crb_relative"].values()) > 0.5 for c in cases),
        "time_per_case_s": {"mean": float(times.mean()), "median": float(np.median(times)),
                            "p90": float(np.percentile(times, 90)), "max": float(times.max())},
        "wall_time_s": wall,
        "workers": workers,
        "target_percent": 95.0,
        "passed": bool(n and within >= 0.95 * n),
        "by_group": by_group,
        "failures": [
            {"index": c["index"], "group": c["group"], "within_3se": c["within_3se"],
             "global_minimum": c["global_minimum"], "max_error_over_se": max(c.get("z", {}).values(), default=None),
             "max_relative_crb": max(c["crb_relative"].values()), "accepted_because": c.get("accepted_because"),
             "error": c["error"]}
            for c in cases if not (c["within_3se"] and c["global_minimum"])
        ],
        "line": f"{within}/{n} within 3 SE ({100.0 * within / n:.1f} %)" if n else "no cases",
        "identifiable_line": (f"{ident_within}/{len(ident)} identifiable cases (largest relative CRB <= 0.5) within 3 SE "
                              f"({100.0 * ident_within / len(ident):.1f} %)") if ident else "no identifiable cases",
        "untruncated_line": f"{untr}/{n} within 3 SE with untruncated standard errors ({100.0 * untr / n:.1f} %)"
                            if n else "no cases",
        "global_and_within_line": f"{both}/{n} within 3 SE and at the global minimum ({100.0 * both / n:.1f} %)"
                                  if n else "no cases",
        "without_uncompensated_line": (f"{others_within}/{len(others)} within 3 SE without the potato_uncompensated "
                                       f"group ({100.0 * others_within / len(others):.1f} %)") if others else "",
    }


def machine() -> dict:
    from mbus_framework.studies.common import machine_info

    return machine_info()


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n-cases", type=int, default=200)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=2, help="processes (at most 2)")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT)
    p.add_argument("--quiet", action="store_true")
    p.add_argument("--groups", default=",".join(GROUPS),
                   help=f"comma-separated groups the cases take turns over (default: all of {', '.join(GROUPS)})")
    p.add_argument("--summary-only", action="store_true",
                   help="recompute and print the summary of the cases already in --out (no fitting)")
    args = p.parse_args(argv)
    if args.summary_only:
        doc = json.loads(args.out.read_text(encoding="utf-8"))
        doc["summary"] = summarise(doc["cases"], doc["summary"]["wall_time_s"], doc["summary"]["workers"])
        _write(args.out, doc)
        _print_summary(doc["summary"])
        return 0
    groups = [g.strip() for g in args.groups.split(",") if g.strip()]
    unknown = [g for g in groups if g not in GROUPS]
    if unknown or not groups:
        p.error(f"unknown group(s) {', '.join(unknown) or '(none)'}; choose from {', '.join(GROUPS)}")
    workers = max(1, min(2, args.workers))
    jobs = [(args.seed, i, tuple(groups)) for i in range(args.n_cases)]
    t0 = time.perf_counter()
    cases = []
    with mp.get_context("spawn").Pool(workers) as pool:
        for k, case in enumerate(pool.imap_unordered(run_case, jobs, chunksize=1), 1):
            cases.append(case)
            if not args.quiet:
                flag = "ok " if case["within_3se"] else "OUT"
                glob = "global" if case["global_minimum"] else "LOCAL "
                worst = max(case.get("z", {}).values(), default=float("nan"))
                print(f"[{k:>3}/{len(jobs)}] case {case['index']:>3} {case['group']:<21} {flag} {glob} "
                      f"max|err|/SE {worst:6.2f}  {case['wall_time_s']:6.2f} s", file=sys.stderr, flush=True)
    cases.sort(key=lambda c: c["index"])
    summary = summarise(cases, time.perf_counter() - t0, workers)
    doc = {
        "benchmark": "convergence",
        "command": "python benchmarks/convergence_benchmark.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "settings": {
            "n_cases": args.n_cases, "seed": args.seed, "groups_used": groups, "n_elements": N_ELEMENTS, "diameter_m": DIAMETER,
            "noise_relative_std": NOISE, "n_samples": N_SAMPLES, "prbs_order": ORDER,
            "samples_per_bit": SAMPLES_PER_BIT, "prbs_bandwidth_over_f99": band_ratio(),
            "initial_factor_range": [INIT_LOW, INIT_HIGH], "solver": "scipy_lm (default strategy)",
            "groups": {g: {"length_m": L, "density": list(rho), "properties": box} for g, (L, rho, box) in GROUPS.items()},
        },
        "machine": machine(),
        "summary": summary,
        "cases": cases,
    }
    _write(args.out, doc)
    _print_summary(summary)
    return 0


def _write(path: Path, doc: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".json.tmp")
    head = {k: v for k, v in doc.items() if k != "cases"}
    text = json.dumps(head, indent=1, allow_nan=True)
    cases = ",\n  ".join(json.dumps(c, allow_nan=True) for c in doc.get("cases", []))
    text = text[:-2] + ',\n "cases": [\n  ' + cases + "\n ]\n}\n"  # one line per case
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def _print_summary(summary: dict) -> None:
    t = summary["time_per_case_s"]
    print(f"{summary['global_minimum']}/{summary['cases']} reached the global minimum "
          f"({summary['global_minimum_percent']:.1f} %); time per case: median {t['median']:.2f} s, "
          f"mean {t['mean']:.2f} s, max {t['max']:.2f} s ({summary['workers']} workers, "
          f"{summary['wall_time_s']:.0f} s in all)")
    for g, s in summary["by_group"].items():
        print(f"  {g:<21} {s['within_3se']}/{s['cases']} within 3 SE, {s['global_minimum']}/{s['cases']} global, "
              f"{s['unidentifiable']} practically unidentifiable, median {s['median_time_s']:.2f} s")
    for f in summary["failures"]:
        if f["group"] != "potato_uncompensated":
            z = f["max_error_over_se"]
            print(f"  case {f['index']} ({f['group']}): {'within' if f['within_3se'] else 'NOT within'} 3 SE "
                  f"(max |error|/SE {z:.3g}), {'global' if f['global_minimum'] else 'LOCAL'} minimum, "
                  f"max relative CRB {f['max_relative_crb']:.2g}; {f['accepted_because']}")
    for key in ("untruncated_line", "identifiable_line", "global_and_within_line", "without_uncompensated_line"):
        if summary.get(key):
            print(summary[key])
    print(summary["line"])


if __name__ == "__main__":
    sys.exit(main())
