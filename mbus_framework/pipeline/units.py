"""Units of the fitted record and what they mean for the results.

The model maps an input force u [N] to an output force y [N]. A record whose channels are in
volts (a scope's ``Vertical Units: V``, a units row ``s,V,V``, a config ``backend.options.units``)
without a gain [N/V] is fitted as if 1 V were 1 N on both channels: the fit sees
y_V / u_V = (s_u / s_y) H with s the channels' sensitivities [N/V], so the properties are in Pa
only when s_u = s_y. Such results get one warning and property units marked ``(V/V)``. An
estimated input gain absorbs s_u / s_y; it is reported in output units per input unit.
"""
from __future__ import annotations

from typing import Any, Mapping

VOLT_UNITS = {"v", "mv", "uv", "µv", "kv", "volt", "volts"}


def is_volts(unit: str | None) -> bool:
    return unit is not None and unit.strip().lower() in VOLT_UNITS


def record_units(meta: Mapping[str, Any]) -> dict[str, str]:
    """{"u": unit, "y": unit} the backend found (empty when the record does not say)."""
    units = meta.get("units") or {}
    return {c: str(units[c]) for c in ("u", "y") if isinstance(units, Mapping) and units.get(c)}


def gain_unit(units: Mapping[str, str]) -> str:
    """Unit of the nuisance input gain: output units per input unit (N/unit when unknown)."""
    if "u" not in units:
        return "N/unit"
    return f"{units.get('y', 'N')}/{units['u']}"


def apply_units(result: dict[str, Any], meta: Mapping[str, Any], gain_estimated: bool, gain_name: str) -> None:
    """Label the gain in its real unit; warn and mark property units when volts meet no gain."""
    units = record_units(meta)
    if not units:
        return
    result["record_units"] = units
    if gain_name in result.get("parameter_units", {}):
        result["parameter_units"][gain_name] = gain_unit(units)
    volts = [c for c in ("u", "y") if is_volts(units.get(c))]
    if not volts or gain_estimated:
        return
    where = meta.get("units_source") or "the record"
    said = ", ".join(f"{c} in {units[c]}" for c in volts)
    result["property_units"] = {n: f"{u} (V/V)" for n, u in result.get("property_units", {}).items()}
    result.setdefault("warnings", []).insert(0, (
        f"units: {where} gives {said} and no gain converts it to newtons: the properties, marked (V/V), hold only "
        f"if 1 V means the same force on both channels; give the gains [N/V] (scope files: "
        f"backend.options.processing.u_gain and y_gain), or set nuisance.input_gain.estimate: true"))
