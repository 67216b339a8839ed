"""``report.html`` of a campaign folder: one self-contained page to open, mail or attach.

What ran (fits, reused, failed, how replicates were treated), the group summary in the layout
of Tables 4.2/4.3 (mean and SD as % of mean), the failed rows with their errors, the warnings
the fits raised (each with how many rows raised it), every property by group as embedded
figures, and links to each sample's own ``report.html``. Built from the same primitives as a
run's report (:mod:`mbus_framework.pipeline.html`).
"""
from __future__ import annotations

import math
from collections import Counter
from pathlib import Path
from typing import Any

from mbus_framework.pipeline import html
from mbus_framework.pipeline.run_report import REPORT_FILE
from mbus_framework.pipeline.storage import atomic_write_text



def _summary_tables(summary, groups: list[str]) -> list[html.Html]:
    """Tables 4.2/4.3 layout: per group n, density and each quantity as "mean (SD %)"; then,
    when the truth is known (simulated samples), the error of each group mean."""
    quantities = [c[: -len("_mean")] for c in summary.columns if c.endswith("_mean") and not c.endswith("_true_mean")]
    keys = groups or ["group"]
    has_density = "density" in summary.columns
    header = [*keys, "n", *(["density"] if has_density else []), *(f"{q} mean (SD %)" for q in quantities)]
    rows, errors = [], []
    for _, r in summary.iterrows():
        label = [_cell(r[k]) for k in keys]
        cells = [f"{_number(r[f'{q}_mean'])} ({_number(r[f'{q}_sd_percent'], 3)} %)" for q in quantities]
        rows.append([*label, int(r["n"]), *([_cell(r["density"])] if has_density else []), *cells])
        if any(f"{q}_error_percent" in summary.columns for q in quantities):
            errors.append([*label, *(_signed_percent(r.get(f"{q}_error_percent")) for q in quantities)])
    out = [html.table(rows, header=header, caption="mean (standard deviation as % of the mean) of each "
                                                   "group's fitted rows")]
    if errors:
        out.append(html.table(errors, header=[*keys, *quantities],
                              caption="error of each group mean against the mean truth (simulated samples)"))
    return out


def _number(value: Any, digits: int = 4) -> str:
    value = _cell(value)
    return "" if value == "" else html.number(float(value), digits)


def _signed_percent(value: Any) -> str:
    value = _cell(value)
    return "" if value in ("", None) else f"{float(value):+.2f} %"


def _cell(value: Any) -> Any:
    """Numbers stay numbers (right-aligned, 5 significant digits); missing values are blank."""
    if hasattr(value, "item"):  # numpy scalars
        value = value.item()
    if isinstance(value, float) and math.isnan(value):
        return ""
    return value


def _warning_counts(table) -> list[list[Any]]:
    counts: Counter[str] = Counter()
    if "warnings" not in table.columns:
        return []
    for cell in table["warnings"].dropna():  # a row's warnings, as one cell
        if str(cell).strip():
            counts[str(cell).strip()[:600]] += 1
    return [[n, w] for w, n in counts.most_common(20)]


def _sample_links(result) -> html.Html:
    out = result.out_dir
    items = []
    for run_dir in result.table.get("run_dir", []):
        report = out / str(run_dir) / REPORT_FILE
        if report.is_file():
            rel = Path(str(run_dir)) / REPORT_FILE
            items.append(f'<li><a href="{html.escape(rel.as_posix())}">{html.escape(Path(str(run_dir)).name)}</a></li>')
    if not items:
        return html.paragraph("No per-sample reports (the fits ran with plots and reports off, or none finished).")
    return html.Html("<ul>" + "".join(items) + "</ul>")


def campaign_report_html(result) -> str:
    """The page for ``result``, a :class:`~mbus_framework.campaigns.runner.CampaignResult`
    (its table, group report and counts)."""
    c = result.campaign
    table = result.table
    from mbus_framework.campaigns.runner import replicates_how

    how = ("each replicate fitted, then aggregated per sample" if c.spec.replicates == "fit"
           else replicates_how(result))
    counts = {
        "fits": len(result.tasks),
        "run now": len(result.fitted),
        "reused from an earlier run": len(result.reused),
        "failed": len(result.failed),
        "replicates": how,
        "groups": ", ".join(c.spec.groups) or "(none)",
        "status": "interrupted: run again to continue" if result.interrupted else "finished",
        "wall time [s]": round(result.wall_time_s, 1),
    }
    parts = [html.section("Campaign", html.key_values(counts), anchor="campaign")]
    if result.report is not None and len(table):
        parts.append(html.section(
            "Group summary", *_summary_tables(result.report.summary, list(c.spec.groups)),
            html.paragraph("Every column, with the standard deviations and truths: group_summary.csv."),
            anchor="summary"))
    if result.failed:
        errors = dict(zip(table["run_dir"], table["error"]))
        parts.append(html.section("Failed rows", html.table([[Path(r).name, errors.get(r, "")] for r in result.failed],
                                                             header=["run", "error"]), anchor="failed"))
    warned = _warning_counts(table) if table is not None else []
    parts.append(html.section(
        "Warnings", html.warnings([f"{n} row(s): {w}" for n, w in warned],
                                  none="No fit raised a warning."), anchor="warnings"))
    figures = []
    if result.report is not None:
        for prop, path in result.report.plots.items():
            p = Path(path)
            if p.is_file():
                figures.append(html.image(p.read_bytes(), f"{prop} by group",
                                          f"{prop} of every row with its 95 % interval, group mean +- SD"))
    if figures:
        parts.append(html.section("Properties by group", *figures, anchor="plots"))
    parts.append(html.section("Samples", _sample_links(result), anchor="samples"))
    nav = [("campaign", "Campaign"), ("summary", "Summary"), ("warnings", "Warnings"), ("plots", "Plots"),
           ("samples", "Samples")]
    return html.page(c.title or "mbus campaign", parts, subtitle=str(c.path), nav=nav)


def write_campaign_report(result) -> Path:
    """Write ``report.html`` into the campaign folder; returns its path."""
    return atomic_write_text(result.out_dir / REPORT_FILE, campaign_report_html(result))
