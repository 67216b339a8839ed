"""Tables (CSV), JSON and printed text of the crispness analysis, in the layouts of
Tables 7.1-7.4."""
from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from mbus_framework.analysis.crispness.model import json_safe
from mbus_framework.pipeline.storage import atomic_write_text


def _tag(s: dict) -> str:
    return ",".join(s["inputs"])


def agreement_table(sets: list[dict]) -> pd.DataFrame:
    rows = []
    for s in sets:
        for model in ("network", "ridge"):
            rows.append({"inputs": _tag(s), "model": model, **s[f"{model}_agreement"].as_dict()})
    return pd.DataFrame(rows)


def sensitivity_table(sets: list[dict]) -> pd.DataFrame:
    """Table 7.4 in long form: inputs (the set), model, input, mean / SD of |change|, signed mean."""
    parts = []
    for s in sets:
        for model in ("network", "ridge"):
            t = s[f"{model}_sensitivity"].reset_index()
            t.insert(0, "model", model)
            t.insert(0, "inputs", _tag(s))
            parts.append(t)
    return pd.concat(parts, ignore_index=True)


def comparison_rows(res: dict) -> list[dict]:
    rows = []
    for s in res["sets"]:
        t = s["network_vs_ridge"]
        rows.append({"test": f"r(network) = r(ridge) [{_tag(s)}], dependent (Meng et al.)", "statistic": "z", "value": t["z"], "p": t["p"]})
    if "fisher_z" in res:
        a, b = (_tag(s) for s in res["sets"][:2])
        rows.append({"test": f"r [{a}] = r [{b}], Fisher's Z (independent samples)", "statistic": "z",
                     "value": res["fisher_z"]["z"], "p": res["fisher_z"]["p"]})
        rows.append({"test": f"r [{a}] = r [{b}], dependent (Meng et al.)", "statistic": "z",
                     "value": res["dependent_z"]["z"], "p": res["dependent_z"]["p"]})
        rows.append({"test": f"equal slopes (parallel lines) [{a}] vs [{b}]", "statistic": "t",
                     "value": res["lines"]["slope_t"], "p": res["lines"]["slope_p"]})
        rows.append({"test": f"equal intercepts [{a}] vs [{b}]", "statistic": "t",
                     "value": res["lines"]["intercept_t"], "p": res["lines"]["intercept_p"]})
    return rows


def predictions_frame(res: dict, data: pd.DataFrame) -> pd.DataFrame:
    out = data[["score", "score_sd", "n_scores"]].rename(columns={"score": "measured"}).copy()
    for s in res["sets"]:
        out[f"network [{_tag(s)}]"] = s["network_loo"]
        out[f"ridge [{_tag(s)}]"] = s["ridge_loo"]
    out.index.name = "sample_id"
    return out


def write_tables(out: Path, res: dict, data: pd.DataFrame) -> list[Path]:
    frames = {
        "panel_by_assessor.csv": res["by_assessor"], "anova_assessor.csv": res["anova_assessor"],
        "lsd_assessor.csv": res["lsd_assessor"].set_index(["a", "b"]),
        "loo_predictions.csv": predictions_frame(res, data),
        "agreement.csv": agreement_table(res["sets"]).set_index(["inputs", "model"]),
        "sensitivity.csv": sensitivity_table(res["sets"]).set_index(["inputs", "model", "input"]),
        "comparisons.csv": pd.DataFrame(comparison_rows(res)).set_index("test"),
    }
    if "by_group" in res:
        frames["panel_by_group.csv"] = res["by_group"]
        frames["anova_group.csv"] = res["anova_group"]
    if "structures" in res:
        frames["structures.csv"] = res["structures"].set_index("structure")
    files = []
    for name, frame in frames.items():
        files.append(atomic_write_text(out / name, frame.to_csv()))
    return files


def write_json(path: Path, res: dict) -> Path:
    doc = {k: res[k] for k in ("table", "panel", "seed", "n_samples", "group", "notes", "network", "change", "files",
                                "validation")}
    if "structure_validation" in res:
        doc["structure_validation"] = res["structure_validation"]
    for key in ("by_assessor", "by_group", "anova_assessor", "anova_group"):
        if key in res:
            doc[key] = res[key].reset_index().to_dict(orient="records")
    if "structures" in res:
        doc["structures"] = res["structures"].to_dict(orient="records")
        doc["learning_curves"] = res["curves"]
    doc["input_sets"] = [
        {
            "inputs": s["inputs"],
            "network": s["network_agreement"].as_dict(), "ridge": s["ridge_agreement"].as_dict(),
            "network_vs_ridge": s["network_vs_ridge"],
            "sensitivity": {"network": s["network_sensitivity"].reset_index().to_dict(orient="records"),
                            "ridge": s["ridge_sensitivity"].reset_index().to_dict(orient="records"),
                            "network_ranking": s["ranking"]},
            "model_file": s["model_file"].name,
        }
        for s in res["sets"]
    ]
    for key in ("fisher_z", "dependent_z", "lines"):
        if key in res:
            doc[key] = res[key]
    return atomic_write_text(path, json.dumps(json_safe(doc), indent=1, allow_nan=False) + "\n")


