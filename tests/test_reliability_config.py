"""Issue 15, bad configs: every value the issue found crashing or hanging ``mbus-run`` is now a
one-line error naming the key (or the file) with the reason, before anything is written."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from mbus_framework.pipeline import yaml_loader
from reliability_support import SMALL, assert_clean_outcome, config, run_cli, strict_json, tree, write_yaml

CASES = {
    # --set override: (key named in the error, fragment of the reason)
    "excitation.options.amplitude=.inf": ("excitation.options.amplitude", "finite"),
    "excitation.options.amplitude=1e300": ("excitation.options.amplitude", "no ultrasonic rig"),
    "backend.options.truth.k_sigma=.nan": ("backend.options.truth.k_sigma", "finite"),
    "backend.options.truth.k_sigma=-3.0e8": ("backend.options.truth.k_sigma", "physical range"),
    "excitation.options.sample_rate=.inf": ("excitation.options.sample_rate", "finite"),
    "excitation.options.sample_rate=1e300": ("excitation.options.sample_rate", "100 GS/s"),
    "excitation.options={order: 5, sample_rate: 2.0e6, duration: 1e300}": ("excitation.options", "samples long"),
    "backend.options.delay=.inf": ("backend.options.delay", "finite"),
    "backend.options.delay=10.0": ("backend.options.delay", "after its end"),
    "calibration={lengths: [0, .inf]}": ("calibration.lengths[1]", "finite"),
    "model.fixed={k_sigma: .nan}": ("model.fixed.k_sigma", "finite"),
    "model.fixed={k_sigma: -1}": ("model.fixed.k_sigma", "physical range"),
    "model.initial={k_sigma: .nan, b_sigma: 1, k_tau: 1.0e7, b_tau: 1}": ("model.initial.k_sigma", "finite"),
    "model.initial={k_sigma: 0, b_sigma: 1, k_tau: 1.0e7, b_tau: 1}": ("model.initial.k_sigma", "physical range"),
    "sample.length=5e-324": ("sample.length", "thinner than 1 um"),
    "sample.length=.inf": ("sample.length", "finite"),
    "sample.diameter=1e300": ("sample.diameter", "outside"),
    "sample.density=1e400": ("sample.density", "finite"),
    "excitation.options.n_samples=2000000000": ("excitation.options.n_samples", "less than or equal"),
    "excitation.options.n_samples=90000000": ("excitation.options", "GiB"),
    "solver.options.strategy.n_starts=1000000000": ("solver.options.strategy.n_starts", "hours"),
    "solver.options.strategy.time_scale_points=1000000000": ("solver.options.strategy.time_scale_points", "more than"),
    "backend.options.seed=-1": ("backend.options.seed", "greater than or equal to 0"),
    "solver.options.strategy.seed=-1": ("solver.options.strategy.seed", "non-negative"),
    "sample.length=!!float abc": ("sample.length", "does not convert"),
    "model.options.n_elements=400": ("model.options.n_elements", "would take hours"),
    "nuisance.max_delay=1.0e10": ("nuisance.max_delay", "not shorter than the record"),
    "nuisance.input_gain={value: 0, estimate: true}": ("nuisance.input_gain.value", "> 0"),
    "excitation.options.amplitude='inf'": ("excitation.options.amplitude", "no ultrasonic rig"),
    "solver.options.xtol=1e-300": ("solver.options.xtol", "machine epsilon"),
}
FOUND_WITH_THE_RECORD = {  # need the record the backend delivers (or the truth it simulates)
    "backend.options.delay=10.0", "backend.options.truth.k_sigma=-3.0e8", "nuisance.max_delay=1.0e10"}


@pytest.mark.parametrize("override", sorted(CASES))
def test_bad_value_is_one_line_naming_the_key_and_nothing_is_written(tmp_path, override):
    key, reason = CASES[override]
    path = write_yaml(tmp_path / "small.yaml", config())
    before = tree(tmp_path)
    o = run_cli([path, "-o", tmp_path / "out", "--set", override], timeout=60)
    assert o.code == 2, (o.code, o.err)
    assert_clean_outcome(o, [key])
    assert reason in o.err, o.err
    assert str(path) in o.err or "--set" in o.err
    if override in FOUND_WITH_THE_RECORD:  # the run folder exists and says why it failed
        status = strict_json(tmp_path / "out" / "status.json")
        assert status["status"] == "failed" and key in status["error"]
        assert not (tmp_path / "out" / "measurement.csv").exists()
    else:
        assert tree(tmp_path) == before  # rejected before the run folder exists


def test_unknown_ipopt_option_is_one_line(tmp_path):
    pytest.importorskip("casadi")
    path = write_yaml(tmp_path / "small.yaml", config(solver={
        "name": "casadi_collocation", "options": {"ipopt": {"no_such_ipopt_option": 3}, "global_search": False}}))
    o = run_cli([path, "-o", tmp_path / "out"], timeout=120)
    assert o.code == 2
    assert_clean_outcome(o, ["solver casadi_collocation"])
    assert "no_such_ipopt_option" in o.err


@pytest.mark.parametrize("depth", [1000, 65])
def test_deep_nesting_is_refused_without_recursion_error(tmp_path, depth):
    text = yaml_dump_small() + "design: " + "[" * depth + "]" * depth + "\n"
    path = tmp_path / "deep.yaml"
    path.write_text(text)
    o = run_cli([path, "-o", tmp_path / "out"], timeout=30)
    assert_clean_outcome(o, [str(path)])
    assert o.code == 2 and "nested deeper than 64 levels" in o.err


def test_alias_bomb_is_refused_fast_and_writes_nothing(tmp_path):
    lines = ['a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for k in range(1, 9):
        lines.append(f"a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * 9) + "]")
    text = yaml_dump_small() + "design:\n" + "\n".join("  " + ln for ln in lines) + "\n"
    assert len(text.encode()) < 2000  # 9^9 = 387 million strings when expanded
    path = tmp_path / "bomb.yaml"
    path.write_text(text)
    o = run_cli([path, "-o", tmp_path / "out"], timeout=30)
    assert_clean_outcome(o, [str(path)])
    assert "expands to" in o.err and "through aliases" in o.err
    assert not (tmp_path / "out").exists()


def test_recursive_alias_is_refused():
    with pytest.raises(yaml_loader.LimitError, match="recursive alias"):
        yaml_loader.yaml_load("a: &x [1, *x]\n")


def test_shared_aliases_within_bounds_still_load():
    data = yaml_loader.yaml_load("base: &b {k: 1}\nx: *b\ny: *b\nz: {<<: *b, j: 2}\n")
    assert data == {"base": {"k": 1}, "x": {"k": 1}, "y": {"k": 1}, "z": {"k": 1, "j": 2}}


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="POSIX FIFOs")
def test_fifo_as_config_fails_at_once(tmp_path):
    fifo = tmp_path / "config.yaml"
    os.mkfifo(fifo)
    o = run_cli([fifo, "-o", tmp_path / "out"], timeout=10)
    assert_clean_outcome(o, [str(fifo)])
    assert o.code == 2 and "a FIFO, not a regular file" in o.err


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="needs /dev/zero")
def test_dev_zero_as_config_fails_at_once(tmp_path):
    link = tmp_path / "zero.yaml"
    link.symlink_to("/dev/zero")
    for path in (Path("/dev/zero"), link):
        o = run_cli([path, "-o", tmp_path / "out"], timeout=10)
        assert_clean_outcome(o, [str(path)])
        assert o.code == 2 and "a device, not a regular file" in o.err


def test_symlink_loop_and_folder_as_config(tmp_path):
    loop = tmp_path / "loop.yaml"
    loop.symlink_to(tmp_path / "loop2.yaml")
    (tmp_path / "loop2.yaml").symlink_to(loop)
    for path, fragment in ((loop, "cannot open config file"), (tmp_path, "a folder, not a regular file")):
        o = run_cli([path, "-o", tmp_path / "out"], timeout=10)
        assert_clean_outcome(o, [str(path)])
        assert o.code == 2 and fragment in o.err


def test_oversized_config_is_refused_before_parsing(tmp_path):
    path = tmp_path / "big.yaml"
    path.write_text(yaml_dump_small() + "# " + "x" * (yaml_loader.MAX_CONFIG_BYTES + 10) + "\n")
    o = run_cli([path, "-o", tmp_path / "out"], timeout=10)
    assert_clean_outcome(o, [str(path)])
    assert "MiB limit" in o.err


@pytest.mark.parametrize("encoding", ["utf-16", "utf-8-sig"])
def test_config_with_a_byte_order_mark_is_read(tmp_path, encoding):
    path = tmp_path / "bom.yaml"
    path.write_bytes(yaml_dump_small().encode(encoding))
    o = run_cli([path, "-o", tmp_path / "out", "-q"], timeout=60)
    assert o.code == 0, o.err


def test_latin1_config_is_a_one_line_error(tmp_path):
    path = tmp_path / "latin1.yaml"
    path.write_bytes(("title: Kartoffelstärke\n" + yaml_dump_small()).encode("latin-1"))
    o = run_cli([path, "-o", tmp_path / "out"], timeout=10)
    assert_clean_outcome(o, [str(path)])
    assert "not UTF-8 text" in o.err


def test_long_and_multiline_names_give_short_single_lines(tmp_path):
    path = write_yaml(tmp_path / "small.yaml", config())
    for override in ("model.name=" + "x" * 100_000, 'model.name="kelvin\\nvoigt"', "x" * 100_000 + "=1",
                     "sample." + "y" * 100_000 + "=1"):
        o = run_cli([path, "-o", tmp_path / "out", "--set", override], timeout=30)
        assert o.code == 2
        assert_clean_outcome(o, ["model.name", "--set", "sample.", "unknown key"])
        assert len(o.err) < 1100


def yaml_dump_small() -> str:
    import yaml

    return yaml.safe_dump(SMALL, sort_keys=False)
