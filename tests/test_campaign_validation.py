"""Campaign files and sample sheets: every problem is one line naming the file, row and column,
all reported before any fit starts; content keys change exactly when what a fit reads changes."""
from __future__ import annotations

import copy
import re
from pathlib import Path

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from campaign_helpers import BASE, draw_truths, simulate_record, write_campaign
from mbus_framework.campaigns import CampaignError, is_campaign_file, load_campaign, run_campaign
from mbus_framework.campaigns.plan import plan_campaign
from mbus_framework.cli import main

ROW = re.compile(r"samples\.csv: row (\d+), column ([\w.]+): ")


def problems_of(path, out):
    with pytest.raises(CampaignError) as info:
        run_campaign(path, out)
    for line in info.value.lines:
        assert "\n" not in line and "Traceback" not in line
    assert not (out / "runs").exists(), "nothing may run before the whole campaign is valid"
    return info.value.lines


def cells(lines):
    return {(int(m.group(1)), m.group(2)) for m in map(ROW.search, lines) if m}


def test_every_problem_of_a_sheet_is_reported_at_once(tmp_path):
    data = simulate_record(tmp_path / "rec" / "a.csv", draw_truths(1, 1)[0], seed=1)
    rows = [
        {"sample_id": "a", "replicate": 1, "cultivar": "x", "data": "rec/a.csv", "sample.length": ""},
        {"sample_id": "a", "replicate": 1, "cultivar": "x", "data": "", "sample.length": ""},  # duplicate
        {"sample_id": "b", "replicate": 1, "cultivar": "y", "data": "rec/missing.csv", "sample.length": ""},
        {"sample_id": "c", "replicate": "two", "cultivar": "y", "data": "", "sample.length": ""},
        {"sample_id": "d", "replicate": 1, "cultivar": "y", "data": "", "sample.length": "-0.02"},
        {"sample_id": "e", "replicate": 1, "cultivar": "", "data": "", "sample.length": ""},
    ]
    for r in rows:
        r["backend.options.noise.relative_std"] = "-1" if r["sample_id"] == "b" else ""
        r["firmnes"] = "1.0"
        r["sample.lenght"] = "0.1" if r["sample_id"] == "a" and r["data"] else ""
    path = write_campaign(tmp_path, rows, covariates=["firmness"])
    lines = problems_of(path, tmp_path / "out")
    assert data.exists()
    assert cells(lines) == {
        (2, "sample.lenght"),  # misspelt config key, read through the run config's own validation
        (3, "replicate"),      # (a, 1) again
        (4, "data"),           # file not found
        (5, "replicate"),      # not an integer
        (6, "sample.length"),  # rejected by the run config (must be > 0)
        (7, "cultivar"),       # empty group label
    }
    text = "\n".join(lines)
    assert "row 3, column replicate: sample 'a' replicate 1 is already on row 2" in text
    assert "did you mean 'length'" in text
    assert "column 'firmnes': unknown column; did you mean 'firmness'" in text
    assert "campaign.covariates: 'firmness' is not a column" in text


@settings(max_examples=15, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(["ok", "zero", "negative", "text", ""]),
                          st.sampled_from(["ok", "text", "negative", ""])), min_size=1, max_size=6))
def test_each_rejected_row_gets_one_line_naming_a_bad_column(tmp_path_factory, cells_spec):
    """Rows with bad cells (density <= 0 or not a number, noise std < 0 or not a number) get
    exactly one line, naming their row and one of their bad columns; good rows get none."""
    tmp = tmp_path_factory.mktemp("sheet")
    density = {"ok": "1050", "zero": "0", "negative": "-3", "text": "heavy", "": ""}
    noise = {"ok": "0.02", "text": "loud", "negative": "-0.1", "": ""}
    rows, bad = [], {}
    for i, (d, n) in enumerate(cells_spec):
        rows.append({"sample_id": f"s{i}", "cultivar": "x", "sample.density": density[d],
                     "backend.options.noise.relative_std": noise[n]})
        cols = {c for c, v in (("sample.density", d), ("backend.options.noise.relative_std", n)) if v not in ("ok", "")}
        if cols:
            bad[i + 2] = cols
    path = write_campaign(tmp, rows)
    if not bad:
        assert len(plan_campaign(load_campaign(path), tmp / "out")) == len(rows)
        return
    lines = problems_of(path, tmp / "out")
    named = [m for m in map(ROW.search, lines) if m]
    assert len(named) == len(lines) == len(bad)
    for m in named:
        assert m.group(2) in bad[int(m.group(1))]


def test_campaign_file_problems(tmp_path):
    path = write_campaign(tmp_path, [{"sample_id": "a", "cultivar": "x"}])
    doc = yaml.safe_load(path.read_text())
    doc["campaign"]["run"] = BASE
    doc["campaign"]["replicate"] = "fit"
    doc["extra"] = 1
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(CampaignError) as info:
        load_campaign(path)
    text = "\n".join(info.value.lines)
    assert "extra: unknown top-level key" in text
    assert "campaign.replicate: unknown key; did you mean 'replicates'" in text
    del doc["campaign"]["replicate"], doc["extra"]
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(CampaignError, match="exactly one of 'base'"):
        load_campaign(path)


