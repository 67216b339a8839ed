"""Element-count sweep (Figs. 3.10-3.11): one record fitted with n = 2..40 elements."""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from mbus_framework.errors import ConfigError, EstimationError
from mbus_framework.pipeline.config import load_config
from mbus_framework.studies.common import (
    _base_components,
    _Context,
    _flow,
    _has_option,
    _pyplot,
)
from mbus_framework.studies.options import ElementSweepOptions


# ---------------------------------------------------------------------------------------
# Element-count sweep (Figs. 3.10-3.11)
# ---------------------------------------------------------------------------------------
def settle_index(values: list[float] | np.ndarray, tolerance: float) -> int | None:
    """First index k from which every later value is within ``tolerance`` (relative) of
    values[k]; None when only the last value qualifies (not settled within the sweep)."""
    v = np.asarray(values, float)
    for k in range(v.size - 1):
        if not np.isfinite(v[k]) or v[k] == 0:
            continue
        later = v[k + 1:]
        if np.all(np.isfinite(later)) and np.all(np.abs(later - v[k]) <= tolerance * abs(v[k])):
            return k
    return None


def _sweep_mapping_to_properties(model, mapping: dict[str, float], where: str) -> dict[str, float]:
    return model.to_properties(model.theta_from_mapping(mapping, where))


