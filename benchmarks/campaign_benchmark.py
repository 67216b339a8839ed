"""Benchmark: campaign throughput on Dask and the cost of a fit inside a campaign.

Run on demand (not part of the test suite), on a machine as quiet as you can get:

    python benchmarks/campaign_benchmark.py [--samples 16] [--out benchmarks/results/campaign.json]

The records are potato slices on the simulated rig (``configs/potato.yaml``: 3 cm, n = 10,
PRBS 0.4 us bits at 25 MS/s, 5000 samples, 3 % noise), each with its own truth drawn
log-uniformly within x/÷1.5 of that config's truth (Table 6.2 "after compensation" means) and
its own noise seed. In one
run the benchmark measures, on the same records:

(a) fits per second of ``run_campaign`` on a LocalCluster of 1 and of 2 single-threaded worker
    processes over its fit phase (first fit submitted to last one back: what more workers
    speed up; cluster start-up timed separately; each cluster's workers import mbus once
    before the clock starts, as they do at the first fit of a campaign) and over the whole
    campaign (validation, table, summary and plots included), in ``--rounds`` alternating
    rounds, best and median, and the speed-up 2 workers / 1 worker (target: at least 1.7 on a
    2-core machine);
(b) t_fit: ``pipeline.run.execute`` of each record in this (warm) process, the work itself,
    in every round before the two campaigns;
(c) one ``mbus-run CONFIG`` process per record (a new Python, imports, plugin discovery);

and reports the per-fit overhead of (a) with 1 worker, wall/N - mean t_fit, against that of
(c), mean process wall - mean t_fit, in wall seconds and in CPU seconds (the workers' CPU time
per fit, the children's user + system time per process, against the CPU time of t_fit); CPU
seconds do not count time spent waiting for a core, so they compare the work itself on a
shared machine. The speed-up is a wall-clock quantity; the load average before and after and
the CPU share the workers got (CPU seconds / (wall x workers)) show how shared the machine was.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
os.environ.setdefault("MPLBACKEND", "Agg")

import numpy as np  # noqa: E402
import yaml  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
POTATO = ROOT / "configs" / "potato.yaml"
#: Truths are drawn log-uniformly within x/÷ SPREAD of configs/potato.yaml's truth (the Table 6.2
#: "after compensation" means, eta_tau at its minimum) [Pa, Pa s].
POTATO_TRUTH = {"E_sigma": 2.42e10, "eta_sigma": 7.18e3, "E_tau": 6.56e9, "eta_tau": 5.14e3}
SPREAD = 1.5
TARGET_SPEEDUP = 1.7


def write_campaign(folder: Path, n: int, seed: int) -> Path:
    rng = np.random.default_rng(seed)
    base = yaml.safe_load(POTATO.read_text())
    base["output"] = {"plots": False}
    (folder / "base.yaml").write_text(yaml.safe_dump(base, sort_keys=False))
    lines = ["sample_id,slice," + ",".join(f"backend.options.truth.{k}" for k in POTATO_TRUTH) + ",backend.options.seed"]
    for i in range(n):
        truth = [float(v * SPREAD ** rng.uniform(-1, 1)) for v in POTATO_TRUTH.values()]
        lines.append(f"p{i:02d},{'ab'[i % 2]}," + ",".join(repr(v) for v in truth) + f",{100 + i}")
    (folder / "samples.csv").write_text("\n".join(lines) + "\n")
    path = folder / "bench.yaml"
    path.write_text(yaml.safe_dump({"campaign": {"title": "campaign benchmark", "base": "base.yaml",
                                                 "samples": "samples.csv", "groups": ["slice"]}}))
    return path


def _warm_worker() -> int:
    import mbus_framework.campaigns.worker  # noqa: F401
    from mbus_framework.interfaces.registry import default_registry

    default_registry()
    return os.getpid()


def _cpu_seconds() -> float:
    import psutil

    t = psutil.Process().cpu_times()
    return t.user + t.system


def rounds(path: Path, out: Path, n_rounds: int) -> tuple[dict[int, dict], dict]:
    """Both clusters up and warm; then, ``n_rounds`` times, every record in this process, the
    campaign on 1 worker and on 2 workers (alternating spreads the machine's other load over
    the three)."""
    from contextlib import ExitStack

    from mbus_framework.campaigns import run_campaign
    from mbus_framework.campaigns.executor import dask_client
    from mbus_framework.campaigns.plan import plan_campaign
    from mbus_framework.campaigns.spec import load_campaign
    from mbus_framework.pipeline.run import execute

    tasks = plan_campaign(load_campaign(path), out / "plan")
    execute(tasks[0].configs[0], [], out / "warm-up", plots=False, source="warm-up")
    runs: dict[int, list[dict]] = {1: [], 2: []}
    here = {"wall_s": [], "cpu_s": []}
    starts = {}
    with ExitStack() as stack:
        clients = {}
        for n in (1, 2):
            t0 = time.perf_counter()
            clients[n] = stack.enter_context(dask_client(workers=n))
            starts[n] = time.perf_counter() - t0
            clients[n].run(_warm_worker)
        for r in range(n_rounds):
            for t in tasks:  # t_fit: the work itself, in this warm process
                t0, c0 = time.perf_counter(), time.process_time()
                execute(t.configs[0], [], out / f"here-{r}" / t.label, plots=False, source=t.label)
                here["wall_s"].append(time.perf_counter() - t0)
                here["cpu_s"].append(time.process_time() - c0)
            for n, client in clients.items():
                cpu0 = sum(client.run(_cpu_seconds).values())
                load0 = os.getloadavg()[0]
                t0 = time.perf_counter()
                result = run_campaign(path, out / f"w{n}-{r}", client=client, progress=False)
                wall = time.perf_counter() - t0
                cpu = sum(client.run(_cpu_seconds).values()) - cpu0
                fits = len(result.table)
                runs[n].append({"wall_s": wall, "fit_phase_s": result.fit_phase_s, "fits": fits,
                                "failed": len(result.failed), "fits_per_s": fits / result.fit_phase_s,
                                "campaign_fits_per_s": fits / wall,
                                "worker_cpu_s": cpu, "worker_cpu_s_per_fit": cpu / fits,
                                "worker_cpu_share": cpu / (wall * n), "load_average_1min_before": load0})
    cluster = {}
    for n, rs in runs.items():
        best = max(rs, key=lambda x: x["fits_per_s"])
        cluster[n] = {"workers": n, "cluster_start_s": starts[n], "rounds": rs, "best_fits_per_s": best["fits_per_s"],
                      "median_fits_per_s": float(np.median([x["fits_per_s"] for x in rs])),
                      "best_campaign_fits_per_s": max(x["campaign_fits_per_s"] for x in rs),
                      "best_wall_s_per_fit": min(x["wall_s"] / x["fits"] for x in rs),
                      "median_worker_cpu_s_per_fit": float(np.median([x["worker_cpu_s_per_fit"] for x in rs]))}
    return cluster, here


def process_per_record(path: Path, out: Path) -> tuple[list[float], list[float]]:
    """Wall and CPU seconds (the child's user + system) of one ``mbus-run CONFIG`` per record."""
    import resource

    from mbus_framework.campaigns.plan import plan_campaign
    from mbus_framework.campaigns.spec import load_campaign

    exe = Path(sys.executable).parent / "mbus-run"
    wall, cpu = [], []
    for t in plan_campaign(load_campaign(path), out):
        cfg = out / f"{t.label}.yaml"
        cfg.parent.mkdir(parents=True, exist_ok=True)
        cfg.write_text(yaml.safe_dump(t.configs[0], sort_keys=False))
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run([str(exe), str(cfg), "-o", str(out / t.label), "--no-plots", "-q"], check=True,
                       capture_output=True)
        wall.append(time.perf_counter() - t0)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    return wall, cpu


def _stats(values: list[float]) -> dict:
    return {"mean": float(np.mean(values)), "median": float(np.median(values)), "all": values}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="Campaign throughput on Dask and per-fit overhead")
    p.add_argument("--samples", type=int, default=16, help="records in the campaign (default 16)")
    p.add_argument("--rounds", type=int, default=3, help="alternating 1-/2-worker rounds (default 3)")
    p.add_argument("--seed", type=int, default=2024)
    p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "campaign.json")
    args = p.parse_args(argv)
    from mbus_framework.studies.common import machine_info

    t_start = time.perf_counter()
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="mbus-campaign-bench-") as tmp:
        tmp = Path(tmp)
        path = write_campaign(tmp, args.samples, args.seed)
        cluster, here = rounds(path, tmp, args.rounds)
        proc_wall, proc_cpu = process_per_record(path, tmp / "procs")
    fit_wall, fit_cpu = here["wall_s"], here["cpu_s"]
    n = args.samples
    best_here = min(float(np.mean(fit_wall[i:i + n])) for i in range(0, len(fit_wall), n))
    load_after = os.getloadavg()
    one, two = cluster[1], cluster[2]
    speedup = two["best_fits_per_s"] / one["best_fits_per_s"]
    median_speedup = two["median_fits_per_s"] / one["median_fits_per_s"]
    campaign_speedup = two["best_campaign_fits_per_s"] / one["best_campaign_fits_per_s"]
    fit, cpu_fit = best_here, float(np.median(fit_cpu))
    overhead = {
        "wall_s": {"campaign_1_worker": one["best_wall_s_per_fit"] - fit, "process_per_record": float(np.mean(proc_wall)) - fit},
        "cpu_s": {"campaign_1_worker": one["median_worker_cpu_s_per_fit"] - cpu_fit,
                  "process_per_record": float(np.mean(proc_cpu)) - cpu_fit},
    }
    doc = {
        "benchmark": "campaign",
        "machine": machine_info(),
        "load_average_before": list(load_before),
        "load_average_after": list(load_after),
        "records": {"count": args.samples, "config": f"configs/potato.yaml (truth per record within x/÷{SPREAD} of its truth)",
                    "seed": args.seed},
        "local_cluster": {"1_worker": one, "2_workers": two},
        "speedup_2_over_1": {"best": speedup, "median": median_speedup, "whole_campaign_best": campaign_speedup},
        "in_process_fit": {"wall_s": _stats(fit_wall), "best_round_mean_wall_s": best_here, "cpu_s": _stats(fit_cpu)},
        "mbus_run_process_per_record": {"wall_s": _stats(proc_wall), "cpu_s": _stats(proc_cpu)},
        "overhead_per_fit": overhead,
        "targets": {"speedup_at_least": TARGET_SPEEDUP, "speedup_met": speedup >= TARGET_SPEEDUP},
        "total_time_s": time.perf_counter() - t_start,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=2) + "\n")
    print(f"load average before {load_before[0]:.2f}, after {load_after[0]:.2f} ({os.cpu_count()} cores)")
    for r in (one, two):
        shares = ", ".join(f"{100 * x['worker_cpu_share']:.0f}" for x in r["rounds"])
        print(f"{r['workers']} worker(s): best {r['best_fits_per_s']:.3f} fits/s, median {r['median_fits_per_s']:.3f}; "
              f"whole campaign best {r['best_campaign_fits_per_s']:.3f} (cluster start {r['cluster_start_s']:.1f} s; worker CPU share per round {shares} %)")
    met = "met" if speedup >= TARGET_SPEEDUP else "NOT met"
    print(f"speed-up 2/1 workers: best {speedup:.2f}x, median {median_speedup:.2f}x (target {TARGET_SPEEDUP}x: {met}); "
          f"whole campaign (validation, table, summary and plots included) {campaign_speedup:.2f}x")
    print(f"per record, wall (best round): warm process {fit:.3f} s; campaign (1 worker) {one['best_wall_s_per_fit']:.3f} s "
          f"(overhead {overhead['wall_s']['campaign_1_worker']:+.3f} s); one mbus-run process {np.mean(proc_wall):.3f} s "
          f"(overhead {overhead['wall_s']['process_per_record']:+.3f} s)")
    print(f"per record, CPU (median): warm process {cpu_fit:.3f} s; campaign worker {one['median_worker_cpu_s_per_fit']:.3f} s "
          f"(overhead {overhead['cpu_s']['campaign_1_worker']:+.3f} s); one mbus-run process {np.mean(proc_cpu):.3f} s "
          f"(overhead {overhead['cpu_s']['process_per_record']:+.3f} s)")
    print(f"written to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
