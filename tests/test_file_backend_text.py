"""``file`` backend: delimited text files written the way scopes and lab scripts write them.

Each variant loads with at most one reader option, and without it the error names that option."""
from __future__ import annotations

import numpy as np
import pytest

from mbus_framework.errors import DataError
from mbus_framework.interfaces.backend import AcquisitionContext
from mbus_framework.pipeline.config import validate_options
from mbus_plugins.backends.file import FileBackend, FileOptions

N = 64
T = np.arange(N) * 4e-8
U = np.sign(np.sin(2 * np.pi * 1.3e6 * T)) + 0.25
Y = 0.01 * np.sin(2 * np.pi * 0.9e6 * T + 0.3)


def acquire(path, **options):
    o = validate_options(FileOptions, {"path": str(path), **options}, "backend.options")
    return FileBackend(o).acquire(AcquisitionContext(None, None, None, None, None, "<config>"))


def rows(sep=",", decimal=".", order=(0, 1, 2)):
    cols = (T, U, Y)
    out = []
    for k in range(N):
        vals = [repr(float(cols[i][k])) for i in order]
        out.append(sep.join(v.replace(".", decimal) for v in vals))
    return out


def write(path, lines):
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def check(m, order=(0, 1, 2)):
    np.testing.assert_allclose(m.t, T - T[0], rtol=0, atol=1e-20)
    np.testing.assert_allclose(m.u, U, rtol=1e-15)
    np.testing.assert_allclose(m.y, Y, rtol=1e-15)


# variant -> (file name, lines, the one option that loads it (or None), words of the error without it)
VARIANTS = {
    "renamed columns": ("r.csv", ["time,excitation,response"] + rows(),
                        {"columns": {"t": "time", "u": "excitation", "y": "response"}},
                        ["missing column(s) t, u, y", "backend.options.columns, e.g. {t: time, u: excitation, y: response}"]),
    "columns by index": ("i.csv", ["a,b,c,d"] + [r + ",0" for r in rows(order=(2, 0, 1))],
                         {"columns": {"t": 1, "u": 2, "y": 0}}, ["backend.options.columns"]),
    "semicolons": ("s.csv", ["t;u;y"] + rows(";"), {"delimiter": ";"}, ["backend.options.delimiter: ';'"]),
    "tabs in a .csv": ("tab.csv", ["t\tu\ty"] + rows("\t"), {"delimiter": "tab"}, ["backend.options.delimiter: 'tab'"]),
    "decimal comma": ("dc.csv", ["t;u;y"] + rows(";", ","), {"decimal": ","}, ["backend.options.decimal: ','"]),
    "units row": ("ur.csv", ["t,u,y", "s,N,N"] + rows(), {"units_row": True}, ["backend.options.units_row: true"]),
    "preamble": ("p.csv", ["Instrument: DSO-X 1204A", "Date: 2026-11-27", "t,u,y"] + rows(),
                 {"skip_rows": 2}, ["line 3", "backend.options.skip_rows: 2"]),
    "headerless": ("h.csv", rows(), {"columns": {"t": 0, "u": 1, "y": 2}},
                   ["no header row", "backend.options.columns: {t: 0, u: 1, y: 2}"]),
    "percent comments": ("pc.csv", ["% recorded by a MATLAB script", "% 2026-11-27", "t,u,y"] + rows(),
                         {"comment": "%"}, ["backend.options.comment: '%'"]),
    "units in the header": ("uh.csv", ["t [s],u (N),y [N]"] + rows(), None, None),
    "hash comments": ("hc.csv", ["# scope export", "t,u,y", "# burst starts here"] + rows(), None, None),
    "numpy.savetxt header": ("np.txt", ["# t u y"] + rows(" "), None, None),
    ".tsv": ("r.tsv", ["t\tu\ty"] + rows("\t"), None, None),
    ".txt with blanks": ("r.txt", ["t   u   y"] + [r.replace(",", "   ") for r in rows()], None, None),
    "quoted header, trailing separator": ("q.csv", ['"t","u","y",'] + [r + "," for r in rows()], None, None),
}


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_variant_loads_with_at_most_one_option(tmp_path, variant):
    name, lines, option, _ = VARIANTS[variant]
    m = acquire(write(tmp_path / name, lines), **(option or {}))
    check(m)


@pytest.mark.parametrize("variant", sorted(v for v in VARIANTS if VARIANTS[v][2] is not None))
def test_without_its_option_the_error_names_it(tmp_path, variant):
    name, lines, _, words = VARIANTS[variant]
    path = write(tmp_path / name, lines)
    with pytest.raises(DataError) as err:
        acquire(path)
    msg = str(err.value)
    assert "\n" not in msg and str(path) in msg
    for w in words:
        assert w in msg, (w, msg)


def test_units_are_kept_from_the_header_or_the_units_row(tmp_path):
    m = acquire(write(tmp_path / "a.csv", ["t [s],u (V),y [V]"] + rows()))
    assert m.meta["units"] == {"t": "s", "u": "V", "y": "V"}
    m = acquire(write(tmp_path / "b.csv", ["time,in,out", "s,N,N"] + rows()), units_row=True,
                columns={"t": "time", "u": "in", "y": "out"})
    assert m.meta["units"] == {"t": "s", "u": "N", "y": "N"}
    assert m.meta["columns"] == {"t": "time", "u": "in", "y": "out"}


def test_npz_arrays_can_be_named(tmp_path):
    np.savez(tmp_path / "r.npz", time=T, force_in=U, force_out=Y)
    check(acquire(tmp_path / "r.npz", columns={"t": "time", "u": "force_in", "y": "force_out"}))
    with pytest.raises(DataError, match="backend.options.columns"):
        acquire(tmp_path / "r.npz")


def test_bad_options_are_one_line_errors(tmp_path):
    path = write(tmp_path / "r.csv", ["t,u,y"] + rows())
    with pytest.raises(DataError, match=r"backend.options.columns.y = 5 is out of range: the rows have 3 columns"):
        acquire(path, columns={"t": 0, "u": 1, "y": 5})
    with pytest.raises(DataError, match=r"missing column\(s\) y \(looked for 'out'\)"):
        acquire(path, columns={"y": "out"})
    with pytest.raises(DataError, match=r"not a number \(line 'x,y,z' under the header\); if it holds units"):
        acquire(write(tmp_path / "u.csv", ["t,u,y", "x,y,z"] + rows()))
    np.savez(tmp_path / "r.npz", t=T, u=U, y=Y)
    with pytest.raises(DataError, match=r"backend.options.delimiter applies to t,u,y text files, not to a mat"):
        from scipy.io import savemat
        savemat(tmp_path / "r.mat", {"t": T, "u": U, "y": Y})
        acquire(tmp_path / "r.mat", delimiter=";")


def test_a_pair_of_generic_time_value_scope_files_with_response_path(tmp_path):
    u = write(tmp_path / "ch1.csv", ["time,value"] + [f"{float(t)!r},{float(v)!r}" for t, v in zip(T, U)])
    y = write(tmp_path / "ch2.csv", ["time,value"] + [f"{float(t)!r},{float(v)!r}" for t, v in zip(T, Y)])
    m = acquire(u, response_path=str(y))
    check(m)
    assert m.meta["response_source"] == str(y)
    short = write(tmp_path / "ch3.csv", ["time,value"] + [f"{float(t)!r},{float(v)!r}" for t, v in zip(T[:40], Y[:40])])
    with pytest.raises(DataError, match=r"ch3.csv: 40 samples but ch1.csv has 64"):
        acquire(u, response_path=str(short))
