"""mbus-analyze classify: k-means and LDA leave-one-out on Table 4.2/4.3-like campaign tables."""
from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from fakes.campaign_tables import TABLE_4_2, TABLE_4_3, grouped_table, mark_failed
from mbus_framework.analysis.classify.model import (DISSERTATION_SETS, classify, confusion_matrix, feature_sets,
                                              kmeans_predict, letters_and_pairs, set_label)
from mbus_framework.analysis.classify.report import PERCENT_ROW, layout_table
from mbus_framework.analysis.cli import main
from mbus_framework.errors import DataError

TABLE_4_4_COLUMNS = ["E_sigma", "eta_sigma", "E_tau", "eta_tau", "E_sigma, eta_sigma", "E_tau, eta_tau",
                     "E_sigma, eta_sigma, E_tau, eta_tau"]


@pytest.fixture(scope="module")
def liquids():
    return grouped_table(TABLE_4_2, 5, seed=1)


def test_lda_leave_one_out_on_well_separated_liquids_is_100_percent(liquids):
    result = classify(liquids, "material", log=True, standardize=True)
    assert [set_label(s) for s in result.features] == TABLE_4_4_COLUMNS
    lda = result.results["lda"]
    assert lda[DISSERTATION_SETS[-1]].percent_correct == 100.0
    assert lda[("E_sigma", "eta_sigma")].percent_correct == 100.0
    # Syrup-2 and Syrup-3 share E_tau (3.11e12 in Table 4.2): E_tau alone cannot separate them fully
    assert ("Syrup-2", "Syrup-3") in [(result.groups[i], result.groups[j])
                                      for i, j in lda[("E_tau",)].not_separated]
    assert result.results["kmeans"][DISSERTATION_SETS[-1]].percent_correct == 100.0


def test_lda_on_one_property_is_leave_one_out_nearest_mean(liquids):
    """Equal priors, one feature: LDA assigns the nearest group mean (pooled variance), independent check."""
    result = classify(liquids, "material", [("E_tau",)], log=True, standardize=False)
    x = np.log10(liquids["E_tau"].to_numpy())
    labels = result.labels
    expected = []
    for i in range(x.size):
        keep = np.arange(x.size) != i
        means = np.array([x[keep & (labels == g)].mean() for g in range(len(result.groups))])
        expected.append(int(np.argmin(np.abs(x[i] - means))))
    np.testing.assert_array_equal(result.results["lda"][("E_tau",)].predicted, expected)


def test_kmeans_matching_is_the_best_one_to_one_assignment():
    """linear_sum_assignment against brute force over all cluster-to-group permutations."""
    from sklearn.cluster import KMeans

    df = grouped_table(TABLE_4_3, 4, seed=7, by="tissue")
    X = np.log10(df[["E_sigma", "eta_sigma"]].to_numpy())
    X = (X - X.mean(0)) / X.std(0)
    groups = list(dict.fromkeys(df.tissue))
    labels = np.array([groups.index(g) for g in df.tissue])
    k = len(groups)
    predicted = kmeans_predict(X, labels, k, restarts=10, seed=3)
    clusters = KMeans(n_clusters=k, n_init=10, random_state=3).fit_predict(X)
    best = max(sum(int(np.sum((clusters == c) & (labels == g))) for c, g in enumerate(perm))
               for perm in itertools.permutations(range(k)))
    assert int(np.sum(predicted == labels)) == best


def test_letters_and_not_separated_pairs():
    labels = np.array([0, 0, 1, 1, 2, 2])
    predicted = np.array([0, 0, 1, 2, 2, 2])
    conf = confusion_matrix(labels, predicted, 3)
    assert conf.tolist() == [[2, 0, 0], [0, 1, 1], [0, 0, 2]]
    letters, pairs = letters_and_pairs(conf)
    assert letters == ["a", "bc", "c"] and pairs == [(1, 2)]


