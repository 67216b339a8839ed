"""Run the mbus model contract suite against this plugin (works installed or from source)."""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

import mbus_fractional_kv  # noqa: E402
from mbus_framework.plugins import Registry, Sample, new_plugin_manager  # noqa: E402
from mbus_framework.testing.models import MediumModelContract  # noqa: E402


def _registry() -> Registry:
    """Installed: found through its entry point. From source: registered in code."""
    pm = new_plugin_manager()
    if not pm.has_plugin("fractional_kv"):
        pm.register_plugin(mbus_fractional_kv, "fractional_kv", "registered in code")
    return Registry.from_manager(pm)


class TestFractionalKelvinVoigt(MediumModelContract):
    model_name = "fractional_kv"
    registry = _registry()

    def make_models(self):
        s = Sample(length=0.02, diameter=0.0254, density=1000.0)
        O = mbus_fractional_kv.FractionalKVOptions
        return [
            mbus_fractional_kv.FractionalKelvinVoigtChain(s, O(n_elements=2)),
            mbus_fractional_kv.FractionalKelvinVoigtChain(s, O(n_elements=1, alpha=0.3, decades=1)),
        ]
