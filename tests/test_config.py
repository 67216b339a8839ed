"""Run configuration: safe YAML, ``--set`` overrides, stage-1 structure and stage-2 plugin options.

Every error is a one-line ConfigError that names the file (where there is one) and the key path,
with a 'did you mean' for misspelt names.
"""
from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml

from mbus_framework.pipeline.config import RunConfig, apply_overrides, load_config, read_yaml, validate_options
from mbus_framework.errors import ConfigError, MbusError, PluginError
from mbus_framework.interfaces.plugin_manager import new_plugin_manager
from mbus_framework.interfaces.registry import Registry
from mbus_framework.pipeline.run import build_components, execute

BASE = {
    "title": "config tests",
    "sample": {"length": 0.02, "diameter": 0.0254, "density": 1000.0},
    "model": {"name": "kelvin_voigt", "options": {"n_elements": 3}},
    "excitation": {
        "name": "prbs",
        "options": {"order": 7, "bit_width": 2.0e-6, "sample_rate": 5.0e6, "n_samples": 800},
    },
    "backend": {
        "name": "simulated",
        "options": {
            "truth": {"E_sigma": 2.0e9, "eta_sigma": 200.0, "E_tau": 3.0e8, "eta_tau": 150.0},
            "noise": {"relative_std": 0.02},
            "seed": 1,
        },
    },
    "solver": {"name": "scipy_lm", "options": {"strategy": {"n_starts": 1}}},
}


@pytest.fixture(scope="module")
def registry() -> Registry:
    return Registry.from_manager(new_plugin_manager())