# -- printed text ---------------------------------------------------------------------------
def _fmt(frame: pd.DataFrame, floats: str = "{:.4g}") -> str:
    return frame.to_string(float_format=lambda v: "" if pd.isna(v) else floats.format(v), na_rep="")


def text(res: dict) -> str:
    from mbus_framework.analysis.crispness.validation import LOO_MAX

    lines = [f"mbus crispness: {res['n_samples']} samples, table {res['table']}, panel {res['panel']}, seed {res['seed']}"]
    lines += [f"  validation: {res['validation']}" + (f" (leave-one-out up to {LOO_MAX} samples; docs/crispness.md)"
                                                    if res["validation"] != "leave-one-out" else "")]
    lines += [f"  note: {n}" for n in res["notes"]]
    lines += ["", "Scores by assessor (Table 7.1)", _fmt(res["by_assessor"], "{:.2f}")]
    a = res["anova_assessor"].iloc[0]
    lines += [f"  ANOVA by assessor: F = {a['F']:.4g}, p = {a['p']:.3g} (F crit {a['F crit']:.4g}); "
              f"{int(res['lsd_assessor']['significant'].sum())} of {len(res['lsd_assessor'])} assessor pairs differ (LSD)"]
    if "by_group" in res:
        lines += ["", f"Scores by {res['group']} (Table 7.2)", _fmt(res["by_group"], "{:.2f}")]
        lines += ["", f"Analysis of variance by {res['group']} (Table 7.3)", _fmt(res["anova_group"], "{:.5g}")]
    if "structures" in res:
        st = res["structures"].set_index("structure")[["layers", "neurons", "weights", "loo_mse", "loo_mse_se", "loo_r", "recommended"]]
        lines += ["", f"Network structures, {res.get('structure_validation', res['validation'])} (Fig. 7.2)", _fmt(st)]
    ag = agreement_table(res["sets"]).set_index(["inputs", "model"])
    cols = ["n", "r", "slope", "slope_p", "intercept", "intercept_p", "rmse"]
    lines += ["", f"Out-of-sample prediction ({res['validation']}): predicted = intercept + slope x measured (Figs 7.3/7.4;",
              "  slope_p tests slope = 1, intercept_p tests intercept = 0)", _fmt(ag[cols])]
    lines += ["", "Tests"] + [f"  {r['test']}: {r['statistic']} = {r['value']:.3f}, p = {r['p']:.3g}" for r in comparison_rows(res)]
    lines += ["", f"Sensitivities: |change in predicted score| for a {100 * res['change']:+g} % input change, mean (SD) (Table 7.4)"]
    lines += [_sens_text(res["sets"])]
    for s in res["sets"]:
        lines.append(f"  network [{_tag(s)}] ranks the inputs: {' > '.join(s['ranking'])}")
    return "\n".join(lines)


def _sens_text(sets: list[dict]) -> str:
    names: list[str] = []
    for s in sets:
        names += [n for n in s["inputs"] if n not in names]
    cols = {}
    for s in sets:
        for model in ("network", "ridge"):
            t = s[f"{model}_sensitivity"]
            cols[f"{model} [{_tag(s)}]"] = [
                f"{t.loc[n, 'mean_abs_change']:.3f} ({t.loc[n, 'sd_abs_change']:.3f})" if n in t.index else "-" for n in names
            ]
    return pd.DataFrame(cols, index=names).to_string()


def predictions_text(pred: pd.DataFrame, model, source) -> str:
    lines = [f"mbus predict: {len(pred)} rows, model {source} (inputs {', '.join(model.inputs)})"]
    lines.append(pred.to_string(index=False, float_format=lambda v: f"{v:.3f}"))
    n_out = int((pred["extrapolated"] != "").sum())
    if n_out:
        lines.append(f"  WARNING: {n_out} row(s) have inputs outside the training range (column 'extrapolated')")
    return "\n".join(lines)
