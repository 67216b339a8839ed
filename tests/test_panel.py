"""Panel data (Section 7.2.4, Tables 7.1-7.3): reading, joining, statistics against
scipy.stats and plain sums of squares, one-line errors."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from mbus_framework.analysis.crispness.panel import (
    attach_group, check_panel, describe_by, join_scores, lsd_comparisons, one_way_anova, read_panel,
)
from mbus_framework.analysis.crispness.virtual_panel import PanelNoise, simulate_panel
from mbus_framework.errors import DataError


def random_panel(sizes, seed):
    rng = np.random.default_rng(seed)
    rows = []
    for g, n in enumerate(sizes):
        for k in range(n):
            rows.append({"sample_id": f"s{g}_{k}", "assessor": "A", "group": f"g{g}", "score": rng.normal(5 + 0.5 * g, 1.5)})
    return pd.DataFrame(rows)


@settings(max_examples=25)
@given(sizes=st.lists(st.integers(2, 15), min_size=2, max_size=6), seed=st.integers(0, 2**31))
def test_anova_agrees_with_scipy_and_sums_of_squares(sizes, seed):
    panel = random_panel(sizes, seed)
    table = one_way_anova(panel, "group", alpha=0.05, label="cultivar")
    groups = [panel.loc[panel.group == g, "score"].to_numpy() for g in sorted(panel.group.unique())]
    f, p = stats.f_oneway(*groups)
    grand = panel.score.mean()
    ss_b = sum(len(x) * (x.mean() - grand) ** 2 for x in groups)
    ss_w = sum(((x - x.mean()) ** 2).sum() for x in groups)
    k, n = len(groups), len(panel)
    between, within, total = table.loc["cultivar"], table.loc["Within groups"], table.loc["Total"]
    assert between["F"] == pytest.approx(f, rel=1e-10)
    assert between["p"] == pytest.approx(p, rel=1e-10, abs=1e-300)
    assert between["SS"] == pytest.approx(ss_b, rel=1e-10)
    assert within["SS"] == pytest.approx(ss_w, rel=1e-10)
    assert total["SS"] == pytest.approx(((panel.score - grand) ** 2).sum(), rel=1e-10)
    assert (between["df"], within["df"], total["df"]) == (k - 1, n - k, n - 1)
    assert between["MS"] == pytest.approx(ss_b / (k - 1), rel=1e-10)
    assert within["MS"] == pytest.approx(ss_w / (n - k), rel=1e-10)
    assert between["F crit"] == pytest.approx(stats.f.ppf(0.95, k - 1, n - k), rel=1e-10)


def test_anova_layout_matches_table_7_3():
    panel = random_panel([8, 12, 15, 11], 0)
    table = one_way_anova(panel, "group", label="Apple cultivar")
    assert list(table.index) == ["Apple cultivar", "Within groups", "Total"]
    assert list(table.columns) == ["SS", "df", "MS", "F", "p", "F crit"]


def test_lsd_of_two_levels_is_the_pooled_t_test():
    panel = random_panel([9, 14], 3)
    lsd = lsd_comparisons(panel, "group")
    t, p = stats.ttest_ind(panel.score[panel.group == "g0"], panel.score[panel.group == "g1"], equal_var=True)
    assert lsd.loc[0, "t"] == pytest.approx(t, rel=1e-10)
    assert lsd.loc[0, "p"] == pytest.approx(p, rel=1e-10)
    assert lsd.loc[0, "significant"] == (p < 0.05)


def test_statistics_by_assessor_and_group():
    ids = [f"apple{k}" for k in range(10)]
    panel = simulate_panel(ids, np.linspace(1, 8, 10), PanelNoise(n_assessors=4), seed=1)
    panel["cultivar"] = panel.sample_id.map({sid: "A" if k < 4 else "B" for k, sid in enumerate(ids)})
    t71 = describe_by(panel, "assessor")
    assert list(t71.columns) == ["n", "min", "max", "mean", "std"] and (t71.n == 10).all()
    t72 = describe_by(panel, "cultivar", total="all samples (10)")
    assert t72.loc["A", "n"] == 16 and t72.loc["all samples (10)", "n"] == 40
    assert t72.loc["B", "std"] == pytest.approx(panel.score[panel.cultivar == "B"].std(ddof=1))
    assert t72.loc["all samples (10)", "mean"] == pytest.approx(panel.score.mean())


def test_simulated_panel_is_seeded_and_on_the_line():
    ids = ["a", "b", "c"]
    p1 = simulate_panel(ids, [0.5, 4.5, 8.8], seed=3)
    p2 = simulate_panel(ids, [0.5, 4.5, 8.8], seed=3)
    pd.testing.assert_frame_equal(p1, p2)
    assert p1.score.between(0, 9).all() and len(p1) == 24
    np.testing.assert_allclose(p1.score * 10, np.round(p1.score * 10), atol=1e-9)


# -- joining to the campaign table ------------------------------------------------------------
def _table(n=8):
    return pd.DataFrame({"sample_id": [f"s{k}" for k in range(n)], "k_sigma": np.linspace(1e10, 3e10, n),
                         "k_tau": np.linspace(3e8, 5e8, n), "success": True, "cultivar": ["A", "B"] * (n // 2)})


def _panel(ids, assessors=("A1", "A2")):
    return pd.DataFrame([{"sample_id": s, "assessor": a, "score": 3.0 + k + (a == "A2")} for k, s in enumerate(ids) for a in assessors])


def test_join_uses_mean_scores_and_notes_what_it_leaves_out():
    table = _table(8)
    table.loc[1, "success"] = False
    table.loc[2, "k_tau"] = np.nan
    panel = _panel([f"s{k}" for k in range(7)])  # s7 has no scores
    joined, notes = join_scores(table, panel, ["k_sigma", "k_tau"], "t.csv", "p.csv")
    assert list(joined.index) == ["s0", "s3", "s4", "s5", "s6"]
    assert joined.loc["s3", "score"] == pytest.approx(6.5) and joined.loc["s3", "n_scores"] == 2
    text = " ".join(notes)
    assert "failed fit" in text and "missing or non-numeric inputs" in text and "no scores" in text


def test_join_averages_replicate_rows():
    table = pd.concat([_table(6), _table(6)], ignore_index=True)
    table.loc[6:, "k_sigma"] *= 1.1
    joined, notes = join_scores(table, _panel([f"s{k}" for k in range(6)]), ["k_sigma"], "t", "p")
    assert joined.loc["s0", "k_sigma"] == pytest.approx(1.05e10)
    assert any("replicate" in n for n in notes)


def test_group_from_the_table_when_the_panel_has_none():
    panel = attach_group(_panel(["s0", "s1"]), _table(4), "cultivar")
    assert list(panel.cultivar) == ["A", "A", "B", "B"]


# -- one-line errors ----------------------------------------------------------------------------
def _one_line(exc_info, *words):
    msg = str(exc_info.value)
    assert "\n" not in msg
    for w in words:
        assert w in msg


def test_unknown_sample_ids_are_one_line_errors():
    with pytest.raises(DataError) as e:
        join_scores(_table(4), _panel(["s0", "s1", "x9"]), ["k_sigma"], "props.csv", "panel.csv")
    _one_line(e, "panel.csv", "'x9'", "props.csv")


def test_missing_input_column_is_a_one_line_error():
    with pytest.raises(DataError) as e:
        join_scores(_table(4), _panel(["s0"]), ["k_sigma", "b_tau"], "props.csv", "panel.csv")
    _one_line(e, "props.csv", "b_tau")


def test_missing_panel_file(tmp_path):
    with pytest.raises(DataError) as e:
        read_panel(tmp_path / "nope.csv")
    _one_line(e, "nope.csv", "not found")


@pytest.mark.parametrize("text, words", [
    ("sample_id,judge,score\ns1,A,3\n", ["panel.csv", "assessor"]),
    ("sample_id,assessor,score\ns1,A,3\ns2,A,crisp\n", ["panel.csv", "row 3", "score", "'crisp'"]),
    ("sample_id,assessor,score\ns1,A,3\ns1,A,4\n", ["rows 2 and 3", "twice"]),
    ("sample_id,assessor,score\n,A,3\n", ["row 2", "sample_id"]),
])
def test_bad_panel_files_are_one_line_errors(tmp_path, text, words):
    (tmp_path / "panel.csv").write_text(text)
    with pytest.raises(DataError) as e:
        read_panel(tmp_path / "panel.csv")
    _one_line(e, *words)


def test_too_few_samples_and_levels():
    with pytest.raises(DataError) as e:
        join_scores(_table(4), _panel(["s0", "s1"]), ["k_sigma"], "t", "p.csv")
    _one_line(e, "at least 5")
    with pytest.raises(DataError) as e:
        one_way_anova(check_panel(_panel(["s0", "s1"])).assign(g="x"), "g")
    _one_line(e, "two levels")
