"""``mbus-analyze calibrate`` and ``mbus-analyze apply-calibration`` (Chapter 6).

    mbus-analyze calibrate TABLE [NAME=TABLE ...] --conventional SHEET [options]
    mbus-analyze apply-calibration TABLE --calibration FILE [--out FILE]

``calibrate`` writes into ``--out`` (default ``<first table's folder>/calibration``):
``table_6_1.csv`` (slope, intercept, r per property and variant), ``table_6_2.csv`` (value
ranges), ``regression.csv`` and ``calibration_report.json`` (every statistic),
``conventional_samples.csv`` and ``conventional_records.csv`` (the reduced conventional
tests), ``fig_6_4_E_sigma.png`` ... (Figs 6.4-6.7), and the saved calibration of each variant
(``calibration.json``, or ``calibration_<variant>.json`` with several) for apply-calibration.
"""
from __future__ import annotations

import argparse
import re
from pathlib import Path

from mbus_framework.errors import DataError
from mbus_framework.analysis.calibrate.model import (CONVENTIONAL_LABEL, calibrate, load_variants, regression_frame,
                                               table_6_1, table_6_2)
from mbus_framework.analysis.outputs import output_dir, write_json
from mbus_framework.analysis.calibrate.property_calibration import OUTPUT_PREFIX, PropertyCalibration
from mbus_framework.analysis.rows import describe_exclusions, failed_mask
from mbus_framework.analysis.table import PROPERTIES, read_table


def add_arguments(parser: argparse.ArgumentParser, name: str = "calibrate") -> None:
    if name == "apply-calibration":
        parser.add_argument("table", help="campaign table of new samples (properties.csv or .parquet)")
        parser.add_argument("--calibration", required=True, metavar="FILE",
                            help="calibration file written by mbus-analyze calibrate")
        parser.add_argument("--replicates", type=int, default=1, metavar="M",
                            help="MBUS measurements averaged into each new value (default 1)")
        parser.add_argument("-o", "--out", metavar="FILE", help="output table (default: <table>_calibrated.csv)")
        return
    parser.add_argument("tables", nargs="+", metavar="TABLE",
                        help="campaign table(s); NAME=PATH names a table's variant (e.g. uncompensated=raw.csv)")
    parser.add_argument("--conventional", metavar="SHEET",
                        help="conventional sheet (sample_id, test, file, ...); without it the table(s) "
                             "must carry conv_<property> columns")
    parser.add_argument("--shear-frequency", type=float, default=10.0, metavar="HZ",
                        help="frequency at which E' and eta' are read from the rheometer sweeps (default 10)")
    parser.add_argument("--drift-degree", type=int, default=1,
                        help="degree of the drift polynomial of the compression fits (default 1)")
    parser.add_argument("--min-explained", type=float, default=0.95,
                        help="least fraction of a compression channel the sinusoid must explain (default 0.95)")
    parser.add_argument("--skip-bad-records", action="store_true",
                        help="leave out unusable conventional records (listed) instead of stopping")
    parser.add_argument("--variant-column", default="compensation", metavar="COLUMN",
                        help="column whose values split a table into MBUS variants (default: compensation)")
    parser.add_argument("--properties", nargs="+", metavar="NAME", help=f"default: {' '.join(PROPERTIES)}")
    parser.add_argument("--level", type=float, default=0.95, help="confidence level of intervals and bands")
    parser.add_argument("-o", "--out", metavar="DIR", help="output folder (default: <table folder>/calibration)")
    parser.add_argument("--no-plots", dest="plots", action="store_false", help="skip the figures")


def run(args: argparse.Namespace) -> int:
    if getattr(args, "calibration", None) is not None:
        return run_apply(args)
    return run_calibrate(args)


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_") or "variant"


