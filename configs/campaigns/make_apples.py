"""Generate the virtual apples campaign of Chapter 7 (docs/crispness.md), seeded.

    python configs/campaigns/make_apples.py            # writes apples_samples.csv, apples_panel.csv
    python configs/campaigns/make_apples.py --stand-in-table TABLE.csv --fit runs/<apple_slice>/result.json

Samples: 46 apples of four cultivars (counts of Table 7.2), one 6 mm slice each, measured
three times (replicates averaged before the fit, Section 7.2.2). Per-sample truth of the
simulated rig: density and the four Kelvin-Voigt properties, drawn per cultivar from
log-normal distributions (ln E_sigma and ln E_tau correlated, rho = 0.4) truncated to the box
in which a 6 mm slice is identifiable (``BOX``; docs/crispness.md).

Sensory scores (0-9 line, eight assessors), with the error sources of Chapter 7: the
*true* crispness is the documented nonlinear relation ``RELATION`` of the stiffnesses of the
half that is eaten,

    s = 9 / (1 + exp(-z)),
    z = 0.4 + 3.2 ln(E_sigma,half / 2.4e10 Pa) + 1.0 ln(E_tau,half / 4.5e9 Pa)

(crispness rises with normal stiffness most and with shear stiffness less; the viscosities do
not enter: the dissertation's conclusion, Section 7.4). The coefficients are sized from Table
7.4's two-input model: over the 46 apples a 10 % change moves the true score by 0.49 (E_sigma)
and 0.15 (E_tau) on average. Error sources between the MBUS values and the panel's mean score:

* **two halves of one apple** (Section 7.2.1: one half is measured, the other eaten, 1-4 h
  later): ln E_sigma,half = ln E_sigma + HALF_SD Z and likewise for E_tau, HALF_SD = 5 %;
* **panel noise**: each assessor scores with an own offset and gain and noise (``PANEL``;
  :mod:`mbus_framework.analysis.crispness.virtual_panel`): offsets SD 0.7, gains SD 0.12,
  noise SD 1.0 (the assessor means spread 4.3-6.3, Table 7.1's 4.4-7.0);
* **MBUS measurement noise**: the rig's 5 % output noise per record, three records averaged.

``--stand-in-table`` writes, without running the campaign, a table in the campaign-table
format from the same truth plus estimation noise drawn with the relative standard errors and
the correlation matrix that a single-record fit reports (``--fit``: its result.json), divided
by sqrt(3) for the three averaged records.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pandas as pd

from mbus_framework.analysis.crispness.virtual_panel import LogisticRelation, PanelNoise, simulate_panel

HERE = Path(__file__).resolve().parent
SEED = 20100202
REPLICATES = 3
PROPERTIES = ("E_sigma", "eta_sigma", "E_tau", "eta_tau")

#: cultivar -> (number of apples, density mean and SD [kg/m^3], median properties [Pa, Pa s])
CULTIVARS = {
    "Fuji": (8, 845.0, 15.0, {"E_sigma": 2.9e10, "eta_sigma": 2.6e3, "E_tau": 5.0e9, "eta_tau": 6.5e3}),
    "Red Delicious": (12, 810.0, 20.0, {"E_sigma": 2.0e10, "eta_sigma": 3.4e3, "E_tau": 4.0e9, "eta_tau": 7.5e3}),
    "Golden Delicious": (15, 800.0, 20.0, {"E_sigma": 2.9e10, "eta_sigma": 2.6e3, "E_tau": 4.8e9, "eta_tau": 7.0e3}),
    "Granny Smith": (11, 830.0, 15.0, {"E_sigma": 2.4e10, "eta_sigma": 3.2e3, "E_tau": 5.0e9, "eta_tau": 6.8e3}),
}
#: within-cultivar SD of ln(property) (ripeness and storage spread the fruit widely)
LOG_SD = {"E_sigma": 0.35, "eta_sigma": 0.30, "E_tau": 0.30, "eta_tau": 0.20}
#: correlation of ln E_sigma and ln E_tau within a cultivar (firm flesh is firm both ways)
RHO_STIFFNESS = 0.4
#: box in which a 6 mm slice is identifiable: Cramer-Rao relative SEs below 1.3 % at 100 random
#: points (three averaged 5 % records). Higher viscosities bring the chain's last oscillatory
#: modes to critical damping, where k_sigma, k_tau and b_tau cannot be told apart (SEs of
#: 15-30 %, e.g. E_sigma 2.4e10, eta_sigma 5.2e3, E_tau 5.5e9, eta_tau 1.4e4); docs/crispness.md.
BOX = {"E_sigma": (1.0e10, 5.5e10), "eta_sigma": (1.2e3, 5.0e3), "E_tau": (1.8e9, 1.2e10), "eta_tau": (5.0e3, 1.0e4)}

RELATION = LogisticRelation(
    coefficients={"E_sigma": 3.2, "E_tau": 1.0},
    reference={"E_sigma": 2.4e10, "E_tau": 4.5e9},
    intercept=0.4,
)
#: SD of ln(stiffness) between the measured and the eaten half of one apple
HALF_SD = 0.05
PANEL = PanelNoise(n_assessors=8, offset_sd=0.7, gain_sd=0.12, noise_sd=1.0, resolution=0.1)


def draw_apples(seed: int = SEED) -> pd.DataFrame:
    """One row per apple: sample_id, cultivar, density and the true properties."""
    rng = np.random.default_rng(seed)
    cov = np.diag([LOG_SD[p] ** 2 for p in PROPERTIES])
    i, j = PROPERTIES.index("E_sigma"), PROPERTIES.index("E_tau")
    cov[i, j] = cov[j, i] = RHO_STIFFNESS * LOG_SD["E_sigma"] * LOG_SD["E_tau"]
    rows = []
    for cultivar, (n, rho_mean, rho_sd, median) in CULTIVARS.items():
        mean = np.log([median[p] for p in PROPERTIES])
        for _ in range(n):
            while True:  # truncate to the identifiable box
                values = dict(zip(PROPERTIES, np.exp(rng.multivariate_normal(mean, cov))))
                if all(BOX[p][0] <= values[p] <= BOX[p][1] for p in PROPERTIES):
                    break
            density = float(np.clip(rng.normal(rho_mean, rho_sd), 780.0, 880.0))
            rows.append({"cultivar": cultivar, "density": round(density, 1), **{p: float(f"{v:.4g}") for p, v in values.items()}})
    apples = pd.DataFrame(rows).sample(frac=1.0, random_state=seed).reset_index(drop=True)  # shuffled order
    apples.insert(0, "sample_id", [f"apple{k + 1:02d}" for k in range(len(apples))])
    return apples


def sample_sheet(apples: pd.DataFrame, seed: int = SEED) -> pd.DataFrame:
    """Sample sheet: three replicate records per apple, each with its own noise seed."""
    rows = []
    for k, a in apples.iterrows():
        for r in range(1, REPLICATES + 1):
            row = {"sample_id": a.sample_id, "replicate": r, "cultivar": a.cultivar, "sample.density": a.density}
            row.update({f"backend.options.truth.{p}": a[p] for p in PROPERTIES})
            row["backend.options.seed"] = seed % 100000 + 10 * k + r
            rows.append(row)
    return pd.DataFrame(rows)


def eaten_halves(apples: pd.DataFrame, seed: int = SEED) -> pd.DataFrame:
    """The properties of the halves the panel eats: each relation input of the measured half
    times exp(HALF_SD Z), Z standard normal (seeded)."""
    rng = np.random.default_rng(seed + 3)
    eaten = apples.copy()
    for p in RELATION.inputs:
        eaten[p] = apples[p] * np.exp(HALF_SD * rng.standard_normal(len(apples)))
    return eaten


def panel_scores(apples: pd.DataFrame, seed: int = SEED) -> pd.DataFrame:
    """Sensory scores of the eight virtual assessors, with the cultivar of each sample."""
    panel = simulate_panel(apples.sample_id, RELATION(eaten_halves(apples, seed)), PANEL, seed=seed + 1)
    return panel.merge(apples[["sample_id", "cultivar"]], on="sample_id")[["sample_id", "cultivar", "assessor", "score"]]


def stand_in_table(apples: pd.DataFrame, fit_result: Path, seed: int = SEED) -> pd.DataFrame:
    """Campaign-table rows from the truth plus estimation noise of a single-record fit /sqrt(3)."""
    from mbus_framework.pipeline.components import build_components
    from mbus_framework.pipeline.config import read_yaml, validate_structure

    result = json.loads(Path(fit_result).read_text())
    unc = result["uncertainty"]
    names = unc["correlation"]["names"]
    rse = np.array([unc["relative_standard_errors"][n] for n in names]) / np.sqrt(REPLICATES)
    corr = np.array(unc["correlation"]["matrix"])
    base = read_yaml(HERE.parent / "apple_slice.yaml")
    model = build_components(validate_structure(base, "apple_slice.yaml"), "apple_slice.yaml").model
    rng = np.random.default_rng(seed + 2)
    rows = []
    for _, a in apples.iterrows():
        truth = model.from_properties({p: a[p] for p in PROPERTIES})
        theta = truth * (1.0 + rng.multivariate_normal(np.zeros(len(names)), corr * np.outer(rse, rse)))
        props = model.to_properties(theta)
        row = {"sample_id": a.sample_id, "cultivar": a.cultivar, "replicate": None, "replicates": "averaged", "n_replicates": REPLICATES}
        row.update(dict(zip(names, theta)))
        row.update({f"{n}_se": abs(v) * s for n, v, s in zip(names, theta, rse)})
        row.update(props)
        row.update({f"{p}_se": abs(props[p]) * s for p, s in zip(model.property_names, rse)})
        row.update({"nrmse": result["fit"].get("nrmse"), "success": True, "warnings": "", "error": ""})
        row.update({f"true_{n}": v for n, v in zip(names, truth)})
        row.update({f"true_{p}": a[p] for p in PROPERTIES})
        rows.append(row)
    return pd.DataFrame(rows)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seed", type=int, default=SEED)
    p.add_argument("--out", type=Path, default=HERE, help="folder for the sheet and the panel (default: next to this script)")
    p.add_argument("--stand-in-table", type=Path, help="also write a campaign-format table from the truth + estimation noise")
    p.add_argument("--fit", type=Path, help="result.json of a single-record fit (apple_slice.yaml) for --stand-in-table")
    args = p.parse_args(argv)
    apples = draw_apples(args.seed)
    args.out.mkdir(parents=True, exist_ok=True)
    sample_sheet(apples, args.seed).to_csv(args.out / "apples_samples.csv", index=False)
    panel_scores(apples, args.seed).to_csv(args.out / "apples_panel.csv", index=False)
    print(f"wrote {args.out / 'apples_samples.csv'} and {args.out / 'apples_panel.csv'} ({len(apples)} apples)")
    if args.stand_in_table:
        if not args.fit:
            p.error("--stand-in-table needs --fit RESULT_JSON")
        stand_in_table(apples, args.fit, args.seed).to_csv(args.stand_in_table, index=False)
        print(f"wrote {args.stand_in_table}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
