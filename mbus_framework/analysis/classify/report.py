"""Tables and JSON of a classification, in the layout of Tables 4.4 and 4.5."""
from __future__ import annotations

from pathlib import Path

from mbus_framework.analysis.classify.model import LETTERS, METHODS, Classification, set_label
from mbus_framework.analysis.outputs import write_json
from mbus_framework.analysis.rows import describe_exclusions

PERCENT_ROW = "% correctly classified"


def layout_table(result: Classification):
    """Rows (section, group | '% correctly classified'), one column per property set.

    Cells are the group letters (groups sharing a letter are not separated) and, in the last
    row of each section, the percentage correctly classified, as in Tables 4.4/4.5.
    """
    import pandas as pd

    sets = list(result.features)
    index, rows = [], []
    for method, title in METHODS.items():
        res = result.results[method]
        for g, group in enumerate(result.groups):
            index.append((title, group))
            rows.append([res[s].letters[g] for s in sets])
        index.append((title, PERCENT_ROW))
        rows.append([f"{res[s].percent_correct:.1f}" for s in sets])
    return pd.DataFrame(rows, index=pd.MultiIndex.from_tuples(index, names=["method", result.by]),
                        columns=[set_label(s) for s in sets])


def confusion_frame(result: Classification):
    """Tidy confusion matrices: method, properties, true group, then one column per assigned group."""
    import pandas as pd

    rows = []
    for method, res in result.results.items():
        for feats, r in res.items():
            for i, group in enumerate(result.groups):
                rows.append({"method": method, "properties": set_label(feats), "group": group,
                             **{f"assigned {g}": int(r.confusion[i, j]) for j, g in enumerate(result.groups)}})
    return pd.DataFrame(rows)


def to_dict(result: Classification, table: str = "") -> dict:
    """Every number of the classification (the JSON file)."""
    sizes = {g: int((result.labels == i).sum()) for i, g in enumerate(result.groups)}
    out = {
        "table": table, "by": result.by, "groups": result.groups, "letters": {g: LETTERS[i] for i, g in
                                                                            enumerate(result.groups)},
        "samples_per_group": sizes, "rows": result.counts,
        "preprocessing": {"log10": result.log, "standardize": result.standardize},
        "kmeans": {"restarts": result.restarts, "seed": result.seed},
        "lda": {"priors": "equal", "validation": lda_validation_text(result)},
        "property_sets": [list(s) for s in result.features],
        "results": {},
    }
    for method, res in result.results.items():
        out["results"][method] = {
            set_label(feats): {
                "properties": list(feats), "percent_correct": r.percent_correct,
                "letters": dict(zip(result.groups, r.letters)),
                "confusion": r.confusion.tolist(),
                "not_separated": [[result.groups[i], result.groups[j]] for i, j in r.not_separated],
                "assigned": {sid: result.groups[p] for sid, p in zip(result.sample_ids, r.predicted)},
                "notes": r.notes,
                **({"validation": r.validation} if r.validation else {}),
            } for feats, r in res.items()}
    return out


def lda_validation_text(result: Classification) -> str:
    """The LDA validation used: 'leave-one-out', or each set's when K-fold was needed somewhere."""
    used = {set_label(f): r.validation for f, r in result.results["lda"].items()}
    kinds = set(used.values())
    if len(kinds) == 1:
        return kinds.pop()
    return "; ".join(f"{label}: {v}" for label, v in used.items())


def render_text(result: Classification) -> str:
    """The printed report: exclusions, the layout table and the groups not separated."""
    lines = [describe_exclusions(result.counts), f"LDA validation: {lda_validation_text(result)}", ""]
    table = layout_table(result)
    for method, title in METHODS.items():
        lines.append(title)
        lines.append(table.loc[title].to_string())
        lines.append("")
    lines.append("Groups not separated (sharing a letter or confused):")
    for method, res in result.results.items():
        for feats, r in res.items():
            if r.not_separated:
                pairs = ", ".join(f"{result.groups[i]}/{result.groups[j]}" for i, j in r.not_separated)
                lines.append(f"  {method:6s} {set_label(feats)}: {pairs}")
    return "\n".join(lines)


def write_reports(result: Classification, out_dir: Path, table: str = "") -> dict[str, Path]:
    """classification.csv (Table 4.4 layout), confusion_matrices.csv, classification.json."""
    paths = {"table": out_dir / "classification.csv", "confusion": out_dir / "confusion_matrices.csv",
             "json": out_dir / "classification.json"}
    layout_table(result).to_csv(paths["table"])
    confusion_frame(result).to_csv(paths["confusion"], index=False)
    write_json(paths["json"], to_dict(result, table))
    return paths
