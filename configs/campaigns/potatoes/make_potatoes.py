"""Generate the virtual potatoes campaign of Chapter 6 (sample sheet and conventional records).

Run from the repository root (it rewrites the files next to this script, identically for the
same seed):

    python configs/campaigns/potatoes/make_potatoes.py

30 potato slices (3 cm, as configs/potato.yaml), with the error sources Chapter 6 names
(Section 6.3: frequency dependence, specimens cut differently, coupling and contact), sized
from its Tables 6.1 and 6.2. For each slice and property p:

1. **The potato's low-frequency property** x_p (``true_conv_<p>`` in the sample sheet) is
   drawn uniformly over a range inside Table 6.2's "conventionally measured" range.
2. **Heterogeneity between what the two methods probe** (frequency dependence: 1-10 Hz against
   0.3-0.7 MHz, and a different piece of tissue): the slice's MBUS property (the simulated
   rig's truth, ``backend.options.truth.<p>``) scatters multiplicatively about the calibration
   line of x_p,

       MBUS_p = (intercept_p + slope_p * x_p) * exp(s_p Z) / c(s_p),   |Z| <= Z_MAX   (RELATION)

   with Z standard normal truncated symmetrically at Z_MAX (so every truth stays positive and
   inside the identifiable range), drawn independent of x_p (in the drawn sample its
   projection on the conventional values is removed: ``independent_of``) and c(s) = E[exp(s Z)] (closed form), so that
   E[MBUS_p | x_p] = intercept_p + slope_p x_p exactly and ordinary least squares of MBUS on
   conventional recovers (intercept_p, slope_p). The normal-direction and E_tau lines are
   Table 6.1's "compensated" lines; the eta_tau line is ours, because Table 6.1's maps into
   shear viscosities (4.7e4-8.6e4 Pa s) at which a 3 cm potato's shear parameters cannot be
   identified (DESIGN.md, Section 3).
3. **Conventional-test error**: the compression specimen and each of the three rheometer
   specimens are separate cylinders whose properties differ from x_p by a specimen-to-specimen
   SD of ``SPECIMEN_SD`` (5 %), and the instruments add their own noise (below).
4. **MBUS measurement noise** is the rig's own: 3 % output noise per record
   (configs/potato.yaml), about 0.2 % on each estimated property.

The heterogeneity SD s_p is the one that sizes the campaign: it is solved (per property, for
the drawn slices) so that the correlation between the 30 MBUS truths and the conventional
specimens' values equals Table 6.1's compensated r (``TARGET_R``: 0.780, 0.568, 0.352,
0.476). The spread of the truths then matches Table 6.2's "after compensation" SDs, which
Table 6.1 implies (SD_MBUS = slope SD_conv / r: 1.82e10 Pa for E_sigma, as tabulated).

The conventional tests then measure the specimens with the noise of real instruments (files
in records/, listed in conventional.csv):

* one cyclic compression record per slice (specimen 20 mm x 30 mm, 1 Hz, 0.2 mm, 400 Hz
  sampling, 4 cycles, preload and drift, force noise 0.5 % of the force amplitude,
  displacement noise 0.2 um): k = E A / l and b = eta A / l of the compression specimen;
* three rheometer sweeps per slice (0.1-100 rad/s, 20 points, power law around 10 Hz), one
  per specimen, with 1 % scatter per point.

The specimen error attenuates the fitted slopes by var(x) / (var(x) + var(specimen error)),
0.96-0.99 here, inside the slopes' 95 % intervals at these correlations.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

SEED = 20100601
N_SAMPLES = 30
HERE = Path(__file__).resolve().parent

#: property -> (intercept [SI], slope [-], x low, x high [SI]) of the line
#: E[MBUS | x] = intercept + slope * x
RELATION = {
    "E_sigma": (-1.560e10, 1.469e4, 2.0e6, 4.99e6),     # Pa;   Table 6.1 compensated line
    "eta_sigma": (-1.121e4, 0.436, 3.5e4, 6.85e4),     # Pa s; Table 6.1 compensated line
    "E_tau": (2.504e9, 2.437e4, 7.41e4, 3.77e5),       # Pa;   Table 6.1 compensated line
    "eta_tau": (2.0e3, 25.0, 2.30e2, 7.65e2),          # Pa s; ours (identifiable range)
}
#: Table 6.1, compensated: r between MBUS and conventional (N = 30)
TARGET_R = {"E_sigma": 0.780, "eta_sigma": 0.568, "E_tau": 0.352, "eta_tau": 0.476}
#: Table 6.1, uncompensated (what potatoes_uncompensated.yaml is compared with)
TARGET_R_UNCOMPENSATED = {"E_sigma": 0.770, "eta_sigma": 0.645, "E_tau": 0.617, "eta_tau": 0.491}
#: where the truths stay (checked by tests/test_calibrate_potatoes.py): Table 6.2 "MBUS after
#: compensation" min-max, E_tau's widened to 1e9-3e10 Pa for the +-2 SD tails of its large
#: scatter, and eta_tau's identifiable range (every slice of the shipped draw is fitted within
#: 0.3 % of its truth, without a warning)
TRUTH_RANGE = {"E_sigma": (4.84e9, 7.41e10), "eta_sigma": (4.87e2, 3.83e4), "E_tau": (1.0e9, 3.0e10),
               "eta_tau": (3.0e3, 3.2e4)}
Z_MAX = 2.0                # heterogeneity truncated at +-2 SD
SPECIMEN_SD = 0.05         # relative specimen-to-specimen SD of the conventional specimens
SPECIMEN = {"length": 0.030, "diameter": 0.020}      # m, compression specimen (Section 6.2.3.2)
COMPRESSION = {"frequency": 1.0, "amplitude": 0.2e-3, "sample_rate": 400.0, "cycles": 4.0}
SHEAR_REPLICATES = 3
SHEAR_POINT_SCATTER = 0.01
FORCE_NOISE = 0.005        # relative to the force amplitude
DISPLACEMENT_NOISE = 0.2e-6  # m


def truncated_normal(rng: np.random.Generator, n: int, limit: float = Z_MAX) -> np.ndarray:
    """n standard normal draws truncated to |Z| <= limit (redrawn until inside)."""
    z = rng.standard_normal(n)
    while np.any(bad := np.abs(z) > limit):
        z[bad] = rng.standard_normal(int(bad.sum()))
    return z


def lognormal_mean(s: float, limit: float = Z_MAX) -> float:
    """c(s) = E[exp(s Z)] for Z standard normal truncated to |Z| <= limit:
    exp(s^2 / 2) (Phi(limit - s) - Phi(-limit - s)) / (Phi(limit) - Phi(-limit))."""
    phi = lambda v: 0.5 * math.erfc(-v / math.sqrt(2.0))  # noqa: E731
    return math.exp(s * s / 2.0) * (phi(limit - s) - phi(-limit - s)) / (phi(limit) - phi(-limit))


def independent_of(z: np.ndarray, x: np.ndarray, limit: float = Z_MAX) -> np.ndarray:
    """z with its least-squares projection on (1, x) removed, rescaled to unit SD and clipped to
    +-limit: heterogeneity uncorrelated with the conventional values in the drawn sample, so
    that the sample's correlation follows s smoothly (a chance alignment of 30 draws with x
    would otherwise decide it)."""
    design = np.column_stack([np.ones_like(x), x])
    resid = z - design @ np.linalg.lstsq(design, z, rcond=None)[0]
    return np.clip(resid / resid.std(), -limit, limit)


def heterogeneity_sd(line: np.ndarray, z: np.ndarray, observed: np.ndarray, target: float) -> float:
    """The s >= 0 at which corr(line exp(s z) / c(s), observed) equals ``target`` (bisection;
    the correlation falls from its s = 0 value as s grows)."""
    def corr(s: float) -> float:
        return float(np.corrcoef(line * np.exp(s * z) / lognormal_mean(s), observed)[0, 1])

    if corr(0.0) <= target:
        return 0.0
    lo, hi = 0.0, 0.5
    while corr(hi) > target:
        lo, hi = hi, 2.0 * hi
        if hi > 20.0:
            raise ValueError(f"no heterogeneity SD reaches r = {target}")
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if corr(mid) > target else (lo, mid)
    return 0.5 * (lo + hi)


def draw_samples(seed: int = SEED, n: int = N_SAMPLES):
    """One row per slice: sample_id, seed, x_p (``true_conv_<p>``), the compression specimen's
    and the three rheometer specimens' values (``specimen_<p>``: compression value, or a list of
    three), their mean as the conventional tests see them (``observed_conv_<p>``), the solved
    heterogeneity SD (``heterogeneity_sd_<p>``) and the MBUS truth y_p."""
    import pandas as pd

    rng = np.random.default_rng(seed)
    rows = {"sample_id": [f"P{i + 1:02d}" for i in range(n)], "seed": 1000 + np.arange(n)}
    for prop, (a, b, lo, hi) in RELATION.items():
        x = rng.uniform(lo, hi, n)
        shear = prop.endswith("tau")
        factors = 1.0 + SPECIMEN_SD * rng.standard_normal((n, SHEAR_REPLICATES if shear else 1))
        specimens = x[:, None] * factors
        observed = specimens.mean(axis=1)
        z = independent_of(truncated_normal(rng, n), observed)
        line = a + b * x
        s = heterogeneity_sd(line, z, observed, TARGET_R[prop])
        rows[f"true_conv_{prop}"] = x
        rows[f"specimen_{prop}"] = list(specimens)
        rows[f"observed_conv_{prop}"] = observed
        rows[f"heterogeneity_sd_{prop}"] = np.full(n, s)
        rows[prop] = line * np.exp(s * z) / lognormal_mean(s)
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
        k, b = row.specimen_E_sigma[0] / shape, row.specimen_eta_sigma[0] / shape
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
        for rep in range(SHEAR_REPLICATES):
            sweep = rheometer_sweep(row.specimen_E_tau[rep], row.specimen_eta_tau[rep],
                                    scatter=SHEAR_POINT_SCATTER, rng=rng)
            name = f"records/{row.sample_id}_shear_{rep + 1}.csv"
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
    sizes = ", ".join(f"{p} {drawn[f'heterogeneity_sd_{p}'].iloc[0]:.3f}" for p in RELATION)
    print(f"wrote {len(drawn)} samples to {HERE}; heterogeneity SDs (of ln MBUS): {sizes}")
