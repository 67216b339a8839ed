"""The solver contract suite (mbus_framework.testing.solvers) over every registered solver.

The global strategies are cut to one start to keep the suite fast; the checks themselves are
those a third-party solver author runs."""
from __future__ import annotations

from mbus_framework.testing.solvers import contract_classes

ONE_START = {"strategy": {"n_starts": 1}}

globals().update(contract_classes({"scipy_lm": ONE_START, "casadi_collocation": ONE_START,
                                   "frequency_domain": ONE_START}))
