"""``mbus-run`` start-up (mbus_framework.startup): scipy's docstring notes made cheap, the
garbage collector paused while the run's modules load.

The reference is scipy's own path: every docstring the decorators change, and every public
function's of the scipy packages a run, its plugins, studies and analyses load, parses with
scipy's numpydoc parser to the same sections with and without the fast path (scipy's
re-rendering only adds roles to See Also entries and escapes ``*`` in a signature line). The fast path is process-local:
importing the library or fitting through the API leaves scipy untouched.
"""
from __future__ import annotations

import inspect
import json
import os
import subprocess
import sys
import types
from pathlib import Path

import pytest

import gc

from mbus_framework.startup import _decorator_as_expected, collector_paused, insert_note

ROOT = Path(__file__).resolve().parents[1]

_SECTIONS = """
import json, re, sys
if sys.argv[1] == "1":
    from mbus_framework.startup import cheap_scipy_notes
    assert cheap_scipy_notes() == ["scipy._lib._array_api", "scipy._lib._util"]
import importlib
# a run's packages first, then what plugins, studies and analyses load in the same process
modules = [importlib.import_module(f"scipy.{name}") for name in
           ("special", "fft", "linalg", "optimize", "signal", "stats", "ndimage", "integrate", "interpolate",
            "spatial", "sparse.linalg")]
from scipy._lib._array_api import xp_capabilities_table
from scipy._lib._docscrape import FunctionDoc
functions = {f"{i}:{f.__name__}": f for i, f in enumerate(xp_capabilities_table)}
for module in modules:
    functions.update({f"{module.__name__}.{name}": getattr(module, name) for name in module.__all__
                      if callable(getattr(module, name, None)) and not isinstance(getattr(module, name), type)})
out = {}
for key, f in functions.items():
    try:
        doc = FunctionDoc(f)  # the docstring as inspect.getdoc (help, Sphinx) shows it
    except Exception as exc:  # the same objects fail in both processes
        out[key] = {"error": type(exc).__name__}
        continue
    sections = {k: repr(doc[k]) for k in doc if k != "See Also"}
    sections["See Also"] = re.findall(r"\\('([^']+)', ", repr(doc["See Also"]))
    sections["Signature"] = repr(doc["Signature"].replace("\\\\*", "*"))  # scipy's rendering escapes *args
    out[key] = sections
print("\\n@@" + json.dumps(out))
"""


def _run(code: str, *args: str) -> object:
    # one hash seed: scipy writes some deprecation notes from a set, in hash order
    done = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, cwd=ROOT, timeout=300,
                          env={**os.environ, "PYTHONHASHSEED": "0"})
    assert "@@" in done.stdout, done.stderr[-2000:]
    return json.loads(done.stdout.rpartition("@@")[2])


def test_notes_fast_path_keeps_every_docstring_section():
    scipys, fast = _run(_SECTIONS, "0"), _run(_SECTIONS, "1")
    assert len(scipys) > 1000 and fast.keys() == scipys.keys()
    assert [name for name in scipys if fast[name] != scipys[name]] == []
    notes = [sections["Notes"] for key, sections in fast.items() if key[0].isdigit()]  # xp_capabilities_table
    assert sum("Array API Standard Support" in n for n in notes) >= len(notes) - 5  # a builtin's __doc__ stays