def test_feature_sets_for_a_subset():
    assert feature_sets(["E_sigma", "eta_sigma"]) == [("E_sigma",), ("eta_sigma",), ("E_sigma", "eta_sigma")]
    assert feature_sets(["E_sigma", "eta_sigma", "E_tau"])[3:] == [("E_sigma", "eta_sigma"),
                                                                   ("E_sigma", "eta_sigma", "E_tau")]


def test_cli_writes_the_table_4_4_layout_json_and_figure(tmp_path, liquids, capsys):
    table = tmp_path / "properties.csv"
    mark_failed(liquids, [3, 17]).to_csv(table, index=False)
    assert main(["classify", str(table), "--by", "material"]) == 0
    out = tmp_path / "classify_material"
    printed = capsys.readouterr().out
    assert "used 23 of 25 rows (excluded: 2 failed (error))" in printed
    layout = pd.read_csv(out / "classification.csv", index_col=[0, 1])
    assert list(layout.columns) == TABLE_4_4_COLUMNS
    sections = list(dict.fromkeys(layout.index.get_level_values(0)))
    assert sections == ["K-means clustering", "Leave-one-out test results by linear discriminant analysis"]
    assert list(layout.loc[sections[1]].index) == list(TABLE_4_2) + [PERCENT_ROW]
    data = json.loads((out / "classification.json").read_text())
    assert data["rows"] == {"rows": 25, "failed": 2, "missing": 0, "used": 23}
    assert data["preprocessing"] == {"log10": False, "standardize": True}  # the dissertation's default
    for method, section in (("kmeans", sections[0]), ("lda", sections[1])):
        for column in TABLE_4_4_COLUMNS:
            entry = data["results"][method][column]
            assert float(layout.loc[(section, PERCENT_ROW), column]) == pytest.approx(entry["percent_correct"], abs=0.05)
            conf = np.array(entry["confusion"])
            assert conf.sum(axis=1).tolist() == [data["samples_per_group"][g] for g in data["groups"]]
            assert entry["percent_correct"] == pytest.approx(100 * np.trace(conf) / conf.sum())
            assert [layout.loc[(section, g), column] for g in data["groups"]] == [entry["letters"][g]
                                                                                  for g in data["groups"]]
    assert data["results"]["lda"]["E_sigma, eta_sigma, E_tau, eta_tau"]["percent_correct"] == 100.0
    confusion = pd.read_csv(out / "confusion_matrices.csv")
    assert len(confusion) == 2 * 7 * 5
    assert (out / "discriminant_space.png").stat().st_size > 10_000


def test_tissues_table_with_confusion_matrices(tmp_path, capsys):
    table = tmp_path / "tissues.csv"
    grouped_table(TABLE_4_3, 3, seed=2, by="tissue").to_csv(table, index=False)
    assert main(["classify", str(table), "--by", "tissue", "--no-plots", "--transform", "none",
                 "--no-standardize", "--out", str(tmp_path / "c")]) == 0
    data = json.loads((tmp_path / "c" / "classification.json").read_text())
    assert data["preprocessing"] == {"log10": False, "standardize": False}
    assert set(data["results"]["lda"]) == set(TABLE_4_4_COLUMNS)
    assert "Groups not separated" in capsys.readouterr().out


def test_user_sets_and_properties(tmp_path, liquids):
    res = classify(liquids, "material", [("E_sigma",), ("eta_sigma", "eta_tau")])
    assert list(res.features) == [("E_sigma",), ("eta_sigma", "eta_tau")]
    table = tmp_path / "t.csv"
    liquids.to_csv(table, index=False)
    assert main(["classify", str(table), "--by", "material", "--sets", "E_sigma,eta_tau", "--no-plots"]) == 0
    assert main(["classify", str(table), "--by", "material", "--properties", "E_tau", "eta_tau",
                 "--no-plots", "--out", str(tmp_path / "p")]) == 0
    layout = pd.read_csv(tmp_path / "p" / "classification.csv", index_col=[0, 1])
    assert list(layout.columns) == ["E_tau", "eta_tau", "E_tau, eta_tau"]


