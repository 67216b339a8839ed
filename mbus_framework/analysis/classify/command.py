"""``mbus-analyze classify TABLE --by COLUMN``: Tables 4.4/4.5 from a campaign table.

Writes, into ``--out`` (default ``<table folder>/classify_<COLUMN>``): ``classification.csv``
(the % correctly classified table in the layout of Tables 4.4/4.5), ``confusion_matrices.csv``,
``classification.json`` (the same numbers, the assignment of every sample) and
``discriminant_space.png``; prints the table and the groups that are not separated.
"""
from __future__ import annotations

import argparse
import sys

from mbus_framework.errors import DataError
from mbus_framework.analysis.classify.model import classify, feature_sets
from mbus_framework.analysis.classify.report import render_text, write_reports
from mbus_framework.analysis.outputs import output_dir
from mbus_framework.analysis.table import PROPERTIES, read_table


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("table", help="campaign table (properties.csv or .parquet)")
    parser.add_argument("--by", required=True, metavar="COLUMN", help="group-label column (e.g. material)")
    parser.add_argument("--properties", nargs="+", metavar="NAME",
                        help="properties to classify by: each alone, the normal and shear pairs among them, "
                             f"and all together (default: {' '.join(PROPERTIES)}, the seven columns of Table 4.4)")
    parser.add_argument("--sets", nargs="+", metavar="A,B",
                        help="explicit property sets instead, each comma-separated (e.g. E_sigma,eta_sigma E_tau)")
    parser.add_argument("--transform", choices=("none", "log"), default="none",
                        help="none (default: the properties as estimated, as the dissertation's SPSS analysis of "
                             "Tables 4.4-4.5) or log (log10 first: positive values spanning decades)")
    parser.add_argument("--no-standardize", dest="standardize", action="store_false",
                        help="do not scale each feature to unit variance (k-means depends on it; LDA does not)")
    parser.add_argument("--restarts", type=int, default=20, help="k-means seeded restarts (default 20)")
    parser.add_argument("--seed", type=int, default=0, help="k-means random seed (default 0)")
    parser.add_argument("-o", "--out", metavar="DIR", help="output folder (default: <table folder>/classify_<COLUMN>)")
    parser.add_argument("--no-plots", dest="plots", action="store_false", help="skip the figure")


def _sets(args, df) -> list[tuple[str, ...]] | None:
    if args.sets:
        sets = [tuple(p.strip() for p in s.split(",") if p.strip()) for s in args.sets]
        if not all(sets):
            raise DataError("--sets: empty property set")
        return sets
    if args.properties:
        return feature_sets(args.properties)
    present = [p for p in PROPERTIES if p in df.columns]
    if len(present) == len(PROPERTIES):
        return None
    if not present:
        raise DataError(f"{args.table}: none of {', '.join(PROPERTIES)} is a column; name --properties")
    absent = [p for p in PROPERTIES if p not in present]
    print(f"{args.table}: no column {', '.join(absent)}: classifying by {', '.join(present)} and their "
          f"combinations only", file=sys.stderr)
    return feature_sets(present)


def run(args: argparse.Namespace) -> int:
    if args.restarts < 1:
        raise DataError(f"--restarts must be at least 1 (got {args.restarts})")
    from mbus_framework.pipeline.progress import make_long_progress

    df = read_table(args.table)
    result = classify(df, args.by, _sets(args, df), log=args.transform == "log", standardize=args.standardize,
                      restarts=args.restarts, seed=args.seed, source=str(args.table), progress=make_long_progress())
    out = output_dir(args.table, args.out, f"classify_{args.by}")
    paths = write_reports(result, out, str(args.table))
    if args.plots:
        from mbus_framework.analysis.classify.plots import plot_discriminant_space

        paths["figure"] = plot_discriminant_space(result, out / "discriminant_space.png")
    print(f"classification of {args.table} by {args.by} ({len(result.groups)} groups)")
    print(render_text(result))
    print()
    for name, path in paths.items():
        print(f"  {name}: {path}")
    return 0
