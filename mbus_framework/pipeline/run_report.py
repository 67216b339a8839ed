"""``report.html`` of a run: one self-contained page to open, share or attach to a lab notebook.

Built from the result.json document, the figures' SVG (inline) or PNG bytes (:mod:`~mbus_framework.pipeline.figures`)
and the validated config, with the primitives of :mod:`~mbus_framework.pipeline.html`. The tables
(:func:`estimate_tables`) are also what a Python :class:`~mbus_framework.api.Result` shows in a
notebook.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from mbus_framework.pipeline import html
from mbus_framework.pipeline.figures import FIGURES
from mbus_framework.pipeline.storage import atomic_write_text

REPORT_FILE = "report.html"


def _error(value: float, truth: float | None) -> float | str:
    return 100.0 * (value / truth - 1.0) if truth else ""


def property_rows(result: dict[str, Any]) -> list[list[Any]]:
    """[name, estimate, unit, 95 % low, 95 % high, rel. SE %, truth, error %] per material property."""
    unc = result.get("uncertainty", {})
    ci, se = unc.get("property_ci95", {}), unc.get("property_standard_errors", {})
    truth = result.get("truth_properties", {})
    rows = []
    for name, value in result["properties"].items():
        lo, hi = ("fixed", "") if name in result.get("fixed_properties", ()) else ci.get(name, ("", ""))
        rel = 100 * se[name] / abs(value) if name in se and value else ""
        rows.append([name, value, result.get("property_units", {}).get(name, ""), lo, hi, rel,
                     truth.get(name, ""), _error(value, truth.get(name))])
    return rows


def parameter_rows(result: dict[str, Any]) -> list[list[Any]]:
    """[name, estimate, unit, SE, rel. SE %, status, truth, error %] per model/nuisance parameter."""
    unc = result.get("uncertainty", {})
    se, rel = unc.get("standard_errors", {}), unc.get("relative_standard_errors", {})
    truth = result.get("truth", {})
    rows = []
    for name, value in result["parameters"].items():
        status = "fixed" if name in result.get("fixed", {}) else "estimated"
        r = 100 * rel[name] if name in rel and math.isfinite(rel[name]) else rel.get(name, "")
        rows.append([name, value, result.get("parameter_units", {}).get(name, ""), se.get(name, ""), r, status,
                     truth.get(name, ""), _error(value, truth.get(name))])
    return rows


def _trim(rows: list[list[Any]], header: list[str], optional: tuple[int, ...]) -> tuple[list[list[Any]], list[str]]:
    """Drop the optional columns that are empty in every row (no truth on recorded data)."""
    drop = {i for i in optional if all(r[i] == "" for r in rows)}
    keep = [i for i in range(len(header)) if i not in drop]
    return [[r[i] for i in keep] for r in rows], [header[i] for i in keep]


def estimate_tables(result: dict[str, Any]) -> list[html.Html]:
    """The properties table, the parameters table and the fit-quality table."""
    prows, phead = _trim(property_rows(result),
                         ["property", "estimate", "unit", "95 % low", "95 % high", "rel. SE %", "truth", "error %"],
                         (3, 4, 5, 6, 7))
    qrows, qhead = _trim(parameter_rows(result),
                         ["parameter", "estimate", "unit", "SE", "rel. SE %", "", "truth", "error %"], (3, 4, 6, 7))
    fit, solver = result["fit"], result["solver"]
    quality = {
        "nrmse (RMS residual / RMS output)": fit["nrmse"],
        "residual autocorrelation (mean |r|, lags 1-10)": fit.get("residual_autocorrelation", ""),
        "samples": fit["n_samples"],
        "sample interval [s]": fit["dt_s"],
        "solver": f"{solver['name']}: {'converged' if solver['success'] else 'NOT converged'} ({solver['message']})",
        "evaluations, time": f"{solver['nfev']} evaluations, {solver['wall_time_s']:.3g} s",
    }
    strategy = result.get("strategy") or {}
    if strategy.get("starts"):
        quality["search"] = (f"{len(strategy['starts'])} start(s) from {strategy.get('initial_source')}; "
                             f"accepted: {strategy.get('accepted_because', '')}")
    return [
        html.table(prows, phead, caption="Material properties (95 % intervals by the delta method)"),
        html.table(qrows, qhead, caption="Model parameters"),
        html.key_values(quality, caption="Fit quality"),
    ]


def _scalars(mapping: dict[str, Any]) -> dict[str, Any]:
    out = {}
    for k, v in mapping.items():
        if isinstance(v, dict):
            out.update({f"{k}.{kk}": vv for kk, vv in _scalars(v).items()})
        elif isinstance(v, (list, tuple)) and len(v) <= 4 and all(isinstance(x, (int, float)) for x in v):
            out[k] = ", ".join(html.number(x, 4) for x in v)
        elif v is None or isinstance(v, (str, int, float, bool)):
            out[k] = v
    return out


def report_html(result: dict[str, Any], figures: dict[str, bytes] | None, config_text: str | None = None,
                files: list[str] | None = None) -> str:
    """The whole page. ``figures`` maps figure names of :data:`FIGURES` to SVG or PNG bytes
    (None: plots were switched off)."""
    model = result["model"]
    title = result.get("title") or str(result.get("config") or "mbus run")
    subtitle = (f"model {model['name']} ({model.get('n_states', '?')} states), solver {result['solver']['name']}, "
                f"{result.get('created', '')}, mbus {result.get('mbus_version', '')}, config {result.get('config')}")
    parts = [html.section("Summary", html.warnings(result.get("warnings", [])), *estimate_tables(result),
                          anchor="summary")]
    if figures:
        shown = [html.image(figures[name], alt=name.replace("_", " "), caption=caption)
                 for name, (_b, _f, caption) in FIGURES.items() if name in figures]
        parts.append(html.section("Figures", *shown, anchor="figures"))
    else:
        parts.append(html.section("Figures", html.paragraph(
            "Figures were not drawn (--no-plots or output.plots: false)."), anchor="figures"))
    unc = result.get("uncertainty")
    if unc and unc.get("correlation", {}).get("names"):
        names = unc["correlation"]["names"]
        rows = [[n, *row] for n, row in zip(names, unc["correlation"]["matrix"])]
        parts.append(html.section("Correlation of the estimates", html.table(rows, ["", *names], digits=3),
                                  html.paragraph(f"Method: {unc.get('method', '')}."), anchor="correlation"))
    parts.append(html.section("Excitation and input", html.key_values(_scalars(result.get("excitation", {}))),
                              anchor="excitation"))
    if config_text:
        parts.append(html.section("Config", html.code(config_text), anchor="config"))
    if files:
        parts.append(html.section("Files", html.table([[f] for f in files], ["file in the run folder"]),
                                  anchor="files"))
    nav = [("summary", "Summary"), ("figures", "Figures"), ("excitation", "Excitation")]
    if config_text:
        nav.append(("config", "Config"))
    return html.page(f"mbus: {title}", parts, subtitle=subtitle, nav=nav)


def write_report(run_dir: Path, result: dict[str, Any], figures: dict[str, bytes] | None) -> Path:
    """Write ``report.html`` into the run folder (with its config.yaml and file list)."""
    run_dir = Path(run_dir)
    config = run_dir / "config.yaml"
    config_text = config.read_text(encoding="utf-8") if config.is_file() else None
    files = sorted({*result.get("files", {}).values(), REPORT_FILE})
    return atomic_write_text(run_dir / REPORT_FILE, report_html(result, figures, config_text, files))
