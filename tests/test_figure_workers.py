"""The run's figures drawn by forked helpers (issue 24, start-up speed): the same PNG bytes as
drawing in process, a fallback to drawing in process when a helper dies or sends garbage, and
no helper where forking is unsafe. Log-axis tick labels are plain text (no mathtext parse) with
the same content as matplotlib's.

Forking runs in fresh interpreters (a pytest worker has threads, where the helpers stand down)."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from mbus_framework.pipeline import figure_workers
from mbus_framework.pipeline.figures import FIGURES, plain_log_label

ROOT = Path(__file__).resolve().parents[1]
POTATO = ROOT / "configs" / "potato.yaml"
FAST = ["--set", "excitation.options.n_samples=1500", "--set", "model.options.n_elements=4", "--set", "output.figures=png"]
LINUX = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the helpers fork on Linux only")

_RUN = """
import json, os, sys
from mbus_framework.cli import main  # first: it limits BLAS to one thread before numpy loads
from mbus_framework.pipeline import figure_workers as fw
started = []
original = fw.start
def start():
    helpers = original()
    started.append(helpers is not None)
    return helpers
fw.start = start
early = []
draw_early = fw.Helpers.draw_early
def record_early(self, d, dpi=100):
    draw_early(self, d, dpi)
    early.extend(self.early)
