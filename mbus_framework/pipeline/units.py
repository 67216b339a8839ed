"""Units of a record's input u and output y, from what its backend knows (``Measurement.meta``).

Rules, first match wins, for each channel c in (u, y):

1. ``meta["units"][c]``: a unit the data file states (a ``y [V]`` header, a units row);
2. ``meta["record_units"][c]``: the units a run folder's record was saved with (refits);
3. a scope record (``shots_averaged`` in meta): volts, or "N" when the processing scaled the
   channel by a gain other than 1 (``u_gain``/``y_gain`` [N/V]);
4. a simulated record: volts through a transducer pair (``transducers`` in meta), else newtons
   (the medium models map force [N] to force [N]);
5. otherwise :data:`UNKNOWN`.

A compensated output: the forward mode keeps the record's unit (band-limited by the window);
deconvolution divides the transducer pair out, leaving the input's unit (band-limited).

Volts without gains (:func:`apply_units`): the model maps an input force u [N] to an output force
y [N]. A record whose channels are in volts (a scope's ``Vertical Units: V``, a units row
``s,V,V``, a config ``backend.options.units``) without a gain [N/V] is fitted as if 1 V were 1 N
on both channels: the fit sees y_V / u_V = (s_u / s_y) H with s the channels' sensitivities
[N/V], so the properties are in Pa only when s_u = s_y. Such results get one warning and property
units marked ``(V/V)``. An estimated input gain absorbs s_u / s_y; it is reported in output units
per input unit.
"""
from __future__ import annotations

from typing import Any, Mapping

#: Label of a channel whose unit the backend did not state.
UNKNOWN = "recorded units"


def _channel(meta: Mapping[str, Any], c: str) -> str:
    for key in ("units", "record_units"):
        stated = meta.get(key)
        if isinstance(stated, Mapping) and stated.get(c):
            return str(stated[c])
    if "shots_averaged" in meta:
        gain = meta.get(f"{c}_gain", 1.0)
        return "V" if gain in (None, 1, 1.0) else "N"
    if meta.get("source") == "simulated":
        return "V" if meta.get("transducers") else "N"
    return UNKNOWN


def record_units(meta: Mapping[str, Any], compensation: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """``{"u": unit, "y": unit, "y_band_limited": bool}`` of the fitted record: the measured
    units of ``meta``, with the output's changed by ``compensation`` (the compensator's info)."""
    u, y = _channel(meta, "u"), _channel(meta, "y")
    band_limited = bool(compensation) and compensation.get("name", "none") != "none"
    if band_limited and compensation.get("mode") == "deconvolve":
        y = u
    return {"u": u, "y": y, "y_band_limited": band_limited}


def bracket(unit: str) -> str:
    """``"[V]"`` for a unit, ``"(recorded units)"`` when it is not known."""
    return f"({unit})" if UNKNOWN in unit else f"[{unit}]"


_PREFIX = {-12: "p", -9: "n", -6: "u", -3: "m", 0: "", 3: "k", 6: "M", 9: "G", 12: "T"}
_NO_PREFIX = ("", "-", "1", "%", "dB", "deg", "rad", "kg", UNKNOWN)


def scaled_unit(values, unit: str) -> tuple[float, str]:
    """(factor, label unit) that show ``values`` [unit] as values / factor, their median in [1, 1000):
    an SI prefix on the unit (2.4e10 Pa -> 24 GPa), or a power of ten in the label where a
    prefix does not apply (dimensionless, kg...), so an axis never needs matplotlib's offset
    text ("x1e10") beside a label without it."""
    import numpy as np

    v = np.abs(np.asarray(values, dtype=float))
    v = v[np.isfinite(v) & (v > 0)]
    unit = unit or "-"
    if not v.size:
        return 1.0, unit
    e3 = int(np.clip(3 * np.floor(np.log10(np.median(v)) / 3), -12, 12))
    if e3 == 0:
        return 1.0, unit
    if unit.startswith(_NO_PREFIX[1:]) or unit == "-":
        return 10.0**e3, f"1e{e3}" if unit in ("-", "1") else f"1e{e3} {unit}"
    return 10.0**e3, f"{_PREFIX[e3]}{unit}"


def label_axis(ax, axis: str, name: str, values, unit: str) -> float:
    """Label ``ax``'s ``axis`` ("x"/"y") as ``name [scaled unit]`` and turn the offset text off;
    returns the factor to divide the plotted values by."""
    factor, shown = scaled_unit(values, unit)
    getattr(ax, f"set_{axis}label")(f"{name} {bracket(shown)}")
    try:
        ax.ticklabel_format(axis=axis, style="plain", useOffset=False)
    except AttributeError:  # a log axis has no scalar formatter (and no offset text)
        pass
    return factor


VOLT_UNITS = {"v", "mv", "uv", "µv", "kv", "volt", "volts"}


def is_volts(unit: str | None) -> bool:
    return unit is not None and unit.strip().lower() in VOLT_UNITS


def stated_units(meta: Mapping[str, Any]) -> dict[str, str]:
    """{"u": unit, "y": unit} the data file states (empty when the record does not say)."""
    units = meta.get("units") or {}
    return {c: str(units[c]) for c in ("u", "y") if isinstance(units, Mapping) and units.get(c)}


def gain_unit(units: Mapping[str, str]) -> str:
    """Unit of the nuisance input gain: output units per input unit (N/unit when unknown)."""
    if "u" not in units:
        return "N/unit"
    return f"{units.get('y', 'N')}/{units['u']}"


def apply_units(result: dict[str, Any], meta: Mapping[str, Any], gain_estimated: bool, gain_name: str) -> None:
    """Label the gain in its real unit; warn and mark property units when volts meet no gain."""
    units = stated_units(meta)
    if not units:
        return
    result.setdefault("record_units", units)
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
