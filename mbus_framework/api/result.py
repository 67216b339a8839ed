"""The result of one identification, for people working in Python or a notebook.

A :class:`Result` wraps the result.json document (:attr:`Result.document`) with typed access
(:attr:`~Result.parameters` and :attr:`~Result.properties` as :class:`Estimate` records with
standard errors and 95 % intervals, :attr:`~Result.warnings`, :attr:`~Result.fit_quality`),
a text :meth:`~Result.summary`, a rich notebook display, :meth:`~Result.to_dataframe` and the
run's figures as ``plot_*`` methods (matplotlib ``Figure`` objects).
"""
from __future__ import annotations

import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from mbus_framework.pipeline import figures as _figures
from mbus_framework.pipeline import html
from mbus_framework.pipeline.report import summary_text
from mbus_framework.pipeline.run_report import estimate_tables, report_html

if TYPE_CHECKING:  # pragma: no cover
    import pandas as pd
    from matplotlib.figure import Figure

    from mbus_framework.pipeline.figures import FitData
    from mbus_framework.pipeline.run import RunOutcome


@dataclass(frozen=True)
class Estimate:
    """One estimated quantity: ``value`` in SI ``unit``, its standard error and 95 % interval
    (None where the run has no uncertainty for it, e.g. a fixed parameter), the truth when the
    rig was simulated. ``float(estimate)`` is the value."""

    name: str
    value: float
    unit: str = ""
    std_error: float | None = None
    ci95: tuple[float, float] | None = None
    truth: float | None = None
    fixed: bool = False

    def __float__(self) -> float:
        return float(self.value)

    @property
    def relative_std_error(self) -> float | None:
        """std_error / |value| (None without a standard error)."""
        if self.std_error is None:
            return None
        return self.std_error / abs(self.value) if self.value else math.inf

    def __str__(self) -> str:
        ci = f" [{self.ci95[0]:.4g}, {self.ci95[1]:.4g}]" if self.ci95 else ""
        return f"{self.name} = {self.value:.5g} {self.unit}{ci}".rstrip()