def _element_sweep(ctx: _Context):
    o: ElementSweepOptions = ctx.options
    c = _base_components(ctx)
    if not _has_option(c.model, "n_elements"):
        raise ConfigError(f"study element_sweep: model '{c.config.model.name}' has no 'n_elements' option")
    model_opts = c.model.options.model_dump(mode="json")
    base: list[str] = []
    reference = "the config's backend"
    bo = c.backend.options
    if o.reference_n is not None and hasattr(bo, "truth") and hasattr(bo, "medium") and bo.medium is None:
        # The truth is a medium, not a parameter vector of one n: convert it to properties with
        # the config's model, and simulate it with a fine chain of the same model.
        props = _sweep_mapping_to_properties(c.model, dict(bo.truth), f"{ctx.config_path}: backend.options.truth")
        medium = {"name": c.config.model.name, "options": {**model_opts, "n_elements": o.reference_n}}
        base += [f"backend.options.truth={_flow(props)}", f"backend.options.medium={_flow(medium)}"]
        reference = f"{c.config.model.name} with {o.reference_n} elements (the config's truth as material properties)"
    elif hasattr(bo, "medium") and bo.medium is not None:
        reference = f"the config's medium {bo.medium.name} {bo.medium.options}"
    if c.config.model.initial:  # parameters depend on n, properties do not
        init = _sweep_mapping_to_properties(c.model, dict(c.config.model.initial), f"{ctx.config_path}: model.initial")
        base.append(f"model.initial={_flow(init)}")
    fixed_props = None
    if c.config.model.fixed:
        theta = np.array([p.typical for p in c.model.parameters])
        if c.config.model.initial:
            theta = c.model.theta_from_mapping(c.config.model.initial, "model.initial")
        for k, v in c.config.model.fixed.items():
            theta[c.model.parameter_names.index(k)] = v
        fixed_props = (c.model.to_properties(theta), list(c.config.model.fixed))

    def fixed_override(n: int) -> list[str]:
        if fixed_props is None:
            return []
        from mbus_framework.pipeline.run import build_components

        cfg = load_config(ctx.config_path, ctx.overrides + [f"model.options.n_elements={n}"])
        model_n = build_components(cfg, ctx.config_path).model
        theta_n = np.asarray(model_n.from_properties(fixed_props[0]), float)
        return [f"model.fixed={_flow({k: float(theta_n[model_n.parameter_names.index(k)]) for k in fixed_props[1]})}"]

    def fit(n: int, label: str, extra: list[str]) -> dict:
        rec = ctx.run(label, base + [f"model.options.n_elements={n}"] + fixed_override(n) + extra)
        rec["n_elements"] = n
        return rec

    def better(a: dict | None, b: dict | None) -> dict | None:
        if a is None or not a["ok"]:
            return b
        if b is None or not b["ok"]:
            return a
        return b if b["cost"] < a["cost"] else a

    ns = o.n_values
    runs: list[dict] = []
    ctx.start(len(ns) + (len(ns) - 1 if o.warm_start else 0))
    try:
        cold: dict[int, dict] = {}
        for n in ns:
            cold[n] = rec = fit(n, f"n-{n:03d}", [])
            rec["start"] = "config"
            runs.append(rec)
            ctx.advance(f"n = {n}: " + (f"nrmse {rec['nrmse']:.3g}" if rec["ok"] else "failed"))
        best = dict(cold)
        if o.warm_start:  # second pass, finest first: start each n from its finer neighbour's estimate
            for finer, n in zip(ns[::-1], ns[-2::-1]):
                src = best[finer]
                if not src["ok"]:
                    ctx.advance(f"n = {n}: no warm start")
                    continue
                rec = fit(n, f"n-{n:03d}-warm", [f"model.initial={_flow(src['properties'])}"])
                rec["start"] = f"warm from n = {finer}"
                runs.append(rec)
                best[n] = better(best[n], rec)
                ctx.advance(f"n = {n} (warm): " + (f"nrmse {rec['nrmse']:.3g}" if rec["ok"] else "failed"))
    finally:
        ctx.stop()
    ok = [best[n] for n in ns if best[n]["ok"]]
    if len(ok) < 2:
        raise EstimationError(f"study element_sweep: fewer than two runs succeeded: {[r.get('error') for r in runs]}")
    pnames = list(ok[0]["properties"])
    truth = ok[-1].get("truth_properties") or {}
    rows = []
    prev = None
    for r in ok:
        row: dict[str, Any] = {"n_elements": r["n_elements"], "run": r["label"], "start": r["start"]}
        for p in pnames:
            v = r["properties"][p]
            row[p] = v
            row[f"{p}_se"] = r["property_standard_errors"].get(p)
            row[f"{p}_change"] = (v / prev["properties"][p] - 1.0) if prev and prev["properties"][p] else None
            if p in truth and truth[p]:
                row[f"{p}_error"] = v / truth[p] - 1.0
        row["nrmse"] = r["nrmse"]
        row["warnings"] = len(r.get("warnings") or [])
        row["cost"] = r["cost"]
        others = [x for x in runs if x["n_elements"] == r["n_elements"] and x is not r and x["ok"]]
        row["other_start_cost"] = others[0]["cost"] if others else None
        row["wall_time_s"] = sum(x["wall_time_s"] for x in runs if x["n_elements"] == r["n_elements"])
        rows.append(row)
        prev = r
    settle = {}
    for p in pnames:
        k = settle_index([r["properties"][p] for r in ok], o.tolerance)
        settle[p] = ok[k]["n_elements"] if k is not None else None
    known = [v for v in settle.values() if v is not None]
    summary = {
        "n_values": o.n_values,
        "reference": reference,
        "truth_properties": truth or None,
        "tolerance": o.tolerance,
        "settled_at": settle,
        "all_settled_at": max(known) if len(known) == len(settle) else None,
        "warm_start": o.warm_start,
        "warm_start_won": [r["n_elements"] for r in ok if r["start"] != "config"],
        "failed": [{"n_elements": r["n_elements"], "run": r["label"], "error": r["error"]} for r in runs if not r["ok"]],
    }
    text = _sweep_text(ctx, rows, summary, pnames)
    units = ok[-1].get("property_units") or {p.name: p.unit for p in c.model.properties}
    return rows, summary, runs, text, _sweep_figure(ok, pnames, truth, settle, units)



