"""Benchmark: ``mbus-analyze classify`` (with plots) and ``crispness`` on a 10,000-row table.

Run on demand (not part of the test suite):

    python benchmarks/analysis_benchmark.py [--rows 10000] [--repeats 1] [--out benchmarks/results/analysis.json]

Tables, synthesised as the tests build theirs:

* classify: the five tissues of Table 4.3 (``tests/fakes/campaign_tables.grouped_table``: each
  sample's properties scatter around the table's means with its between-replicate SD, plus
  0.2 % estimation error), rows/5 samples per tissue, classified by ``material``;
* crispness: apples drawn from the virtual apples generator (``configs/campaigns/make_apples.py``,
  its four cultivars in their proportions scaled up to ``rows``), Kelvin-Voigt parameters from the
  model plugin with 1 % estimation noise, and the eight virtual assessors' scores.

Each command runs as its own process (``python -m mbus_framework.analysis.cli``): wall time,
its CPU time (user + system: what the work costs, whatever the machine's load), peak resident
memory of the child (ru_maxrss), the load average before and after, and the validation the
output names.
Targets (issue 24): classify at most 15 s with plots, crispness at most 5 min.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

REPO = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO / "tests")]


def classify_table(rows: int, seed: int = 0) -> pd.DataFrame:
    from fakes.campaign_tables import TABLE_4_3, grouped_table

    return grouped_table(TABLE_4_3, rows // len(TABLE_4_3), seed=seed)


def apples_table(rows: int, seed: int = 0) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(campaign table, panel) of ``rows`` virtual apples (see the module docstring)."""
    from virtual_apples import apple_model, generator

    gen = generator()
    total = sum(c[0] for c in gen.CULTIVARS.values())
    gen.CULTIVARS = {k: (max(1, round(v[0] * rows / total)), *v[1:]) for k, v in gen.CULTIVARS.items()}
    apples = gen.draw_apples(seed).iloc[:rows].reset_index(drop=True)
    apples["sample_id"] = [f"apple{k + 1:05d}" for k in range(len(apples))]
    model = apple_model()
    rng = np.random.default_rng(seed + 100)
    out = []
    for a in apples.itertuples(index=False):
        theta = model.from_properties({p: getattr(a, p) for p in gen.PROPERTIES})
        theta = theta * (1 + 0.01 * rng.normal(size=theta.size))
        out.append({"sample_id": a.sample_id, "cultivar": a.cultivar, **dict(zip(model.parameter_names, theta)),
                    **model.to_properties(theta), "success": True})
    panel = gen.simulate_panel(apples.sample_id, gen.RELATION(apples), gen.PANEL, seed=seed + 1)
    return pd.DataFrame(out), panel


def brute_force_lda_estimate(table: pd.DataFrame, folds: int = 200) -> dict:
    """The previous method, for comparison: scikit-learn LDA refitted per left-out sample.
    Times ``folds`` leave-one-out folds on all four log properties (one thread) and
    extrapolates to n folds x 7 property sets; also checks the closed form on those folds."""
    from sklearn.discriminant_analysis import LinearDiscriminantAnalysis
    from threadpoolctl import threadpool_limits

    from mbus_framework.analysis.classify.loo import closed_form_loo

    props = ["E_sigma", "eta_sigma", "E_tau", "eta_tau"]
    X = np.log10(table[props].to_numpy(dtype=float))
    groups = list(dict.fromkeys(table["material"]))
    labels = np.array([groups.index(g) for g in table["material"]])
    k, n = len(groups), len(labels)
    rows = np.random.default_rng(0).choice(n, folds, replace=False)
    pred = np.empty(folds, dtype=int)
    with threadpool_limits(1):
        t0 = time.process_time()
        for j, i in enumerate(rows):
            keep = np.arange(n) != i
            lda = LinearDiscriminantAnalysis(priors=np.full(k, 1.0 / k)).fit(X[keep], labels[keep])
            pred[j] = lda.predict(X[i:i + 1])[0]
        per_fold = (time.process_time() - t0) / folds
        t0 = time.process_time()
        fast = closed_form_loo(X, labels, k)
        closed = time.process_time() - t0
    return {"method": "sklearn LDA refitted per left-out sample (before)", "folds_timed": folds,
            "cpu_s_per_fold": round(per_fold, 5), "cpu_s_extrapolated_7_sets": round(per_fold * n * 7, 1),
            "closed_form_cpu_s_one_set": round(closed, 4), "agree_on_timed_folds": bool(np.array_equal(fast[rows], pred))}


