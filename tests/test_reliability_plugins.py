"""Issue 15, plugins: a clash, a ``sys.exit()`` on import or a broken third-party plugin stays
with that plugin; a third-party plugin that raises is one line naming it; a bug in mbus itself is
reported in one line with its traceback saved (or raised with MBUS_DEBUG=1)."""
from __future__ import annotations

from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

import pytest

from mbus_framework.interfaces import plugin_manager as pm_module
from mbus_framework.interfaces import registry as registry_module
from mbus_framework.interfaces.hookspecs import MediumModelSpec
from mbus_framework.interfaces.plugin_manager import new_plugin_manager
from mbus_framework.interfaces.registry import Registry
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain
from reliability_support import assert_clean_outcome, config, run_cli, strict_json, write_yaml
from test_plugins import plugin_module as plugin


def use_registry(monkeypatch, *extra, entry_points=()) -> Registry:
    """Make ``reg`` (built-ins + ``extra`` plugins + fake entry points) what mbus-run uses."""
    if entry_points:
        real = pm_module._entry_points

        def patched(group):
            yield from real(group)
            yield from entry_points

        monkeypatch.setattr(pm_module, "_entry_points", patched)
    reg = Registry.from_manager(new_plugin_manager(extra_plugins=list(extra)))
    monkeypatch.setattr(registry_module, "_default", reg)
    return reg


def run_small(tmp_path, **sections):
    path = write_yaml(tmp_path / "run.yaml", config(**sections))
    return run_cli([path, "-o", tmp_path / "out", "-q"], timeout=60)


def test_duplicate_name_leaves_every_other_command_working(tmp_path, monkeypatch):
    impostor = plugin("acme_impostor", mbus_medium_models=lambda: [MediumModelSpec("kelvin_voigt", KelvinVoigtChain, "x")])
    use_registry(monkeypatch, ("acme_impostor", impostor))
    listing = run_cli(["--list-plugins"])
    assert listing.code == 0
    assert "model 'kelvin_voigt' is registered twice" in listing.out
    o = run_small(tmp_path / "a", model={"name": "maxwell", "options": {"n_elements": 3}})
    assert o.code == 0, o.err
    o = run_small(tmp_path / "b")
    assert o.code == 2
    assert_clean_outcome(o, ["model.name"])
    assert "registered twice" in o.err and "acme_impostor" in o.err and "builtin.kelvin_voigt" in o.err


def test_sys_exit_in_a_plugin_import_or_hook_is_a_broken_plugin(tmp_path, monkeypatch):
    (tmp_path / "acme_exits_on_import.py").write_text("import sys\nsys.exit(3)\n")
    monkeypatch.syspath_prepend(str(tmp_path))

    def exits():
        raise SystemExit("acme: no license")

    reg = use_registry(monkeypatch, ("acme_hook_exit", plugin("acme_hook_exit", mbus_medium_models=exits)),
                       entry_points=[metadata.EntryPoint("acme_exit", "acme_exits_on_import", "mbus_framework")])
    broken = {b.name: b.error for b in reg.broken}
    assert broken["acme_exit"] == "SystemExit: 3"
    assert broken["acme_hook_exit"] == "mbus_medium_models: SystemExit: acme: no license"
    assert run_cli(["--list-plugins"]).code == 0
    assert run_small(tmp_path / "run").code == 0


def test_asking_for_a_model_of_a_broken_plugin_names_the_failure(tmp_path, monkeypatch):
    use_registry(monkeypatch, entry_points=[
        metadata.EntryPoint("fractional_kv", "acme_fractional_missing_7f3a", "mbus_framework")])
    o = run_small(tmp_path, model={"name": "fractional_kv"})
    assert o.code == 2
    assert_clean_outcome(o, ["model.name"])
    assert "unknown model 'fractional_kv'" in o.err
    assert "Plugins that failed to load (--list-plugins): fractional_kv (" in o.err
    assert "ModuleNotFoundError" in o.err


@dataclass
class RaisingInInit(KelvinVoigtChain):
    summary = "raises in __init__"

    def __post_init__(self):
        raise ZeroDivisionError("acme: float division by zero")


