"""Plugins imported when their names are used: the built-ins' declared names
(``mbus_plugins.MBUS_PLUGIN_NAMES``) match what their hooks register, a registry lists every name
without importing a plugin module, a lookup imports only the module that provides it, a potato run
imports only the five plugins it names, and a third-party package can declare its names too."""
from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from importlib import metadata
from pathlib import Path

import pytest

import mbus_plugins
from mbus_framework.errors import PluginError
from mbus_framework.interfaces import plugin_manager as pm_module
from mbus_framework.interfaces.hookspecs import MediumModelSpec
from mbus_framework.interfaces.plugin_manager import declared_names, new_plugin_manager
from mbus_framework.interfaces.registry import Registry
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain
from test_plugins import plugin_module

REPO = Path(__file__).resolve().parents[1]
BUILTIN_EPS = [ep for ep in metadata.entry_points(group="mbus_framework") if ep.value.startswith("mbus_plugins.")]


def in_fresh_python(code: str) -> dict:
    """Run ``code`` (which prints one JSON document last) in a new interpreter from the repo root."""
    done = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=REPO, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.splitlines()[-1])


def test_every_builtin_entry_point_is_declared():
    assert BUILTIN_EPS, "no built-in entry points (reinstall: pip install -e .)"
    assert {ep.value for ep in BUILTIN_EPS} == set(mbus_plugins.MBUS_PLUGIN_NAMES)


def test_declared_names_are_what_the_hooks_register():
    """The table against an eager registry (every module imported, hooks called)."""
    eager = Registry.from_manager(new_plugin_manager(lazy=False))
    registered: dict[str, dict[str, set[str]]] = {}
    for kind, names in eager.loaded.items():
        for name, entry in names.items():
            registered.setdefault(entry.source.split("[")[-1].rstrip("]"), {}).setdefault(kind, set()).add(name)
    declared = {module: {kind: set(names) for kind, names in kinds.items()}
                for module, kinds in mbus_plugins.MBUS_PLUGIN_NAMES.items()}
    assert registered == declared


def test_lazy_registry_lists_the_same_names_as_the_eager_one():
    lazy = Registry.from_manager(new_plugin_manager())
    eager = Registry.from_manager(new_plugin_manager(lazy=False))
    for kind in eager.loaded:
        assert lazy.names(kind) == eager.names(kind)
    assert lazy.entries.keys() == eager.entries.keys()
    for kind in eager.loaded:
        assert {n: e.spec for n, e in lazy.entries[kind].items()} == {n: e.spec for n, e in eager.entries[kind].items()}


def test_names_import_no_plugin_module_and_get_imports_only_its_provider():
    out = in_fresh_python("""
        import json, sys
        from mbus_framework.interfaces.registry import default_registry
        reg = default_registry()
        names = reg.names("model")
        before = sorted(m for m in sys.modules if m.startswith("mbus_plugins."))
        reg.get("model", "maxwell")
        after = sorted(m for m in sys.modules if m.startswith("mbus_plugins."))
        print(json.dumps({"names": names, "before": before, "after": after}))
    """)
    assert "maxwell" in out["names"] and "kelvin_voigt" in out["names"]
    assert out["before"] == []
    assert "mbus_plugins.models.maxwell" in out["after"]
    assert not [m for m in out["after"] if m.startswith(("mbus_plugins.backends", "mbus_plugins.solvers",
                                                          "mbus_plugins.excitations", "mbus_plugins.instruments"))]
    assert "mbus_plugins.models.kelvin_voigt" not in out["after"]


def test_potato_run_imports_only_the_plugins_it_names(tmp_path):
    out = in_fresh_python(f"""
        import json, sys
        from mbus_framework.cli import main
        code = main(["configs/potato.yaml", "-o", {str(tmp_path / "run")!r}, "-q", "--no-plots"])
        print(json.dumps({{"code": code, "modules": sorted(m for m in sys.modules if m.startswith("mbus_plugins."))}}))
    """)
    assert out["code"] == 0
    used = {"mbus_plugins.models.kelvin_voigt", "mbus_plugins.excitations.prbs", "mbus_plugins.backends.simulated",
            "mbus_plugins.solvers.scipy_lm", "mbus_plugins.compensators.none"}
    entry_point_modules = {m for m in out["modules"] if m in mbus_plugins.MBUS_PLUGIN_NAMES}
    assert entry_point_modules == used
    assert not [m for m in out["modules"] if m.startswith("mbus_plugins.instruments")]


