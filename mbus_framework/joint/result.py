"""The result of a joint fit: shared properties with intervals, per-record values, agreement."""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
    import pandas as pd

    from mbus_framework.api.result import Estimate


class JointResult:
    """``document`` is the joint result.json mapping; ``run_dir`` the run folder (None in memory);
    ``outcome`` the :class:`~mbus_framework.joint.run.JointOutcome` (problem and per-record fits)."""

    def __init__(self, document: dict[str, Any], run_dir: Path | None = None, outcome: Any = None):
        self.document, self.outcome = document, outcome
        self.run_dir = Path(run_dir) if run_dir is not None else None

    @classmethod
    def load(cls, run_dir: str | Path) -> "JointResult":
        return cls(json.loads((Path(run_dir) / "result.json").read_text(encoding="utf-8")), Path(run_dir))

    @property
    def properties(self) -> dict[str, "Estimate"]:
        """The shared properties with joint standard errors and 95 % intervals."""
        from mbus_framework.api.result import Estimate

        d = self.document
        unc, truth = d["uncertainty"], d.get("truth_properties", {})
        return {n: Estimate(n, float(v), d["property_units"].get(n, ""), unc["property_standard_errors"].get(n),
                            tuple(unc["property_ci95"][n]), truth.get(n))
                for n, v in d["properties"].items()}

    @property
    def records(self) -> list[dict[str, Any]]:
        return list(self.document["records"])

    @property
    def agreement(self) -> dict[str, Any]:
        return dict(self.document["agreement"])

    @property
    def warnings(self) -> list[str]:
        return list(self.document.get("warnings", []))

    def to_dataframe(self) -> "pd.DataFrame":
        """One row per estimate: ``record`` ("shared" or the record's label), ``name``, ``value``,
        ``std_error``, ``ci95_low``, ``ci95_high`` (per-record properties and nuisance values)."""
        import pandas as pd

        rows = []
        for e in self.properties.values():
            rows.append({"record": "shared", "name": e.name, "value": e.value, "unit": e.unit, "std_error": e.std_error,
                         "ci95_low": e.ci95[0], "ci95_high": e.ci95[1], "truth": e.truth})
        q = 1.959963984540054
        from mbus_framework.estimation.nuisance import DELAY
        from mbus_framework.estimation.uncertainty import confidence_intervals

        for rec in self.records:
            for name, value in rec["per_record"].items():
                se = rec["per_record_standard_errors"].get(name)
                lo, hi = confidence_intervals([value], [se], q, [name != DELAY])[0]  # positive but the delay
                rows.append({"record": rec["label"], "name": name, "value": value, "unit": "", "std_error": se,
                             "ci95_low": float(lo), "ci95_high": float(hi),
                             "truth": rec.get("truth_nuisance", {}).get(name)})
        return pd.DataFrame(rows, columns=["record", "name", "value", "unit", "std_error", "ci95_low", "ci95_high",
                                           "truth"])

    def summary(self) -> str:
        d = self.document
        lines = [f"mbus joint identification: {d.get('title') or d.get('config')}",
                 f"model {d['model']['name']} {d['model']['options']}; {len(d['records'])} records; "
                 f"shared: {', '.join(d['shared'])}; per record: {', '.join(d['per_record']) or '-'}", ""]
        lines += [f"  WARNING: {w}" for w in d.get("warnings", [])]
        lines.append(f"  {'shared property':<16}{'estimate':>13} {'unit':<6}{'95 % interval':>28}{'rel. SE':>9}"
                     + (f"{'truth':>12}" if d.get("truth_properties") else ""))
        for e in self.properties.values():
            rel = e.std_error / abs(e.value) if e.value else math.inf
            row = f"  {e.name:<16}{e.value:>13.5g} {e.unit:<6}  [{e.ci95[0]:>11.5g}, {e.ci95[1]:>11.5g}]{100 * rel:>8.3g}%"
            lines.append(row + (f"{e.truth:>12.5g}" if e.truth is not None else ""))
        lines.append("")
        for rec in d["records"]:
            own = ", ".join(f"{n} = {v:.5g} +- {rec['per_record_standard_errors'][n]:.2g}" for n, v in rec["per_record"].items())
            v = rec["verdict"]
            lines.append(f"  record {rec['label']} (L = {rec['sample']['length']:g} m, {rec['fit']['n_samples']} samples): "
                         f"{own or 'no per-record parameters'}; nrmse {rec['fit']['nrmse']:.3g}; "
                         f"{'accepted' if v['accepted'] else 'REJECTED: ' + v['reason']}")
        a = d["agreement"]
        lines.append("")
        lines.append(f"  agreement: likelihood ratio {a['statistic']:.4g}, df {a['df']}, p = {a['p_value']:.3g} -> "
                     + ("the records agree" if a["agree"] else f"the records DO NOT agree (p < {a['level']:g})"))
        if self.run_dir is not None:
            lines.append(f"  run folder: {self.run_dir}")
        return "\n".join(lines)

    def __repr__(self) -> str:
        return self.summary()
