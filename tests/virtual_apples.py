"""Test helpers: the virtual apples generator (configs/campaigns/make_apples.py) and small
campaign-format tables made from apple-like truths through the Kelvin-Voigt model plugin."""
from __future__ import annotations

import importlib.util
from functools import lru_cache
from pathlib import Path

import numpy as np
import pandas as pd

REPO = Path(__file__).resolve().parents[1]
CAMPAIGNS = REPO / "configs" / "campaigns"
APPLE_SLICE = REPO / "configs" / "apple_slice.yaml"
PARAMETER_OF = {"E_sigma": "k_sigma", "eta_sigma": "b_sigma", "E_tau": "k_tau", "eta_tau": "b_tau"}


@lru_cache(maxsize=1)
def generator():
    """The generator script, imported as a module."""
    spec = importlib.util.spec_from_file_location("make_apples", CAMPAIGNS / "make_apples.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@lru_cache(maxsize=1)
def apple_model():
    from mbus_framework.pipeline.components import build_components
    from mbus_framework.pipeline.config import load_config

    return build_components(load_config(APPLE_SLICE), str(APPLE_SLICE)).model


def physics_table(n: int = 20, seed: int = 0, relative_se: float = 0.01) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(campaign table, panel): n apple-like samples drawn from the generator's cultivar
    distributions, Kelvin-Voigt parameters from the model plugin, independent relative
    estimation noise, and panel scores from the generator's relation and panel noise."""
    gen = generator()
    apples = gen.draw_apples(seed).iloc[:n].reset_index(drop=True)
    model = apple_model()
    rng = np.random.default_rng(seed + 100)
    rows = []
    for _, a in apples.iterrows():
        theta = model.from_properties({p: a[p] for p in gen.PROPERTIES})
        theta = theta * (1 + relative_se * rng.normal(size=theta.size))
        rows.append({"sample_id": a.sample_id, "cultivar": a.cultivar, **dict(zip(model.parameter_names, theta)),
                     **model.to_properties(theta), "success": True})
    panel = gen.simulate_panel(apples.sample_id, gen.RELATION(apples), gen.PANEL, seed=seed + 1)
    return pd.DataFrame(rows), panel


def cramer_rao_relative(truth: dict, noise: float = 0.05 / 3**0.5) -> dict[str, float]:
    """Cramer-Rao relative standard errors of the Kelvin-Voigt parameters of a 6 mm slice
    (apple_slice.yaml) with the given true properties and relative output noise."""
    import tempfile

    from mbus_framework.interfaces.backend import AcquisitionContext
    from mbus_framework.pipeline.components import build_components
    from mbus_framework.pipeline.config import apply_overrides, read_yaml, validate_structure
    from mbus_framework.pipeline.results import cramer_rao
    from mbus_framework.pipeline.run import make_problem

    sets = [f"backend.options.truth.{k}={v}" for k, v in truth.items()] + [f"backend.options.noise.relative_std={noise}"]
    c = build_components(validate_structure(apply_overrides(read_yaml(APPLE_SLICE), sets), "apple"), "apple")
    with tempfile.TemporaryDirectory() as tmp:
        m = c.backend.acquire(AcquisitionContext(c.excitation.waveform(), c.sample, c.model, c.registry, Path(tmp), "apple"))
    theta = c.model.theta_from_mapping(truth, "truth")
    se = cramer_rao(make_problem(c, m), theta, m.meta["noise_std"])
    return {name: se[name] / value for name, value in zip(c.model.parameter_names, theta)}
