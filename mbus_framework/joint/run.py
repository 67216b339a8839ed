"""Run a joint fit: per-record fits (the global strategy), then the joint fit from them.

:func:`run_records` takes records already built (components and measurement per record, as
the Python API and :mod:`~mbus_framework.joint.config` make them) and returns the result
document (schema in docs/joint.md): ``properties`` (shared, with intervals), ``records`` (per
record: source, own properties and nuisance values, fit statistics, residual verdict, own fit)
and ``agreement`` (likelihood-ratio test).
"""
from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from scipy import special

from mbus_framework import __version__
from mbus_framework.errors import ConfigError
from mbus_framework.estimation.acceptance import estimate_noise, judge
from mbus_framework.estimation.uncertainty import positive_interval
from mbus_framework.interfaces.backend import Measurement
from mbus_framework.interfaces.excitation import Waveform
from mbus_framework.joint.estimate import agreement, fit_joint, noise_level, precision_weighted
from mbus_framework.joint.problem import JointProblem
from mbus_framework.joint.spec import NUISANCE, JointSpec
from mbus_framework.pipeline.components import Components


@dataclass
class RecordInput:
    """One record of a joint fit: its label, built components (geometry, model, nuisance) and data."""

    label: str
    components: Components
    measurement: Measurement
    designed: Waveform | None = None


@dataclass
class JointOutcome:
    document: dict[str, Any]
    problem: JointProblem
    singles: list[Any] = field(default_factory=list)  # the per-record RunOutcomes


def merge_nuisance(config: dict[str, Any], per_record: Sequence[str] | None) -> dict[str, Any]:
    """A record's config mapping with each nuisance parameter declared per record estimated."""
    from mbus_framework.joint.config import merge

    names = [n for n in (per_record or []) if n in NUISANCE]
    return merge(config, {"nuisance": {n: {"estimate": True} for n in names}}) if names else config


def check_records(labels: Sequence[str], components: Sequence[Components], shared: Sequence[str] | None,
                  per_record: Sequence[str] | None, source: str) -> JointSpec:
    """One model (name and options) for all records, no ``model.fixed``, a valid declaration:
    one-line ConfigErrors; returns the declaration."""
    if not components:
        raise ConfigError(f"{source}: a joint fit needs at least one record")
    first = components[0].config.model
    for i, (label, c) in enumerate(zip(labels, components)):
        model = c.config.model
        if model.name != first.name or model.options != first.options:
            raise ConfigError(f"{source}: records[{i}] ({label}): model {model.name} {model.options} differs from "
                              f"records[0]'s {first.name} {first.options}; a joint fit needs one model for all records")
        if model.fixed:
            raise ConfigError(f"{source}: records[{i}] ({label}): model.fixed is not supported in a joint fit; "
                              f"declare the property per_record or fit the records one by one")
    return JointSpec.declare(components[0].model.property_names, shared, per_record, where=f"{source}: joint")


def run_records(records: Sequence[RecordInput], shared: Sequence[str] | None, per_record: Sequence[str] | None,
                source: str, title: str | None = None, progress=None) -> JointOutcome:
    """Fit each record alone, then all jointly; returns the result document and the problem."""
    from mbus_framework.pipeline.run import estimate

    spec = check_records([r.label for r in records], [r.components for r in records], shared, per_record, source)
    singles = [estimate(rec.components, rec.measurement, rec.designed, progress) for rec in records]
    problems = [s.problem for s in singles]
    sigmas = [noise_level(s.fit.cost, s.problem.y.size, int(s.fit.free.sum())) for s in singles]
    labels = [rec.label for rec in records]
    jp = JointProblem(problems, spec, sigmas, labels)
    phi0 = start(jp, singles)
    joint = fit_joint(jp, phi0)
    single_chi2 = [2.0 * s.fit.cost / sig**2 for s, sig in zip(singles, sigmas)]
    test = agreement(joint, single_chi2, jp.n_shared)
    document = build_document(jp, joint, test, singles, records, source, title)
    return JointOutcome(document, jp, singles)


def start(jp: JointProblem, singles) -> np.ndarray:
    """Shared: precision-weighted mean of the per-record estimates; the rest: each record's own fit."""
    shared = {}
    for name in jp.spec.shared:
        values = [s.result["properties"][name] for s in singles]
        se = [s.result.get("uncertainty", {}).get("property_standard_errors", {}).get(name, np.nan) for s in singles]
        shared[name] = precision_weighted(np.array(values), np.array(se, dtype=float))
    per = [{**s.result["properties"], **s.fit.parameters} for s in singles]
    return jp.phi_from(shared, per)


