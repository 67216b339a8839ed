"""Benchmark: campaign throughput on Dask and the cost of a fit inside a campaign.

Run on demand (not part of the test suite), on a machine as quiet as you can get:

    python benchmarks/campaign_benchmark.py [--samples 16] [--out benchmarks/results/campaign.json]

The records are potato slices on the simulated rig (``configs/potato.yaml``: 3 cm, n = 10,
PRBS 0.4 us bits at 25 MS/s, 5000 samples, 3 % noise), each with its own truth drawn
log-uniformly within x/÷1.5 of that config's truth (Table 6.2 "after compensation" means) and
its own noise seed. In one
run the benchmark measures, on the same records:

(a) fits per second of ``run_campaign`` on a LocalCluster of 1 and of 2 single-threaded worker
    processes (cluster start-up timed separately; each cluster's workers import mbus once
    before the clock starts, as they do at the first fit of a campaign), and the speed-up
    2 workers / 1 worker (target: at least 1.7 on a 2-core machine);
(b) t_fit: ``pipeline.run.execute`` of each record in this (warm) process, the work itself;
(c) one ``mbus-run CONFIG`` process per record (a new Python, imports, plugin discovery);

and reports the per-fit overhead of (a) with 1 worker, wall/N - mean t_fit, against that of
(c), mean process wall - mean t_fit. Wall clocks are used (a speed-up is a wall-clock
quantity); the load average before and after and the CPU time the workers got
(CPU seconds / (wall x workers)) show how much the machine was shared.
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


def campaign_rate(path: Path, out: Path, workers: int) -> dict:
    from mbus_framework.campaigns import run_campaign
    from mbus_framework.campaigns.executor import dask_client

    t0 = time.perf_counter()
    with dask_client(workers=workers) as client:
        start = time.perf_counter() - t0
        client.run(_warm_worker)
        cpu0 = sum(client.run(_cpu_seconds).values())
        load0 = os.getloadavg()[0]
        t1 = time.perf_counter()
        result = run_campaign(path, out, client=client, progress=False)
        wall = time.perf_counter() - t1
        cpu = sum(client.run(_cpu_seconds).values()) - cpu0
    n = len(result.table)
    return {
        "workers": workers,
        "fits": n,
        "failed": len(result.failed),
        "cluster_start_s": start,
        "wall_s": wall,
        "fits_per_s": n / wall,
        "worker_cpu_s": cpu,
        "worker_cpu_share": cpu / (wall * workers),
        "load_average_1min_before": load0,
        "mean_fit_time_s": float(result.table["fit_time_s"].mean()),
    }


def in_process_fits(path: Path, out: Path) -> list[float]:
    from mbus_framework.campaigns.plan import plan_campaign
    from mbus_framework.campaigns.spec import load_campaign
    from mbus_framework.pipeline.run import execute

    tasks = plan_campaign(load_campaign(path), out)
    execute(tasks[0].configs[0], [], out / "warm-up", plots=False, source="warm-up")
    times = []
    for t in tasks:
        t0 = time.perf_counter()
        execute(t.configs[0], [], out / t.label, plots=False, source=t.label)
        times.append(time.perf_counter() - t0)
    return times


def process_per_record(path: Path, out: Path) -> list[float]:
    from mbus_framework.campaigns.plan import plan_campaign
    from mbus_framework.campaigns.spec import load_campaign

    exe = Path(sys.executable).parent / "mbus-run"
    times = []
    for t in plan_campaign(load_campaign(path), out):
        cfg = out / f"{t.label}.yaml"
        cfg.parent.mkdir(parents=True, exist_ok=True)
        cfg.write_text(yaml.safe_dump(t.configs[0], sort_keys=False))
        t0 = time.perf_counter()
        subprocess.run([str(exe), str(cfg), "-o", str(out / t.label), "--no-plots", "-q"], check=True,
                       capture_output=True)
        times.append(time.perf_counter() - t0)
    return times


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="Campaign throughput on Dask and per-fit overhead")
    p.add_argument("--samples", type=int, default=16, help="records in the campaign (default 16)")
    p.add_argument("--seed", type=int, default=2024)
    p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "campaign.json")
    args = p.parse_args(argv)
    from mbus_framework.studies.common import machine_info

    t_start = time.perf_counter()
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="mbus-campaign-bench-") as tmp:
        tmp = Path(tmp)
        path = write_campaign(tmp, args.samples, args.seed)
        one = campaign_rate(path, tmp / "w1", 1)
        two = campaign_rate(path, tmp / "w2", 2)
        t_fit = in_process_fits(path, tmp / "inproc")
        per_process = process_per_record(path, tmp / "procs")
    load_after = os.getloadavg()
    mean_fit = float(np.mean(t_fit))
    campaign_per_fit = one["wall_s"] / one["fits"]
    process_mean = float(np.mean(per_process))
    speedup = two["fits_per_s"] / one["fits_per_s"]
    doc = {
        "benchmark": "campaign",
        "machine": machine_info(),
        "load_average_before": list(load_before),
        "load_average_after": list(load_after),
        "records": {"count": args.samples, "config": f"configs/potato.yaml (truth per record within x/÷{SPREAD} of its truth)",
                    "seed": args.seed},
        "local_cluster": {"1_worker": one, "2_workers": two},
        "speedup_2_over_1": speedup,
        "in_process_fit_s": {"mean": mean_fit, "median": float(np.median(t_fit)), "all": t_fit},
        "mbus_run_process_per_record_s": {"mean": process_mean, "median": float(np.median(per_process)),
                                          "all": per_process},
        "overhead_per_fit_s": {
            "campaign_1_worker": campaign_per_fit - mean_fit,
            "process_per_record": process_mean - mean_fit,
        },
        "targets": {"speedup_at_least": TARGET_SPEEDUP, "speedup_met": speedup >= TARGET_SPEEDUP},
        "total_time_s": time.perf_counter() - t_start,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=2) + "\n")
    print(f"load average before {load_before[0]:.2f}, after {load_after[0]:.2f} ({os.cpu_count()} cores)")
    for r in (one, two):
        print(f"{r['workers']} worker(s): {r['fits']} fits in {r['wall_s']:.2f} s = {r['fits_per_s']:.3f} fits/s "
              f"(cluster start {r['cluster_start_s']:.1f} s, worker CPU share {100 * r['worker_cpu_share']:.0f} %)")
    print(f"speed-up 2/1 workers: {speedup:.2f}x (target {TARGET_SPEEDUP}x: {'met' if speedup >= TARGET_SPEEDUP else 'NOT met'})")
    print(f"per record: fit in a warm process {mean_fit:.3f} s; in a campaign (1 worker) {campaign_per_fit:.3f} s "
          f"(overhead {campaign_per_fit - mean_fit:+.3f} s); one mbus-run process {process_mean:.3f} s "
          f"(overhead {process_mean - mean_fit:+.3f} s)")
    print(f"written to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