def _sweep_text(ctx, rows, summary, pnames) -> str:
    lines = [
        f"Element-count sweep: {ctx.config_path}, data from {summary['reference']}",
        "",
        f"  {'n':>4}" + "".join(f"{p:>14}" for p in pnames) + f"{'nrmse':>9}{'time s':>8}  start",
    ]
    for r in rows:
        lines.append(f"  {r['n_elements']:>4}" + "".join(f"{r[p]:>14.5g}" for p in pnames)
                     + f"{r['nrmse']:>9.3g}{r['wall_time_s']:>8.1f}  {r['start']}")
    truth = summary.get("truth_properties")
    if truth:
        lines.append(f"  {'true':>4}" + "".join(f"{truth[p]:>14.5g}" if p in truth else f"{'':>14}" for p in pnames))
    lines.append("")
    tol = 100 * summary["tolerance"]
    for p in pnames:
        n = summary["settled_at"][p]
        lines.append(f"  {p:<12} settles at n = {n} (later estimates within {tol:g} %)" if n is not None
                     else f"  {p:<12} does not settle within the sweep (tolerance {tol:g} %)")
    if summary["warm_start"]:
        lines.append("  each n was fitted from the config's start and from its finer neighbour's estimate; "
                     "the lower cost is shown")
    if summary["failed"]:
        lines.append(f"  failed runs: {', '.join(f['run'] for f in summary['failed'])}")
    return "\n".join(lines)


def _sweep_figure(ok, pnames, truth, settle, units=None):
    """One panel per property against n, in a scaled unit of the property (e.g. GPa)."""
    from mbus_framework.pipeline.units import label_axis

    units = units or {}
    plt = _pyplot()
    cols = 2
    nrow = math.ceil(len(pnames) / cols)
    fig, axes = plt.subplots(nrow, cols, figsize=(10, 3.4 * nrow), squeeze=False)
    n = np.array([r["n_elements"] for r in ok])
    for ax, p in zip(axes.flat, pnames):
        v = np.array([r["properties"][p] for r in ok], float)
        se = np.array([r["property_standard_errors"].get(p, np.nan) for r in ok], float)
        k = label_axis(ax, "y", p, np.concatenate([v, [truth[p]] if p in truth else []]), units.get(p, ""))
        v, se = v / k, se / k
        truth = {**truth, p: truth[p] / k} if p in truth else truth
        # A coarse chain can drive a coefficient to ~0 (a degenerate fit): keep the axis to
        # three decades around the median and mark such points at the edge.
        ref = [x for x in [truth.get(p)] if x] + list(v[np.isfinite(v)])
        med = float(np.median(np.abs(ref))) if ref else 1.0
        lo, hi = med / 1e3, med * 1e3
        inside = (v >= lo) & (v <= hi)
        ax.errorbar(n[inside], v[inside], yerr=1.96 * np.nan_to_num(se[inside]), fmt="o-", ms=4, capsize=2,
                    label="estimate (95 %)")
        if np.any(~inside):
            edge = np.where(v < lo, lo, hi)
            ax.plot(n[~inside], edge[~inside], "v", color="tab:orange", label="off scale (degenerate fit)")
        if p in truth:
            ax.axhline(truth[p], color="k", ls=":", lw=1, label="truth")
        if settle.get(p) is not None:
            ax.axvline(settle[p], color="tab:red", ls="--", lw=1, label=f"settles at n = {settle[p]}")
        ax.set_title(p)
        ax.set_xlabel("number of elements n [-]")
        shown = np.concatenate([v[inside], [truth[p]] if p in truth else []])
        if shown.size and np.all(shown > 0) and shown.max() / shown.min() > 20 or np.any(~inside):
            ax.set_yscale("log")
            ax.set_ylim(min(shown.min(), lo if np.any(v < lo) else shown.min()) / 1.5,
                        max(shown.max(), hi if np.any(v > hi) else shown.max()) * 1.5)
        ax.legend(fontsize=8)
    for ax in list(axes.flat)[len(pnames):]:
        ax.axis("off")
    fig.suptitle("Material properties against the number of elements (Figs. 3.10-3.11)")
    fig.tight_layout()
    return fig
