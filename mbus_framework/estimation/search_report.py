"""What the estimation strategy tried and what won: :class:`SearchReport` (result.json
``strategy``), the labelled trace of each local solve, and the parameters that ended on the
search region's edge."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mbus_framework.estimation.local import LocalResult


@dataclass
class SearchReport:
    """What the strategy tried and what won (written to result.json ``strategy``)."""

    initial_source: str
    initial: dict[str, float]
    signal_bandwidth_hz: float | None = None
    bands_hz: list[float] = field(default_factory=list)
    starts: list[dict] = field(default_factory=list)
    winner: int | None = None
    accepted: bool = False
    accepted_because: str = ""
    verdict: dict | None = None
    noise: dict | None = None
    scan: dict | None = None
    poles: dict | None = None
    box: dict | None = None
    widened: list[str] = field(default_factory=list)
    wall_time_s: float = 0.0
    cpu_time_s: float = 0.0  # CPU seconds of this process spent in the search (the budget's clock)
    stopped_by_budget: str | None = None

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def at_box_edge(report: dict, theta: dict[str, float], rtol: float = 1e-3) -> list[str]:
    """Names of parameters that ended on the edge of the search region."""
    box = report.get("box") or {}
    out = []
    for name, value in theta.items():
        lo, hi = box.get("lower", {}).get(name), box.get("upper", {}).get(name)
        for edge in (lo, hi):
            if edge not in (None, 0.0) and np.isfinite(edge) and abs(value - edge) <= rtol * abs(edge):
                out.append(name)
                break
    return out


def stage_trace(res: LocalResult, stage: str) -> list[dict]:
    """The Jacobian-evaluation records of one local solve, labelled with their stage.

    Costs of band stages are those of the band-limited residual."""
    return [dict(rec, stage=stage) for rec in res.trace]