def test_a_clash_with_a_deferred_builtin_is_reported_at_once():
    impostor = plugin_module("acme_impostor", mbus_medium_models=lambda: [MediumModelSpec("kelvin_voigt", KelvinVoigtChain, "x")])
    reg = Registry.from_manager(new_plugin_manager(extra_plugins=[("acme_impostor", impostor)]))
    assert ("model", "kelvin_voigt") in reg.clashes
    assert "kelvin_voigt" not in reg.names("model")
    with pytest.raises(PluginError, match="registered twice"):
        reg.get("model", "kelvin_voigt")


@pytest.fixture
def acme_lazy(tmp_path, monkeypatch):
    """A third-party package declaring the names of its two plugin modules; one fails to import."""
    pkg = tmp_path / "acme_lazy"
    pkg.mkdir()
    (pkg / "__init__.py").write_text(
        "MBUS_PLUGIN_NAMES = {'acme_lazy.models': {'model': ['acme_kv']}, 'acme_lazy.broken': {'model': ['acme_x']}}\n")
    (pkg / "models.py").write_text(textwrap.dedent("""
        from mbus_framework.plugins import MediumModelSpec, hookimpl
        from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain

        @hookimpl
        def mbus_medium_models():
            return [MediumModelSpec("acme_kv", KelvinVoigtChain, "acme's chain")]
    """))
    (pkg / "broken.py").write_text("raise RuntimeError('acme: no licence')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    real = pm_module._entry_points
    fakes = [metadata.EntryPoint("acme_models", "acme_lazy.models", "mbus_framework"),
             metadata.EntryPoint("acme_broken", "acme_lazy.broken", "mbus_framework")]

    def patched(group):
        yield from real(group)
        yield from fakes

    monkeypatch.setattr(pm_module, "_entry_points", patched)
    yield fakes
    for name in [m for m in sys.modules if m.startswith("acme_lazy")]:
        del sys.modules[name]


def test_a_third_party_package_can_declare_its_names(acme_lazy):
    assert declared_names(acme_lazy[0]) == {"model": ("acme_kv",)}
    reg = Registry.from_manager(new_plugin_manager())
    assert {"acme_kv", "acme_x"} <= set(reg.names("model"))
    assert "acme_lazy.models" not in sys.modules and reg.broken == []
    assert reg.get("model", "acme_kv").implementation is KelvinVoigtChain
    assert "acme_lazy.models" in sys.modules and "acme_lazy.broken" not in sys.modules
    with pytest.raises(PluginError) as info:
        reg.get("model", "acme_x")
    assert "unknown model 'acme_x'" in str(info.value) and "acme: no licence" in str(info.value)
    assert [b.name for b in reg.broken] == ["acme_broken"]


@pytest.mark.parametrize("table", ["MBUS_PLUGIN_NAMES = 3", "MBUS_PLUGIN_NAMES = {'acme_lazy.models': {'modle': ['a']}}",
                                   "MBUS_PLUGIN_NAMES = {'acme_lazy.models': {'model': 'acme_kv'}}", ""])
def test_an_unusable_declaration_means_an_eager_import(acme_lazy, table):
    (Path(sys.path[0]) / "acme_lazy" / "__init__.py").write_text(table + "\n")
    assert declared_names(acme_lazy[0]) is None
    reg = Registry.from_manager(new_plugin_manager())
    assert "acme_lazy.models" in sys.modules
    assert "acme_kv" in reg.loaded["model"]


def test_two_registries_of_one_manager_each_load_what_they_are_asked(acme_lazy):
    pm = new_plugin_manager()
    first, second = Registry.from_manager(pm), Registry.from_manager(pm)
    assert first.get("model", "acme_kv") == second.get("model", "acme_kv")
    for reg in (first, second):  # the second finds the failure the first one's import recorded
        with pytest.raises(PluginError, match="acme: no licence"):
            reg.get("model", "acme_x")
    third = Registry.from_manager(pm)  # built after: the loaded plugin is simply registered
    assert "acme_kv" in third.loaded["model"] and third.names("model") == first.names("model")
