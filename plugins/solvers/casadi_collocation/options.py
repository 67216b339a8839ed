"""Options of the ``casadi_collocation`` solver and IPOPT's return codes in scipy's status vocabulary."""
from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from mbus_framework.estimation.strategy import StrategyOptions

LOG_RANGE = 23.0  # a log-parameter moves at most e^23 ~ 1e10 from the start of a local solve
IPOPT_STATUS = {
    "Solve_Succeeded": 1,
    "Solved_To_Acceptable_Level": 2,
    "Search_Direction_Becomes_Too_Small": 3,
    "Maximum_Iterations_Exceeded": 0,
    "Maximum_CpuTime_Exceeded": 0,
    "Maximum_WallTime_Exceeded": 0,
}


class CasadiCollocationOptions(BaseModel):
    """Options of ``casadi_collocation`` (the ``solver.options`` config section)."""

    model_config = ConfigDict(extra="forbid")
    scheme: Literal["legendre", "radau", "trapezoidal"] = Field(
        "legendre", description="collocation points: Gauss-Legendre, Radau IIA, or the trapezoidal rule"
    )
    degree: int = Field(3, ge=1, le=9, description="collocation points per sample interval (trapezoidal: 1)")
    formulation: Literal["condensed", "full"] = Field(
        "condensed",
        description="condensed: collocation and intra-node states eliminated exactly (linear model); "
        "full: every sample and collocation-point state is an NLP variable",
    )
    samples_per_node: int | Literal["auto"] = Field(
        "auto", description="condensed: samples between NLP state nodes (no effect on the optimum)"
    )
    node_phase: float = Field(2.0, gt=0, description="auto: radians the fastest mode turns per node")
    coordinates: Literal["linear", "log"] = Field(
        "linear", description="NLP coordinates of log-scale parameters: theta/theta_start or ln(theta/theta_start)"
    )
    hessian: Literal["gauss-newton", "exact", "limited-memory"] = Field(
        "gauss-newton", description="Hessian of the Lagrangian given to IPOPT"
    )
    tol: float = Field(1e-10, gt=0, description="IPOPT tol (scaled NLP)")
    xtol: float = Field(1e-10, gt=0, description="final solve also stops at this relative parameter step")
    ftol: float = Field(1e-12, gt=0, description="final solve also stops at this relative cost change")
    stage_xtol: float = Field(1e-5, gt=0, description="search stages stop at this relative parameter step")
    stage_ftol: float = Field(1e-8, gt=0, description="search stages stop at this relative cost change")
    max_iter: int = Field(300, ge=1, description="IPOPT iteration limit of the final solve")
    global_search: bool = Field(True, description="run the local solves inside the global strategy")
    strategy: StrategyOptions = Field(default_factory=StrategyOptions)
    search_samples: int | None = Field(
        None, ge=16, description="run the global search on the first n samples only (final solve: whole record)"
    )
    print_level: int | None = Field(
        None, ge=0, le=12, description="IPOPT print_level; default 5 on an interactive terminal, else 0"
    )
    ipopt: dict[str, float | int | str] = Field(
        default_factory=dict, description="further IPOPT options, e.g. {mu_strategy: adaptive}"
    )

    @field_validator("samples_per_node")
    @classmethod
    def _positive(cls, v):
        if v != "auto" and v < 1:
            raise ValueError("samples_per_node must be 'auto' or >= 1")
        return v
