"""Start-up of ``mbus-run``: numpy's Fortran wrapper generator loaded only if something uses it.

scipy (1.15 and later) builds its array-API namespace with ``from numpy import *``, which imports
every numpy submodule named in ``numpy.__all__``, ``numpy.f2py`` (and with it charset_normalizer)
among them: about 0.1 s of CPU at every start-up for a module no run uses. :func:`defer_f2py`
registers ``numpy.f2py`` as a lazy module (:class:`importlib.util.LazyLoader`): the name exists,
and the module runs on its first attribute access, so code that does use f2py gets the real
module.
"""
from __future__ import annotations

import sys


def defer_f2py() -> bool:
    """Make ``numpy.f2py`` lazy (imports numpy); False when it is already loaded or cannot be."""
    if "numpy.f2py" in sys.modules:
        return False
    try:
        import importlib.util

        import numpy

        spec = importlib.util.find_spec("numpy.f2py")
        if spec is None or spec.loader is None:
            return False
        spec.loader = importlib.util.LazyLoader(spec.loader)
        module = importlib.util.module_from_spec(spec)
        sys.modules["numpy.f2py"] = module
        spec.loader.exec_module(module)
        numpy.f2py = module  # what ``import numpy.f2py`` would bind (numpy's __getattr__ is not asked)
        return True
    except Exception:  # noqa: BLE001 - an optimisation only: never stop a run
        sys.modules.pop("numpy.f2py", None)
        return False
