"""Campaign replicates fitted jointly (issue 25): ``campaign.replicates: joint | auto``, the
automatic choice, one row per sample with the joint estimate and replicates.csv beside it."""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import yaml

from campaign_helpers import draw_truths, truth_columns, write_campaign
from mbus_framework.campaigns import run_campaign
from mbus_framework.campaigns.executor import dask_client
from mbus_framework.campaigns.plan import plan_campaign
from mbus_framework.campaigns.problems import CampaignError
from mbus_framework.campaigns.replicate_choice import GAIN_TOLERANCE, choose, lag
from mbus_framework.campaigns.runner import summary_text
from mbus_framework.campaigns.spec import load_campaign
from mbus_framework.interfaces.backend import Measurement

PROPS = ["E_sigma", "eta_sigma", "E_tau", "eta_tau"]
DT = 4e-8


@pytest.fixture(scope="module")
def client():
    with dask_client(workers=1) as c:
        yield c


def rig_rows(truths, rigs):
    """Sheet rows: sample "a", "b", ... each with one replicate per (gain, delay in samples)."""
    rows = []
    for i, truth in enumerate(truths):
        for r, (gain, delay) in enumerate(rigs, start=1):
            rows.append({"sample_id": "ab"[i], "replicate": r, "backend.options.seed": 40 + 10 * i + r,
                         "backend.options.input_gain": gain, "backend.options.delay": delay * DT,
                         **truth_columns(truth)})
    return rows


# --- the option ----------------------------------------------------------------------------

@pytest.mark.parametrize("value", ["jointly", "", 3])
def test_an_unknown_replicates_option_is_a_one_line_error(tmp_path, value):
    path = write_campaign(tmp_path, rig_rows(draw_truths(1, 1), [(1, 0)]), groups=())
    data = yaml.safe_load(path.read_text())
    data["campaign"]["replicates"] = value
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(CampaignError) as err:
        load_campaign(path)
    message = str(err.value)
    assert len(message.strip().splitlines()) == 1
    assert "campaign.replicates" in message and str(path) in message


def test_the_default_is_auto(tmp_path):
    path = write_campaign(tmp_path, rig_rows(draw_truths(1, 1), [(1, 0)]), groups=())
    data = yaml.safe_load(path.read_text())
    del data["campaign"]["replicates"]
    path.write_text(yaml.safe_dump(data))
    assert load_campaign(path).spec.replicates == "auto"


def test_joint_replicates_may_differ_in_length_but_averaged_ones_may_not(tmp_path):
    rows = rig_rows(draw_truths(1, 2), [(1, 0), (1, 0)])
    rows[1]["sample.length"] = 0.02
    for mode in ("joint", "average", "auto"):
        path = write_campaign(tmp_path / mode, rows, groups=(), replicates=mode)
        if mode == "joint":
            tasks = plan_campaign(load_campaign(path), tmp_path / "out")
            assert len(tasks) == 1 and tasks[0].replicates == "joint" and len(tasks[0].configs) == 2
        else:
            with pytest.raises(CampaignError, match=f"campaign.replicates: {mode}.*must share every setting"):
                plan_campaign(load_campaign(path), tmp_path / "out")


# --- the automatic choice on records made here -----------------------------------------------

