"""mbus-analyze over corrupted tables (issue 28): constant columns, text cells, NaN, missing
columns, one-row groups, empty and header-only files. Every subcommand either finishes and
names what it dropped and why, or stops with a one-line error naming the file; never a
traceback."""
from __future__ import annotations

import numpy as np
import pytest

from fakes.campaign_tables import TABLE_4_3, grouped_table, schema_table
from mbus_framework.analysis.cli import main
from virtual_apples import physics_table

KINDS = ("constant", "text", "nan", "missing_column", "one_row_group", "empty", "header_only")


def corrupt(df, kind: str, column: str, group: str | None = None):
    d = df.copy()
    if kind == "constant":
        d[column] = 5.0
    elif kind == "text":
        d[column] = d[column].astype(object)
        d.loc[d.index[2], column] = "n/a?"
    elif kind == "nan":
        d.loc[d.index[[1, 4]], column] = np.nan
    elif kind == "missing_column":
        d = d.drop(columns=[column])
    elif kind == "one_row_group" and group is not None:
        first = d[group].iloc[0]
        d = d[(d[group] != first) | (d.index == d.index[0])]
    return d


def write(d, kind: str, path):
    if kind == "empty":
        path.write_text("")
    elif kind == "header_only":
        path.write_text(",".join(map(str, d.columns)) + "\n")
    else:
        d.to_csv(path, index=False)
    return path


def check(code: int, out: str, err: str, kind: str, path) -> None:
    text = out + err
    assert "Traceback" not in text, text[-2000:]
    assert code in (0, 2), (code, text[-2000:])
    if code == 2:
        errors = [line for line in err.splitlines() if "error" in line]  # (progress lines may precede it)
        assert len(errors) == 1 and path.name in errors[0] and "Error:" not in errors[0], err
    elif kind in ("text", "nan"):
        assert "excluded" in text or "dropped" in text or "missing" in text, text[-2000:]
    if code == 0 and kind == "text":
        assert "n/a?" in text  # the offending cell is named


@pytest.mark.parametrize("kind", KINDS)
def test_classify_on_corrupted_tables(tmp_path, capsys, kind):
    df = grouped_table(TABLE_4_3, 3, seed=2, by="tissue")
    path = write(corrupt(df, kind, "eta_sigma", "tissue"), kind, tmp_path / f"{kind}.csv")
    code = main(["classify", str(path), "--by", "tissue", "--no-plots", "--out", str(tmp_path / "out")])
    out, err = capsys.readouterr()
    check(code, out, err, kind, path)


@pytest.mark.parametrize("kind", KINDS)
def test_calibrate_on_corrupted_tables(tmp_path, capsys, kind):
    rng = np.random.default_rng(0)
    n = 20
    conv = {"conv_E_sigma": rng.uniform(1e6, 5e6, n), "conv_eta_sigma": rng.uniform(1.6e4, 6.9e4, n)}
    est = {"E_sigma": 1.5e4 * conv["conv_E_sigma"] + 3e9 * rng.standard_normal(n),
           "eta_sigma": 0.3 * conv["conv_eta_sigma"] + 1e3 * rng.standard_normal(n)}
    df = schema_table([f"S{i:02d}" for i in range(n)], est, extra=conv)
    path = write(corrupt(df, kind, "eta_sigma"), kind, tmp_path / f"{kind}.csv")
    code = main(["calibrate", str(path), "--no-plots", "--out", str(tmp_path / "out")])
    out, err = capsys.readouterr()
    check(code, out, err, kind, path)


TRAINS = pytest.mark.slow  # these kinds train the networks (tens of seconds); the others stop at once


@pytest.mark.parametrize("kind", (pytest.param("text", marks=TRAINS), pytest.param("constant", marks=TRAINS),
                                  "missing_column", "empty", "header_only"))
def test_crispness_on_corrupted_tables(tmp_path, capsys, kind):
    table, panel = physics_table(n=12, seed=3)
    panel_path = tmp_path / "panel.csv"
    panel.to_csv(panel_path, index=False)
    path = write(corrupt(table, kind, "k_sigma"), kind, tmp_path / f"{kind}.csv")  # an input of the network
    code = main(["crispness", str(path), "--scores", str(panel_path), "--group", "cultivar", "--no-plots",
                 "-o", str(tmp_path / "out")])
    out, err = capsys.readouterr()
    check(code, out, err, kind, path)
