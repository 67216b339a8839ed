"""Issue 29 polish: run files with the umask's mode, ``-o`` on every analysis command, a clear
message for options given to a plugin without any, and ``model:`` optional (kelvin_voigt)."""
from __future__ import annotations

import os
import stat

import pytest
import yaml

from fakes.campaign_tables import TABLE_4_2, grouped_table
from mbus_framework.analysis.cli import main as analyze
from mbus_framework.errors import ConfigError
from mbus_framework.pipeline.config import load_config
from mbus_framework.pipeline.run import build_components
from mbus_framework.pipeline.storage import atomic_write_json, atomic_write_text
from test_config import BASE


@pytest.mark.parametrize("mask", [0o022, 0o077, 0o002])
def test_atomic_writes_get_the_mode_the_umask_gives(tmp_path, mask):
    old = os.umask(mask)
    try:
        written = atomic_write_text(tmp_path / "a.txt", "x")
        plain = tmp_path / "b.txt"
        plain.write_text("x")
        atomic_write_json(tmp_path / "c.json", {"a": 1})
    finally:
        os.umask(old)
    expected = 0o666 & ~mask
    assert stat.S_IMODE(plain.stat().st_mode) == expected  # the reference: what open() gives
    assert stat.S_IMODE(written.stat().st_mode) == expected
    assert stat.S_IMODE((tmp_path / "c.json").stat().st_mode) == expected


def test_classify_takes_dash_o_like_crispness(tmp_path):
    table = tmp_path / "properties.csv"
    grouped_table(TABLE_4_2, 3, seed=1).to_csv(table, index=False)
    assert analyze(["classify", str(table), "--by", "material", "--no-plots", "-o", str(tmp_path / "c")]) == 0
    assert (tmp_path / "c" / "classification.json").is_file()


def test_options_for_a_plugin_without_options_name_the_section(tmp_path):
    path = tmp_path / "run.yaml"
    path.write_text(yaml.safe_dump({**BASE, "compensator": {"name": "none", "options": {"mode": "forward"}}}))
    with pytest.raises(ConfigError) as info:
        build_components(load_config(path), str(path))
    msg = str(info.value)
    assert msg.endswith("compensator.options.mode: unknown key; compensator.options takes no keys "
                        "(the chosen plugin has no options)"), msg
    assert "allowed:" not in msg


def test_model_is_optional_and_defaults_to_kelvin_voigt(tmp_path):
    from mbus_framework.api.fitting import fit

    data = {k: v for k, v in BASE.items() if k != "model"}
    path = tmp_path / "run.yaml"
    path.write_text(yaml.safe_dump(data))
    config = load_config(path)
    assert config.model.name == "kelvin_voigt" and config.model.options == {}
    import inspect

    assert inspect.signature(fit).parameters["model"].default == config.model.name  # the API's default
    components = build_components(config, str(path))
    assert type(components.model).__name__ == "KelvinVoigtChain"
    path.write_text(yaml.safe_dump({**data, "model": {"options": {"n_elements": 4}}}))
    assert load_config(path).model.name == "kelvin_voigt"