def timed(args: list[str]) -> dict:
    """Run ``mbus-analyze ARGS`` in a new process: wall s, the child's peak RSS (MB), output."""
    ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    before = ru0.ru_maxrss
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "mbus_framework.analysis.cli", *args], capture_output=True, text=True,
                          cwd=REPO, env={**os.environ, "CI": "1"})
    wall = time.perf_counter() - t0
    ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    peak = ru1.ru_maxrss
    cpu = (ru1.ru_utime + ru1.ru_stime) - (ru0.ru_utime + ru0.ru_stime)
    if proc.returncode:
        raise SystemExit(f"mbus-analyze {' '.join(args)} failed ({proc.returncode}): {proc.stderr.strip()[-500:]}")
    return {"wall_s": round(wall, 2), "cpu_s": round(cpu, 2), "peak_rss_mb": round(max(peak, before) / 1024, 1), "stdout": proc.stdout,
            "stderr_lines": len(proc.stderr.splitlines())}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=10_000)
    ap.add_argument("--repeats", type=int, default=1, help="classify runs (median reported); crispness runs once")
    ap.add_argument("--skip-crispness", action="store_true")
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "analysis.json"))
    a = ap.parse_args()
    res: dict = {"rows": a.rows, "machine": {"python": platform.python_version(), "cpus": os.cpu_count(),
                                              "load_before": os.getloadavg()[0]}}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        table = tmp / "tissues.csv"
        classify_table(a.rows).to_csv(table, index=False)
        runs = [timed(["classify", str(table), "--by", "material", "--out", str(tmp / "classify")]) for _ in range(a.repeats)]
        doc = json.loads((tmp / "classify" / "classification.json").read_text())
        res["classify"] = {
            "command": "mbus-analyze classify TABLE --by material (7 property sets, k-means 20 restarts, LDA, figure)",
            "wall_s": [r["wall_s"] for r in runs], "median_wall_s": float(np.median([r["wall_s"] for r in runs])),
            "cpu_s": [r["cpu_s"] for r in runs], "median_cpu_s": float(np.median([r["cpu_s"] for r in runs])),
            "peak_rss_mb": max(r["peak_rss_mb"] for r in runs), "lda_validation": doc["lda"]["validation"],
            "lda_percent_all_four": doc["results"]["lda"][", ".join(doc["property_sets"][-1])]["percent_correct"],
            "figure_written": (tmp / "classify" / "discriminant_space.png").is_file(), "target_s": 15,
        }
        res["classify"]["lda_before"] = brute_force_lda_estimate(pd.read_csv(table))
        print(f"classify: {res['classify']['median_wall_s']} s wall, {res['classify']['median_cpu_s']} s CPU, {res['classify']['peak_rss_mb']} MB", flush=True)
        if not a.skip_crispness:
            t0 = time.perf_counter()
            apples, panel = apples_table(a.rows)
            build = time.perf_counter() - t0
            apples.to_csv(tmp / "apples.csv", index=False)
            panel.to_csv(tmp / "panel.csv", index=False)
            run = timed(["crispness", str(tmp / "apples.csv"), "--scores", str(tmp / "panel.csv"), "--group", "cultivar",
                         "-o", str(tmp / "crisp")])
            doc = json.loads((tmp / "crisp" / "crispness.json").read_text())
            res["crispness"] = {
                "command": "mbus-analyze crispness TABLE --scores PANEL --group cultivar (defaults: 8 structures, "
                           "6-neuron network, 5 members x 3 restarts, ridge baseline, figures)",
                "table_build_s": round(build, 1), "wall_s": run["wall_s"], "cpu_s": run["cpu_s"],
                "peak_rss_mb": run["peak_rss_mb"],
                "validation": doc["validation"], "structure_validation": doc.get("structure_validation"),
                "network_r": doc["input_sets"][0]["network"]["r"], "ridge_r": doc["input_sets"][0]["ridge"]["r"],
                "progress_lines_on_stderr": run["stderr_lines"], "target_s": 300,
            }
            print(f"crispness: {run['wall_s']} s wall, {run['cpu_s']} s CPU, {run['peak_rss_mb']} MB, {doc['validation']}", flush=True)
    res["machine"]["load_after"] = os.getloadavg()[0]
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(res, indent=1) + "\n")
    print(f"written: {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
