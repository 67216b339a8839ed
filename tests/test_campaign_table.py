"""The campaign table, its group summary and the replicate arithmetic, against pandas/numpy
computed independently; the Chapter 4 sheets against Tables 4.2/4.3."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mbus_framework.campaigns.plan import plan_campaign
from mbus_framework.campaigns.replicates import aggregate_replicates, average_records
from mbus_framework.campaigns.report import group_report
from mbus_framework.campaigns.spec import load_campaign
from mbus_framework.campaigns.table import build_table, parameter_names, property_names, write_table
from mbus_framework.errors import DataError
from mbus_framework.interfaces.backend import Measurement

ROOT = Path(__file__).resolve().parents[1]
CAMPAIGNS = ROOT / "configs" / "campaigns"
DISSERTATION = Path("/work/shared/reference/mbus-dissertation.md")
PROPS = ["E_sigma", "eta_sigma", "E_tau", "eta_tau"]
PARAMS = ["k_sigma", "b_sigma", "k_tau", "b_tau"]


def fake_rows(values: list[list[float]], groups: list[str], failed: set[int] = frozenset()) -> list[dict]:
    rows = []
    for i, (v, g) in enumerate(zip(values, groups)):
        row = {"sample_id": f"s{i}", "material": g, "replicate": None, "replicates": "averaged", "n_replicates": 1,
               "sample_density": 1000.0}
        row.update({p: float("nan") if i in failed else x for p, x in zip(PARAMS, v)})
        row.update({f"{p}_se": 0.01 * x for p, x in zip(PARAMS, v)})
        row.update({p: float("nan") if i in failed else 2 * x for p, x in zip(PROPS, v)})
        row.update({f"{p}_se": 0.02 * x for p, x in zip(PROPS, v)})
        row.update({f"{p}_ci_low": 1.9 * x for p, x in zip(PROPS, v)})
        row.update({f"{p}_ci_high": 2.1 * x for p, x in zip(PROPS, v)})
        row.update(nrmse=0.03, success=i not in failed, warnings=None, error="bad file" if i in failed else None)
        row.update({f"true_{p}": 2 * x for p, x in zip(PROPS, v)})
        row.update(firmness=str(i) if i % 2 else f"{i}.5", run_dir=f"runs/s{i}", fit_time_s=0.1)
        rows.append(row)
    return rows


positive = st.floats(min_value=1e-3, max_value=1e12, allow_nan=False, allow_infinity=False)


@settings(max_examples=20, deadline=None)
@given(st.lists(st.tuples(st.lists(positive, min_size=4, max_size=4), st.sampled_from(["water", "milk", "syrup"])),
                min_size=1, max_size=12), st.sets(st.integers(0, 11), max_size=3))
def test_group_summary_matches_pandas(data, failed):
    values, groups = [d[0] for d in data], [d[1] for d in data]
    df = build_table(fake_rows(values, groups, failed), ["material"], ["firmness"])
    report = group_report(df, ["material"])
    ok = df[df["error"].isna()]
    expected = ok.groupby("material", sort=False)[PROPS].agg(["mean", "std", "count"])
    summary = report.summary.set_index("material")
    assert list(summary.index) == list(dict.fromkeys(groups))
    for g in summary.index:
        n_failed = int(((df["material"] == g) & df["error"].notna()).sum())
        assert summary.loc[g, "n_failed"] == n_failed
        if g not in expected.index:
            assert summary.loc[g, "n"] == 0
            continue
        assert summary.loc[g, "n"] == expected.loc[g, ("E_sigma", "count")]
        for p in PROPS:
            mean, sd = expected.loc[g, (p, "mean")], expected.loc[g, (p, "std")]
            assert summary.loc[g, f"{p}_mean"] == pytest.approx(mean, rel=1e-12)
            assert summary.loc[g, f"{p}_true_mean"] == pytest.approx(mean, rel=1e-12)
            assert summary.loc[g, f"{p}_error_percent"] == pytest.approx(0.0, abs=1e-9)
            if np.isnan(sd):
                assert np.isnan(summary.loc[g, f"{p}_sd_percent"])
            else:
                assert summary.loc[g, f"{p}_sd_percent"] == pytest.approx(100 * sd / mean, rel=1e-9, abs=1e-12)
    assert all(g in report.text for g in summary.index)


def test_table_dtypes_and_round_trip(tmp_path):
    rng = np.random.default_rng(3)
    rows = fake_rows(rng.uniform(1, 10, (5, 4)).tolist(), ["a", "b", "a", "b", "a"], failed={3})
    rows[1]["replicate"] = 2
    df = build_table(rows, ["material"], ["firmness"])
    assert str(df["sample_id"].dtype) == "string" and str(df["material"].dtype) == "string"
    assert str(df["replicate"].dtype) == "Int64" and df["replicate"].isna().sum() == 4
    assert df["n_replicates"].dtype == np.int64 and df["success"].dtype == bool
    assert df["firmness"].dtype == np.float64  # every value is a number
    for col in PROPS + PARAMS + [f"{p}_ci_low" for p in PROPS] + ["nrmse", "true_E_sigma", "fit_time_s"]:
        assert df[col].dtype == np.float64, col
    assert df["error"].notna().tolist() == [False, False, False, True, False]
    assert property_names(df) == PROPS and parameter_names(df) == PARAMS
    files = write_table(df, tmp_path)
    back = pd.read_parquet(files["properties_parquet"])
    pd.testing.assert_frame_equal(back, df, check_dtype=False)
    assert [str(back[c].dtype) for c in ("replicate", "n_replicates", "success", "E_sigma")] == [
        "Int64", "int64", "bool", "float64"]
    csv = pd.read_csv(files["properties_csv"])
    assert list(csv.columns) == list(df.columns)
    np.testing.assert_array_equal(csv[PROPS].to_numpy(), df[PROPS].to_numpy())  # full precision


def test_text_covariates_stay_text():
    rows = fake_rows([[1, 2, 3, 4]] * 3, ["a", "a", "b"])
    rows[2]["firmness"] = "soft"
    df = build_table(rows, ["material"], ["firmness"])
    assert df["firmness"].tolist() == ["0.5", "1", "soft"]


def test_fitted_replicates_aggregate_like_pandas():
    rng = np.random.default_rng(11)
    values = rng.uniform(1, 5, (7, 4)).tolist()
    rows = fake_rows(values, ["a"] * 3 + ["b"] * 4, failed={5})
    for r, sid in zip(rows, ["x", "x", "x", "y", "y", "y", "y"]):
        r["sample_id"] = sid
    df = build_table(rows, ["material"], [])
    agg = aggregate_replicates(df, ["sample_id", "material"], PROPS).set_index("sample_id")
    ok = df[df["error"].isna()]
    for sid, part in ok.groupby("sample_id"):
        assert agg.loc[sid, "n_fitted"] == len(part)
        for p in PROPS:
            assert agg.loc[sid, p] == pytest.approx(part[p].mean(), rel=1e-12)
            assert agg.loc[sid, f"{p}_sd"] == pytest.approx(part[p].std(ddof=1), rel=1e-12)
            assert agg.loc[sid, f"{p}_sem"] == pytest.approx(part[p].std(ddof=1) / np.sqrt(len(part)), rel=1e-12)
    assert agg.loc["y", "n_replicates"] == 4 and agg.loc["y", "n_fitted"] == 3


def test_average_records_is_the_samplewise_mean():
    rng = np.random.default_rng(2)
    t = np.arange(50) * 4e-8
    recs = [Measurement(t + 1e-6, rng.normal(size=50), rng.normal(size=50), truth={"k": 1.0}) for _ in range(3)]
    mean = average_records(recs, ["r1", "r2", "r3"], "s")
    np.testing.assert_allclose(mean.u, np.mean([r.u for r in recs], axis=0), rtol=0, atol=1e-15)
    np.testing.assert_allclose(mean.y, np.mean([r.y for r in recs], axis=0), rtol=0, atol=1e-15)
    assert mean.t[0] == 0.0 and mean.truth == {"k": 1.0}
    recs[2].truth = {"k": 2.0}
    assert average_records(recs, ["r1", "r2", "r3"], "s").truth is None
    short = Measurement(t[:40], recs[0].u[:40], recs[0].y[:40])
    with pytest.raises(DataError, match="s: replicate r2 has 40 samples but r1 has 50"):
        average_records([recs[0], short], ["r1", "r2"], "s")
    slow = Measurement(2 * t, recs[0].u, recs[0].y)
    with pytest.raises(DataError, match="time step"):
        average_records([recs[0], slow], ["r1", "r2"], "s")


def test_report_plots_every_property(tmp_path):
    rows = fake_rows(np.random.default_rng(4).uniform(1, 3, (6, 4)).tolist(), ["a", "b", "c"] * 2, failed={1})
    report = group_report(build_table(rows, ["material"], []), ["material"], tmp_path, title="t")
    assert sorted(report.plots) == sorted(PROPS)
    for path in report.plots.values():
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert pd.read_csv(report.files["group_summary_csv"])["n"].tolist() == [2, 1, 2]


# -- the shipped Chapter 4 campaigns -----------------------------------------------------
@pytest.mark.parametrize("name, n, group, table", [("liquids", 25, "material", "TABLE_4_2"),
                                                   ("tissues", 15, "tissue", "TABLE_4_3")])
def test_chapter4_sheets_carry_the_tables(tmp_path, name, n, group, table):
    """The sheets are the generator's output, and each medium's truths have the table's mean and SD %."""
    subprocess.run([sys.executable, str(CAMPAIGNS / "generate_chapter4.py"), "--out", str(tmp_path)], check=True,
                   capture_output=True)
    assert (tmp_path / f"{name}_samples.csv").read_bytes() == (CAMPAIGNS / f"{name}_samples.csv").read_bytes()
    sys.path.insert(0, str(CAMPAIGNS))
    try:
        import generate_chapter4 as gen
    finally:
        sys.path.remove(str(CAMPAIGNS))
    sheet = pd.read_csv(CAMPAIGNS / f"{name}_samples.csv")
    for sample_id, _label, density, *stats in getattr(gen, table):
        part = sheet[sheet[group] == sample_id]
        assert (part["sample.density"] == density).all()
        for p, (mean, sd), scale in zip(PROPS, stats, (1e12, 1e5, 1e12, 1e5)):
            v = part[f"backend.options.truth.{p}"]
            assert v.mean() == pytest.approx(mean * scale, rel=1e-12)
            assert 100 * v.std(ddof=1) / v.mean() == pytest.approx(sd, rel=1e-9)
    assert sheet["backend.options.seed"].is_unique
    tasks = plan_campaign(load_campaign(CAMPAIGNS / f"{name}.yaml"), tmp_path / "out")
    assert len(tasks) == n and all(t.replicates == "fitted" for t in tasks)


@pytest.mark.skipif(not DISSERTATION.exists(), reason="the dissertation's Markdown is not on this machine")
def test_chapter4_tables_are_transcribed_from_the_dissertation():
    out = subprocess.run([sys.executable, str(CAMPAIGNS / "generate_chapter4.py"), "--check", str(DISSERTATION)],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stdout


def test_progress_bar_counts_done_failed_and_remaining(capsys):
    from mbus_framework.campaigns.progress import CampaignProgress

    with CampaignProgress(3, "liquids", enabled=True) as bar:
        bar.finished(failed=False)
        bar.finished(failed=True)
        task = bar._bar.tasks[0]
        assert (task.completed, task.fields["failed"], task.fields["remaining"]) == (2, 1, 1)
    assert "liquids" in capsys.readouterr().err
    with CampaignProgress(3, "quiet", enabled=None) as bar:  # not a terminal (pytest captures stderr)
        bar.finished(failed=False)
    assert bar._bar is None and capsys.readouterr().err == ""
