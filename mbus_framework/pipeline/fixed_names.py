"""``model.fixed`` by parameter or property name.

A property name P (e.g. ``eta_tau``) is resolved to the one parameter it moves: from a template
theta (the typical values, and a second template 1.7 times them), set P to the given value,
map back with ``from_properties`` and find the parameters that changed. Exactly one must change,
to the same value from both templates (eta_tau = b_tau L / A moves b_tau only); otherwise the
property depends on several parameters and the user is asked to fix parameters instead.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from mbus_framework.errors import ConfigError
from mbus_framework.interfaces.model import MediumModel
from mbus_framework.suggest import did_you_mean


def resolve_fixed(model: MediumModel, mapping: Mapping[str, float], where: str, source: str) -> dict[str, float]:
    """``mapping`` with property names replaced by the parameter each moves (value converted)."""
    out: dict[str, float] = {}
    for name, value in mapping.items():
        if name in model.parameter_names:
            key, val = name, float(value)
        elif name in model.property_names:
            key, val = _parameter_of_property(model, name, float(value), f"{source}: {where}.{name}")
        else:
            hint = did_you_mean(name, model.parameter_names + model.property_names)
            raise ConfigError(
                f"{source}: {where}.{name}: not a parameter or property of this model{hint}; "
                f"parameters: {', '.join(model.parameter_names)}; properties: {', '.join(model.property_names)}"
            )
        if key in out and not np.isclose(out[key], val, rtol=1e-9):
            raise ConfigError(f"{source}: {where}.{name}: fixes {key} a second time, to another value")
        out[key] = val
    return out


def _parameter_of_property(model: MediumModel, prop: str, value: float, where: str) -> tuple[str, float]:
    base = np.array([p.typical for p in model.parameters], dtype=float)
    picks = []
    for theta in (base, 1.7 * base):
        props = dict(model.to_properties(theta))
        probe = dict(props, **{prop: 1.5 * props[prop] if props[prop] else 1.0})
        try:
            moved = np.asarray(model.from_properties(probe), dtype=float)
            fixed = np.asarray(model.from_properties(dict(props, **{prop: value})), dtype=float)
        except Exception:  # noqa: BLE001 - a model that cannot invert this mapping: no single parameter
            picks.append(None)
            continue
        changed = np.flatnonzero(~np.isclose(moved, theta, rtol=1e-9, atol=0.0))
        picks.append((int(changed[0]), float(fixed[changed[0]])) if changed.size == 1 else None)
    a, b = picks
    if a is None or b is None or a[0] != b[0] or not np.isclose(a[1], b[1], rtol=1e-9):
        raise ConfigError(f"{where}: this property depends on several parameters of the model; fix parameters "
                          f"instead ({', '.join(model.parameter_names)})")
    return model.parameter_names[a[0]], a[1]
