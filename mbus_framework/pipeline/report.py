"""Human-facing output of a run: the printed summary and the figure files (SVG or PNG) (report.html is
:mod:`~mbus_framework.pipeline.run_report`)."""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
    from mbus_framework.pipeline.figure_workers import Helpers
    from mbus_framework.pipeline.figures import FitData


def summary_text(result: dict[str, Any], run_dir: Path | None = None) -> str:
    """Plain-text summary: parameters, properties (with CIs and truth), fit and solver."""
    lines: list[str] = []
    title = result.get("title") or result.get("config")
    lines.append(f"mbus identification: {title}")
    lines.append(f"model {result['model']['name']} {result['model']['options']}")
    first = [w for w in result.get("warnings", []) if w.startswith("measurement: ")]  # partial acquisitions
    lines += [f"  WARNING: {w}" for w in first]
    pre = result.get("pretrigger") or {}
    if pre.get("samples"):
        lines.append(f"  record: {pre['samples']} pre-trigger samples ({pre['seconds']:.3g} s) cut before the onset; "
                     f"offsets removed: u {pre['offset_u']:.3g}, y {pre['offset_y']:.3g}")
    unc = result.get("uncertainty", {})
    truth = result.get("truth", {})
    err = result.get("error_percent", {})
    se = unc.get("relative_standard_errors", {})
    lines.append("")
    head = f"  {'parameter':<12}{'estimate':>14} {'unit':<8}{'rel. SE':>10}"
    if truth:
        head += f"{'truth':>14}{'error':>10}"
    lines.append(head)
    for name, value in result["parameters"].items():
        fixed = name in result.get("fixed", {})
        row = f"  {name:<12}{value:>14.5g} {result['parameter_units'].get(name, ''):<8}"
        row += f"{'fixed':>10}" if fixed else (f"{100 * se[name]:>9.3g}%" if name in se else f"{'':>10}")
        if name in truth:
            row += f"{truth[name]:>14.5g}{err.get(name, float('nan')):>9.3f}%"
        lines.append(row)
    lines.append("")
    tprops = result.get("truth_properties", {})
    pci = unc.get("property_ci95", {})
    head = f"  {'property':<12}{'estimate':>14} {'unit':<8}{'95% interval':>28}"
    if tprops:
        head += f"{'truth':>14}{'error':>10}"
    lines.append(head)
    for name, value in result["properties"].items():
        row = f"  {name:<12}{value:>14.5g} {result['property_units'].get(name, ''):<8}"
        if name in result.get("fixed_properties", ()):
            row += f"{'fixed':>28}"
        elif name in pci:
            lo, hi = pci[name]
            row += f"{f'[{lo:.4g}, {hi:.4g}]':>28}"
        else:
            row += f"{'':>28}"
        if name in tprops and tprops[name]:
            row += f"{tprops[name]:>14.5g}{100 * (value / tprops[name] - 1):>9.3f}%"
        lines.append(row)
    for g in unc.get("correlated_groups") or []:
        if g.get("best") and g.get("worst") and not g.get("warning"):  # a warning says it below
            lines.append(f"  correlated: {', '.join(g['parameters'])} (|r| up to {g['max_correlation']:.6g}); the "
                         f"record determines {g['best']['expression']} to "
                         f"{100 * g['best']['relative_standard_error']:.2g} % and {g['worst']['expression']} to "
                         f"{100 * g['worst']['relative_standard_error']:.2g} %")
    if result.get("dispersion"):
        from mbus_framework.pipeline.dispersion import summary_line

        lines.append(summary_line(result["dispersion"]))
    fit, sol, strat = result["fit"], result["solver"], result.get("strategy", {})
    lines.append("")
    lines.append(f"  fit: mse {fit['mse']:.4g}, nrmse {fit['nrmse']:.4g} over {fit['n_samples']} samples")
    state = "converged" if sol["success"] else "NOT converged"
    lines.append(
        f"  solver {sol['name']}: {state} (status {sol['status']}: {sol['message']}); "
        f"{sol['nfev']} evaluations, {sol['wall_time_s']:.2f} s"
    )
    if strat.get("starts"):
        lines.append(
            f"  strategy: start from {strat.get('initial_source')}, {len(strat['starts'])} start(s) tried, "
            f"start {strat.get('winner')} won; accepted: {strat.get('accepted_because', '')}"
        )
    crb = unc.get("cramer_rao", {})
    if crb:
        lines.append(
            "  Cramer-Rao standard errors at the truth: "
            + ", ".join(f"{n} {100 * v / abs(truth[n]):.3g}%" for n, v in crb.items() if truth.get(n))
        )
    for w in result.get("warnings", []):
        if w not in first:
            lines.append(f"  WARNING: {w}")
    if run_dir is not None:
        lines.append(f"  output: {run_dir}")
    return "\n".join(lines)


def write_figures(run_dir: Path, data: "FitData", dpi: int = 100, helpers: "Helpers | None" = None,
                  fmt: str = "png") -> tuple[dict[str, str], dict[str, bytes]]:
    """Draw every figure once and write it into the run folder: ``fmt`` ``svg`` here
    (:mod:`~mbus_framework.pipeline.svg`, no matplotlib), ``png`` by matplotlib (by the forked
    ``helpers`` when given, :mod:`~mbus_framework.pipeline.figure_workers`; each PNG is written
    as it arrives). Returns the result.json ``files`` entries (``<name>_plot``, in
    :data:`~mbus_framework.pipeline.figures.FIGURES` order) and the files' bytes (for report.html)."""
    from mbus_framework.pipeline.figures import file_name, render_all, render_svg
    from mbus_framework.pipeline.storage import atomic_write_bytes

    def save(name: str, content: bytes) -> None:
        atomic_write_bytes(Path(run_dir) / file_name(name, fmt), content)

    if fmt == "svg":
        drawn = render_svg(data)
        for name, svg in drawn.items():
            save(name, svg)
    elif helpers is not None:
        drawn = helpers.render(data, dpi, save)
    else:
        drawn = render_all(data, dpi)
        for name, png in drawn.items():
            save(name, png)
    return {f"{name}_plot": file_name(name, fmt) for name in drawn}, drawn
