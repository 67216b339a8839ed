"""Real records: every material law on the shipped VeroWhite plates, judged against the
model-free measurement of the same record (issue 23 criteria), with the time of each
whole analysis (spectra, model-free inversion, fit; median of 5).

    python benchmarks/real_records.py        # writes benchmarks/results/real_records.json
"""
from __future__ import annotations

import json
import time
from pathlib import Path

from mbus_framework.substitution.analysis import analyse
from mbus_framework.substitution.chains import ALL_LAWS
from mbus_framework.substitution.record import read_mat

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "examples" / "real" / "thetascan"


def main() -> None:
    rows = []
    for name in ("VW100a", "VW0"):
        record = read_mat(DATA / f"{name}.mat")
        for law in ALL_LAWS:
            times = []
            for _ in range(5):
                t = time.perf_counter()
                a = analyse(record, [law])
                times.append(time.perf_counter() - t)
            fit = a.best
            rows.append({
                "record": name, "law": law, "passed": a.passed(), "explained_in_band_energy": fit.explained,
                "bic": fit.bic, "nfev": fit.nfev, "median_analysis_s": sorted(times)[2],
                "properties": dict(zip(fit.law.parameters, map(float, fit.values))),
                "checks": a.checks(),
            })
            print(f"{name:7} {law:13} passed={a.passed()!s:5} explained={100 * fit.explained:6.2f} % "
                  f"BIC={fit.bic:8.1f} nfev={fit.nfev:4d} {1e3 * sorted(times)[2]:7.1f} ms")
    out = ROOT / "benchmarks" / "results" / "real_records.json"
    out.write_text(json.dumps(rows, indent=1) + "\n")
    print(f"written {out}")


if __name__ == "__main__":
    main()
