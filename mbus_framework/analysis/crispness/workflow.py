"""The work behind ``mbus-analyze crispness`` / ``predict`` (arguments in crispness.command).

``run_crispness`` joins the panel's mean score per sample to the table, writes the panel
statistics (Tables 7.1-7.3), compares network structures (Fig. 7.2), predicts every sample
leave-one-out with the LM-trained network and with a ridge baseline (Figs 7.3/7.4), tests
the agreement and the difference between two input sets (Fisher's Z), computes the
sensitivities (eq. 7.2, Table 7.4) of a network trained on all samples, and saves that
network for ``run_predict``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from sklearn.base import clone

from mbus_framework.analysis.crispness import plots
from mbus_framework.analysis.crispness import report
from mbus_framework.analysis.crispness.agreement import agreement, compare_lines, dependent_correlation_test, fisher_z_test
from mbus_framework.analysis.crispness import validation as validation_settings
from mbus_framework.analysis.crispness.validation import (
    cross_validate, rank, ridge_baseline, sensitivities, structure_comparison, structure_label,
    validation_for,
)
from mbus_framework.analysis.crispness.model import CrispnessModel
from mbus_framework.analysis.crispness.panel import attach_group, describe_by, join_scores, lsd_comparisons, one_way_anova, read_panel
from mbus_framework.analysis.crispness.regressor import LMNetworkRegressor
from mbus_framework.analysis.table import read_table
from mbus_framework.errors import ConfigError, DataError


# -- predict --------------------------------------------------------------------------------
def run_predict(args) -> int:
    model = CrispnessModel.load(args.model)
    table = read_table(args.table)
    pred = model.predict_table(table, str(args.table))
    if args.out:
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        pred.to_csv(out, index=False)
    print(report.predictions_text(pred, model, args.model))
    if args.out:
        print(f"  written: {args.out}")
    return 0


# -- crispness ------------------------------------------------------------------------------
def _columns(text: str, option: str) -> list[str]:
    cols = [c.strip() for c in str(text).split(",") if c.strip()]
    if not cols:
        raise ConfigError(f"{option}: give at least one column name")
    if len(set(cols)) != len(cols):
        raise ConfigError(f"{option}: a column is named twice in {text!r}")
    return cols


def _structures(text: str) -> list[tuple[int, ...]]:
    if text.strip().lower() == "none":
        return []
    try:
        out = [tuple(int(n) for n in item.split("-")) for item in text.split(",") if item.strip()]
    except ValueError:
        raise ConfigError(f"--structures: {text!r} is not a list like 2,4,6,3-3") from None
    if any(min(s) < 1 for s in out):
        raise ConfigError("--structures: every layer needs at least one neuron")
    return out


def _network(args) -> LMNetworkRegressor:
    try:
        hidden = tuple(int(h) for h in args.hidden.split(","))
    except ValueError:
        raise ConfigError(f"--hidden: {args.hidden!r} is not a list of neuron counts like 6 or 3,3") from None
    if min(hidden) < 1 or args.restarts < 1 or args.members < 1:
        raise ConfigError("--hidden, --restarts and --members need positive numbers")
    if not 0 <= args.validation_fraction < 0.9:
        raise ConfigError(f"--validation-fraction: {args.validation_fraction} is not in [0, 0.9)")
    return LMNetworkRegressor(hidden_layer_sizes=hidden, activation=args.activation, n_restarts=args.restarts,
                              n_members=args.members, validation_fraction=args.validation_fraction, random_state=args.seed)


def _default_group(panel: pd.DataFrame) -> str | None:
    extra = [c for c in panel.columns if c not in ("sample_id", "assessor", "score")]
    return extra[0] if len(extra) == 1 else None


def analyse_inputs(inputs, data: pd.DataFrame, network: LMNetworkRegressor, args, progress) -> dict:
    """Leave-one-out (K-fold above ``LOO_MAX`` samples) network and ridge predictions, their
    agreement, and both models fitted on all samples (for the sensitivities and the saved model)."""
    X, y = data[inputs].to_numpy(dtype=float), data["score"].to_numpy(dtype=float)
    name, folds = validation_for(len(y))
    net_loo = cross_validate(network, X, y, args.seed, progress, f"{name} ({','.join(inputs)})", folds=folds).predictions
    ridge_loo = cross_validate(ridge_baseline(), X, y, args.seed, folds=folds).predictions
    if progress is not None:
        progress.start(f"final network ({','.join(inputs)})", total=1)
    try:
        final, ridge = clone(network).fit(X, y), ridge_baseline().fit(X, y)
    finally:
        if progress is not None:
            progress.advance(1)
            progress.stop()
    net_a, ridge_a = agreement(y, net_loo), agreement(y, ridge_loo)
    return {
        "inputs": list(inputs), "X": X, "y": y, "network_loo": net_loo, "ridge_loo": ridge_loo,
        "network_agreement": net_a, "ridge_agreement": ridge_a, "model": final,
        "network_sensitivity": sensitivities(final.predict, X, inputs, args.change),
        "ridge_sensitivity": sensitivities(ridge.predict, X, inputs, args.change),
        "network_vs_ridge": dependent_correlation_test(net_a.r, ridge_a.r, float(np.corrcoef(net_loo, ridge_loo)[0, 1]), len(y)),
    }


def run_crispness(args) -> int:
    from mbus_framework.pipeline.progress import make_long_progress

    inputs = _columns(args.inputs, "--inputs")
    compare = _columns(args.compare_inputs, "--compare-inputs") if args.compare_inputs else None
    structures = _structures(args.structures)
    network = _network(args)
    if not 0 < args.alpha < 1 or not args.change > -1:
        raise ConfigError("--alpha must be in (0, 1) and --change above -1")

    table = read_table(args.table)
    panel = read_panel(args.scores)
    data, notes = join_scores(table, panel, sorted(set(inputs) | set(compare or [])), str(args.table), str(args.scores))
    panel = panel[panel["sample_id"].isin(data.index)]
    group = args.group or _default_group(panel)
    if group:
        panel = attach_group(panel, table, group, str(args.scores))
        if panel[group].isna().any():
            raise DataError(f"{args.scores}: no {group!r} label for sample {panel.loc[panel[group].isna(), 'sample_id'].iloc[0]!r}")
    out = Path(args.out) if args.out else Path(args.table).resolve().parent / "crispness"
    out.mkdir(parents=True, exist_ok=True)
    progress = None if args.quiet else make_long_progress()
    validation, folds = validation_for(len(data))

    res: dict = {"table": str(args.table), "panel": str(args.scores), "seed": args.seed, "notes": notes,
                 "n_samples": len(data), "group": group, "network": network.get_params(), "change": args.change,
                 "validation": validation}
    res["by_assessor"] = describe_by(panel, "assessor")
    res["anova_assessor"] = one_way_anova(panel, "assessor", args.alpha, "Assessor")
    res["lsd_assessor"] = lsd_comparisons(panel, "assessor", args.alpha)
    if group:
        res["by_group"] = describe_by(panel, group, total=f"all samples ({len(data)})")
        res["anova_group"] = one_way_anova(panel, group, args.alpha, str(group))
    if structures:
        Xs, ys = data[inputs].to_numpy(dtype=float), data["score"].to_numpy(dtype=float)
        subset = validation_settings.STRUCTURE_SUBSET  # read at call time (a caller or test may set it)
        if len(ys) > subset:  # documented: structures compared on a seeded subset
            keep = np.sort(np.random.default_rng(args.seed).choice(len(ys), subset, replace=False))
            Xs, ys = Xs[keep], ys[keep]
        sub_name, sub_folds = validation_for(len(ys))
        res["structure_validation"] = sub_name + (f" on a random subset of {len(ys)} of {len(data)} samples"
                                                  if len(ys) < len(data) else "")
        res["structures"], res["curves"] = structure_comparison(Xs, ys, structures, network, args.seed, progress, folds=sub_folds)
    sets = [analyse_inputs(inputs, data, network, args, progress)]
    if compare:
        sets.append(analyse_inputs(compare, data, network, args, progress))
        a, b = sets[0]["network_agreement"], sets[1]["network_agreement"]
        res["fisher_z"] = fisher_z_test(a.r, a.n, b.r, b.n)
        res["dependent_z"] = dependent_correlation_test(
            a.r, b.r, float(np.corrcoef(sets[0]["network_loo"], sets[1]["network_loo"])[0, 1]), a.n)
        res["lines"] = compare_lines(sets[0]["y"], sets[0]["network_loo"], sets[1]["network_loo"])
    res["sets"] = sets
    for k, s in enumerate(sets):
        s["ranking"] = rank(s["network_sensitivity"])
        training = {"table": str(args.table), "panel": str(args.scores), "seed": args.seed, "samples": list(data.index),
                    "network": network.get_params(), "loo_r": s["network_agreement"].r,
                    "target": "mean sensory score over assessors"}
        s["model_file"] = CrispnessModel(s["inputs"], s["model"], training).save(out / ("model.json" if k == 0 else "model_compare.json"))
    files = report.write_tables(out, res, data)
    if not args.no_plots:
        files += _plots(out, res, panel, group, args.change)
    res["files"] = [str(f.relative_to(out)) for f in files] + [str(s["model_file"].relative_to(out)) for s in sets]
    report.write_json(out / "crispness.json", res)
    text = report.text(res)
    (out / "report.txt").write_text(text + "\n", encoding="utf-8")
    print(out if args.quiet else text + f"\n  output: {out}")
    return 0


def _plots(out: Path, res: dict, panel: pd.DataFrame, group: str | None, change: float) -> list[Path]:
    rows = []
    for s in res["sets"]:
        title = "inputs: " + ", ".join(s["inputs"])
        m = s["model"]
        name = f"LM network {structure_label(m.hidden_layer_sizes)}" + (f", {m.n_members} members" if m.n_members > 1 else "")
        rows.append((title, [(name, s["y"], s["network_loo"], s["network_agreement"]),
                             ("ridge baseline", s["y"], s["ridge_loo"], s["ridge_agreement"])]))
    lo, hi = float(min(0.0, panel["score"].min())), float(max(9.0, panel["score"].max()))
    files = [plots.measured_vs_predicted(rows, out / "measured_vs_predicted.png", (lo, hi))]
    sens = {}
    for s in res["sets"]:
        tag = ",".join(s["inputs"])
        sens[f"network [{tag}]"] = s["network_sensitivity"]
        sens[f"ridge [{tag}]"] = s["ridge_sensitivity"]
    files.append(plots.sensitivity_bars(sens, out / "sensitivities.png", change))
    if "structures" in res:
        files.append(plots.structures(res["structures"], res["curves"], out / "structures.png"))
    files.append(plots.panel_scores(panel, group, out / "panel.png"))
    return files