fw.Helpers.draw_early = record_early
SABOTAGE
status = main(sys.argv[1:])
print("\\n@@RUN@@" + json.dumps([status, started, "matplotlib" in sys.modules, early]))
"""

SABOTAGE = {
    "none": "",
    # the helper (and its fork) die as soon as they have the data: nothing comes back
    "dies": "fw._draw = lambda d, dpi, names, out: os._exit(3)",
    # the helpers send bytes that are no record at all
    "garbage": "fw._draw = lambda d, dpi, names, out: (out.write(b'not a pickle' * 1000), out.flush())",
    # a whole record that is no (name, PNG) pickle
    "bad_record": "fw._draw = lambda d, dpi, names, out: (out.write(fw.FRAME.pack(12000) + b'not a pickle' * 1000), out.flush())",
    # one figure fails to draw in the helpers (only there): it is drawn in the parent instead
    "one_fails": ("import mbus_framework.pipeline.figures as F\n"
                  "b, f, c = F.FIGURES['fit']\n"
                  "def broken(d, fig=None, _p=os.getpid()):\n"
                  "    if os.getpid() != _p: raise RuntimeError('helper only')\n"
                  "    return b(d, fig)\n"
                  "F.FIGURES['fit'] = (broken, f, c)"),
    # the figure drawn before the fit is drawn at another resolution than the run asks for later
    "early_other_dpi": ("_early_at = fw.Helpers.draw_early\n"
                        "fw.Helpers.draw_early = lambda self, d, dpi=100: _early_at(self, d, 50)"),
    # the figure drawn before the fit fails in the helper: the parent draws it after the fit
    "early_fails": ("import mbus_framework.pipeline.figures as F\n"
                    "b, f, c = F.FIGURES['excitation']\n"
                    "def broken(d, fig=None, _p=os.getpid()):\n"
                    "    if os.getpid() != _p: raise RuntimeError('helper only')\n"
                    "    return b(d, fig)\n"
                    "F.FIGURES['excitation'] = (broken, f, c)"),
}


def _run(out: Path, sabotage: str = "none", helpers: str = "1") -> tuple[int, list[bool], bool, list[str]]:
    code = _RUN.replace("SABOTAGE", SABOTAGE[sabotage])
    done = subprocess.run([sys.executable, "-c", code, str(POTATO), "-o", str(out), "-q", *FAST], cwd=ROOT,
                          capture_output=True, text=True, timeout=600,
                          env={**os.environ, figure_workers.ENV: helpers})
    assert "@@RUN@@" in done.stdout, done.stderr[-2000:]
    return tuple(json.loads(done.stdout.rpartition("@@RUN@@")[2]))


def _pngs(run: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(run.glob("*.png"))}


@pytest.fixture(scope="module")
def serial(tmp_path_factory) -> dict[str, bytes]:
    out = tmp_path_factory.mktemp("serial") / "run"
    status, started, imported, early = _run(out, helpers="0")
    assert status == 0 and not any(started) and imported and not early
    pngs = _pngs(out)
    assert {FIGURES[n][1] for n in FIGURES} <= set(pngs)  # all six figures apply to a potato run
    return pngs


@LINUX
def test_helpers_draw_the_same_bytes(serial, tmp_path):
    """The excitation spectrum is sent before the fit (it needs none) and comes back the same."""
    status, started, imported, early = _run(tmp_path / "run")
    assert status == 0 and started and all(started)
    assert early == ["excitation"]
    assert not imported  # the run's own process never imported matplotlib: the helpers drew
    assert _pngs(tmp_path / "run") == serial
    report = (tmp_path / "run" / "report.html").read_text()
    assert report.count("data:image/png;base64,") == len(serial)


@LINUX
def test_an_early_figure_at_another_dpi_is_drawn_again(serial, tmp_path):
    """A PNG drawn before the fit at another resolution than the one asked for is not used: the
    helpers draw that figure again."""
    status, started, imported, early = _run(tmp_path / "run", "early_other_dpi")
    assert status == 0 and all(started) and early == ["excitation"]
    assert not imported  # the helpers drew it again, not the parent
    assert _pngs(tmp_path / "run") == serial


@LINUX
@pytest.mark.parametrize("sabotage", ["dies", "garbage", "bad_record", "one_fails", "early_fails"])
def test_a_failing_helper_costs_only_time(serial, tmp_path, sabotage):
    status, started, imported, _early = _run(tmp_path / "run", sabotage)
    assert status == 0 and started and all(started)
    assert imported  # the parent drew what the helpers did not deliver
    assert _pngs(tmp_path / "run") == serial


def test_no_helpers_where_forking_is_unsafe(monkeypatch):
    monkeypatch.setenv(figure_workers.ENV, "0")
    assert not figure_workers.available() and figure_workers.start() is None
    monkeypatch.delenv(figure_workers.ENV)
    stop = threading.Event()
    worker = threading.Thread(target=stop.wait)
    worker.start()
    try:
        assert figure_workers.threads() != 1 or not sys.platform.startswith("linux")
        assert not figure_workers.available()  # a second thread: no fork
    finally:
        stop.set()
        worker.join()


def test_split_balances_the_figures():
    names = list(FIGURES)
    a, b = figure_workers.split(names)
    assert sorted(a + b) == sorted(names) and not set(a) & set(b)
    cost = [sum(figure_workers.WEIGHT[n] for n in g) for g in (a, b)]
    assert abs(cost[0] - cost[1]) <= max(figure_workers.WEIGHT.values())
    assert cost[0] >= cost[1]  # the helper draws the costlier group, its fork the other
    rest = [n for n in names if n != "excitation"]  # what is left once the early figure is drawn
    a, b = figure_workers.split(rest)
    assert sum(figure_workers.WEIGHT[n] for n in a) >= sum(figure_workers.WEIGHT[n] for n in b)
    assert figure_workers.split(["fit"]) == (["fit"], [])


def _superscript(n: int) -> str:
    digits = dict(zip("0123456789-", ["\u2070", "\u00b9", "\u00b2", "\u00b3", "\u2074", "\u2075", "\u2076",
                                       "\u2077", "\u2078", "\u2079", "\u207b"]))
    return "".join(digits[ch] for ch in str(n))


@pytest.mark.parametrize("value", [1e-5, 1e-1, 1.0, 10.0, 1e3, 2e3, 5e-2, 3e7])
def test_plain_log_labels_say_what_mathtext_says(value):
    """matplotlib's label of ``value`` on a log axis, written without mathtext: 10 to the power
    in superscript digits, and c x 10^k for the labelled minor ticks."""
    from matplotlib.ticker import LogFormatterSciNotation

    label = LogFormatterSciNotation(labelOnlyBase=False)(value)
    k = math.floor(math.log10(value) + 1e-12)
    c = round(value / 10**k)
    expected = f"10{_superscript(k)}" if c == 1 else f"{c}\u00d710{_superscript(k)}"
    assert plain_log_label(label) == expected
    assert plain_log_label("0.5") == "0.5" and plain_log_label("") == ""


def test_log_axes_are_labelled_without_mathtext():
    """Every drawn tick label of the log-axis figures is plain text (no ``$...$`` to parse)."""
    import numpy as np

    from mbus_framework.pipeline.figures import FitData

    t = np.arange(2000) * 4e-8
    rng = np.random.default_rng(0)
    u = rng.standard_normal(t.size)
    y = np.convolve(u, np.exp(-np.arange(50) / 8.0))[: t.size]
    trace = [{"theta": [1.0 + 0.1 / (i + 1), 2.0], "cost": 10.0 ** -i, "stage": "s"} for i in range(6)]
    d = FitData(t, u, y, y + 0.01 * rng.standard_normal(t.size), ["a", "b"], trace)
    for name in ("frequency_response", "excitation", "convergence"):
        fig = FIGURES[name][0](d)
        fig.canvas.draw()
        labels = [lab.get_text() for ax in fig.axes for axis in (ax.xaxis, ax.yaxis)
                  for lab in axis.get_ticklabels(which="both")]
        assert labels and not [lab for lab in labels if "$" in lab], name
        assert any("10" in lab for lab in labels), name


@LINUX
def test_helpers_end_with_a_killed_run(tmp_path):
    """A run killed outright (SIGKILL: no clean-up code runs) leaves no helper behind: they die with
    their parent (PR_SET_PDEATHSIG), whether waiting for the data or drawing."""
    import signal
    import time

    run = subprocess.Popen([sys.executable, "-c", "import sys; from mbus_framework.cli import main; sys.exit(main())",
                            str(POTATO), "-o", str(tmp_path / "run"), "-q", *FAST], cwd=ROOT, start_new_session=True,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    def group() -> list[str]:
        found = subprocess.run(["pgrep", "-g", str(run.pid)], capture_output=True, text=True).stdout.split()
        return [pid for pid in found if pid != str(run.pid)]

    deadline = time.monotonic() + 120  # liveness bound, not a timing claim
    while not group() and run.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert run.poll() is None and group(), "the run ended before its helper could be seen"
    os.kill(run.pid, signal.SIGKILL)
    run.wait()
    while group() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert group() == []


def test_figures_before_the_fit_need_no_prediction():
    """The :data:`BEFORE_FIT` figures drawn from the record alone (prediction unknown) are byte for
    byte those drawn after the fit; every other figure needs the fit."""
    import types

    import numpy as np

    from mbus_framework.interfaces.excitation import Waveform
    from mbus_framework.pipeline.figures import BEFORE_FIT, FitData, applicable, render_all

    rng = np.random.default_rng(3)
    t = np.arange(2000) * 4e-8
    u = np.sign(rng.normal(size=t.size))
    y = np.convolve(u, np.exp(-np.arange(60) / 9.0), mode="full")[: t.size] + 0.1 * rng.normal(size=t.size)
    record = types.SimpleNamespace(t=t, u=u, y=y)
    designed = Waveform(t, u)
    before = FitData.before_fit(record, designed)
    after = FitData(t, u, y, 0.9 * y, ["a"], [{"iteration": 0, "cost": 1.0, "theta": [1.0]}], designed, "title")
    assert np.isnan(before.yhat).all()
    assert set(BEFORE_FIT) <= set(applicable(before))
    assert render_all(before, 60, list(BEFORE_FIT)) == render_all(after, 60, list(BEFORE_FIT))


def test_records_are_passed_on_as_soon_as_they_are_whole():
    """The parent saves each PNG as its record completes, whatever the pipe's chunking; an
    unreadable record stops the reading of that pipe."""
    import pickle

    records = [("fit", 100, b"\x89PNG-1" * 50), ("correlation", 100, b"\x89PNG-2" * 70)]
    stream = b"".join(figure_workers.FRAME.pack(len(b)) + b
                      for b in (pickle.dumps(r) for r in records))
    got: list[tuple[str, int, bytes]] = []
    buf = bytearray()
    for i in range(0, len(stream), 37):  # arbitrary chunks
        buf += stream[i:i + 37]
        assert figure_workers._records(buf, lambda *record: got.append(record))
    assert got == records and not buf
    bad = bytearray(figure_workers.FRAME.pack(5) + b"junk!")
    assert not figure_workers._records(bad, lambda *record: got.append(record))
    assert got == records
