"""Benchmark: joint fits over several records of one material (issue 25).

Run on demand (not part of the test suite):

    python benchmarks/joint_benchmark.py [--cases 40] [--mismatch 20] [--seed 1] [--out benchmarks/results/joint.json]

Each case draws 2-5 simulated records of the potato of configs/potato.yaml (Table 6.2 truth,
Kelvin-Voigt chain, n = ``--elements``): lengths 1.5-4 cm, record lengths 1000-2000 samples
(h = 40 ns, random-telegraph ZOH input with 10-sample bits), input gains log-uniform within
a factor 3 of each other (0.58-1.73), delays 0-20 samples, noise 1-10 % of the output RMS,
each record its own seed. The joint fit (per-record input gain and delay, all four
properties shared) starts from the per-record fits (the default global strategy). Measured:

* recovery: every shared property within 4 joint standard errors of the truth (target >= 95 %);
* coverage: the truth inside the 95 % interval, per property (target 92-98 %);
* the joint SE below the best single-record SE, per property;
* agreement p-value on true cases (false alarms at the 1 % level);
* mismatch cases (``--mismatch``): the same draw with one record of another potato (each
  property x/÷ 1.1-1.3 off): flagged at the 1 % level (target >= 90 %).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import mbus_framework as mbus  # noqa: E402
from mbus_framework.estimation.nuisance import delayed_prediction  # noqa: E402
from mbus_framework.interfaces.sample import Sample  # noqa: E402
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions  # noqa: E402

POTATO = {"E_sigma": 2.42e10, "eta_sigma": 7.18e3, "E_tau": 6.56e9, "eta_tau": 5.14e3}
DIAMETER, DENSITY, DT = 0.0254, 1080.0, 4e-8


def simulate(rng, length, truth, gain, delay_samples, noise, n, n_elements):
    u = np.repeat(rng.choice([-1.0, 1.0], size=n // 10 + 1), 10)[:n]
    model = KelvinVoigtChain(Sample(length, DIAMETER, DENSITY), KelvinVoigtOptions(n_elements=n_elements))
    y = delayed_prediction(model, model.from_properties(truth), u, DT, gain, delay_samples * DT)
    y = y + noise * np.sqrt(np.mean(y**2)) * rng.standard_normal(n)
    return mbus.Record(np.arange(n) * DT, u, y)


def draw(rng):
    k = int(rng.integers(2, 6))
    gains = np.exp(rng.uniform(np.log(1 / np.sqrt(3)), np.log(np.sqrt(3)), k))
    return [dict(length=float(rng.uniform(0.015, 0.04)), gain=float(g), delay_samples=float(rng.uniform(0, 20)),
                 noise=float(rng.uniform(0.01, 0.10)), n=int(rng.integers(1000, 2001)), seed=int(rng.integers(1 << 30)))
            for g in gains]


def run_case(specs, truths, n_elements):
    records = [simulate(np.random.default_rng(s["seed"]), s["length"], t, s["gain"], s["delay_samples"], s["noise"],
                        s["n"], n_elements) for s, t in zip(specs, truths)]
    samples = [{"length": s["length"], "diameter": DIAMETER, "density": DENSITY} for s in specs]
    t0 = time.perf_counter()
    joint = mbus.fit(records, sample=samples, model="kelvin_voigt", model_options={"n_elements": n_elements},
                     per_record=["input_gain", "delay"])
    return joint, time.perf_counter() - t0


def evaluate(joint):
    d = joint.document
    out = {"p_value": d["agreement"]["p_value"], "within_4se": True, "covered": {}, "joint_se_smaller": {},
           "z": {}, "success": d["solver"]["success"]}
    for name, truth in POTATO.items():
        e = joint.properties[name]
        z = (e.value - truth) / e.std_error
        out["z"][name] = z
        out["within_4se"] &= abs(z) <= 4
        out["covered"][name] = e.ci95[0] <= truth <= e.ci95[1]
        singles = [r["own_fit"]["property_standard_errors"].get(name, np.inf) for r in d["records"]]
        out["joint_se_smaller"][name] = e.std_error < min(singles)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=40)
    ap.add_argument("--mismatch", type=int, default=20)
    ap.add_argument("--elements", type=int, default=4)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    rng = np.random.default_rng(a.seed)
    cases, mismatches = [], []
    for i in range(a.cases):
        specs = draw(rng)
        joint, wall = run_case(specs, [POTATO] * len(specs), a.elements)
        cases.append({"records": specs, "wall_s": wall, **evaluate(joint)})
        c = cases[-1]
        print(f"case {i + 1}: {len(specs)} records, within 4 SE {c['within_4se']}, p {c['p_value']:.3g}, "
              f"z {', '.join(f'{v:+.2f}' for v in c['z'].values())}, {wall:.1f} s", flush=True)
    for i in range(a.mismatch):
        specs = draw(rng)
        other = {n: v * float(np.exp(rng.choice([-1, 1]) * rng.uniform(np.log(1.1), np.log(1.3))))
                 for n, v in POTATO.items()}
        truths = [POTATO] * (len(specs) - 1) + [other]
        joint, wall = run_case(specs, truths, a.elements)
        mismatches.append({"records": specs, "other": other, "p_value": joint.agreement["p_value"],
                           "flagged": not joint.agreement["agree"], "warned": any("do not agree" in w for w in joint.warnings),
                           "wall_s": wall})
        print(f"mismatch {i + 1}: {len(specs)} records, p {joint.agreement['p_value']:.3g}", flush=True)
    names = list(POTATO)
    summary = {
        "cases": len(cases),
        "recovered_within_4se": float(np.mean([c["within_4se"] for c in cases])) if cases else None,
        "coverage_95": {n: float(np.mean([c["covered"][n] for c in cases])) for n in names} if cases else None,
        "coverage_95_all": float(np.mean([c["covered"][n] for c in cases for n in names])) if cases else None,
        "joint_se_smaller": float(np.mean([c["joint_se_smaller"][n] for c in cases for n in names])) if cases else None,
        "false_alarms_1pct": float(np.mean([c["p_value"] < 0.01 for c in cases])) if cases else None,
        "mismatch_cases": len(mismatches),
        "mismatch_flagged_1pct": float(np.mean([m["flagged"] and m["warned"] for m in mismatches])) if mismatches else None,
        "median_wall_s": float(np.median([c["wall_s"] for c in cases + mismatches])) if cases or mismatches else None,
    }
    print(json.dumps(summary, indent=2))
    if a.out:
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        Path(a.out).write_text(json.dumps({"summary": summary, "cases": cases, "mismatch": mismatches,
                                           "options": vars(a)}, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
