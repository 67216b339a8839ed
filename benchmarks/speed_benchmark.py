"""Speed benchmark (issue 24): mbus against the dissertation's method and a typical user's fit.

Run on demand (not part of the test suite):

    python benchmarks/speed_benchmark.py [--repeats 3] [--skip-alternatives] [--out benchmarks/results/speed.json]

In one run on one machine it measures

* **whole process**: ``mbus-run --help`` and ``mbus-run CONFIG`` (plots and report.html
  included) as subprocesses, median of ``--repeats``, for Table 3.1 with the second initial
  set, the potato (configs/potato.yaml) and a 6 mm apple slice (configs/apple_slice.yaml);
* **in process**: the same runs through :func:`mbus_framework.run_config` without plots,
  with the solver's own wall time (result.json ``solver.wall_time_s``);
* **alternatives** on the Table 3.1 set-2 record (the same data mbus fitted): the
  dissertation's method (RK4 + 1 % forward-difference Jacobian + Levenberg-Marquardt,
  ``benchmarks/dissertation_method.py``) and a typical user's fit (``scipy.signal.lsim``
  inside ``scipy.optimize.least_squares`` with 2-point finite differences, parameters scaled
  by their initial values). lmfit is not installed here and is not measured;
* **arithmetic lower bound** of one simulation: the state recursion x_{k+1} = A_d x_k + B_d u_k,
  y_k = C x_k + D u_k costs N (2 n^2 + 4 n) flops for n states and N samples; divided by the
  machine's rate measured with a 512 x 512 numpy matmul (2 m^3 flops), it is the time no
  implementation of that recursion can beat; the engine's measured simulation is beside it.

Ratios matter, not absolute times (the machine may be shared: the load average is recorded).
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# One BLAS thread, as mbus-run sets for itself: the in-process runs and the alternatives must
# not pay threaded BLAS hand-off costs that the whole-process runs do not (set before numpy loads).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

SET2 = {"k_sigma": 1.95e8, "b_sigma": 7.5, "k_tau": 3.25e7, "b_tau": 6.0}  # -35 %, -50 %, -35 %, -50 %
CASES = {
    "table3_1_set2": ("configs/table3_1.yaml", [f"model.initial={json.dumps(SET2)}"]),
    "potato": ("configs/potato.yaml", []),
    "apple_slice_6mm": ("configs/apple_slice.yaml", []),
}


def mbus_run_command() -> list[str]:
    exe = Path(sys.executable).with_name("mbus-run")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "mbus_framework.cli"]


def whole_process(args: list[str], repeats: int) -> dict:
    """Median wall time [s] of ``mbus-run ARGS`` in a fresh process, and its CPU time (user +
    system of the child: on a shared machine the wall clock also counts waiting for a core)."""
    import resource

    times, cpu = [], []
    for _ in range(repeats):
        with tempfile.TemporaryDirectory(prefix="mbus-speed-") as tmp:
            out = ["-o", str(Path(tmp) / "run"), "-q"] if args and args[0] != "--help" else []
            r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            done = subprocess.run([*mbus_run_command(), *args, *out], cwd=ROOT, capture_output=True, text=True)
            times.append(time.perf_counter() - t0)
            r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu.append(r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime)
            if done.returncode != 0:
                raise RuntimeError(f"mbus-run {' '.join(args)} failed: {done.stderr.strip()[-500:]}")
    return {"median_s": statistics.median(times), "median_cpu_s": statistics.median(cpu), "runs_s": times}


def in_process(config: str, overrides: list[str]) -> dict:
    """One run through the Python API (no plots): total wall time and the solver's own."""
    import mbus_framework as mbus

    with tempfile.TemporaryDirectory(prefix="mbus-speed-") as tmp:
        t0, c0 = time.perf_counter(), time.process_time()
        result = mbus.run_config(ROOT / config, overrides, Path(tmp) / "run", plots=False, progress=False)
        total, total_cpu = time.perf_counter() - t0, time.process_time() - c0
        record = Path(tmp) / "run" / "measurement.csv"
        import numpy as np

        t, u, y = np.loadtxt(record, delimiter=",", skiprows=1, unpack=True)[:3]
    solver = result.document["solver"]
    return {"total_s": total, "total_cpu_s": total_cpu, "solver_s": solver["wall_time_s"],
            "solver_cpu_s": (result.document.get("strategy") or {}).get("cpu_time_s"), "nfev": solver.get("nfev"),
            "nrmse": result.document["fit"].get("nrmse"), "record": (t, u, y)}


def table31_model():
    from mbus_framework.plugins import Sample
    from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions

    return KelvinVoigtChain(Sample(length=0.05, diameter=0.0254, density=1000.0), KelvinVoigtOptions(n_elements=10))


def dissertation(u, y, dt) -> dict:
    import numpy as np
    from dissertation_method import Rk4ForwardDifference, levenberg_marquardt

    theta0 = np.array(list(SET2.values()))
    t0, c0 = time.perf_counter(), time.process_time()
    r = levenberg_marquardt(Rk4ForwardDifference(table31_model(), u, dt), y, theta0)
    return {"time_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0, "iterations": r.iterations, "simulations": r.n_simulations + 4 * r.n_jacobians,
            "theta": r.theta.tolist()}


