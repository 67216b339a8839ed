"""Write the sample sheets of the Chapter 4 virtual campaigns from Tables 4.1-4.3.

    python configs/campaigns/generate_chapter4.py            # writes liquids_samples.csv, tissues_samples.csv
    python configs/campaigns/generate_chapter4.py --check /work/shared/reference/mbus-dissertation.md

Tables 4.2 and 4.3 give, per medium, the density and the mean and standard deviation (as % of
the mean) of the four effective properties over the replications (5 per liquid, 3 positions
per tissue). Each replication here is one simulated record whose true properties are drawn
around the table mean with the table's SD % as scatter:

    x_r = mean * (1 + (SD% / 100) * z_r),   r = 1..R,

with z drawn from N(0, 1) (``numpy.random.default_rng(SEED)``, one stream per table, in the
table's row and column order) and then standardised to sample mean 0 and sample SD 1
(ddof = 1), so that the truths of each medium have exactly the table's mean and SD %. (For
R = 3, |z_r| <= 2/sqrt(3), so even kidney's 77 % keeps every truth positive.) Each record gets
its own noise seed. The liquids also carry Table 4.1's viscosity as a covariate (a
conventional measurement, not used by the fit).

``--check`` parses the tables from the dissertation's Markdown and fails when a number below
differs from it (the numbers here are transcribed from that file).
"""
from __future__ import annotations

import argparse
import csv
import re
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SEED = 20240402
PROPERTIES = ("E_sigma", "eta_sigma", "E_tau", "eta_tau")
#: Column scales of Tables 4.2/4.3: E x 10^12 Pa, eta x 10^5 Pa s.
SCALES = (1e12, 1e5, 1e12, 1e5)

#: Table 4.2 (liquids, 5 replications): id, label in the table, density [kg/m^3],
#: (mean, SD %) of E_sigma [1e12 Pa], eta_sigma [1e5 Pa s], E_tau [1e12 Pa], eta_tau [1e5 Pa s].
TABLE_4_2 = [
    ("water", "Water", 998, (3.22, 0.59), (3.07, 1.82), (2.11, 0.82), (5.18, 0.05)),
    ("milk", "Milk", 1006, (3.39, 0.07), (3.96, 0.12), (2.31, 0.02), (5.55, 0.05)),
    ("syrup_1", "Syrup-1 (Light)", 1093, (3.97, 0.04), (4.88, 0.12), (2.59, 0.06), (6.18, 0.06)),
    ("syrup_2", "Syrup-2 (Medium)", 1197, (4.60, 0.15), (7.24, 0.39), (3.11, 0.19), (6.83, 0.04)),
    ("syrup_3", "Syrup-3 (Heavy)", 1307, (4.53, 0.31), (4.99, 1.69), (3.11, 0.76), (7.21, 0.76)),
]
#: Table 4.1: viscosity [Pa s] of the liquids (a covariate of the liquids campaign).
TABLE_4_1_VISCOSITY = {"water": 0.0010, "milk": 0.0021, "syrup_1": 0.0938, "syrup_2": 0.3513, "syrup_3": 1.0396}
#: Table 4.3 (beef tissues, 3 positions), same columns.
TABLE_4_3 = [
    ("muscle_0", "Muscle 0°", 1070, (2.82, 0.55), (4.94, 1.60), (2.62, 1.16), (6.14, 0.95)),
    ("muscle_90", "Muscle 90°", 1070, (2.92, 2.92), (5.26, 4.77), (2.69, 0.91), (5.84, 0.67)),
    ("liver", "Liver", 1060, (1.37, 16.20), (3.96, 12.17), (3.05, 3.83), (4.56, 4.75)),
    ("kidney", "Kidney", 1040, (1.97, 5.54), (1.92, 77.20), (2.78, 13.75), (5.36, 17.57)),
    ("fat", "Fat", 919.6, (2.80, 1.05), (2.75, 10.14), (2.03, 6.64), (5.41, 1.70)),
]


def standard_scores(rng: np.random.Generator, n: int) -> np.ndarray:
    """n normal draws standardised to sample mean 0 and sample SD 1 (ddof = 1)."""
    z = rng.standard_normal(n)
    return (z - z.mean()) / z.std(ddof=1)


def sheet_rows(table, replicates: int, group: str, first_seed: int, covariate=None) -> list[dict]:
    """One row per replication: truths drawn around the table (module docstring), own seed."""
    rng = np.random.default_rng(SEED + first_seed)
    rows = []
    seed = first_seed
    for sample_id, _label, density, *stats in table:
        draws = {p: mean * scale * (1.0 + sd / 100.0 * standard_scores(rng, replicates))
                 for p, (mean, sd), scale in zip(PROPERTIES, stats, SCALES)}
        for r in range(replicates):
            row = {"sample_id": sample_id, "replicate": r + 1, group: sample_id}
            if covariate:
                row[covariate[0]] = covariate[1][sample_id]
            row["sample.density"] = density
            row["backend.options.seed"] = seed
            row.update({f"backend.options.truth.{p}": repr(float(draws[p][r])) for p in PROPERTIES})
            rows.append(row)
            seed += 1
    return rows


def write_csv(path: Path, rows: list[dict]) -> None:
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]), lineterminator="\n")
        w.writeheader()
        w.writerows(rows)


def parse_markdown_table(text: str, caption: str) -> list[tuple]:
    """(label, density, (mean, SD%) x 4) rows of the Markdown table following ``caption``."""
    start = text.index(caption)
    rows = []
    for line in text[start:].splitlines()[1:]:
        if rows and not line.startswith("|"):
            break
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 6 or not re.match(r"^[\d,.]+$", cells[1]):
            continue
        stats = []
        for cell in cells[2:]:
            m = re.match(r"([\d.]+)<br>\(([\d.]+)%\)", cell)
            stats.append((float(m.group(1)), float(m.group(2))))
        rows.append((cells[0], float(cells[1].replace(",", "")), *stats))
    return rows


def check(markdown: Path) -> list[str]:
    """Differences between the tables above and the dissertation's (empty when they agree)."""
    text = markdown.read_text(encoding="utf-8")
    problems = []
    for caption, table in (("Table 4.2. Model validation", TABLE_4_2), ("Table 4.3. Effective mechanical", TABLE_4_3)):
        parsed = parse_markdown_table(text, caption)
        if len(parsed) != len(table):
            problems.append(f"{caption}: {len(parsed)} rows in the dissertation, {len(table)} here")
        for (_id, label, density, *stats), (plabel, pdensity, *pstats) in zip(table, parsed):
            if (label, float(density), list(stats)) != (plabel, pdensity, list(pstats)):
                problems.append(f"{caption}: {label} {density} {stats} here, {plabel} {pdensity} {pstats} there")
    return problems


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--check", type=Path, metavar="DISSERTATION_MD", help="compare the tables with the dissertation")
    p.add_argument("--out", type=Path, default=HERE, help="folder for the sheets (default: next to this script)")
    args = p.parse_args(argv)
    if args.check:
        problems = check(args.check)
        print("\n".join(problems) or "Tables 4.2 and 4.3 agree with the dissertation")
        return 1 if problems else 0
    write_csv(args.out / "liquids_samples.csv",
              sheet_rows(TABLE_4_2, 5, "material", 1, ("viscosity_pa_s", TABLE_4_1_VISCOSITY)))
    write_csv(args.out / "tissues_samples.csv", sheet_rows(TABLE_4_3, 3, "tissue", 101))
    print(f"wrote {args.out / 'liquids_samples.csv'} and {args.out / 'tissues_samples.csv'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