def test_averaged_replicates_must_share_their_settings(tmp_path):
    rows = [
        {"sample_id": "a", "replicate": 1, "cultivar": "x", "sample.length": "0.03", "backend.options.seed": "1"},
        {"sample_id": "a", "replicate": 2, "cultivar": "y", "sample.length": "0.02", "backend.options.seed": "2"},
    ]
    lines = problems_of(write_campaign(tmp_path, rows), tmp_path / "out")
    assert cells(lines) == {(3, "cultivar"), (3, "sample.length")}
    # Fitted one by one, replicates may differ in anything but their group.
    lines = problems_of(write_campaign(tmp_path, rows, replicates="fit"), tmp_path / "out")
    assert cells(lines) == {(3, "cultivar")}


def test_an_invalid_campaign_exits_2_with_one_line_per_problem(tmp_path, capsys):
    rows = [{"sample_id": "a", "cultivar": "x", "sample.density": "-1"}, {"sample_id": "b", "cultivar": "x", "bogus": "1"}]
    path = write_campaign(tmp_path, rows)
    assert main([str(path), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("mbus-run: error: ") for line in err)
    assert "Traceback" not in "".join(err) and not (tmp_path / "out").exists()


def test_campaign_files_are_recognised_by_their_campaign_key(tmp_path):
    path = write_campaign(tmp_path, [{"sample_id": "a", "cultivar": "x"}])
    assert is_campaign_file(path)
    assert not is_campaign_file(tmp_path / "base.yaml")
    assert not is_campaign_file(tmp_path / "samples.csv")


def test_content_keys_change_exactly_with_what_a_fit_reads(tmp_path):
    truths = draw_truths(3, 5)
    for i, t in enumerate(truths):
        simulate_record(tmp_path / "rec" / f"s{i}.csv", t, seed=i)
    rows = [{"sample_id": f"s{i}", "cultivar": "x", "data": f"rec/s{i}.csv", "sample.length": "0.03"} for i in range(3)]
    path = write_campaign(tmp_path, rows)

    def keys():
        return {t.label: t.key for t in plan_campaign(load_campaign(path), tmp_path / "out")}

    before = keys()
    assert len(set(before.values())) == 3 and keys() == before
    # output.plots does not change a fit
    base = copy.deepcopy(BASE)
    base["output"]["plots"] = True
    write_campaign(tmp_path, rows, base=base)
    assert keys() == before
    # one override cell
    rows[1]["sample.length"] = "0.031"
    write_campaign(tmp_path, rows, base=base)
    after = keys()
    assert [k for k in after if after[k] != before[k]] == ["s1"]
    # one byte of one data file
    raw = bytearray((tmp_path / "rec" / "s2.csv").read_bytes())
    raw[-3] = ord("7") if raw[-3] != ord("7") else ord("8")
    (tmp_path / "rec" / "s2.csv").write_bytes(bytes(raw))
    last = keys()
    assert [k for k in last if last[k] != after[k]] == ["s2"]
    # the base config reaches every sample
    base["solver"]["options"]["strategy"]["n_starts"] = 3
    write_campaign(tmp_path, rows, base=base)
    assert all(keys()[k] != last[k] for k in last)


def test_inline_samples_and_mapping_cells(tmp_path):
    t = draw_truths(2, 9)
    path = write_campaign(tmp_path, [{"sample_id": "a", "cultivar": "x"}])
    doc = yaml.safe_load(path.read_text())
    doc["campaign"]["samples"] = [
        {"sample_id": "a", "cultivar": "x", "backend.options.truth": t[0], "sample.density": 1050},
        {"sample_id": 7, "cultivar": "y", "backend.options.truth": t[1]},
    ]
    path.write_text(yaml.safe_dump(doc))
    tasks = plan_campaign(load_campaign(path), tmp_path / "out")
    assert [x.sample_id for x in tasks] == ["a", "7"]
    assert tasks[0].configs[0]["backend"]["options"]["truth"] == pytest.approx(t[0])
    assert tasks[0].sample["density"] == 1050 and tasks[1].sample["density"] == BASE["sample"]["density"]


def test_options_that_do_not_apply_to_a_campaign(tmp_path, capsys):
    path = write_campaign(tmp_path, [{"sample_id": "a", "cultivar": "x"}])
    assert main([str(path), "--study", "monte_carlo"]) == 2
    assert capsys.readouterr().err.strip() == (
        f"mbus-run: error: {path}: --study runs on a run config, not on a campaign file")


def test_a_study_from_the_command_line_goes_to_the_dask_scheduler_given(tmp_path, capsys, monkeypatch):
    """--study runs through the campaigns' executor: an unreachable --scheduler is a one-line error."""
    import socket

    from mbus_framework.campaigns import executor

    monkeypatch.setattr(executor, "CONNECT_TIMEOUT_S", 1)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        address = f"tcp://127.0.0.1:{s.getsockname()[1]}"
    study = Path(__file__).parent / "data" / "studies_small.yaml"
    code = main([str(study), "--study", "monte_carlo", "--study-option", "n_runs=2", "--scheduler", address,
                 "-o", str(tmp_path / "mc")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err == [f"mbus-run: error: cannot connect to the Dask scheduler at {address}: "
                                 + err[0].split(f"{address}: ", 1)[1]]
