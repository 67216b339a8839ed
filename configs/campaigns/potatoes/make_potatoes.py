"""Generate the virtual potatoes campaign of Chapter 6 (sample sheet and conventional records).

Run from the repository root (it rewrites the files next to this script, identically for the
same seed):

    python configs/campaigns/potatoes/make_potatoes.py

30 potato slices (3 cm, as configs/potato.yaml). For each slice and property p, a conventional
value x_p is drawn uniformly over a range inside Table 6.2's "conventionally measured" range,
and the slice's true MBUS property (the simulated rig's truth, ``backend.options.truth.<p>`` in
the sample sheet) is the documented linear relation of the conventional value plus scatter:

    MBUS_p = intercept_p + slope_p * x_p + e_p,      e_p ~ N(0, scatter_p^2)      (RELATION)

i.e. the conventional value is a linear function of the MBUS truth plus noise. It is written
in this direction because Table 6.1 regresses MBUS on conventional: with the noise in MBUS,
ordinary least squares recovers exactly (intercept_p, slope_p). The normal-direction and E_tau
relations are Table 6.1's "compensated" lines; the eta_tau line is ours, because Table 6.1's
maps into shear viscosities (4.7e4-8.6e4 Pa s) at which a 3 cm potato's shear parameters cannot
be identified (DESIGN.md, Section 3); ours keeps eta_tau within 3e3-2.6e4 Pa s. The ranges of x
keep every MBUS truth positive (3 scatter SDs) and inside Table 6.2's "after compensation" range.

The conventional tests then measure x_p with the noise of real instruments (files in records/,
listed in conventional.csv):

* one cyclic compression record per slice (specimen 20 mm x 30 mm, 1 Hz, 0.2 mm, 400 Hz
  sampling, 4 cycles, preload and drift, force noise 0.5 % of the force amplitude,
  displacement noise 0.2 um): k = E A / l and b = eta A / l of the compression specimen;
* three rheometer sweeps per slice (0.1-100 rad/s, 20 points, power law around 10 Hz), each
  from a specimen whose E' and eta' differ from x_p by 2 % (specimen-to-specimen SD), with 1 %
  scatter per point.

The conventional noise is an error in the regressor; it attenuates the slopes by a factor
var(x) / (var(x) + var(noise)) > 0.998 here, far inside the slopes' 95 % intervals.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

SEED = 20100601
N_SAMPLES = 30
HERE = Path(__file__).resolve().parent

#: property -> (intercept [SI], slope [-], scatter SD [SI], x low, x high [SI]) of
#: MBUS = intercept + slope * conventional + N(0, scatter^2)
RELATION = {
    "E_sigma": (-1.560e10, 1.469e4, 4.0e9, 2.0e6, 4.99e6),     # Pa;   Table 6.1 compensated line
    "eta_sigma": (-1.121e4, 0.436, 1.2e3, 3.5e4, 6.85e4),     # Pa s; Table 6.1 compensated line
    "E_tau": (2.504e9, 2.437e4, 1.2e9, 7.41e4, 3.77e5),       # Pa;   Table 6.1 compensated line
    "eta_tau": (2.0e3, 25.0, 1.5e3, 2.30e2, 7.65e2),          # Pa s; ours (identifiable range)
}
SPECIMEN = {"length": 0.030, "diameter": 0.020}      # m, compression specimen (Section 6.2.3.2)
COMPRESSION = {"frequency": 1.0, "amplitude": 0.2e-3, "sample_rate": 400.0, "cycles": 4.0}
SHEAR_REPLICATES = 3
SHEAR_SPECIMEN_SD = 0.02   # relative specimen-to-specimen SD of E' and eta'
SHEAR_POINT_SCATTER = 0.01
FORCE_NOISE = 0.005        # relative to the force amplitude
DISPLACEMENT_NOISE = 0.2e-6  # m


def draw_samples(seed: int = SEED, n: int = N_SAMPLES):
    """One row per slice: sample_id, seed, conventional truth x_p, MBUS truth y_p."""
    import pandas as pd

    rng = np.random.default_rng(seed)
    rows = {"sample_id": [f"P{i + 1:02d}" for i in range(n)], "seed": 1000 + np.arange(n)}
    for prop, (a, b, sd, lo, hi) in RELATION.items():
        x = rng.uniform(lo, hi, n)
        rows[f"true_conv_{prop}"] = x
        rows[prop] = a + b * x + sd * rng.standard_normal(n)
    return pd.DataFrame(rows)


def write_campaign(folder: Path = HERE, seed: int = SEED, n: int = N_SAMPLES):
    """Write samples.csv, conventional.csv and records/ into ``folder``; return the draw."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
    from mbus_framework.analysis.conventional.synthetic import (compression_record, rheometer_sweep,
                                                                write_compression_csv, write_sweep_csv)
    import pandas as pd

    samples = draw_samples(seed, n)
    rng = np.random.default_rng(seed + 1)
    records = folder / "records"
    records.mkdir(parents=True, exist_ok=True)
    area = math.pi * SPECIMEN["diameter"] ** 2 / 4.0
    shape = SPECIMEN["length"] / area
    conventional = []
    for row in samples.itertuples(index=False):
        k, b = row.true_conv_E_sigma / shape, row.true_conv_eta_sigma / shape
        omega = 2.0 * math.pi * COMPRESSION["frequency"]
        force_amplitude = COMPRESSION["amplitude"] * math.hypot(k, omega * b)
        rec = compression_record(k, b, **COMPRESSION, phase=rng.uniform(0, 2 * math.pi),
                                 preload=0.05 * force_amplitude, offset=1.0e-3, creep=2.0e-6,
                                 relaxation=-0.002 * force_amplitude,
                                 force_noise=FORCE_NOISE * force_amplitude,
                                 displacement_noise=DISPLACEMENT_NOISE, rng=rng)
        name = f"records/{row.sample_id}_compression.csv"
        write_compression_csv(folder / name, rec)
        conventional.append({"sample_id": row.sample_id, "test": "compression", "file": name,
                             "length [mm]": SPECIMEN["length"] * 1e3, "diameter [mm]": SPECIMEN["diameter"] * 1e3,
                             "frequency [Hz]": COMPRESSION["frequency"]})
        for rep in range(1, SHEAR_REPLICATES + 1):
            spec = 1.0 + SHEAR_SPECIMEN_SD * rng.standard_normal(2)
            sweep = rheometer_sweep(row.true_conv_E_tau * spec[0], row.true_conv_eta_tau * spec[1],
                                    scatter=SHEAR_POINT_SCATTER, rng=rng)
            name = f"records/{row.sample_id}_shear_{rep}.csv"
            write_sweep_csv(folder / name, sweep)
            conventional.append({"sample_id": row.sample_id, "test": "rheometer", "file": name})
    pd.DataFrame(conventional).to_csv(folder / "conventional.csv", index=False)
    sheet = pd.DataFrame({"sample_id": samples["sample_id"], "backend.options.seed": samples["seed"]})
    for prop in RELATION:
        sheet[f"backend.options.truth.{prop}"] = samples[prop].map(lambda v: float(f"{v:.6g}"))
    for prop in RELATION:
        sheet[f"true_conv_{prop}"] = samples[f"true_conv_{prop}"].map(lambda v: float(f"{v:.6g}"))
    sheet.to_csv(folder / "samples.csv", index=False)
    return samples


if __name__ == "__main__":
    drawn = write_campaign()
    print(f"wrote {len(drawn)} samples to {HERE}")