def test_decorated_functions_work_and_carry_their_note():
    code = """
import json
from mbus_framework.startup import cheap_scipy_notes
patched = cheap_scipy_notes()
import inspect
import numpy as np
from scipy import fft, linalg, optimize, special
from scipy._lib import _array_api
x = np.array([1.0, 2.0, 0.5, -1.0, 3.0])
T = np.array([[4.0, 1.0, 0.5], [1.0, 4.0, 1.0], [0.5, 1.0, 4.0]])
fit = optimize.least_squares(lambda p: p - np.array([1.0, -2.0]), np.zeros(2), method="lm")
print("\\n@@" + json.dumps({
    "patched": patched, "inserter": type(_array_api.FunctionDoc).__name__ + _array_api.FunctionDoc.__name__,
    "ndtr": float(special.ndtr(0.0)), "stdtrit": float(special.stdtrit(10, 0.975)),
    "fdtrc": float(special.fdtrc(2, 10, 4.102821015130399)),
    "fft": float(np.max(np.abs(fft.irfft(fft.rfft(x), 5) - x))),
    "toeplitz": float(np.max(np.abs(linalg.solve_toeplitz(T[:, 0], x[:3]) - np.linalg.solve(T, x[:3])))),
    "lsq": fit.x.tolist(),
    "rng": [inspect.getdoc(optimize.differential_evolution),
            optimize.differential_evolution(lambda p: (p[0] - 0.3) ** 2, [(-1, 1)], rng=1, maxiter=30).x.tolist(),
            str(inspect.signature(optimize.differential_evolution)).endswith("seed=None)")],
    "docs": [inspect.getdoc(f) for f in (special.ndtr, special.stdtrit, special.fdtrc, fft.rfft)],
    "batch": [inspect.getdoc(f) for f in (linalg.eig, linalg.svd, linalg.qr)],
    "expm": float(np.max(np.abs(linalg.expm(np.diag([0.0, 1.0])) - np.diag([1.0, np.e])))),
}))
"""
    got = _run(code)
    assert got["patched"] == ["scipy._lib._array_api", "scipy._lib._util"] and got["inserter"] == "type_NoteInserter"
    assert got["ndtr"] == 0.5
    assert got["stdtrit"] == pytest.approx(2.228138852, rel=1e-9)  # t-table, 10 dof, 97.5 %
    assert got["fdtrc"] == pytest.approx(0.05, rel=1e-9)  # F-table: F(2, 10) 95 % point 4.1028
    assert got["fft"] < 1e-14 and got["toeplitz"] < 1e-14
    assert got["lsq"] == pytest.approx([1.0, -2.0], abs=1e-12)
    doc, x, seed_keyword = got["rng"]  # scipy's rng rewrite, from the Parameters section alone
    assert "rng : {None, int, `numpy.random.Generator`}, optional\n    If `rng` is passed by keyword" in doc
    assert "legacy behavior for the argument `seed` applies" in doc and seed_keyword
    assert x == pytest.approx([0.3], abs=1e-4)
    assert got["expm"] < 1e-14
    for doc in got["docs"]:
        assert "Array API Standard Support" in doc and "Notes\n-----" in doc
    for doc in got["batch"]:  # the batch note ends the extended summary, before the first section
        assert doc.index('"batch" dimensions') < doc.index("Parameters\n----------")


def test_mbus_run_applies_the_fast_path_and_library_use_does_not(tmp_path):
    run = tmp_path / "run"
    code = f"""
import json, sys
from mbus_framework.cli import main
import gc
import mbus_framework.api as api
assert "scipy" not in sys.modules
run_config, enabled = api.run_config, []
api.run_config = lambda *a, **k: enabled.append(gc.isenabled()) or run_config(*a, **k)
status = main([{str(ROOT / "configs" / "potato.yaml")!r}, "-o", {str(run)!r}, "-q", "--no-plots"])
from scipy._lib import _array_api
print("\\n@@" + json.dumps([status, _array_api.FunctionDoc.__name__, enabled, gc.isenabled()]))
"""
    assert _run(code) == [0, "_NoteInserter", [True], True]  # the fit ran with the collector on
    code = f"""
import json
import numpy as np
import mbus_framework as mbus
import mbus_framework.pipeline.run, mbus_framework.api
t, u, y = np.loadtxt({str(run / "measurement.csv")!r}, delimiter=",", skiprows=1, unpack=True)[:3]
fit = mbus.fit(t, u, y, sample={{"length": 0.03, "diameter": 0.0254, "density": 1080.0}}, plots=False)
import scipy.special
from scipy._lib import _array_api, _docscrape
print("\\n@@" + json.dumps([bool(fit.success), _array_api.FunctionDoc is _docscrape.FunctionDoc]))
"""
    assert _run(code) == [True, True]


