"""The model contract suite (mbus_framework.testing.models) over every built-in model."""
from __future__ import annotations

from mbus_framework.interfaces.sample import Sample
from mbus_framework.testing.models import MediumModelContract
from mbus_plugins.models.generalized_maxwell import GeneralizedMaxwellChain, GeneralizedMaxwellOptions
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions
from mbus_plugins.models.layered import LayeredChain, LayeredOptions
from mbus_plugins.models.maxwell import MaxwellChain, MaxwellOptions
from mbus_plugins.models.sls import SlsChain, SlsOptions

SAMPLE = Sample(length=0.02, diameter=0.0254, density=1000.0)


class TestKelvinVoigtContract(MediumModelContract):
    model_name = "kelvin_voigt"

    def make_models(self):
        return [KelvinVoigtChain(SAMPLE, KelvinVoigtOptions(n_elements=n)) for n in (3, 1)]


class TestMaxwellContract(MediumModelContract):
    model_name = "maxwell"

    def make_models(self):
        return [
            MaxwellChain(SAMPLE, MaxwellOptions(n_elements=3)),
            MaxwellChain(SAMPLE, MaxwellOptions(n_elements=2, shear_link="kelvin_voigt")),
        ]


class TestSlsContract(MediumModelContract):
    model_name = "sls"

    def make_models(self):
        return [SlsChain(SAMPLE, SlsOptions(n_elements=3)), SlsChain(SAMPLE, SlsOptions(n_elements=1))]


class TestGeneralizedMaxwellContract(MediumModelContract):
    model_name = "generalized_maxwell"

    def make_models(self):
        return [
            GeneralizedMaxwellChain(SAMPLE, GeneralizedMaxwellOptions(n_elements=3, n_arms=2)),
            GeneralizedMaxwellChain(SAMPLE, GeneralizedMaxwellOptions(n_elements=2, n_arms=3,
                                                                      shear_link="generalized_maxwell")),
        ]


class TestLayeredContract(MediumModelContract):
    model_name = "layered"

    def make_models(self):
        return [
            LayeredChain(SAMPLE, LayeredOptions(
                shared=["k_tau", "b_tau"],
                layers=[{"name": "plate", "length": 0.006, "density": 1180.0, "n_elements": 1,
                         "fixed": {"E_sigma": 5.6e9}},
                        {"name": "flesh", "n_elements": 3}])),
            LayeredChain(SAMPLE, LayeredOptions(
                layers=[{"name": "skin", "length": 0.004, "n_elements": 1, "link": "sls"},
                        {"name": "core", "length": 0.016, "n_elements": 2, "link": "maxwell",
                         "shear_link": "kelvin_voigt"}])),
        ]
