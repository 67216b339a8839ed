"""Long records (issue 24): fitting time and peak memory of the simulated potato
(configs/potato.yaml) on three long records, each fitted in a fresh process:

* ``explained_200k``: the potato record at 200,000 samples (the model explains it);
* ``mismatched_200k``: the 5,000-sample potato record's first 1,000 samples repeated 200
  times, so every period restarts a transient the model cannot explain (model mismatch);
  the search must end with its honest verdict;
* ``explained_2M``: the potato record at 2,000,000 samples, fitted or refused with a
  one-line reason.

    python benchmarks/long_records.py          # writes benchmarks/results/long_records.json
    python benchmarks/long_records.py --case mismatched_200k   # one case, printed as JSON
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "potato.yaml"
CASES = {"explained_200k": 200_000, "mismatched_200k": 200_000, "explained_2M": 2_000_000}
TARGETS = {"explained_200k": (20.0, 1.0), "mismatched_200k": (60.0, 1.0), "explained_2M": (60.0, 2.0)}


def _record(case: str, c, tmp: Path):
    """The case's record, acquired from the simulated backend of the potato config."""
    from mbus_framework.interfaces.backend import AcquisitionContext, Measurement
    from mbus_framework.pipeline.run import designed_waveform, load_components

    if case == "mismatched_200k":
        base = load_components(str(CONFIG))
        m = base.backend.acquire(AcquisitionContext(designed_waveform(base), base.sample, base.model,
                                                    base.registry, tmp, base.source))
        u, y = np.tile(m.u[:1000], 200), np.tile(m.y[:1000], 200)
        return Measurement(np.arange(len(u)) * m.dt, u, y, meta={"built": "potato first 1000 samples x 200"}), None
    designed = designed_waveform(c)
    return c.backend.acquire(AcquisitionContext(designed, c.sample, c.model, c.registry, tmp, c.source)), designed


def _cpu() -> float:
    """CPU seconds of this process (user + system): the machine's load does not count."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def run_case(case: str) -> dict:
    """Fit one case in this process: wall time of the estimate (fit and uncertainty), peak RSS."""
    from mbus_framework.errors import MbusError
    from mbus_framework.pipeline.run import estimate, load_components

    n = CASES[case]
    overrides = [] if case == "mismatched_200k" else [f"excitation.options.n_samples={n}"]
    row: dict = {"case": case, "n_samples": n}
    t0 = time.perf_counter()
    try:
        c = load_components(str(CONFIG), overrides)
        with tempfile.TemporaryDirectory() as tmp:
            m, designed = _record(case, c, Path(tmp))
            t1, c1 = time.perf_counter(), _cpu()
            out = estimate(c, m, designed)
        row["fit_s"], row["fit_cpu_s"] = time.perf_counter() - t1, _cpu() - c1
        fit, res = out.fit, out.result
        strategy = fit.strategy or {}
        row.update(outcome="fitted", nfev=fit.nfev, success=bool(fit.success), message=str(fit.message),
                   accepted_because=strategy.get("accepted_because"), parameters=fit.parameters,
                   fit_quality=res.get("fit_quality"), warnings=res.get("warnings", []))
    except MbusError as e:  # a refusal is a one-line reason
        row.update(outcome="refused", reason=str(e))
    row["wall_s"], row["cpu_s"] = time.perf_counter() - t0, _cpu()
    row["load_average"] = os.getloadavg()[0]
    row["peak_rss_gb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 ** 2
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", choices=sorted(CASES))
    args = ap.parse_args()
    if args.case:
        print(json.dumps(run_case(args.case), default=str))
        return
    rows = []
    for case in CASES:
        proc = subprocess.run([sys.executable, __file__, "--case", case], capture_output=True, text=True, cwd=ROOT)
        if proc.returncode:
            row = {"case": case, "outcome": "crashed", "stderr": proc.stderr[-2000:]}
        else:
            row = json.loads(proc.stdout.strip().splitlines()[-1])
            wall, gb = TARGETS[case]
            row["target"] = {"wall_s": wall, "peak_rss_gb": gb}
            row["met"] = row["wall_s"] <= wall and row["peak_rss_gb"] <= gb
        rows.append(row)
        print(f"{case:16} {row.get('outcome'):8} wall {row.get('wall_s', float('nan')):7.1f} s  "
              f"cpu {row.get('cpu_s', float('nan')):7.1f} s  "
              f"peak {row.get('peak_rss_gb', float('nan')):5.2f} GB  nfev {row.get('nfev', '-')}  "
              f"{row.get('accepted_because') or row.get('reason') or ''}")
    out = ROOT / "benchmarks" / "results" / "long_records.json"
    out.write_text(json.dumps(rows, indent=1, default=str) + "\n")
    print(f"written {out}")


if __name__ == "__main__":
    main()