def typical_user(t, u, y) -> dict:
    """scipy.signal.lsim in scipy.optimize.least_squares, 2-point finite differences."""
    import numpy as np
    from scipy import signal
    from scipy.optimize import least_squares

    from mbus_framework.engine.simulation import as_float_ss

    model = table31_model()
    theta0 = np.array(list(SET2.values()))
    calls = [0]

    def residual(v):
        calls[0] += 1
        A, B, C, D = as_float_ss(model.state_space(theta0 * np.abs(v)))
        _, yhat, _ = signal.lsim((A, B, C, D), u, t)
        return yhat - y

    t0, c0 = time.perf_counter(), time.process_time()
    r = least_squares(residual, np.ones(theta0.size), method="trf", max_nfev=400)
    return {"time_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0, "simulations": calls[0], "success": bool(r.success),
            "theta": (theta0 * np.abs(r.x)).tolist()}


def lower_bound(u, dt) -> dict:
    import numpy as np

    from mbus_framework.engine.simulation import as_float_ss, simulate

    model = table31_model()
    theta = np.array([3.0e8, 15.0, 5.0e7, 12.0])
    n = as_float_ss(model.state_space(theta))[0].shape[0]
    m = 512
    a = np.random.default_rng(0).standard_normal((m, m))
    rates = []
    for _ in range(5):
        t0 = time.perf_counter()
        a @ a
        rates.append(2.0 * m**3 / (time.perf_counter() - t0))
    rate = max(rates)
    flops = u.size * (2 * n * n + 4 * n)
    sims = []
    for _ in range(5):
        t0 = time.perf_counter()
        simulate(model, theta, u, dt, "zoh")
        sims.append(time.perf_counter() - t0)
    bound = flops / rate
    return {"states": n, "samples": int(u.size), "flops": flops, "machine_flops_per_s": rate, "bound_s": bound,
            "engine_simulation_s": min(sims), "engine_over_bound": min(sims) / bound}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--skip-alternatives", action="store_true", help="only mbus (the alternatives take tens of seconds)")
    p.add_argument("--out", default=str(HERE / "results" / "speed.json"))
    p.add_argument("--cases", default=",".join(CASES), help=f"comma list of cases to run (of {', '.join(CASES)})")
    p.add_argument("--solver-repeats", type=int, default=1, help="in-process runs per case: the solver time is "
                   "their median (each run's solver wall and CPU time recorded)")
    a = p.parse_args(argv)
    chosen = [c.strip() for c in a.cases.split(",") if c.strip()]
    unknown = [c for c in chosen if c not in CASES]
    if unknown:
        p.error(f"--cases: unknown case(s) {', '.join(unknown)} (known: {', '.join(CASES)})")
    report: dict = {"load_average_start": list(os.getloadavg()), "cpu_count": os.cpu_count(), "repeats": a.repeats,
                    "whole_process": {"help": whole_process(["--help"], a.repeats)}, "in_process": {}}
    for name, (config, overrides) in CASES.items():
        if name not in chosen:
            continue
        sets = [x for o in overrides for x in ("--set", o)]
        report["whole_process"][name] = whole_process([config, *sets], a.repeats)
        runs = [in_process(config, overrides) for _ in range(max(1, a.solver_repeats))]
        run = sorted(runs, key=lambda r: r["solver_s"])[len(runs) // 2]
        run["solver_runs_s"] = [r["solver_s"] for r in runs]
        run["solver_runs_cpu_s"] = [r["solver_cpu_s"] for r in runs]
        for r in runs:
            r.pop("record", None) if r is not run else None
        t, u, y = run.pop("record")
        report["in_process"][name] = run
        if name == "table3_1_set2":
            dt = float(t[1] - t[0])
            report["lower_bound_one_simulation"] = lower_bound(u, dt)
            if not a.skip_alternatives:
                alt = {"dissertation": dissertation(u, y, dt), "typical_user_lsim_least_squares": typical_user(t, u, y),
                       "lmfit": "not installed: not measured"}
                for key in ("dissertation", "typical_user_lsim_least_squares"):
                    alt[key]["over_mbus_solver"] = alt[key]["time_s"] / run["solver_s"]
                    if run.get("solver_cpu_s"):
                        alt[key]["cpu_over_mbus_solver_cpu"] = alt[key]["cpu_s"] / run["solver_cpu_s"]
                report["alternatives_table3_1_set2"] = alt
        print(f"{name}: whole process {report['whole_process'][name]['median_s']:.2f} s, "
              f"in process {run['total_s']:.2f} s (solver {run['solver_s']:.2f} s)", flush=True)
    report["load_average_end"] = list(os.getloadavg())
    Path(a.out).write_text(json.dumps(report, indent=2) + "\n")
    print(json.dumps({k: v for k, v in report.items() if k != "in_process"}, indent=1)[:3000])
    return 0


if __name__ == "__main__":
    sys.exit(main())
