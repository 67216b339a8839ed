"""``mbus-analyze crispness`` and ``mbus-analyze predict`` (Chapter 7; docs/crispness.md).

    mbus-analyze crispness TABLE --scores PANEL [--inputs k_sigma,b_sigma,k_tau,b_tau]
                           [--compare-inputs k_sigma,k_tau] [--group cultivar] [--seed S] [-o DIR]
    mbus-analyze predict TABLE --model DIR/model.json [-o predictions.csv]

Arguments only; the work is in :mod:`mbus_framework.analysis.crispness.workflow`, imported
when a subcommand runs (so ``mbus-analyze`` starts without loading scikit-learn).
"""
from __future__ import annotations

import argparse

from mbus_framework.analysis.table import PARAMETERS

#: structures compared by default (Fig. 7.2): one hidden layer of 2..10 neurons, two layers of 3
DEFAULT_STRUCTURES = "2,3,4,5,6,8,10,3-3"


def add_arguments(p: argparse.ArgumentParser, name: str = "crispness") -> None:
    p.add_argument("table", help="campaign table (properties.csv / .parquet)")
    if name == "predict":
        p.add_argument("--model", required=True, help="model file written by 'mbus-analyze crispness' (model.json)")
        p.add_argument("-o", "--out", help="write the predictions to this CSV (default: print only)")
        p.set_defaults(_mode="predict")
        return
    p.set_defaults(_mode="crispness")
    p.add_argument("--scores", required=True, metavar="PANEL", help="panel CSV: sample_id, assessor, score[, group]")
    p.add_argument("--inputs", default=",".join(PARAMETERS), help="comma-separated input columns (default: %(default)s)")
    p.add_argument("--compare-inputs", metavar="COLS", help="a second input set, compared with Fisher's Z test")
    p.add_argument("--group", help="group column (panel or table) for Table 7.2/7.3; default: the panel's one extra column")
    p.add_argument("--hidden", default="6", help="neurons per hidden layer, comma-separated (default: %(default)s)")
    p.add_argument("--activation", choices=["tanh", "logistic"], default="tanh")
    p.add_argument("--restarts", type=int, default=3, help="random initialisations per network (default: %(default)s)")
    p.add_argument("--members", type=int, default=5,
                   help="networks averaged per model, each on its own train/validation split (default: %(default)s; 1 = the dissertation)")
    p.add_argument("--validation-fraction", type=float, default=0.22, help="early-stopping share (default: %(default)s)")
    p.add_argument("--structures", default=DEFAULT_STRUCTURES,
                   help="structures compared (Fig. 7.2), e.g. 2,4,6,3-3; 'none' to skip (default: %(default)s)")
    p.add_argument("--change", type=float, default=0.1, help="relative input change of the sensitivities (default: %(default)s)")
    p.add_argument("--alpha", type=float, default=0.05, help="significance level of the ANOVA (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="seed of every random choice (default: %(default)s)")
    p.add_argument("-o", "--out", help="output folder (default: crispness/ next to TABLE)")
    p.add_argument("--no-plots", action="store_true", help="do not write PNG figures")
    p.add_argument("-q", "--quiet", action="store_true", help="print only the output folder")


def run(args) -> int:
    from mbus_framework.analysis.crispness import workflow

    if args._mode == "predict":
        return workflow.run_predict(args)
    return workflow.run_crispness(args)
