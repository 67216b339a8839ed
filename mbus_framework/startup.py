"""Start-up of ``mbus-run``: numpy's submodules that no run uses are loaded only if something uses them.

scipy (1.15 and later) builds its array-API namespace with ``from numpy import *``, which imports
every numpy submodule named in ``numpy.__all__``: ``numpy.f2py`` (and with it charset_normalizer),
``numpy.testing`` (and unittest), ``numpy.polynomial``, ``numpy.ctypeslib``, ``numpy.rec``,
``numpy.char`` and ``numpy.strings`` among them, about 0.1 s of CPU at every start-up for modules
a run does not use. :func:`defer_unused_numpy` registers them as lazy modules
(:class:`importlib.util.LazyLoader`): the names exist, and a module runs on its first attribute
access, so code that does use one gets the real module. (``numpy.ma``, ``numpy.random``,
``numpy.fft``, ``numpy.linalg`` and ``numpy.typing`` are used: ``np.median`` asks ``numpy.ma``.)
"""
from __future__ import annotations

import sys

#: numpy submodules that ``from numpy import *`` loads and a run does not use.
UNUSED_NUMPY = ("numpy.f2py", "numpy.testing", "numpy.polynomial", "numpy.ctypeslib", "numpy.rec", "numpy.char",
                "numpy.strings")


def defer_unused_numpy(names: tuple[str, ...] = UNUSED_NUMPY) -> list[str]:
    """Make the numpy submodules ``names`` lazy (imports numpy); returns those made lazy (not the
    ones already loaded or not found)."""
    return [name for name in names if _defer(name)]


def _defer(name: str) -> bool:
    if name in sys.modules:
        return False
    try:
        import importlib.util

        import numpy

        spec = importlib.util.find_spec(name)
        if spec is None or spec.loader is None:
            return False
        spec.loader = importlib.util.LazyLoader(spec.loader)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
        # what ``import numpy.<name>`` would bind (numpy's __getattr__ is not asked)
        setattr(numpy, name.rpartition(".")[2], module)
        return True
    except Exception:  # noqa: BLE001 - an optimisation only: never stop a run
        sys.modules.pop(name, None)
        return False
