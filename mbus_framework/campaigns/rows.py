"""One row of the campaign table (docs/campaign-table.md) from a run's result.json, or from
the error of a failed run."""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
    from mbus_framework.campaigns.plan import SampleTask

NAN = float("nan")


def _head(task: "SampleTask") -> dict[str, Any]:
    row: dict[str, Any] = {"sample_id": task.sample_id, **task.groups}
    row.update(replicate=task.replicate, replicates=task.replicates, n_replicates=task.n_replicates)
    row.update(
        sample_length=float(task.sample.get("length", NAN)),
        sample_diameter=float(task.sample.get("diameter", NAN)),
        sample_density=float(task.sample.get("density", NAN)),
    )
    return row


def _estimates(row: dict[str, Any], task: "SampleTask", result: dict[str, Any] | None) -> None:
    result = result or {}
    unc = result.get("uncertainty") or {}
    params = dict.fromkeys(task.parameter_names, NAN) | dict(result.get("parameters") or {})
    props = dict.fromkeys(task.property_names, NAN) | dict(result.get("properties") or {})
    se = unc.get("standard_errors") or {}
    pse = unc.get("property_standard_errors") or {}
    pci = unc.get("property_ci95") or {}
    row.update({p: _f(v) for p, v in params.items()})
    row.update({f"{p}_se": _f(se.get(p)) for p in params})
    row.update({p: _f(v) for p, v in props.items()})
    row.update({f"{p}_se": _f(pse.get(p)) for p in props})
    row.update({f"{p}_ci_low": _f((pci.get(p) or [NAN, NAN])[0]) for p in props})
    row.update({f"{p}_ci_high": _f((pci.get(p) or [NAN, NAN])[1]) for p in props})


def _choice(row: dict[str, Any], task: "SampleTask", result: dict[str, Any] | None) -> None:
    """``joint``/``auto`` campaigns: ``replicates`` becomes what was done ("averaged" or "joint"),
    with ``replicates_reason`` and the joint fit's ``agreement_p_value`` (NaN when averaged)."""
    if task.replicates not in ("joint", "auto"):
        return
    rep = (result or {}).get("replicates") or {}
    row["replicates"] = rep.get("mode", task.replicates)
    row["replicates_reason"] = rep.get("reason")
    row["agreement_p_value"] = _f(rep.get("agreement_p_value"))


def _tail(row: dict[str, Any], task: "SampleTask", truth: dict[str, float], run_dir: str, seconds: float) -> None:
    row.update({f"true_{k}": _f(v) for k, v in truth.items()})
    row.update(task.covariates)
    row["run_dir"] = run_dir
    row["fit_time_s"] = _f(seconds)


def result_row(task: "SampleTask", result: dict[str, Any], run_dir: str, truth: dict[str, float] | None = None) -> dict:
    """The table row of a finished fit; ``truth`` overrides the result's (averaged replicates)."""
    row = _head(task)
    _estimates(row, task, result)
    warnings = list(result.get("warnings") or [])
    row.update(
        nrmse=_f(result.get("fit", {}).get("nrmse")),
        success=bool(result.get("solver", {}).get("success", False)),
        warnings="; ".join(warnings) if warnings else None,
        error=None,
    )
    _choice(row, task, result)
    if truth is None:
        truth = {**(result.get("truth") or {}), **(result.get("truth_properties") or {})}
    _tail(row, task, truth, run_dir, result.get("solver", {}).get("wall_time_s", NAN))
    return row


def failed_row(task: "SampleTask", error: str, run_dir: str, truth: dict[str, float] | None = None) -> dict:
    """The table row of a sample whose data or fit failed: estimates NaN, ``error`` set."""
    row = _head(task)
    _estimates(row, task, None)
    row.update(nrmse=NAN, success=False, warnings=None, error=" ".join(error.split()) or "failed")
    _choice(row, task, None)
    _tail(row, task, truth or {}, run_dir, NAN)
    return row


def _f(value: Any) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return NAN