def write(tmp_path: Path, data, name: str = "run.yaml") -> Path:
    path = tmp_path / name
    path.write_text(data if isinstance(data, str) else yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


def config_error(func, *args, **kwargs) -> str:
    """Run ``func``; it must raise a one-line ConfigError; return the message."""
    with pytest.raises(ConfigError) as info:
        func(*args, **kwargs)
    msg = str(info.value)
    assert "\n" not in msg, msg
    assert info.value.exit_code == 2
    return msg


def variant(**changes) -> dict:
    """BASE with dotted-path changes (None deletes the key)."""
    data = copy.deepcopy(BASE)
    for dotted, value in changes.items():
        *parents, last = dotted.split("__")
        node = data
        for p in parents:
            node = node[p]
        if value is None:
            node.pop(last)
        else:
            node[last] = value
    return data


# ---------------------------------------------------------------------------------------
# Reading YAML safely
# ---------------------------------------------------------------------------------------
def test_good_config_loads_with_defaults(tmp_path):
    cfg = load_config(write(tmp_path, BASE))
    assert isinstance(cfg, RunConfig)
    assert cfg.sample.length == 0.02
    assert cfg.model.name == "kelvin_voigt" and cfg.model.options == {"n_elements": 3}
    assert cfg.model.initial is None and cfg.model.fixed == {} and cfg.model.hold == "zoh"
    assert cfg.compensator.name == "none"  # optional section
    assert cfg.output.plots is True


@pytest.mark.parametrize("shipped", ["potato.yaml", "table3_1.yaml"])
def test_shipped_configs_pass_both_stages(shipped, registry):
    path = Path(__file__).resolve().parents[1] / "configs" / shipped
    c = build_components(load_config(path), str(path), registry)
    assert c.model.parameter_names == ["k_sigma", "b_sigma", "k_tau", "b_tau"]


def test_python_object_tag_is_rejected_and_never_executed(tmp_path):
    marker = tmp_path / "pwned"
    text = (
        "sample: !!python/object/apply:pathlib.Path.touch [!!python/object/apply:pathlib.Path ['%s']]\n" % marker
    )
    msg = config_error(load_config, write(tmp_path, text))
    assert "invalid YAML" in msg and "python/object" in msg
    assert str(tmp_path / "run.yaml") in msg
    assert not marker.exists()


def test_python_name_tag_is_rejected(tmp_path):
    msg = config_error(read_yaml, write(tmp_path, "title: !!python/name:os.system\n"))
    assert "line 1" in msg


def test_yaml_syntax_error_names_the_line(tmp_path):
    text = "sample:\n  length: 0.02\n  diameter: [0.0254\nmodel:\n  name: kelvin_voigt\n"
    msg = config_error(load_config, write(tmp_path, text))
    assert str(tmp_path / "run.yaml") in msg
    assert "invalid YAML at line" in msg
    line = int(msg.split("at line ")[1].split(",")[0])
    assert 3 <= line <= 5


def test_tab_indentation_error_names_the_line(tmp_path):
    msg = config_error(load_config, write(tmp_path, "sample:\n\tlength: 0.02\n"))
    assert "line 2" in msg


def test_empty_file(tmp_path):
    assert "empty" in config_error(load_config, write(tmp_path, ""))
    assert "empty" in config_error(load_config, write(tmp_path, "# only a comment\n"))


@pytest.mark.parametrize("text, kind", [("- a\n- b\n", "list"), ("just a string\n", "str"), ("42\n", "int")])
def test_top_level_must_be_a_mapping(tmp_path, text, kind):
    msg = config_error(load_config, write(tmp_path, text))
    assert "top level must be a mapping" in msg and kind in msg


def test_missing_file_and_directory(tmp_path):
    assert "not found" in config_error(load_config, tmp_path / "nope.yaml")
    assert "cannot read" in config_error(load_config, tmp_path)


def test_non_utf8_file(tmp_path):
    path = tmp_path / "latin1.yaml"
    path.write_bytes("title: caf\xe9\n".encode("latin-1"))
    assert str(path) in config_error(load_config, path)


# ---------------------------------------------------------------------------------------
# Stage 1: core structure
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("section", ["sample", "backend"])
def test_missing_section(tmp_path, section):
    msg = config_error(load_config, write(tmp_path, variant(**{section: None})))
    assert f"{section}: required key is missing" in msg
    assert str(tmp_path / "run.yaml") in msg


def test_missing_excitation_is_an_error_only_for_a_backend_that_plays_it(tmp_path, registry):
    """A simulated rig plays the excitation: without one, a one-line error naming the key; the
    file backend reads the input from the record and needs none."""
    path = write(tmp_path, variant(excitation=None))
    config = load_config(path)
    assert config.excitation is None
    msg = config_error(build_components, config, str(path), registry)
    assert msg.startswith(f"{path}: excitation: required by backend 'simulated'")
    recorded = variant(excitation=None, backend={"name": "file", "options": {"path": "record.csv"}})
    c = build_components(load_config(write(tmp_path, recorded, "recorded.yaml")), "recorded.yaml", registry)
    assert c.excitation is None and c.backend.needs_excitation is False


def test_missing_key_inside_a_section(tmp_path):
    msg = config_error(load_config, write(tmp_path, variant(sample__density=None)))
    assert "sample.density: required key is missing" in msg


@pytest.mark.parametrize(
    "changes, path, suggestion",
    [
        ({"sample__lenght": 0.02}, "sample.lenght", "length"),
        ({"model__intial": {"k_sigma": 1.0}}, "model.intial", "initial"),
        ({"solvr": {"name": "scipy_lm"}}, "solvr", "solver"),
        ({"excitation__option": {}}, "excitation.option", "options"),
        ({"output": {"plot": False}}, "output.plot", "plots"),
    ],
)
def test_unknown_key_with_did_you_mean(tmp_path, changes, path, suggestion):
    msg = config_error(load_config, write(tmp_path, variant(**changes)))
    assert f"{path}: unknown key" in msg
    assert f"did you mean '{suggestion}'" in msg


@pytest.mark.parametrize(
    "section, wrong, right",
    [(None, "sampel", "sample"), ("sample", "lenght", "length"), ("model", "nme", "name")],
)
def test_misspelt_required_key_gets_did_you_mean(tmp_path, section, wrong, right):
    """A misspelt required key is both unknown and missing; the message must name the misspelling."""
    data = copy.deepcopy(BASE)
    node = data if section is None else data[section]
    node[wrong] = node.pop(right)
    msg = config_error(load_config, write(tmp_path, data))
    assert wrong in msg
    assert f"did you mean '{right}'" in msg


def test_unknown_top_level_key_lists_the_sections(tmp_path):
    msg = config_error(load_config, write(tmp_path, variant(plots=True)))
    assert "plots: unknown key" in msg
    for section in ("sample", "model", "excitation", "backend", "compensator", "solver", "output"):
        assert section in msg


@pytest.mark.parametrize(
    "changes, fragment",
    [
        ({"sample__length": -1}, "sample.length: Input should be greater than 0 (got -1)"),
        ({"sample__diameter": 0}, "sample.diameter: Input should be greater than 0"),
        ({"sample__density": "heavy"}, "sample.density: Input should be a valid number"),
        ({"model__name": 3}, "model.name: Input should be a valid string"),
        ({"model__options": [1, 2]}, "model.options: Input should be a valid dictionary"),
        ({"model__hold": "cubic"}, "model.hold: Input should be 'zoh' or 'foh'"),
        ({"model__initial": {"k_sigma": "big"}}, "model.initial.k_sigma: Input should be a valid number"),
        ({"model__fixed": {"k_tau": None}}, "model.fixed.k_tau"),
        ({"backend": "simulated"}, "backend: Input should be"),
        ({"output": {"plots": "sometimes"}}, "output.plots: Input should be a valid boolean"),
    ],
)
def test_type_and_range_errors_name_the_key_path(tmp_path, changes, fragment):
    msg = config_error(load_config, write(tmp_path, variant(**changes)))
    assert fragment in msg, msg
    assert msg.startswith(str(tmp_path / "run.yaml") + ": ")


@pytest.mark.parametrize("section", ["model", "excitation", "backend", "compensator", "solver"])
def test_empty_options_key_means_no_options(tmp_path, registry, section):
    data = variant(compensator={"name": "none"})
    data[section]["options"] = None
    path = write(tmp_path, data)
    if section == "backend":
        with pytest.raises(ConfigError) as info:  # the rig needs its truth: a stage-2 error
            build_components(load_config(path), str(path), registry)
        assert "backend.options.truth: required key is missing" in str(info.value)
    else:
        c = build_components(load_config(path), str(path), registry)
        assert getattr(c, section) is not None


def test_several_problems_are_counted(tmp_path):
    msg = config_error(load_config, write(tmp_path, variant(sample__length=-1, sample__density=-2)))
    assert "(and 1 more problem)" in msg


# ---------------------------------------------------------------------------------------
# --set overrides
# ---------------------------------------------------------------------------------------
def test_override_replaces_and_keeps_the_rest():
    out = apply_overrides(BASE, ["sample.length=0.03"])
    assert out["sample"] == {"length": 0.03, "diameter": 0.0254, "density": 1000.0}
    assert BASE["sample"]["length"] == 0.02  # the input is not modified


def test_override_creates_nested_sections():
    out = apply_overrides(BASE, ["solver.options.strategy.n_starts=4", "compensator.name=none", "model.fixed.k_tau=5.0e7"])
    assert out["solver"]["options"]["strategy"] == {"n_starts": 4}
    assert out["compensator"] == {"name": "none"}
    assert float(out["model"]["fixed"]["k_tau"]) == 5.0e7


@pytest.mark.parametrize(
    "text, value",
    [
        ("7", 7),
        ("2.5e-6", 2.5e-6),  # YAML 1.1 reads this as a string; validation coerces it (below)
        ("2.5e+6", 2.5e6),
        ("0.5", 0.5),
        ("true", True),
        ("off", False),
        ("null", None),
        ("'42'", "42"),
        ("hello world", "hello world"),
        ("[0.1, 0.3]", [0.1, 0.3]),
        ("{k_sigma: 1.95e+8, b_sigma: 7.5}", {"k_sigma": 1.95e8, "b_sigma": 7.5}),
        ("", ""),
        ("a=b", "a=b"),  # only the first '=' separates key and value
    ],
)
def test_override_values_are_yaml_typed(text, value):
    out = apply_overrides({}, [f"x.y={text}"])
    got = out["x"]["y"]
    if text == "2.5e-6":
        assert float(got) == value
    else:
        assert got == value and type(got) is type(value)


def test_scientific_notation_override_validates_as_number(tmp_path):
    cfg = load_config(write(tmp_path, BASE), ["sample.length=3e-2", "model.initial={k_sigma: 1.95e8}"])
    assert cfg.sample.length == 0.03
    assert cfg.model.initial == {"k_sigma": 1.95e8}


def test_mapping_override_replaces_a_whole_section(tmp_path):
    cfg = load_config(
        write(tmp_path, BASE), ["model.initial={k_sigma: 1.95e8, b_sigma: 7.5, k_tau: 3.25e7, b_tau: 6.0}"]
    )
    assert cfg.model.initial == {"k_sigma": 1.95e8, "b_sigma": 7.5, "k_tau": 3.25e7, "b_tau": 6.0}


def test_later_override_wins():
    assert apply_overrides(BASE, ["sample.length=1", "sample.length=2"])["sample"]["length"] == 2


@pytest.mark.parametrize(
    "item, fragment",
    [
        ("sample.length", "expected dotted.key=value"),
        ("=3", "expected dotted.key=value"),
        ("sample..length=3", "expected dotted.key=value"),
        (".length=3", "expected dotted.key=value"),
        ("sample.length.unit=m", "'sample.length' is not a section"),
        ("title.x=1", "'title' is not a section"),
    ],
)
def test_bad_override_syntax(item, fragment):
    msg = config_error(apply_overrides, BASE, [item])
    assert msg.startswith(f"--set '{item}'")
    assert fragment in msg


def test_override_errors_are_validated_like_the_file(tmp_path):
    msg = config_error(load_config, write(tmp_path, BASE), ["sample.length=-5"])
    assert "sample.length: Input should be greater than 0 (got -5)" in msg
    msg = config_error(load_config, write(tmp_path, BASE), ["sample.lenght=5"])
    assert "did you mean 'length'" in msg


# ---------------------------------------------------------------------------------------
# Stage 2: each plugin's own options, and names that depend on the chosen model
# ---------------------------------------------------------------------------------------
def stage2(tmp_path, registry, overrides):
    path = write(tmp_path, BASE)
    return build_components(load_config(path, overrides), str(path), registry)


def test_stage_two_builds_the_plugins(tmp_path, registry):
    c = stage2(tmp_path, registry, [])
    assert c.model.n == 3
    assert c.excitation.options.n_samples == 800
    assert c.solver.options.strategy.n_starts == 1


@pytest.mark.parametrize(
    "override, fragment",
    [
        ("model.options.n_element=5", "model.options.n_element: unknown key; did you mean 'n_elements'?"),
        ("model.options.n_elements=0", "model.options.n_elements: Input should be greater than or equal to 1"),
        ("model.options.n_elements=many", "model.options.n_elements: Input should be a valid integer"),
        ("excitation.options.ordr=9", "excitation.options.ordr: unknown key; did you mean 'order'?"),
        ("excitation.options.order=25", "excitation.options.order: Input should be less than or equal to 20"),
        ("excitation.options.duration=1.0e-3", "excitation.options: give n_samples or duration, not both"),
        ("backend.options.sead=3", "backend.options.sead: unknown key; did you mean 'seed'?"),
        ("backend.options.noise.relative_sd=0.1", "backend.options.noise.relative_sd: unknown key"),
        ("solver.options.xtoll=1", "solver.options.xtoll: unknown key; did you mean 'xtol'?"),
        ("solver.options.strategy.n_start=3", "solver.options.strategy.n_start: unknown key; did you mean 'n_starts'?"),
        ("solver.options.jacobian=numeric", "solver.options.jacobian: Input should be"),
        ("compensator={name: none, options: {gain: 2}}", "compensator.options.gain: unknown key"),
        ("excitation.options=7", "excitation.options: "),
    ],
)
def test_plugin_option_errors_carry_the_section_prefix(tmp_path, registry, override, fragment):
    msg = config_error(stage2, tmp_path, registry, [override])
    assert fragment in msg, msg
    assert msg.startswith(str(tmp_path / "run.yaml") + ": ")


@pytest.mark.parametrize(
    "override, kind, suggestion",
    [
        ("model.name=kelvin_voight", "model", "kelvin_voigt"),
        ("excitation.name=prbss", "excitation", "prbs"),
        ("backend.name=simulate", "backend", "simulated"),
        ("solver.name=scipy-lm", "solver", "scipy_lm"),
        ("compensator.name=non", "compensator", "none"),
    ],
)
def test_unknown_plugin_name_lists_the_choices(tmp_path, registry, override, kind, suggestion):
    with pytest.raises(PluginError) as info:
        stage2(tmp_path, registry, [override])
    msg = str(info.value)
    assert f"{kind}.name: unknown {kind}" in msg
    assert f"did you mean '{suggestion}'?" in msg
    assert "choose one of: " in msg and suggestion in msg.split("choose one of: ")[1]
    assert "\n" not in msg


@pytest.mark.parametrize(
    "override, fragment",
    [
        (
            "model.initial={k_sigma: 1.0e8, b_sigma: 10.0, k_tau: 1.0e7, b_tua: 5.0}",
            "model.initial.b_tua: not a parameter or property of this model; did you mean 'b_tau'?",
        ),
        (
            "model.initial={E_sigma: 1.0e9, eta_sigma: 10.0, E_tau: 1.0e7, eta_tay: 5.0}",
            "model.initial.eta_tay: not a parameter or property of this model; did you mean 'eta_tau'?",
        ),
        ("model.initial={k_sigma: 1.0e8, b_sigma: 10.0}", "model.initial: give all of"),
        ("model.initial={k_sigma: 1.0e8, b_sigma: 10.0, E_tau: 1.0e7, eta_tau: 5.0}", "model.initial: give all of"),
        ("model.fixed={k_sigam: 1.0e8}", "model.fixed.k_sigam: not a parameter or property of this model"),
        ("model.fixed={E_tua: 1.0e8}", "model.fixed.E_tua: not a parameter or property of this model; did you "
                                       "mean 'E_tau'?"),
    ],
)
def test_unknown_parameter_names_in_initial_and_fixed(tmp_path, registry, override, fragment):
    """Checked before anything is acquired: no run folder is made."""
    out = tmp_path / "out"
    msg = config_error(execute, write(tmp_path, BASE), [override], out, registry=registry, plots=False)
    assert fragment in msg, msg
    assert not out.exists()


def test_fixed_suggests_the_parameter(tmp_path, registry):
    msg = config_error(stage2, tmp_path, registry, ["model.fixed={k_sigam: 1.0e8}"])
    assert "did you mean 'k_sigma'" in msg


@pytest.mark.parametrize(
    "override, fragment",
    [
        (
            "backend.options.truth={E_sigma: 2.0e9, eta_sigma: 200.0, E_tau: 3.0e8, eta_taux: 150.0}",
            "backend.options.truth.eta_taux: not a parameter or property of this model; did you mean 'eta_tau'?",
        ),
        (
            "backend.options.truth={k_sigma: 2.0e9, b_sigma: 200.0, k_tauu: 3.0e8, b_tau: 150.0}",
            "backend.options.truth.k_tauu",
        ),
        ("backend.options.truth={k_sigma: 2.0e9}", "backend.options.truth: give all of"),
    ],
)
def test_unknown_names_in_the_simulated_truth(tmp_path, registry, override, fragment):
    msg = config_error(execute, write(tmp_path, BASE), [override], tmp_path / "out", registry=registry, plots=False)
    assert fragment in msg, msg


def test_validate_options_without_options_uses_defaults():
    from mbus_plugins.models.kelvin_voigt import KelvinVoigtOptions

    assert validate_options(KelvinVoigtOptions, None, "model.options").n_elements == 10
    msg = config_error(validate_options, KelvinVoigtOptions, "ten", "model.options", "f.yaml")
    assert msg == "f.yaml: model.options: must be a mapping, not str"


def test_errors_are_mbus_errors_not_pydantic_errors(tmp_path):
    with pytest.raises(MbusError):
        load_config(write(tmp_path, variant(sample__length="x")))


def test_read_yaml_gives_each_caller_its_own_copy_of_the_current_file(tmp_path):
    """The parse is remembered by text (mbus-run reads its config several times), but a caller's
    changes never reach the next reader, and a changed file is read anew."""
    from mbus_framework.pipeline.config import read_yaml

    path = tmp_path / "c.yaml"
    path.write_text("model:\n  name: kelvin_voigt\n  options: {n_elements: 3}\n")
    first = read_yaml(path)
    first["model"]["options"]["n_elements"] = 99
    assert read_yaml(path) == {"model": {"name": "kelvin_voigt", "options": {"n_elements": 3}}}
    path.write_text("model:\n  name: maxwell\n")
    assert read_yaml(path) == {"model": {"name": "maxwell"}}