def _records(gains, delays, seed=0, n=1500):
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.choice([-1.0, 1.0], n // 10 + 1), 10)[:n]
    kernel = np.exp(-np.arange(60) / 12.0) * np.sin(np.arange(60) / 4.0)  # a damped echo
    y0 = np.convolve(u, kernel)[:n]
    out = []
    for g, d in zip(gains, delays):
        y = g * np.concatenate([np.zeros(d), y0[: n - d]])
        y = y + 0.03 * np.std(y0) * rng.standard_normal(n)
        out.append(Measurement(np.arange(n) * DT, u.copy(), y))
    return out


def test_records_of_different_length_are_fitted_jointly():
    a, b = _records([1.0, 1.0], [0, 0])
    short = Measurement(b.t[:1000], b.u[:1000], b.y[:1000])
    choice = choose([a, short])
    assert choice.mode == "joint" and "differ in length" in choice.reason
    assert choose([a, b]).mode == "average"


def test_lag_finds_a_known_shift():
    rng = np.random.default_rng(3)
    a = rng.standard_normal(500)
    assert lag(a, np.concatenate([np.zeros(7), a[:-7]])) == 7
    assert lag(np.concatenate([np.zeros(7), a[:-7]]), a) == -7


@pytest.mark.parametrize("gains, delays, mode", [
    ([1.0, 1.0, 1.0], [0, 0, 0], "average"),
    ([1.0, 1.0 + GAIN_TOLERANCE / 2, 1.0], [0, 0, 1], "average"),  # within the tolerances
    ([0.5, 1.0, 2.0], [0, 0, 0], "joint"),
    ([1.0, 1.0, 1.0], [0, 4, 9], "joint"),
    ([1.0, 1.5], [0, 0], "joint"),
])
def test_choose_joint_only_when_gain_or_delay_differ(gains, delays, mode):
    choice = choose(_records(gains, delays))
    assert choice.mode == mode, choice.reason
    assert choice.reason.startswith(f"auto: {mode}")
    assert choice.gain_ratio == pytest.approx(max(gains) / min(gains), rel=0.03)
    assert choice.max_lag == pytest.approx(max(delays), abs=1)


# --- small campaigns on a LocalCluster ---------------------------------------------------------

@pytest.fixture(scope="module")
def differing(tmp_path_factory, client):
    folder = tmp_path_factory.mktemp("differing")
    truths = draw_truths(2, seed=5)
    path = write_campaign(folder, rig_rows(truths, [(0.6, 0), (1.7, 6)]), groups=(), replicates="auto")
    return run_campaign(path, folder / "out", client=client, progress=False), dict(zip("ab", truths))


def test_auto_fits_replicates_of_differing_gain_jointly_one_row_per_sample(differing):
    result, truths = differing
    table = result.table
    assert list(table["sample_id"]) == ["a", "b"]
    assert list(table["replicates"]) == ["joint", "joint"] and list(table["n_replicates"]) == [2, 2]
    assert table["replicates_reason"].str.startswith("auto: joint, gains differ").all()
    assert table["error"].isna().all()
    for _, row in table.iterrows():
        doc = json.loads((result.out_dir / row["run_dir"] / "result.json").read_text())
        assert doc["kind"] == "joint" and doc["per_record"] == ["input_gain", "delay"]
        assert 0.0 < row["agreement_p_value"] <= 1.0
        assert row["agreement_p_value"] == pytest.approx(doc["agreement"]["p_value"])
        for p in PROPS:  # the joint estimate, within 4 joint SE of the sample's truth
            assert row[p] == pytest.approx(doc["properties"][p])
            assert abs(row[p] - truths[row["sample_id"]][p]) <= 4 * row[f"{p}_se"], (row["sample_id"], p)
            assert row[f"true_{p}"] == pytest.approx(truths[row["sample_id"]][p])
    on_disk = pd.read_csv(result.out_dir / "properties.csv")
    assert len(on_disk) == 2 and list(on_disk["replicates"]) == ["joint", "joint"]
    meta = json.loads((result.out_dir / "campaign.json").read_text())
    assert meta["replicates"] == "auto" and meta["replicates_chosen"]["a"].startswith("joint (auto: joint")
    assert "2 sample(s) fitted jointly" in summary_text(result)


def test_replicates_csv_holds_each_replicates_gain_delay_and_own_fit(differing):
    result, truths = differing
    reps = pd.read_csv(result.out_dir / "replicates.csv")
    assert list(reps["sample_id"]) == ["a", "a", "b", "b"] and list(reps["replicate"]) == ["r1", "r2"] * 2
    for _, r in reps.iterrows():
        assert abs(r["joint_input_gain"] - r["true_input_gain"]) <= 4 * r["joint_input_gain_se"]
        assert abs(r["joint_delay"] - r["true_delay"]) <= max(4 * r["joint_delay_se"], 0.5 * DT)
        for p in PROPS:  # the replicate's own fit: near its sample's truth, less precise than the joint fit
            assert abs(r[p] - truths[r["sample_id"]][p]) <= 4 * r[f"{p}_se"]
    assert list(reps["true_input_gain"]) == [0.6, 1.7, 0.6, 1.7]
    table = result.table.set_index("sample_id")
    for p in PROPS:
        for s in "ab":
            assert table.loc[s, f"{p}_se"] < reps.loc[reps["sample_id"] == s, f"{p}_se"].min()


def test_auto_averages_replicates_of_one_gain_and_delay(tmp_path, client):
    truths = draw_truths(2, seed=9)
    path = write_campaign(tmp_path, rig_rows(truths, [(1.0, 0), (1.0, 0)]), groups=(), replicates="auto")
    result = run_campaign(path, tmp_path / "out", client=client, progress=False)
    table = result.table
    assert list(table["replicates"]) == ["averaged", "averaged"]
    assert table["replicates_reason"].str.startswith("auto: average").all()
    assert table["agreement_p_value"].isna().all()
    for _, row in table.iterrows():  # the averaged record of one rig fits the truth
        truth = truths["ab".index(row["sample_id"])]
        assert all(abs(row[p] - truth[p]) <= 4 * row[f"{p}_se"] for p in PROPS), row["sample_id"]
    assert not (result.out_dir / "replicates.csv").exists()
    doc = json.loads((result.out_dir / "runs" / "a" / "result.json").read_text())
    assert doc["replicates"]["averaged"] == ["r1", "r2"] and doc["replicates"]["mode"] == "averaged"
    assert "0 sample(s) fitted jointly" in summary_text(result) and "2 averaged" in summary_text(result)


def test_joint_fits_two_thicknesses_of_one_sample(tmp_path, client):
    """``replicates: joint`` on replicates of equal gain: still joint (no choice), each its own length."""
    truth = draw_truths(1, seed=12)[0]
    rows = rig_rows([truth], [(1.0, 0), (1.0, 0)])
    rows[0]["sample.length"], rows[1]["sample.length"] = 0.02, 0.03
    path = write_campaign(tmp_path, rows, groups=(), replicates="joint")
    result = run_campaign(path, tmp_path / "out", client=client, progress=False)
    row = result.table.iloc[0]
    assert row["replicates"] == "joint" and row["replicates_reason"] == "campaign.replicates: joint"
    for p in PROPS:
        assert abs(row[p] - truth[p]) <= 4 * row[f"{p}_se"], p
    reps = pd.read_csv(result.out_dir / "replicates.csv")
    assert list(reps["sample_length"]) == [0.02, 0.03]
    assert "a: joint (campaign.replicates: joint)" in summary_text(result)
