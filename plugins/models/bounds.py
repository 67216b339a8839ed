"""Bounds shared by the built-in models' options.

A chain of n elements has 2n states; one simulation with its parameter sensitivities costs
O(n^3) (eigen-decomposition) plus O(n N) per record of N samples, and a fit needs hundreds of
them: about 0.01 s per evaluation at n = 10, 0.8 s at n = 40 and 13 s at n = 100 (2000 samples).
The properties settle long before (Figs. 3.10-3.11: n of about 20-40), so more than
:data:`MAX_ELEMENTS` elements is a slip that would run for hours.
"""
from __future__ import annotations

from typing import Annotated

from pydantic import AfterValidator, Field

MAX_ELEMENTS = 100
"""Most elements of a chain (all layers together for ``layered``)."""


def check_elements(value: int, what: str = "elements") -> int:
    if value > MAX_ELEMENTS:
        raise ValueError(f"{value} {what} is more than {MAX_ELEMENTS}: a fit would take hours (each model evaluation "
                         f"costs O(n^3)), and the material properties settle by n of about 20-40 (Figs. 3.10-3.11)")
    return value


Elements = Annotated[int, Field(ge=1), AfterValidator(check_elements)]
"""Number of elements of a chain, 1..MAX_ELEMENTS."""
