"""``import mbus``: the Python API of mbus under the distribution's own name.

The same objects as :mod:`mbus_framework` (the core package) re-exports, imported on first
use so that ``import mbus`` stays cheap::

    >>> import mbus
    >>> result = mbus.fit(t, u, y, sample={"length": 0.03, "diameter": 0.0254, "density": 1080.0})  # doctest: +SKIP

Plugin authors import :mod:`mbus_framework.plugins`.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

from mbus_framework import __all__, __version__  # noqa: F401

if TYPE_CHECKING:  # pragma: no cover
    from mbus_framework.api import Estimate, Record, Result, fit, load_record, run_config  # noqa: F401


def __getattr__(name: str) -> Any:
    """Lazy re-export of the API names (PEP 562)."""
    if name in __all__:
        import mbus_framework

        return getattr(mbus_framework, name)
    raise AttributeError(f"module 'mbus' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