class Result:
    """One identification: estimates with uncertainty, warnings, fit quality and figures.

    Made by :func:`mbus_framework.fit`, :func:`mbus_framework.run_config` or :meth:`Result.load`.
    ``document`` is the result.json mapping (schema in the documentation), ``run_dir`` the run
    folder (None for a fit kept in memory), ``data`` the arrays behind the figures.
    """

    def __init__(self, document: dict[str, Any], data: "FitData | None" = None, run_dir: Path | None = None):
        self.document = document
        self.data = data
        self.run_dir = Path(run_dir) if run_dir is not None else None

    # -- construction -----------------------------------------------------------------
    @classmethod
    def from_outcome(cls, outcome: "RunOutcome") -> "Result":
        return cls(outcome.result, outcome.fit_data(), outcome.run_dir)

    @classmethod
    def load(cls, run_dir: str | Path) -> "Result":
        """A finished run folder's result; the figures' arrays are rebuilt from its config and
        measurement (one simulation at the estimate) when that is possible, else plots raise."""
        from mbus_framework.api.reload import fit_data_from_run

        run_dir = Path(run_dir)
        path = run_dir / "result.json"
        if not path.is_file():
            from mbus_framework.errors import DataError

            raise DataError(f"{run_dir}: no result.json (not a finished run folder)")
        document = json.loads(path.read_text(encoding="utf-8"))
        return cls(document, fit_data_from_run(run_dir, document), run_dir)

    # -- estimates --------------------------------------------------------------------
    @property
    def title(self) -> str:
        return self.document.get("title") or str(self.document.get("config") or "")

    @property
    def model(self) -> str:
        return self.document["model"]["name"]

    @property
    def parameters(self) -> dict[str, Estimate]:
        """Model (and nuisance) parameters, in the model's order."""
        d = self.document
        unc = d.get("uncertainty", {})
        se, ci, truth = unc.get("standard_errors", {}), unc.get("ci95", {}), d.get("truth", {})
        return {
            n: Estimate(n, float(v), d.get("parameter_units", {}).get(n, ""), _opt(se.get(n)),
                        _pair(ci.get(n)), _opt(truth.get(n)), n in d.get("fixed", {}))
            for n, v in d["parameters"].items()
        }

    @property
    def properties(self) -> dict[str, Estimate]:
        """Material properties (moduli [Pa], viscosities [Pa s]) with 95 % intervals."""
        d = self.document
        unc = d.get("uncertainty", {})
        se, ci = unc.get("property_standard_errors", {}), unc.get("property_ci95", {})
        truth = d.get("truth_properties", {})
        return {
            n: Estimate(n, float(v), d.get("property_units", {}).get(n, ""), _opt(se.get(n)),
                        _pair(ci.get(n)), _opt(truth.get(n)), n in d.get("fixed_properties", ()))
            for n, v in d["properties"].items()
        }

    @property
    def warnings(self) -> list[str]:
        """Plain-language warnings (identifiability, fit, data); empty when all is well."""
        return list(self.document.get("warnings", []))

    @property
    def fit_quality(self) -> dict[str, float]:
        """``nrmse`` (RMS residual / RMS output), ``mse``, ``residual_autocorrelation``
        (mean |r|, lags 1-10), ``n_samples``, ``dt_s``."""
        return dict(self.document["fit"])

    @property
    def success(self) -> bool:
        """True when the solver converged (read the warnings too)."""
        return bool(self.document["solver"]["success"])

    # -- text, tables, notebook -------------------------------------------------------
    def summary(self) -> str:
        """The text ``mbus-run`` prints."""
        return summary_text(self.document, self.run_dir)

    def __repr__(self) -> str:
        props = ", ".join(f"{e.name}={e.value:.4g} {e.unit}".rstrip() for e in self.properties.values())
        n = len(self.warnings)
        return (f"<Result {self.model}: {props}; nrmse {self.fit_quality['nrmse']:.3g}; "
                f"{n} warning{'s' * (n != 1)}>")

    def _repr_html_(self) -> str:
        head = html.Html(f"<h3>mbus: {html.escape(self.title)}</h3>") if self.title else html.Html("")
        style = html.Html(
            "<style>.mbus .warnings{border-left:4px solid #d4a72c;background:#fff8c5;padding:.3rem .8rem}"
            ".mbus .warnings.ok{border-color:#2da44e;background:#dafbe1}.mbus td.num{text-align:right}</style>")
        return html.fragment(style, head, html.warnings(self.warnings), *estimate_tables(self.document))

    def to_dataframe(self, layout: Literal["long", "wide"] = "long") -> "pd.DataFrame":
        """The estimates as a pandas table.

        ``long`` (default): one row per quantity, indexed by name, with columns ``kind``
        (parameter or property), ``estimate``, ``unit``, ``std_error``, ``rel_std_error``,
        ``ci95_low``, ``ci95_high``, ``truth``, ``fixed``. ``wide``: one row in the campaign
        table's columns (``k_sigma``, ``k_sigma_se``, ``E_sigma_ci_low``, ..., ``nrmse``,
        ``success``, ``warnings``), so results concatenate into a table the analyses read.
        """
        import pandas as pd

        if layout == "wide":
            return pd.DataFrame([self._wide_row()])
        if layout != "long":
            raise ValueError(f"layout must be 'long' or 'wide', not {layout!r}")
        rows = []
        for kind, estimates in (("parameter", self.parameters), ("property", self.properties)):
            for e in estimates.values():
                rows.append({"name": e.name, "kind": kind, "estimate": e.value, "unit": e.unit,
                             "std_error": _nan(e.std_error), "rel_std_error": _nan(e.relative_std_error),
                             "ci95_low": e.ci95[0] if e.ci95 else np.nan, "ci95_high": e.ci95[1] if e.ci95 else np.nan,
                             "truth": _nan(e.truth), "fixed": e.fixed})
        return pd.DataFrame(rows).set_index("name")

    def _wide_row(self) -> dict[str, Any]:
        row: dict[str, Any] = {}
        for e in self.parameters.values():
            row[e.name] = e.value
            row[f"{e.name}_se"] = _nan(e.std_error)
        for e in self.properties.values():
            row[e.name] = e.value
            row[f"{e.name}_se"] = _nan(e.std_error)
            row[f"{e.name}_ci_low"] = e.ci95[0] if e.ci95 else np.nan
            row[f"{e.name}_ci_high"] = e.ci95[1] if e.ci95 else np.nan
        row.update(nrmse=self.fit_quality["nrmse"], success=self.success, warnings="; ".join(self.warnings))
        for group in (self.parameters, self.properties):
            for e in group.values():
                if e.truth is not None:
                    row[f"true_{e.name}"] = e.truth
        return row

    # -- figures and the report -------------------------------------------------------
    def _data(self) -> "FitData":
        if self.data is None:
            raise ValueError("this result has no fitted arrays to plot (the run folder's measurement or config "
                             "could not be read again)")
        return self.data

    def _plot(self, name: str, fig: "Figure | None") -> "Figure":
        _show_figures_in_notebooks()
        return _figures.FIGURES[name][0](self._data(), fig)

    def plot_fit(self, fig: "Figure | None" = None) -> "Figure":
        """Measured vs predicted output and the residual (Fig. 3.9)."""
        return self._plot("fit", fig)

    def plot_residual_correlation(self, fig: "Figure | None" = None) -> "Figure":
        """Residual autocorrelation and input-residual cross-correlation with their 99 % band
        (MATLAB ``resid``)."""
        return self._plot("correlation", fig)

    def plot_frequency_response(self, fig: "Figure | None" = None) -> "Figure":
        """Measured vs model frequency response (H1 estimates)."""
        return self._plot("frequency_response", fig)

    def plot_excitation(self, fig: "Figure | None" = None) -> "Figure":
        """Power spectrum of the fitted input (and of the designed excitation)."""
        return self._plot("excitation", fig)

    def plot_convergence(self, fig: "Figure | None" = None) -> "Figure":
        """Parameters and cost per iteration of the winning start (Fig. 3.8)."""
        return self._plot("convergence", fig)

    def report_html(self, plots: bool = True, figures: str = "svg") -> str:
        """The self-contained report page (what ``report.html`` holds): ``figures`` ``svg``
        (inline, no matplotlib) or ``png`` (matplotlib, data URIs)."""
        if figures not in ("svg", "png"):
            raise ValueError(f"figures: expected 'svg' or 'png', got {figures!r}")
        pngs = None if not plots else (_figures.render_svg(self._data()) if figures == "svg"
                                       else _figures.render_all(self._data()))
        config = self.run_dir / "config.yaml" if self.run_dir else None
        text = config.read_text(encoding="utf-8") if config is not None and config.is_file() else None
        return report_html(self.document, pngs, text)


def _opt(value: Any) -> float | None:
    return None if value is None or value == "" else float(value)


def _pair(values: Any) -> tuple[float, float] | None:
    return None if values is None else (float(values[0]), float(values[1]))


def _nan(value: float | None) -> float:
    return np.nan if value is None else float(value)


def _show_figures_in_notebooks() -> None:
    """In IPython, display returned matplotlib figures as PNG even without pyplot."""
    ipython = sys.modules.get("IPython")
    shell = ipython.get_ipython() if ipython is not None and hasattr(ipython, "get_ipython") else None
    if shell is None:
        return
    from matplotlib.figure import Figure

    formatter = shell.display_formatter.formatters["image/png"]
    formatter.for_type(Figure, lambda fig: html.png_bytes(fig))