@pytest.mark.parametrize("change, args, message", [
    (None, ["--by", "cultivar"], "missing column(s) cultivar"),
    ("one_sample", ["--by", "material"], "group(s) Water of 'material' have fewer than 2 usable samples"),
    ("negative", ["--by", "material", "--transform", "log"], "E_sigma of sample Milk-1 is -3.3"),
    ("one_group", ["--by", "material"], "has 1 group(s)"),
    (None, ["--by", "material", "--properties", "E_bulk"], "missing column(s) E_bulk"),
])
def test_bad_tables_give_one_line_errors(tmp_path, liquids, capsys, change, args, message):
    df = liquids.copy()
    if change == "one_sample":
        df = df.drop(df.index[1:5])
    elif change == "negative":
        df.loc[df.sample_id == "Milk-1", "E_sigma"] *= -1
    elif change == "one_group":
        df = df[df.material == "Water"]
    table = tmp_path / "t.csv"
    df.to_csv(table, index=False)
    assert main(["classify", str(table), "--no-plots", *args]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and str(table) in err


def test_missing_table_is_one_line(tmp_path, capsys):
    assert main(["classify", str(tmp_path / "none.csv"), "--by", "material"]) == 2
    assert "none.csv: table not found" in capsys.readouterr().err


def test_missing_values_are_counted_not_fatal(liquids):
    df = liquids.copy()
    df.loc[df.index[0], "eta_tau"] = np.nan
    with pytest.raises(DataError):
        classify(df.drop(columns=["material"]), "material")
    res = classify(df, "material")
    assert res.counts == {"rows": 25, "failed": 0, "missing": 1, "used": 24}
    assert layout_table(res).shape == (12, 7)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["liquids", "tissues"])
def test_shipped_campaign_classification(tmp_path, name):
    """End to end once the campaign runner and its virtual campaigns exist (issue 13, Done when)."""
    import subprocess
    import sys
    from pathlib import Path

    from mbus_framework.pipeline.config import read_yaml

    pytest.importorskip("mbus_framework.campaigns")
    campaign = Path(__file__).resolve().parents[1] / "configs" / "campaigns" / f"{name}.yaml"
    if not campaign.is_file():
        pytest.skip(f"{campaign} not shipped")
    by = read_yaml(campaign)["campaign"]["groups"][0]
    run = subprocess.run([sys.executable, "-m", "mbus_framework.cli", str(campaign), "-o", str(tmp_path / "c"),
                          "--no-plots", "-q"], capture_output=True, text=True, cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    table = next((tmp_path / "c").rglob("properties.csv"))
    assert main(["classify", str(table), "--by", by, "--out", str(tmp_path / "out")]) == 0
    data = json.loads((tmp_path / "out" / "classification.json").read_text())
    assert list(data["results"]["lda"]) == TABLE_4_4_COLUMNS
    assert (tmp_path / "out" / "confusion_matrices.csv").is_file()
    if name == "liquids":
        assert data["rows"]["failed"] == 0
        assert data["results"]["lda"][TABLE_4_4_COLUMNS[-1]]["percent_correct"] == 100.0


@pytest.mark.slow
def test_shipped_tissues_campaign_reproduces_table_4_5_with_defaults(tmp_path):
    """docs/analysis.md's commands as written: LDA leave-one-out with all four properties 93.3 %."""
    import subprocess
    import sys

    repo = Path(__file__).resolve().parents[1]
    run = subprocess.run([sys.executable, "-m", "mbus_framework.cli", str(repo / "configs/campaigns/tissues.yaml"),
                          "-o", str(tmp_path / "tissues"), "-q"], capture_output=True, text=True, timeout=1800)
    assert run.returncode == 0, run.stderr[-2000:]
    assert main(["classify", str(tmp_path / "tissues" / "properties.csv"), "--by", "tissue", "--no-plots",
                 "--out", str(tmp_path / "c")]) == 0
    data = json.loads((tmp_path / "c" / "classification.json").read_text())
    assert data["results"]["lda"]["E_sigma, eta_sigma, E_tau, eta_tau"]["percent_correct"] == pytest.approx(93.3, abs=0.05)
