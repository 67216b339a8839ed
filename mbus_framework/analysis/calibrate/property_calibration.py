"""A saved calibration: converts new MBUS estimates to the conventional scale.

``mbus-analyze calibrate`` fits, per property, MBUS = a + b * conventional (Table 6.1) and saves
those lines as JSON (``FORMAT``). ``mbus-analyze apply-calibration`` inverts them for new
samples: the calibrated value is ``(MBUS - a) / b`` and its prediction interval is the Fieller
inverse interval of :meth:`LineFit.inverse` (every conventional value whose prediction interval
contains the new MBUS value). New values outside the MBUS range the calibration was made on
are flagged as extrapolations.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mbus_framework.errors import DataError
from mbus_framework.analysis.calibrate.regression import LineFit
from mbus_framework.analysis.rows import failed_mask

FORMAT = "mbus-property-calibration/1"
OUTPUT_PREFIX = "calibrated_"


@dataclass
class PropertyCalibration:
    """Per-property lines MBUS = intercept + slope * conventional, for one MBUS variant."""

    variant: str
    fits: dict[str, LineFit]
    conventional: dict[str, str] = field(default_factory=dict)
    source: str = ""

    def to_dict(self) -> dict:
        return {"format": FORMAT, "variant": self.variant, "source": self.source,
                "model": "MBUS = intercept + slope * conventional (OLS); inverse with Fieller intervals",
                "properties": {p: {"conventional": self.conventional.get(p, ""), **fit.as_dict()}
                               for p, fit in self.fits.items()}}

    def save(self, path: str | Path) -> Path:
        from mbus_framework.analysis.outputs import write_json

        return write_json(path, self.to_dict())

    @classmethod
    def load(cls, path: str | Path) -> "PropertyCalibration":
        p = Path(path)
        if not p.is_file():
            raise DataError(f"{p}: calibration file not found (write one with mbus-analyze calibrate)")
        try:
            data = json.loads(p.read_text())
        except (OSError, ValueError) as exc:
            raise DataError(f"{p}: not a JSON calibration ({str(exc).splitlines()[0][:120]})") from None
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise DataError(f"{p}: not an mbus property calibration (expected format '{FORMAT}')")
        props = data.get("properties")
        if not isinstance(props, dict) or not props:
            raise DataError(f"{p}: 'properties' is missing or empty")
        fits = {name: LineFit.from_dict(entry, f"{p}: properties.{name}") for name, entry in props.items()}
        return cls(variant=str(data.get("variant", "")), fits=fits,
                   conventional={n: str(e.get("conventional", "")) for n, e in props.items()},
                   source=str(data.get("source", "")))

    def apply(self, table, *, replicates: int = 1, source: str = "<table>"):
        """The table with ``calibrated_<p>``, ``_pi_low``, ``_pi_high`` and ``calibration_warnings``.

        Failed rows (non-empty ``error``) get empty values. ``replicates`` is m, the number
        of MBUS measurements averaged into each new value.
        """
        present = [p for p in self.fits if p in table.columns]
        if not present:
            raise DataError(f"{source}: none of the calibrated properties ({', '.join(self.fits)}) is a column")
        out = table.copy()
        failed = failed_mask(out)
        warnings = [[] for _ in range(len(out))]
        for prop in present:
            fit = self.fits[prop]
            y0 = np.where(failed, np.nan, np.asarray(out[prop], dtype=float))
            x0, low, high = fit.inverse(y0, m=replicates)
            out[f"{OUTPUT_PREFIX}{prop}"] = x0
            out[f"{OUTPUT_PREFIX}{prop}_pi_low"] = low
            out[f"{OUTPUT_PREFIX}{prop}_pi_high"] = high
            for i, value in enumerate(y0):
                if math.isfinite(value) and not (fit.y_min <= value <= fit.y_max):
                    warnings[i].append(f"{prop} outside the calibrated MBUS range "
                                       f"[{fit.y_min:.4g}, {fit.y_max:.4g}] (extrapolated)")
        out["calibration_warnings"] = ["; ".join(w) for w in warnings]
        return out, [p for p in self.fits if p not in present]