def build_document(jp: JointProblem, joint, test, singles, records, source: str, title: str | None) -> dict[str, Any]:
    unc = joint.uncertainty
    se = dict(zip(jp.names, map(float, unc.standard_errors)))
    q = float(special.ndtri(0.975))  # the noise levels are taken as known: normal quantile
    phi = dict(zip(jp.names, map(float, joint.phi)))
    units = {s.label: s.unit for s in jp.slots}
    shared = {n: phi[n] for n in jp.spec.shared}
    doc: dict[str, Any] = {
        "mbus_version": __version__,
        "kind": "joint",
        "created": _dt.datetime.now().isoformat(timespec="seconds"),
        "config": source,
        "title": title,
        "model": {"name": records[0].components.config.model.name,
                  "options": jp.problems[0].model.options.model_dump(mode="json")},
        "shared": list(jp.spec.shared),
        "per_record": [*jp.spec.per_record, *jp.spec.nuisance],
        "properties": shared,
        "property_units": {n: units[n] for n in shared},
        "uncertainty": {
            "method": "joint linearised: (J_w^T J_w)^-1, residuals weighted by each record's noise level",
            "property_standard_errors": {n: se[n] for n in shared},
            "property_ci95": {n: positive_interval(phi[n], se[n], q) for n in shared},
            "correlation": {"names": jp.names, "matrix": unc.correlation.tolist()},
            "condition": unc.condition,
        },
        "records": [],
        "agreement": test.as_dict(),
        "solver": {"method": "lm (scipy.optimize.least_squares), exact block Jacobian", "success": joint.success,
                   "status": joint.status, "message": joint.message, "nfev": joint.nfev, "njev": joint.njev,
                   "cost": joint.cost, "n_parameters": len(jp.names), "n_samples": jp.n_samples},
        "warnings": [],
    }
    truths = [s.result.get("truth_properties") for s in singles]
    if truths[0] and all(t and all(math.isclose(t[n], truths[0][n], rel_tol=1e-9) for n in shared) for t in truths):
        doc["truth_properties"] = {n: truths[0][n] for n in shared}
    for r, (rec, s, w) in enumerate(zip(records, singles, joint.residuals)):
        p = jp.problems[r]
        _, own, nuis = jp.indices(r)
        theta = jp.theta(joint.phi, r)
        res = w * jp.sigmas[r]
        n_params = jp.n_shared + len(own) + len(nuis)
        verdict = judge(res, p.u, n_params, estimate_noise(p.t, p.u, p.y), white_noise=p.noise_filter is None)
        nuisance = {n: float(theta[k]) for k, n in enumerate(p.names) if k >= p.n_model}
        labels = [jp.names[i] for i in (*own, *nuis)]
        entry = {
            "label": rec.label,
            "source": rec.measurement.meta.get("source") or s.result.get("config") or rec.components.source,
            "sample": rec.components.config.sample.model_dump(),
            "properties": jp.properties(joint.phi, r),
            "per_record": {lab.split("[")[0]: phi[lab] for lab in labels},
            "per_record_standard_errors": {lab.split("[")[0]: se[lab] for lab in labels},
            "nuisance": nuisance,
            "fit": {"n_samples": int(p.y.size), "dt_s": p.dt, "noise_std": float(jp.sigmas[r]),
                    "chi2": float(w @ w), "chi2_own_fit": float(2.0 * s.fit.cost / jp.sigmas[r] ** 2),
                    "nrmse": float(np.sqrt(np.mean(res**2)) / (np.sqrt(np.mean(p.y**2)) or 1.0))},
            "verdict": verdict.as_dict(),
            "own_fit": {"properties": s.result["properties"],
                        "property_standard_errors": s.result.get("uncertainty", {}).get("property_standard_errors", {}),
                        "parameters": s.fit.parameters, "warnings": s.result.get("warnings", [])},
        }
        truth = s.result.get("truth")
        if truth:
            entry["truth_nuisance"] = {n: truth[n] for n in nuisance if n in truth}
        doc["records"].append(entry)
        if not verdict.accepted:
            doc["warnings"].append(f"record {rec.label}: the joint fit does not explain it: {verdict.reason}")
    if not test.agree:
        doc["warnings"].insert(0, (
            f"the records do not agree on the shared properties (likelihood ratio {test.statistic:.4g}, df {test.df}, "
            f"p = {test.p_value:.2g} < {test.level:g}): they do not share one material, or a per-record rig "
            f"parameter is missing; the joint estimate is not a property of one material"))
    if not joint.success:
        doc["warnings"].append(f"the joint fit did not converge: {joint.message}")
    return doc