@dataclass
class RaisingInStateSpace(KelvinVoigtChain):
    summary = "raises in state_space from its 40th call on (inside the fit)"
    calls: int = 0

    def state_space(self, theta):
        self.calls += 1
        if self.calls >= 40:
            raise KeyError("acme_table_entry")
        return super().state_space(theta)


@pytest.mark.parametrize("cls, fragment", [
    (RaisingInInit, "ZeroDivisionError: acme: float division by zero"),
    (RaisingInStateSpace, "KeyError: 'acme_table_entry'"),
])
def test_third_party_model_that_raises_is_one_line_naming_it(tmp_path, monkeypatch, cls, fragment):
    acme = plugin("acme_models", mbus_medium_models=lambda: [MediumModelSpec("acme_kv", cls, cls.summary)])
    use_registry(monkeypatch, ("acme_models", acme))
    o = run_small(tmp_path, model={"name": "acme_kv", "options": {"n_elements": 3}},
                  backend={"name": "simulated", "options": {"truth": {"k_sigma": 3.0e8, "b_sigma": 15.0,
                                                                       "k_tau": 5.0e7, "b_tau": 12.0}}})
    assert o.code == 2, o.err
    assert_clean_outcome(o, ["model 'acme_kv'"])
    assert "model 'acme_kv' (registered in code) failed: " + fragment in o.err
    assert "a bug in that plugin" in o.err
    status = tmp_path / "out" / "status.json"
    if status.exists():
        assert strict_json(status)["status"] == "failed"


def test_a_bug_in_mbus_itself_is_one_line_with_the_traceback_saved(tmp_path, monkeypatch):
    def broken(self, theta):
        raise ZeroDivisionError("simulated bug in a built-in model")

    monkeypatch.setattr(KelvinVoigtChain, "state_space", broken)
    monkeypatch.delenv("MBUS_DEBUG", raising=False)
    o = run_small(tmp_path)
    assert o.code == 70
    (line,) = o.err.splitlines()
    assert line.startswith("mbus-run: internal error: ZeroDivisionError: simulated bug in a built-in model")
    saved = Path(line.split("traceback in ")[1].split(";")[0])
    assert "Traceback" in saved.read_text() and "broken" in saved.read_text()
    saved.unlink()
    monkeypatch.setenv("MBUS_DEBUG", "1")
    with pytest.raises(ZeroDivisionError):
        run_small(tmp_path / "debug")


def test_long_or_multi_line_plugin_names_stay_on_one_line(tmp_path, monkeypatch):
    """A third-party plugin that registers a model name with a newline (or 3,000 characters), and
    an entry point named so: the plugin is listed as broken, saying why; --list-plugins keeps
    one line per plugin and errors stay one short line."""
    evil_name = "acme\nevil" + "x" * 400
    evil = plugin(evil_name, mbus_medium_models=lambda: [
        MediumModelSpec("kv\nsecond line" + "y" * 3000, KelvinVoigtChain, "summary\nover lines " + "s" * 900)])
    fine = plugin("acme_fine", mbus_medium_models=lambda: [
        MediumModelSpec("kv-acme.v2", KelvinVoigtChain, "summary\nover two lines")])
    reg = use_registry(monkeypatch, (evil_name, evil), ("acme_fine", fine), entry_points=[
        metadata.EntryPoint("bad\nentry" + "z" * 500, "acme_missing_module_51c2", "mbus_framework")])
    broken = {b.name: b.error for b in reg.broken}
    assert "must be one word of 1-64 printable characters" in broken[evil_name]
    assert "kv-acme.v2" in reg.names("model")  # hyphens and dots are fine

    listing = run_cli(["--list-plugins"])
    assert listing.code == 0
    lines = listing.out.splitlines()
    assert all(len(line) <= 400 for line in lines), max(map(len, lines))
    assert any(line.startswith("  kv-acme.v2 ") and line.rstrip().endswith("[registered in code]") for line in lines)
    assert sum(line.startswith("  bad entry") for line in lines) == 1  # the newline folded
    assert sum(line.startswith("  acme evil") for line in lines) == 1

    o = run_small(tmp_path / "run", model={"name": "nope"})
    assert_clean_outcome(o, ["model.name"])
    assert "kv-acme.v2" in o.err and "bad entry" in o.err
