"""Statistical efficiency and runtime on the Table 3.1 case (issue 4, second and third targets).

    python benchmarks/monte_carlo_table3_1.py [--n-seeds 200] [--timing-runs 7]
                                              [--study-dir DIR] [--out benchmarks/results/monte_carlo_table3_1.json]

1. **Monte Carlo** (``run_study("monte_carlo", "configs/table3_1.yaml", n_runs=N)``): the
   Table 3.1 record (rho 1000, L 0.05 m, D 0.0254 m, n 10, 6200 samples at 6.25 MS/s, PRBS
   2.5 us bits, noise std 10 % of the noise-free RMS) from initial set 1, over N noise seeds
   (N >= 50; default 200, because with 50 seeds a perfectly calibrated 95 % interval still falls
   outside 90-99 % coverage for one of four parameters about 40 % of the time, with 200 about
   1 %). Targets: each parameter's RMS error <= 1.5 x its Cramer-Rao bound, and the 95 %
   intervals cover the truth in 90-99 % of seeds.
2. **Both dissertation initial sets** (Table 3.1: +100/+150 % and -35/-50 %) on the config's
   own seed: errors and whether every parameter ends within 3 standard errors.
3. **Runtime** of one Table 3.1 identification with the full strategy (``execute`` of the
   config, without plots: acquisition, fit, uncertainty, result.json): median of
   ``--timing-runs`` runs, target < 2 s on a 2-core machine. The solver's own time is
   reported too, and the 1-minute load average, since the machine may be shared.

Writes ``--out`` (JSON) and prints one line per target.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
CONFIG = ROOT / "configs" / "table3_1.yaml"
DEFAULT_OUT = HERE / "results" / "monte_carlo_table3_1.json"
INITIAL_SETS = {
    "set 1 (+100/+150 %)": {"k_sigma": 6.0e8, "b_sigma": 37.5, "k_tau": 1.0e8, "b_tau": 30.0},
    "set 2 (-35/-50 %)": {"k_sigma": 1.95e8, "b_sigma": 7.5, "k_tau": 3.25e7, "b_tau": 6.0},
}
RMS_OVER_CRB_MAX = 1.5
COVERAGE_RANGE = (0.90, 0.99)
RUNTIME_TARGET_S = 2.0


def _flow(d: dict) -> str:
    return "{" + ", ".join(f"{k}: {v!r}" for k, v in d.items()) + "}"


def monte_carlo(n_seeds: int, study_dir: Path) -> dict:
    from mbus_framework.pipeline.progress import make_progress
    from mbus_framework.studies.runner import run_study

    study = run_study("monte_carlo", CONFIG, [], study_dir, progress=make_progress(), n_runs=n_seeds)
    print(study.text)
    params = [r for r in study.rows if r["kind"] == "parameter"]
    checks = {}
    for r in params:
        checks[r["quantity"]] = {
            "rmse_over_crb": r["rmse_over_crb"],
            "rmse_ok": r["rmse_over_crb"] is not None and r["rmse_over_crb"] <= RMS_OVER_CRB_MAX,
            "coverage": r["coverage"],
            "coverage_ok": COVERAGE_RANGE[0] <= r["coverage"] <= COVERAGE_RANGE[1],
        }
    ok_runs = [run for run in study.runs if run["ok"]]
    return {
        "n_seeds": n_seeds,
        "n_ok": len(ok_runs),
        "seeds": [study.runs[0]["seed"], study.runs[-1]["seed"]],
        "table": study.rows,
        "checks": checks,
        "passed": all(c["rmse_ok"] and c["coverage_ok"] for c in checks.values()),
        "noise_std": study.summary["noise_std"],
        "cramer_rao_reported_vs_computed_max_rel_diff": study.summary["cramer_rao_max_relative_difference"],
        "all_within_3se": study.summary["all_within_3se"],
        "median_run_time_s": study.summary["median_run_time_s"],
        "study_wall_time_s": study.summary["wall_time_s"],
        "per_seed": [
            {"seed": run["seed"], "parameters": run["parameters"], "standard_errors": run["standard_errors"]}
            for run in ok_runs
        ],
        "study_dir": str(study_dir),
    }


def initial_sets(tmp: Path) -> dict:
    from mbus_framework.pipeline.run import execute

    out = {}
    for name, init in INITIAL_SETS.items():
        o = execute(CONFIG, [f"model.initial={_flow(init)}"], tmp / f"init-{len(out)}", plots=False)
        r = o.result
        se = r["uncertainty"]["standard_errors"]
        z = {k: abs(r["parameters"][k] - r["truth"][k]) / se[k] for k in se}
        out[name] = {
            "initial": init,
            "estimate": r["parameters"],
            "error_percent": r["error_percent"],
            "relative_standard_errors": r["uncertainty"]["relative_standard_errors"],
            "error_over_se": z,
            "within_3se": all(v <= 3 for v in z.values()),
            "cost": r["solver"]["cost"],
            "strategy": r["strategy"].get("accepted_because"),
        }
    return out


def timing(n: int, tmp: Path) -> dict:
    from mbus_framework.pipeline.run import execute

    execute(CONFIG, [], tmp / "warm-up", plots=False)  # imports, plugin discovery, caches
    total, solver = [], []
    for k in range(n):
        t0 = time.perf_counter()
        o = execute(CONFIG, [], tmp / f"time-{k}", plots=False)
        total.append(time.perf_counter() - t0)
        solver.append(o.result["solver"]["wall_time_s"])
    med = statistics.median(total)
    return {
        "runs": n,
        "execute_s": total,
        "solver_s": solver,
        "median_execute_s": med,
        "median_solver_s": statistics.median(solver),
        "target_s": RUNTIME_TARGET_S,
        "passed": med < RUNTIME_TARGET_S,
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n-seeds", type=int, default=200)
    p.add_argument("--timing-runs", type=int, default=7)
    p.add_argument("--study-dir", type=Path, default=None, help="keep the study folder here (default: a temp dir)")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = p.parse_args(argv)
    if args.n_seeds < 50:
        print("note: the target asks for at least 50 seeds", file=sys.stderr)
    from mbus_framework.studies.common import machine_info

    with tempfile.TemporaryDirectory(prefix="mbus-bench-") as tmp:
        tmp = Path(tmp)
        load_before = machine_info()["load_average_1min"]
        tim = timing(args.timing_runs, tmp)
        sets = initial_sets(tmp)
        mc = monte_carlo(args.n_seeds, args.study_dir or tmp / "study")
    doc = {
        "benchmark": "monte_carlo_table3_1",
        "command": "python benchmarks/monte_carlo_table3_1.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "config": "configs/table3_1.yaml",
        "machine": {**machine_info(), "load_average_1min_before": load_before},
        "targets": {"rmse_over_crb_max": RMS_OVER_CRB_MAX, "coverage_range": list(COVERAGE_RANGE),
                    "runtime_s": RUNTIME_TARGET_S},
        "monte_carlo": mc,
        "initial_sets": sets,
        "timing": tim,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp_out = args.out.with_suffix(".json.tmp")
    tmp_out.write_text(json.dumps(doc, indent=1, allow_nan=True) + "\n", encoding="utf-8")
    os.replace(tmp_out, args.out)

    print()
    for name, c in mc["checks"].items():
        print(f"{name:<8} RMS/CRB {c['rmse_over_crb']:.2f} ({'ok' if c['rmse_ok'] else 'ABOVE 1.5'}), "
              f"95 % coverage {100 * c['coverage']:.1f} % ({'ok' if c['coverage_ok'] else 'OUTSIDE 90-99 %'})")
    print(f"Monte Carlo ({mc['n_ok']} seeds): {'PASS' if mc['passed'] else 'FAIL'}")
    for name, s in sets.items():
        errs = ", ".join(f"{k} {v:+.2f} %" for k, v in s["error_percent"].items())
        print(f"initial {name}: {errs}; {'within' if s['within_3se'] else 'NOT within'} 3 SE")
    print(f"Table 3.1 identification (full strategy): median {tim['median_execute_s']:.2f} s per run "
          f"(solver {tim['median_solver_s']:.2f} s) over {tim['runs']} runs, target < {RUNTIME_TARGET_S:g} s: "
          f"{'PASS' if tim['passed'] else 'FAIL'}; load average {doc['machine']['load_average_1min']:.1f} "
          f"on {doc['machine']['cores']} cores")
    return 0


if __name__ == "__main__":
    sys.exit(main())