def run_calibrate(args: argparse.Namespace) -> int:
    if not 0 < args.level < 1:
        raise DataError(f"--level must be between 0 and 1 (got {args.level})")
    variants = load_variants(args.tables, args.variant_column)
    first = next(iter(variants.values())).attrs["source"]
    out = output_dir(first, args.out, "calibration")
    conventional = None
    if args.conventional:
        from mbus_framework.analysis.conventional.sheet import conventional_table

        conventional, records, problems = conventional_table(
            args.conventional, shear_frequency=args.shear_frequency, skip_bad=args.skip_bad_records,
            drift_degree=args.drift_degree, min_explained=args.min_explained)
        conventional.to_csv(out / "conventional_samples.csv", index=False)
        records.to_csv(out / "conventional_records.csv", index=False)
        for problem in problems:
            print(f"skipped: {problem}")
    analysis = calibrate(variants, conventional, args.properties, args.level)
    t61, t62, reg = table_6_1(analysis), table_6_2(analysis), regression_frame(analysis)
    t61.to_csv(out / "table_6_1.csv")
    t62.to_csv(out / "table_6_2.csv", float_format="%.4E")
    reg.to_csv(out / "regression.csv", index=False)
    saved = {}
    for variant in analysis.variants:
        fits = {p: analysis.fits[(variant, p)] for p in analysis.properties if (variant, p) in analysis.fits}
        name = "calibration.json" if len(analysis.variants) == 1 else f"calibration_{_slug(variant)}.json"
        conv = {p: f"{CONVENTIONAL_LABEL.get(p, p)}" + (f" at {args.shear_frequency:g} Hz" if p.endswith("tau")
                                                         and args.conventional else "") for p in fits}
        saved[variant] = PropertyCalibration(variant, fits, conv, source=str(variants[variant].attrs["source"])
                                             ).save(out / name)
    write_json(out / "calibration_report.json", {
        "tables": list(args.tables), "conventional": args.conventional, "shear_frequency": args.shear_frequency,
        "level": args.level, "variants": analysis.variants, "properties": analysis.properties,
        "regressions": reg.to_dict(orient="records"), "table_6_2": {
            f"{b} / {s}": row for (b, s), row in t62.to_dict(orient="index").items()},
        "notes": analysis.notes, "calibration_files": {v: str(p) for v, p in saved.items()}})
    figures = {}
    if args.plots:
        from mbus_framework.analysis.calibrate.plots import plot_all

        figures = plot_all(analysis, out)
    _print_report(analysis, t61, t62)
    print(f"\n  outputs: {out}")
    for variant, path in saved.items():
        print(f"  calibration ({variant}): {path}")
    for prop, path in figures.items():
        print(f"  figure ({prop}): {path}")
    return 0


def _print_report(analysis, t61, t62) -> None:
    import pandas as pd

    for variant in analysis.variants:
        counts = [analysis.counts[(variant, p)] for p in analysis.properties if (variant, p) in analysis.counts]
        if counts:
            worst = min(counts, key=lambda c: c["used"])
            print(f"{variant}: {describe_exclusions(worst, 'samples')}")
    for note in analysis.notes:
        print(note)
    ns = sorted({f.n for f in analysis.fits.values()})
    print("\nTable 6.1. Slope and intercept of calibration equations (MBUS = intercept + slope x conventional)")
    print(t61.to_string())
    print(f"* Significant at the 0.01 level (N = {', '.join(map(str, ns))}).")
    print("\nTable 6.2. Value ranges of the material properties")
    with pd.option_context("display.float_format", "{:.2E}".format):
        print(t62.to_string())


def run_apply(args: argparse.Namespace) -> int:
    if args.replicates < 1:
        raise DataError(f"--replicates must be at least 1 (got {args.replicates})")
    calibration = PropertyCalibration.load(args.calibration)
    table = read_table(args.table)
    result, missing = calibration.apply(table, replicates=args.replicates, source=str(args.table))
    path = Path(args.out) if args.out else Path(args.table).with_name(Path(args.table).stem + "_calibrated.csv")
    result.to_csv(path, index=False)
    n_failed = int(failed_mask(table).sum())
    print(f"applied {args.calibration} ({calibration.variant}) to {len(table)} rows"
          + (f" ({n_failed} failed rows left empty)" if n_failed else ""))
    for prop in missing:
        print(f"  {prop}: not a column of {args.table}; skipped")
    for prop, fit in calibration.fits.items():
        if prop in table.columns and not fit.finite_inverse:
            print(f"  {prop}: the calibration slope is not significant at {fit.level:.0%}: intervals unbounded")
    n_extra = int((result["calibration_warnings"] != "").sum())
    if n_extra:
        print(f"  {n_extra} rows outside the calibrated MBUS range (see calibration_warnings)")
    props = [p for p in calibration.fits if p in table.columns]
    shown = result[["sample_id"]].astype(str).copy()
    for p in props:
        shown[p] = [f"{v:.4g} [{lo:.4g}, {hi:.4g}]" for v, lo, hi in zip(
            result[f"{OUTPUT_PREFIX}{p}"], result[f"{OUTPUT_PREFIX}{p}_pi_low"], result[f"{OUTPUT_PREFIX}{p}_pi_high"])]
    print(f"conventional-scale values [{next(iter(calibration.fits.values())).level:.0%} prediction interval]:")
    print(shown.head(10).to_string(index=False))
    if len(shown) > 10:
        print(f"  ... {len(shown) - 10} more rows")
    print(f"  output: {path}")
    return 0
