"""The joint problem: records stacked, residuals weighted by each record's noise level.

The joint vector phi holds the shared properties P_s, then per record r its own properties
P_r and its free nuisance parameters (input gain g_r [N/unit], delay tau_r [s]). Record r's
model parameters are theta_r = from_properties_r(P_s, P_r) with its own geometry, and

    w_r(phi) = (y_r - yhat_r(theta_r, g_r, tau_r)) / sigma_r,      cost = 1/2 sum_r ||w_r||^2.

The Jacobian is assembled from the per-record exact sensitivities J_r = d yhat_r / d theta_r
(forward-sensitivity system) in blocks,

    d yhat_r / d P_s = J_r^model T_r[:, s],   d yhat_r / d P_r = J_r^model T_r[:, r],
    d yhat_r / d (g_r, tau_r) = J_r^nuisance,  zero for every other record's own parameters,

with T_r = d theta_r / d P. For the chain models theta is linear in P (theta_i = P_i / c_i, c_i
a geometry factor), so T_r from central differences is exact to round-off.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mbus_framework.estimation.nuisance import DELAY
from mbus_framework.estimation.problem import FitProblem
from mbus_framework.joint.spec import JointSpec


@dataclass(frozen=True)
class Slot:
    """One entry of phi: its label, what it is, which record owns it (None: shared)."""

    label: str
    name: str
    record: int | None
    unit: str
    log_scale: bool


class JointProblem:
    """Records (each a :class:`FitProblem` with its own model, geometry and nuisance settings)
    fitted with one shared property vector; ``sigmas`` are the records' noise levels [output units]."""

    def __init__(self, problems: list[FitProblem], spec: JointSpec, sigmas: list[float], labels: list[str]):
        if not problems:
            raise ValueError("a joint problem needs at least one record")
        self.problems, self.spec, self.labels = problems, spec, list(labels)
        self.sigmas = np.asarray(sigmas, dtype=float)
        model = problems[0].model
        self.property_names = list(model.property_names)
        units = {p.name: p.unit for p in model.properties}
        slots = [Slot(n, n, None, units[n], True) for n in spec.shared]
        self.nuisance_free: list[list[str]] = []
        for r, (p, label) in enumerate(zip(problems, self.labels)):
            slots += [Slot(f"{n}[{label}]", n, r, units[n], True) for n in spec.per_record]
            free = [q for q, f in zip(p.parameters[p.n_model:], p.free[p.n_model:]) if f]
            self.nuisance_free.append([q.name for q in free])
            slots += [Slot(f"{q.name}[{label}]", q.name, r, q.unit, q.name != DELAY) for q in free]
        self.slots = slots
        self.n_shared = len(spec.shared)

    # -- the parameter map -------------------------------------------------------------------
    @property
    def names(self) -> list[str]:
        return [s.label for s in self.slots]

    @property
    def n_samples(self) -> int:
        return int(sum(p.y.size for p in self.problems))

    def indices(self, r: int) -> tuple[list[int], list[int], list[int]]:
        """Positions in phi of record r's properties (in the model's property order), of its
        per-record properties only, and of its free nuisance parameters."""
        own = {s.name: i for i, s in enumerate(self.slots) if s.record == r}
        shared = {s.name: i for i, s in enumerate(self.slots) if s.record is None}
        props = [shared[n] if n in shared else own[n] for n in self.property_names]
        return props, [own[n] for n in self.spec.per_record], [own[n] for n in self.nuisance_free[r]]

    def properties(self, phi: np.ndarray, r: int) -> dict[str, float]:
        props, _, _ = self.indices(r)
        return {n: float(phi[i]) for n, i in zip(self.property_names, props)}

    def theta(self, phi: np.ndarray, r: int) -> np.ndarray:
        """Record r's full parameter vector (model parameters, then nuisance as its problem orders them)."""
        p = self.problems[r]
        model_theta = np.asarray(p.model.from_properties(self.properties(phi, r)), dtype=float)
        theta = np.zeros(len(p.names))
        theta[: p.n_model] = model_theta
        _, _, nuis = self.indices(r)
        values = dict(zip(self.nuisance_free[r], (phi[i] for i in nuis)))
        for k, name in enumerate(p.names[p.n_model:], start=p.n_model):
            theta[k] = values[name] if name in values else p.fixed[name]
        return theta

    def phi_from(self, shared: dict[str, float], per_record: list[dict[str, float]]) -> np.ndarray:
        """phi from shared values and, per record, its own properties and nuisance values."""
        return np.array([shared[s.name] if s.record is None else per_record[s.record][s.name] for s in self.slots])

    def dtheta_dproperties(self, phi: np.ndarray, r: int) -> np.ndarray:
        """T_r = d theta_model / d P (n_model x n_properties), central differences (exact for linear maps)."""
        model = self.problems[r].model
        base = self.properties(phi, r)
        T = np.zeros((self.problems[r].n_model, len(self.property_names)))
        for j, name in enumerate(self.property_names):
            h = 1e-6 * abs(base[name]) or 1e-12
            up, dn = dict(base), dict(base)
            up[name] += h
            dn[name] -= h
            T[:, j] = (np.asarray(model.from_properties(up), float) - np.asarray(model.from_properties(dn), float)) / (2 * h)
        return T

    # -- residuals and Jacobian ----------------------------------------------------------------
    def weighted_residuals(self, phi: np.ndarray) -> list[np.ndarray]:
        """w_r = (y_r - yhat_r) / sigma_r per record."""
        return [(p.y - p.predict(self.theta(phi, r))) / s for r, (p, s) in enumerate(zip(self.problems, self.sigmas))]

    def residuals_and_jacobian(self, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Stacked w(phi) and the exact d yhat_w / d phi (sum N_r x len(phi)) in blocks."""
        rows, blocks = [], []
        for r, (p, s) in enumerate(zip(self.problems, self.sigmas)):
            theta = self.theta(phi, r)
            yhat, J = p.predict_with_jacobian(theta)
            block = np.zeros((p.y.size, len(self.slots)))
            props, _, nuis = self.indices(r)
            dprops = J[:, : p.n_model] @ self.dtheta_dproperties(phi, r)
            for j, i in enumerate(props):
                block[:, i] += dprops[:, j]
            names = p.names
            for name, i in zip(self.nuisance_free[r], nuis):
                block[:, i] = J[:, names.index(name)]
            rows.append((p.y - yhat) / s)
            blocks.append(block / s)
        return np.concatenate(rows), np.vstack(blocks)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounds of phi: properties and gains positive, delays within their problem's bounds."""
        lo, hi = np.zeros(len(self.slots)), np.full(len(self.slots), np.inf)
        for i, s in enumerate(self.slots):
            if s.record is not None and s.name == DELAY:
                p = self.problems[s.record]
                k = p.names.index(DELAY)
                lo[i], hi[i] = p.lower[k], p.upper[k]
        return lo, hi
