"""A virtual sensory panel: scores from a known nonlinear relation of material properties,
plus assessor effects and noise. For demonstrations (the virtual apples campaign,
``configs/campaigns/make_apples.py``) and for tests that need a truth to check against.

Relation (a logistic response to log-stimuli, bounded by the score line):

    s = low + (high - low) / (1 + exp(-z)),   z = z_0 + sum_j b_j ln(x_j / x_ref_j)

Assessor a scores sample i as

    score_ai = clip(m + g_a (s_i - m) + o_a + e_ai, low, high),   m = (low + high) / 2,

with an offset o_a ~ N(0, offset_sd^2), a gain g_a ~ N(1, gain_sd^2) (how widely the assessor
uses the line) and e_ai ~ N(0, noise_sd^2), read to ``resolution`` (0.1 on a 0-9 line).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np


@dataclass(frozen=True)
class LogisticRelation:
    """s = low + (high - low) sigmoid(z_0 + sum_j b_j ln(x_j / x_ref_j)).

    ``coefficients`` b_j and ``reference`` x_ref_j are keyed by column name (e.g. E_sigma).
    """

    coefficients: Mapping[str, float]
    reference: Mapping[str, float]
    intercept: float = 0.0
    low: float = 0.0
    high: float = 9.0

    def __post_init__(self):
        missing = set(self.coefficients) - set(self.reference)
        if missing:
            raise ValueError(f"no reference value for {', '.join(sorted(missing))}")

    @property
    def inputs(self) -> list[str]:
        return list(self.coefficients)

    def linear_predictor(self, values: Mapping[str, Sequence[float]]) -> np.ndarray:
        z = self.intercept
        for name, b in self.coefficients.items():
            x = np.asarray(values[name], dtype=float)
            if np.any(x <= 0):
                raise ValueError(f"{name} must be positive for a log stimulus")
            z = z + b * np.log(x / self.reference[name])
        return np.asarray(z, dtype=float)

    def __call__(self, values: Mapping[str, Sequence[float]]) -> np.ndarray:
        z = self.linear_predictor(values)
        return self.low + (self.high - self.low) / (1.0 + np.exp(-z))

    def sensitivities(self, values: Mapping[str, Sequence[float]], relative_change: float = 0.1) -> dict[str, tuple[float, float]]:
        """Eq. 7.2 on the true relation: mean and SD over the samples of |s(x_j (1 + c)) - s(x)|."""
        base = self(values)
        out = {}
        for name in self.coefficients:
            moved = {k: np.asarray(values[k], dtype=float) for k in self.coefficients}
            moved[name] = moved[name] * (1.0 + relative_change)
            d = np.abs(self(moved) - base)
            out[name] = (float(d.mean()), float(d.std(ddof=1)) if d.size > 1 else 0.0)
        return out

    def effect_order(self, values: Mapping[str, Sequence[float]], relative_change: float = 0.1) -> list[str]:
        """Inputs by decreasing mean |change| for a ``relative_change`` of each."""
        sens = self.sensitivities(values, relative_change)
        return sorted(sens, key=lambda k: -sens[k][0])

    def describe(self) -> str:
        terms = " ".join(f"{b:+g} ln({k}/{self.reference[k]:g})" for k, b in self.coefficients.items())
        return f"s = {self.low:g} + {self.high - self.low:g} / (1 + exp(-z)), z = {self.intercept:+g} {terms}"


@dataclass(frozen=True)
class PanelNoise:
    """How a panel of assessors departs from the true score (see the module docstring)."""

    n_assessors: int = 8
    offset_sd: float = 0.7
    gain_sd: float = 0.12
    noise_sd: float = 1.0
    resolution: float = 0.1
    low: float = 0.0
    high: float = 9.0
    assessor_names: Sequence[str] = field(default=())

    def names(self) -> list[str]:
        if self.assessor_names:
            return list(self.assessor_names)
        return [f"Assessor {a + 1}" for a in range(self.n_assessors)]


def simulate_panel(sample_ids: Sequence[str], true_scores: Sequence[float], noise: PanelNoise = PanelNoise(), seed: int | None = None):
    """Long panel table (sample_id, assessor, score): every assessor scores every sample."""
    import pandas as pd

    rng = np.random.default_rng(seed)
    s = np.asarray(true_scores, dtype=float)
    names = noise.names()
    mid = 0.5 * (noise.low + noise.high)
    offsets = rng.normal(0.0, noise.offset_sd, len(names))
    gains = rng.normal(1.0, noise.gain_sd, len(names))
    rows = []
    for a, name in enumerate(names):
        raw = mid + gains[a] * (s - mid) + offsets[a] + rng.normal(0.0, noise.noise_sd, s.size)
        score = np.clip(raw, noise.low, noise.high)
        if noise.resolution > 0:
            score = np.round(score / noise.resolution) * noise.resolution
        rows += [{"sample_id": sid, "assessor": name, "score": round(float(v), 6)} for sid, v in zip(sample_ids, score)]
    return pd.DataFrame(rows)
