"""mbus: model-based ultrasound (MBUS) evaluation of viscoelastic materials.

The core defines the interfaces (medium models, excitations, solvers, compensators,
instrument backends), the plugin system, configuration, the exact simulator, the global
estimation strategy and the run pipeline; implementations live in plugins.

The Python API (:mod:`mbus_framework.api`) is available from the package itself and is
imported on first use, so plugins importing the interfaces do not load the pipeline:

    >>> import mbus_framework as mbus
    >>> sorted(mbus.__all__)
    ['Estimate', 'Record', 'Result', 'fit', 'load_record', 'run_config']
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"
__all__ = ["Estimate", "Record", "Result", "fit", "load_record", "run_config"]

if TYPE_CHECKING:  # pragma: no cover
    from mbus_framework.api import Estimate, Record, Result, fit, load_record, run_config  # noqa: F401


def __getattr__(name: str) -> Any:
    """Lazy re-export of the API names (PEP 562)."""
    if name in __all__:
        from mbus_framework import api

        return getattr(api, name)
    raise AttributeError(f"module 'mbus_framework' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
