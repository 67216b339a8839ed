"""Plugin system: built-ins through entry points, --list-plugins, unknown names, broken
third-party plugins (reported and skipped), name clashes, and the top-level ``plugins`` package."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import types
from importlib import metadata
from pathlib import Path

import pytest

from mbus_framework.interfaces import plugin_manager as pm_module
from mbus_framework.interfaces import registry as registry_module
from mbus_framework.cli import main
from mbus_framework.errors import PluginError
from mbus_framework.interfaces.hookspecs import (
    PROJECT,
    BackendSpec,
    CompensatorSpec,
    ExcitationSpec,
    MediumModelSpec,
    SolverSpec,
    hookimpl,
)
from mbus_framework.interfaces.plugin_manager import new_plugin_manager
from mbus_framework.interfaces.registry import Registry

REPO = Path(__file__).resolve().parents[1]

# The built-ins of the core issue: kind -> (config name, entry-point name, module).
BUILTINS = {
    "model": ("kelvin_voigt", "builtin.kelvin_voigt", "mbus_plugins.models.kelvin_voigt"),
    "excitation": ("prbs", "builtin.prbs", "mbus_plugins.excitations.prbs"),
    "backend": ("simulated", "builtin.simulated", "mbus_plugins.backends.simulated"),
    "solver": ("scipy_lm", "builtin.scipy_lm", "mbus_plugins.solvers.scipy_lm"),
    "compensator": ("none", "builtin.none", "mbus_plugins.compensators.none"),
}
FILE_BACKEND = ("backend", "file", "builtin.file", "mbus_plugins.backends.file")
ALL_BUILTINS = [(k, *v) for k, v in BUILTINS.items()] + [FILE_BACKEND]


def mbus_version() -> str:
    return metadata.version("mbus")


@pytest.fixture(scope="module")
def registry() -> Registry:
    return Registry.from_manager(new_plugin_manager())


def plugin_module(name: str, **hooks) -> types.ModuleType:
    """A module object carrying the given hook implementations (as a third party writes them)."""
    mod = types.ModuleType(name)
    for hook_name, func in hooks.items():
        func.__name__ = hook_name
        setattr(mod, hook_name, hookimpl(func))
    return mod


# ---------------------------------------------------------------------------------------
# Built-ins come through the entry-point group, like any third-party plugin
# ---------------------------------------------------------------------------------------
def test_group_marker_and_project_share_one_name():
    assert PROJECT == "mbus_framework"
    assert new_plugin_manager(entry_points=False).project_name == "mbus_framework"


@pytest.mark.parametrize("kind, name, ep_name, module", ALL_BUILTINS)
def test_builtin_is_declared_as_an_entry_point_of_our_distribution(kind, name, ep_name, module):
    eps = [ep for ep in metadata.entry_points(group="mbus_framework") if ep.name == ep_name]
    assert eps, f"entry point {ep_name} missing from group mbus_framework (reinstall: pip install -e .)"
    assert {ep.value for ep in eps} == {module}
    assert all(ep.dist is not None and ep.dist.name == "mbus" for ep in eps)


@pytest.mark.parametrize("kind, name, ep_name, module", ALL_BUILTINS)
def test_builtin_is_registered_with_its_source_distribution(registry, kind, name, ep_name, module):
    entry = registry.entries[kind][name]
    assert entry.plugin == ep_name
    assert entry.source == f"mbus {mbus_version()} [{module}]"
    assert entry.spec.implementation.__module__ == module
    assert entry.spec.summary


def test_builtins_are_not_hard_wired():
    """Without entry points the manager knows nothing: the built-ins are not a special path."""
    bare = Registry.from_manager(new_plugin_manager(entry_points=False))
    assert all(bare.names(kind) == [] for kind in BUILTINS)


def test_core_builtins_are_not_broken(registry):
    builtin_eps = {ep for _, _, ep, _ in ALL_BUILTINS}
    assert [b for b in registry.broken if b.name in builtin_eps] == []


def test_list_plugins_shows_every_kind_name_summary_and_source(capsys):
    assert main(["--list-plugins"]) == 0
    out, err = capsys.readouterr()
    assert err == ""
    for heading in ("models:", "excitations:", "solvers:", "compensators:", "backends:"):
        assert heading in out.splitlines()
    for kind, name, ep_name, module in ALL_BUILTINS:
        line = next((ln for ln in out.splitlines() if ln.split() and ln.split()[0] == name), None)
        assert line is not None, f"{name} not listed"
        assert f"[mbus {mbus_version()} [{module}]]" in line
    assert "Kelvin-Voigt" in out


# ---------------------------------------------------------------------------------------
# Unknown names
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "kind, wrong, right",
    [
        ("model", "kelvin-voigt", "kelvin_voigt"),
        ("excitation", "prbs2", "prbs"),
        ("backend", "simulted", "simulated"),
        ("solver", "scipy_ml", "scipy_lm"),
        ("compensator", "nnone", "none"),
    ],
)
def test_unknown_name_lists_the_choices_and_suggests(registry, kind, wrong, right):
    with pytest.raises(PluginError) as info:
        registry.get(kind, wrong)
    msg = str(info.value)
    assert msg.startswith(f"unknown {kind} '{wrong}'; did you mean '{right}'?; choose one of: ")
    choices = msg.split("choose one of: ")[1].split(", ")
    assert choices == sorted(registry.names(kind))
    assert right in choices
    assert info.value.exit_code == 2


def test_unknown_name_without_a_close_match(registry):
    with pytest.raises(PluginError) as info:
        registry.get("solver", "xyzzy")
    assert "did you mean" not in str(info.value)
    assert "choose one of: " in str(info.value) and "scipy_lm" in str(info.value)


def test_no_plugins_of_a_kind():
    bare = Registry.from_manager(new_plugin_manager(entry_points=False))
    with pytest.raises(PluginError, match=r"choose one of: \(none registered\)"):
        bare.get("model", "kelvin_voigt")


# ---------------------------------------------------------------------------------------
# Broken third-party plugins are reported and skipped, never fatal
# ---------------------------------------------------------------------------------------
def assert_builtins_intact(reg: Registry):
    for kind, name, *_ in ALL_BUILTINS:
        assert name in reg.names(kind)


def with_fake_entry_points(monkeypatch, *fakes: metadata.EntryPoint):
    real = pm_module._entry_points

    def patched(group):
        yield from real(group)
        yield from fakes

    monkeypatch.setattr(pm_module, "_entry_points", patched)


def test_entry_point_whose_module_is_missing(monkeypatch):
    with_fake_entry_points(
        monkeypatch, metadata.EntryPoint("acme_missing", "acme_no_such_module_7f3a", "mbus_framework")
    )
    reg = Registry.from_manager(new_plugin_manager())
    broken = {b.name: b for b in reg.broken}
    assert "ModuleNotFoundError" in broken["acme_missing"].error
    assert "acme_no_such_module_7f3a" in broken["acme_missing"].error
    assert "acme_no_such_module_7f3a" in broken["acme_missing"].source
    assert_builtins_intact(reg)


def test_entry_point_whose_module_raises_on_import(monkeypatch, tmp_path):
    (tmp_path / "acme_raises_on_import.py").write_text("raise RuntimeError('acme: cannot find my license file')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with_fake_entry_points(
        monkeypatch,
        metadata.EntryPoint("acme_raises", "acme_raises_on_import", "mbus_framework"),
        metadata.EntryPoint("acme_attr", "json:no_such_attribute", "mbus_framework"),
    )
    reg = Registry.from_manager(new_plugin_manager())
    broken = {b.name: b.error for b in reg.broken}
    assert broken["acme_raises"] == "RuntimeError: acme: cannot find my license file"
    assert broken["acme_attr"].startswith("AttributeError")
    assert_builtins_intact(reg)


def _bad_signature_plugin() -> types.ModuleType:
    """A plugin with one valid hook (an excitation) and one hook whose signature pluggy rejects."""

    def mbus_medium_models(unexpected_argument):
        return []

    return plugin_module(
        "acme_sig", mbus_excitations=lambda: [_good_excitation_spec()], mbus_medium_models=mbus_medium_models
    )


def test_plugin_with_a_bad_hook_signature_is_reported():
    pm = new_plugin_manager(extra_plugins=[("acme_sig", _bad_signature_plugin())])
    broken = [b for b in pm.broken if b.name.startswith("acme_")]
    assert [b.name for b in broken] == ["acme_sig"]
    assert "unexpected_argument" in broken[0].error
    assert_builtins_intact(Registry.from_manager(pm))


def test_plugin_with_a_bad_hook_signature_is_skipped_entirely():
    pm = new_plugin_manager(extra_plugins=[("acme_sig", _bad_signature_plugin())])
    assert not pm.has_plugin("acme_sig")
    assert "acme_prbs" not in Registry.from_manager(pm).names("excitation")


def test_broken_plugin_error_is_one_line():
    pm = new_plugin_manager(extra_plugins=[("acme_sig", _bad_signature_plugin())])
    (broken,) = [b for b in pm.broken if b.name == "acme_sig"]
    assert "\n" not in broken.error


def _good_excitation_spec():
    from mbus_plugins.excitations.prbs import Prbs

    return ExcitationSpec("acme_prbs", Prbs, "a working plugin next to the broken ones")


BROKEN_HOOKS = {
    "hook raises": (
        "mbus_medium_models",
        lambda: (_ for _ in ()).throw(RuntimeError("acme model database offline")),
        "mbus_medium_models: RuntimeError: acme model database offline",
    ),
    "wrong spec type": (
        "mbus_medium_models",
        lambda: [_good_excitation_spec()],
        "expected MediumModelSpec records, got ExcitationSpec",
    ),
    "not a list of specs": (
        "mbus_solvers",
        lambda: {"name": "acme_solver"},
        "expected SolverSpec records, got str",
    ),
    "class does not subclass the interface": (
        "mbus_medium_models",
        lambda: [MediumModelSpec("acme_plain", type("PlainModel", (), {}), "not a MediumModel")],
        "acme_plain: implementation must subclass MediumModel",
    ),
    "implementation is not a class": (
        "mbus_backends",
        lambda: [BackendSpec("acme_fn", lambda options: None, "a function")],
        "acme_fn: implementation must subclass Backend",
    ),
    "compensator of the wrong interface": (
        "mbus_compensators",
        lambda: [CompensatorSpec("acme_comp", __import__("mbus_plugins.solvers.scipy_lm", fromlist=["ScipyLM"]).ScipyLM)],
        "acme_comp: implementation must subclass Compensator",
    ),
}


@pytest.mark.parametrize("case", sorted(BROKEN_HOOKS))
def test_broken_hook_is_reported_and_skipped(case, monkeypatch, capsys):
    hook_name, func, expected = BROKEN_HOOKS[case]
    bad = plugin_module("acme_bad", **{hook_name: func})
    good = plugin_module("acme_good", mbus_excitations=lambda: [_good_excitation_spec()])
    reg = Registry.from_manager(new_plugin_manager(extra_plugins=[("acme_bad", bad), ("acme_good", good)]))
    broken = [b for b in reg.broken if b.name == "acme_bad"]
    assert len(broken) == 1, reg.broken
    assert expected in broken[0].error
    assert broken[0].source == "registered in code"
    for kind in BUILTINS:
        assert not any(n.startswith("acme_") and n != "acme_prbs" for n in reg.names(kind))
    assert "acme_prbs" in reg.names("excitation")
    assert_builtins_intact(reg)
    # --list-plugins shows it under "broken plugins (skipped)" and still exits 0.
    monkeypatch.setattr(registry_module, "_default", reg)
    assert main(["--list-plugins"]) == 0
    out = capsys.readouterr().out
    tail = out.split("broken plugins (skipped):")[1]
    assert "acme_bad" in tail and expected in tail


def test_broken_plugin_does_not_take_a_run_down(tmp_path):
    from mbus_framework.pipeline.run import execute

    bad = plugin_module("acme_bad", mbus_solvers=lambda: 1 / 0)
    reg = Registry.from_manager(new_plugin_manager(extra_plugins=[("acme_bad", bad)]))
    assert any(b.name == "acme_bad" for b in reg.broken)
    cfg = tmp_path / "run.yaml"
    cfg.write_text(
        "sample: {length: 0.02, diameter: 0.0254, density: 1000.0}\n"
        "model: {name: kelvin_voigt, options: {n_elements: 3}}\n"
        "excitation: {name: prbs, options: {order: 7, bit_width: 1.0e-6, sample_rate: 1.0e+7, n_samples: 1000}}\n"
        "backend: {name: simulated, options: {truth: {E_sigma: 3.0e+9, eta_sigma: 300.0, E_tau: 5.0e+8, eta_tau: 400.0},"
        " noise: {relative_std: 0.01}}}\n"
    )
    outcome = execute(cfg, [], tmp_path / "out", registry=reg, plots=False)
    assert outcome.result["solver"]["success"]


# ---------------------------------------------------------------------------------------
# Name clashes
# ---------------------------------------------------------------------------------------
def test_clash_with_a_builtin_names_both_providers():
    from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain

    impostor = plugin_module(
        "acme_impostor", mbus_medium_models=lambda: [MediumModelSpec("kelvin_voigt", KelvinVoigtChain, "mine")]
    )
    reg = Registry.from_manager(new_plugin_manager(extra_plugins=[("acme_impostor", impostor)]))
    assert "kelvin_voigt" not in reg.names("model") and "maxwell" in reg.names("model")  # only that name
    with pytest.raises(PluginError) as info:
        reg.get("model", "kelvin_voigt")
    msg = str(info.value)
    assert "model 'kelvin_voigt' is registered twice" in msg
    assert f"builtin.kelvin_voigt (mbus {mbus_version()} [mbus_plugins.models.kelvin_voigt])" in msg
    assert "acme_impostor (registered in code)" in msg
    assert "\n" not in msg


def test_clash_between_two_third_party_plugins():
    from mbus_plugins.solvers.scipy_lm import ScipyLM

    a = plugin_module("acme_a", mbus_solvers=lambda: [SolverSpec("fast", ScipyLM, "a")])
    b = plugin_module("acme_b", mbus_solvers=lambda: [SolverSpec("fast", ScipyLM, "b")])
    reg = Registry.from_manager(new_plugin_manager(extra_plugins=[("acme_a", a), ("acme_b", b)], entry_points=False))
    with pytest.raises(PluginError) as info:
        reg.get("solver", "fast")
    assert "acme_a" in str(info.value) and "acme_b" in str(info.value)


def test_same_plugin_name_twice_is_reported_not_fatal():
    one = plugin_module("acme_dup", mbus_excitations=lambda: [])
    two = plugin_module("acme_dup", mbus_excitations=lambda: [])
    pm = new_plugin_manager(extra_plugins=[("acme_dup", one), ("acme_dup", two)], entry_points=False)
    assert [b.name for b in pm.broken] == ["acme_dup"]
    Registry.from_manager(pm)


# ---------------------------------------------------------------------------------------
# The built-ins install as `mbus_plugins`, never as a top-level `plugins`
# ---------------------------------------------------------------------------------------
def test_builtins_are_the_mbus_plugins_package_of_this_checkout():
    import mbus_plugins

    assert Path(mbus_plugins.__file__).resolve().parent == REPO / "plugins"
    for _, _, _, module in ALL_BUILTINS:
        assert module.startswith("mbus_plugins."), module
        mod = __import__(module, fromlist=["_"])
        assert Path(mod.__file__).resolve().is_relative_to(REPO / "plugins")


def test_no_top_level_plugins_package_is_installed(tmp_path):
    """From any folder but the checkout, ``import plugins`` finds nothing of ours; ``mbus``
    and ``mbus_framework`` both import."""
    code = ("import importlib.util as u, mbus, mbus_framework; "
            "print(u.find_spec('plugins') is None, mbus.__version__ == mbus_framework.__version__)")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True,
                         timeout=120, check=True, env=env).stdout.split()
    assert out == ["True", "True"]


def test_a_users_own_plugins_folder_does_not_shadow_the_builtins(tmp_path):
    """A lab folder with its own ``plugins/`` package next to its configs must not break mbus-run."""
    exe = shutil.which("mbus-run")
    if exe is None:
        pytest.skip("mbus-run console script not on PATH")
    decoy = tmp_path / "plugins"
    (decoy / "models").mkdir(parents=True)
    (decoy / "__init__.py").write_text("raise ImportError('decoy plugins package imported')\n")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    proc = subprocess.run([exe, "--list-plugins"], cwd=tmp_path, capture_output=True, text=True, timeout=120, env=env)
    assert proc.returncode == 0, proc.stderr
    assert "decoy" not in proc.stdout + proc.stderr
    for _, name, _, _ in ALL_BUILTINS:
        assert any(ln.split()[:1] == [name] for ln in proc.stdout.splitlines()), name