def test_a_different_decorator_is_left_alone():
    """scipy's internals as expected pass the check; any other shape fails it (scipy then runs as usual)."""
    from scipy._lib import _array_api, _docscrape, _util

    assert _decorator_as_expected(vars(_array_api), "xp_capabilities", "Notes", _docscrape) or \
        _array_api.FunctionDoc.__name__ == "_NoteInserter"
    assert _decorator_as_expected(vars(_util), "_apply_over_batch", "Extended Summary", _docscrape) or \
        _util.FunctionDoc.__name__ == "_NoteInserter"

    def xp_capabilities(**kw):
        def decorator(f):
            f.__doc__ = (f.__doc__ or "") + "\n" + str(kw)  # not the FunctionDoc round trip
            return f
        return decorator

    other = {"FunctionDoc": _docscrape.FunctionDoc, "xp_capabilities": xp_capabilities}
    assert not _decorator_as_expected(other, "xp_capabilities", "Notes", _docscrape)
    renamed = {"FunctionDoc": object, "xp_capabilities": _array_api.xp_capabilities}
    assert not _decorator_as_expected(renamed, "xp_capabilities", "Notes", _docscrape)
    assert not _decorator_as_expected(vars(_array_api), "xp_capabilities", "Extended Summary", _docscrape)
    assert not _decorator_as_expected({}, "xp_capabilities", "Notes", types.SimpleNamespace())


def test_insert_note_places_the_note_in_the_notes_section():
    doc = "Summary.\n\nParameters\n----------\nx : float\n\nNotes\n-----\nOld note.\n\nExamples\n--------\n>>> 1\n"
    assert insert_note(doc, "\nNEW\n") == ("Summary.\n\nParameters\n----------\nx : float\n\nNotes\n-----\n"
                                           "Old note.\n\nNEW\n\nExamples\n--------\n>>> 1\n")
    no_notes = "Summary.\n\nReferences\n----------\n.. [1] A.\n\nExamples\n--------\n>>> 1"
    assert insert_note(no_notes, "NEW") == ("Summary.\n\nNotes\n-----\nNEW\n\nReferences\n----------\n.. [1] A.\n\n"
                                            "Examples\n--------\n>>> 1")
    assert insert_note("Summary only.", "NEW") == "Summary only.\n\nNotes\n-----\nNEW\n"
    assert insert_note("", "NEW") == "Notes\n-----\nNEW\n"
    assert insert_note(doc, "NEW", "Extended Summary") == doc.replace("Parameters", "NEW\n\nParameters")
    assert insert_note("Summary.", "NEW", "Extended Summary") == "Summary.\n\nNEW\n"


@pytest.mark.parametrize("section", ["Notes", "Extended Summary"])
@pytest.mark.parametrize("notes", ["", "    Notes\n    -----\n    Old.\n\n"])
def test_insert_note_into_a_docstring_as_written(section, notes):
    """An indented docstring (as in the source) shows, through inspect.getdoc, what the dedented
    one would with the note."""
    raw = f"Summary.\n\n    More.\n\n    Parameters\n    ----------\n    x : float\n\n{notes}    Examples\n    --------\n    >>> 1\n    "
    note = "**Note**\n\n    a  b\n    == ==\n"
    shown = inspect.cleandoc(insert_note(raw, note, section))
    assert shown == insert_note(inspect.cleandoc(raw), note, section).rstrip("\n")
    assert ("More.\n\n**Note**" in shown) == (section == "Extended Summary")


def test_collector_paused_restores_the_collector():
    assert gc.isenabled()
    with collector_paused():
        assert not gc.isenabled()
    assert gc.isenabled()
    with pytest.raises(ValueError), collector_paused():
        raise ValueError("a failed import")
    assert gc.isenabled()
    gc.disable()
    try:
        with collector_paused():
            pass
        assert not gc.isenabled()  # it was off: left off
    finally:
        gc.enable()


def test_parameters_read_as_numpydoc_reads_them():
    """The Parameters section read for scipy's ``rng`` rewrite equals numpydoc's reading, for
    every public function of scipy.optimize and scipy.signal."""
    from scipy import optimize, signal
    from scipy._lib._docscrape import FunctionDoc

    from mbus_framework.startup import _getdoc, _parameters

    checked = 0
    for module in (optimize, signal):
        for name in module.__all__:
            f = getattr(module, name)
            if not callable(f) or isinstance(f, type):
                continue
            ours = [param for param, _, _ in _parameters(_getdoc(f))]
            assert ours == list(FunctionDoc(f)["Parameters"]), f"{module.__name__}.{name}"
            checked += bool(ours)
    assert checked > 150
