"""Benchmark: a potatoes campaign whose replicates differ in gain and delay, fitted jointly
(``campaign.replicates: joint``) against the averaged-record fit (``replicates: average``)
(issue 25).

Run on demand (not part of the test suite):

    python benchmarks/campaign_replicates.py [--samples 8] [--replicates 3] [--elements 6]
        [--n-samples 2500] [--workers 2] [--seed 1] [--out benchmarks/results/campaign_replicates.json]
        [--figure docs/img/campaign_replicates.png] [--plot-only]

The first ``--samples`` slices of configs/campaigns/potatoes/samples.csv (their true
properties, configs/potato.yaml's rig: PRBS at 25 MS/s, 3 % noise) are each measured
``--replicates`` times, each replicate re-coupled: input gain log-uniform in 0.5-2, delay
uniform in 0-10 samples (integer), its own noise seed. The same sheet runs twice through
:func:`mbus_framework.campaigns.run_campaign`, once with ``replicates: joint`` and once with
``replicates: average`` (the base config fits no gain or delay, as the averaged campaign did).
Measured per sample and property: the relative error |estimate - truth| / truth of each;
a sample counts as closer with the joint fit when its RMS relative error over the four
properties is smaller (the target: every sample), and per property the fraction of samples
closer. ``--elements`` and ``--n-samples`` shrink the rig's chain and records to keep the run short.
"""
from __future__ import annotations

import argparse
import csv
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mbus_framework.campaigns import run_campaign  # noqa: E402

PROPS = ["E_sigma", "eta_sigma", "E_tau", "eta_tau"]
SHEET = ROOT / "configs" / "campaigns" / "potatoes" / "samples.csv"
BASE = ROOT / "configs" / "potato.yaml"
DT = 1 / 25.0e6


def sheet_rows(n_samples: int, n_replicates: int, seed: int) -> tuple[list[dict], dict[str, dict]]:
    rng = np.random.default_rng(seed)
    with open(SHEET, newline="", encoding="utf-8") as fh:
        slices = list(csv.DictReader(fh))[:n_samples]
    rows, truths = [], {}
    for s in slices:
        truth = {p: float(s[f"backend.options.truth.{p}"]) for p in PROPS}
        truths[s["sample_id"]] = truth
        for r in range(1, n_replicates + 1):
            rows.append({"sample_id": s["sample_id"], "replicate": r, "backend.options.seed": int(rng.integers(1 << 30)),
                         "backend.options.input_gain": float(np.exp(rng.uniform(np.log(0.5), np.log(2.0)))),
                         "backend.options.delay": int(rng.integers(0, 11)) * DT,
                         **{f"backend.options.truth.{p}": truth[p] for p in PROPS}})
    return rows, truths


def write(folder: Path, rows: list[dict], mode: str, elements: int, n_samples: int) -> Path:
    base = yaml.safe_load(BASE.read_text(encoding="utf-8"))
    base["model"]["options"]["n_elements"] = elements
    base["excitation"]["options"]["n_samples"] = n_samples
    base["output"] = {"plots": False}
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "base.yaml").write_text(yaml.safe_dump(base, sort_keys=False))
    with open(folder / "samples.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]), lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
    path = folder / f"potatoes_{mode}.yaml"
    path.write_text(yaml.safe_dump({"campaign": {"title": f"potatoes, replicates {mode}", "base": "base.yaml",
                                                 "samples": "samples.csv", "replicates": mode}}, sort_keys=False))
    return path


def errors(table, truths) -> dict[str, dict[str, float]]:
    out = {}
    for _, row in table.iterrows():
        t = truths[row["sample_id"]]
        out[row["sample_id"]] = {p: abs(row[p] - t[p]) / t[p] for p in PROPS}
    return out


def plot(report: dict, path: Path) -> Path:
    """Per sample and property: relative error of the joint and of the averaged-record fit (log scale)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    samples = list(report["samples"])
    fig, axes = plt.subplots(1, len(PROPS), figsize=(13, 3.4), sharey=True)
    x = np.arange(len(samples))
    for ax, p in zip(axes, PROPS):
        for k, (mode, colour) in enumerate((("joint", "C0"), ("average", "C3"))):
            v = [100 * report["samples"][s][mode][p] for s in samples]
            ax.bar(x + (k - 0.5) * 0.4, v, 0.4, color=colour, label=f"{mode} fit")
        ax.set_yscale("log")
        ax.set_title(p)
        ax.set_xticks(x, samples, rotation=90, fontsize=7)
    axes[0].set_ylabel("|estimate - truth| / truth [%]")
    axes[0].legend(fontsize=8)
    s = report["settings"]
    fig.suptitle(f"potato slices, {s['replicates']} replicates each (gain 0.5-2x, delay 0-10 samples): "
                 f"joint vs averaged-record fit", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=8)
    ap.add_argument("--replicates", type=int, default=3)
    ap.add_argument("--elements", type=int, default=6)
    ap.add_argument("--n-samples", type=int, default=2500)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "campaign_replicates.json")
    ap.add_argument("--figure", type=Path, default=ROOT / "docs" / "img" / "campaign_replicates.png")
    ap.add_argument("--plot-only", action="store_true", help="redraw the figure from --out, fit nothing")
    args = ap.parse_args(argv)
    if args.plot_only:
        print(plot(json.loads(args.out.read_text(encoding="utf-8")), args.figure))
        return 0
    rows, truths = sheet_rows(args.samples, args.replicates, args.seed)
    settings = {k: v for k, v in vars(args).items() if k not in ("out", "figure", "plot_only")}
    report = {"settings": settings, "replicates": rows, "runs": {}}
    tables = {}
    with tempfile.TemporaryDirectory() as tmp:
        for mode in ("joint", "average"):
            path = write(Path(tmp) / mode, rows, mode, args.elements, args.n_samples)
            t0 = time.perf_counter()
            result = run_campaign(path, Path(tmp) / mode / "out", workers=args.workers, progress=False)
            tables[mode] = result.table
            report["runs"][mode] = {"wall_time_s": time.perf_counter() - t0, "failed": result.failed}
            if mode == "joint":
                report["agreement_p_value"] = dict(zip(result.table["sample_id"], result.table["agreement_p_value"]))
    err = {mode: errors(t, truths) for mode, t in tables.items()}
    per_sample = {}
    for s in truths:
        j = float(np.sqrt(np.mean([err["joint"][s][p] ** 2 for p in PROPS])))
        a = float(np.sqrt(np.mean([err["average"][s][p] ** 2 for p in PROPS])))
        per_sample[s] = {"joint_rms_rel_error": j, "average_rms_rel_error": a, "joint_closer": j < a,
                         "joint": err["joint"][s], "average": err["average"][s]}
    report["samples"] = per_sample
    report["summary"] = {
        "samples_closer_with_joint": sum(v["joint_closer"] for v in per_sample.values()),
        "n_samples": len(per_sample),
        "property_closer_fraction": {p: float(np.mean([err["joint"][s][p] < err["average"][s][p] for s in truths]))
                                     for p in PROPS},
        "median_rel_error": {mode: {p: float(np.median([err[mode][s][p] for s in truths])) for p in PROPS}
                             for mode in err},
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2, default=float))
    plot(report, args.figure)
    print(json.dumps(report["summary"], indent=2))
    for s, v in per_sample.items():
        print(f"{s}: joint {100 * v['joint_rms_rel_error']:.2f} %  average {100 * v['average_rms_rel_error']:.2f} %  "
              f"p = {report['agreement_p_value'][s]:.3g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
