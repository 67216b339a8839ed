"""Fuzzing ``mbus-run`` (issue 15): mutated configs and mutated data files of every supported
format (t,u,y CSV, NPZ, GDS-2000 CSV exports in both layouts, lab run folders, other run
folders) through ``mbus_framework.cli.main`` in-process. The cases and the checks are in
:mod:`fuzz_cases`.

Default run: hypothesis-driven, about a minute. ``pytest -m slow tests/test_fuzz.py`` runs the
seeded campaign (1,000 configs and 500 data files by default; ``MBUS_FUZZ_CONFIGS``,
``MBUS_FUZZ_DATA``, ``MBUS_FUZZ_START``, ``MBUS_FUZZ_SEED`` choose a slice, ``MBUS_FUZZ_REPORT``
names the JSON report) and prints its figures: cases run, exit codes, tracebacks, hangs, time.
"""
from __future__ import annotations

import collections
import faulthandler
import itertools
import json
import os
import tempfile
import time
import traceback
from contextlib import contextmanager
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import fuzz_cases as fc
from reliability_support import Hang

CASE_TIMEOUT = 60.0


@contextmanager
def debug_mode():
    """MBUS_DEBUG=1: an exception that is not an MbusError escapes main() and fails the case."""
    old = os.environ.get("MBUS_DEBUG")
    os.environ["MBUS_DEBUG"] = "1"
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("MBUS_DEBUG", None)
        else:
            os.environ["MBUS_DEBUG"] = old


@pytest.fixture(scope="module")
def materials(tmp_path_factory):
    return fc.Materials(tmp_path_factory.mktemp("fuzz-materials"))


@pytest.fixture(scope="module")
def cases_root(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz-cases")


_counter = itertools.count()
FUZZ = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                                   HealthCheck.function_scoped_fixture])


@settings(max_examples=150, **FUZZ)
@given(data=st.data())
def test_mutated_configs(materials, cases_root, data):
    # fixed-width folder names: the config text embeds the path, and hypothesis needs its length
    # (drawn bounds) to be the same when it replays an example
    case = fc.config_case(fc.HypothesisChooser(data), cases_root / f"c{next(_counter):07d}", materials)
    with debug_mode():
        fc.run_case(case, CASE_TIMEOUT)


@settings(max_examples=150, **FUZZ)
@given(data=st.data(), fmt=st.sampled_from(fc.DATA_FORMATS))
def test_mutated_data_files(materials, cases_root, data, fmt):
    case = fc.data_case(fc.HypothesisChooser(data), cases_root / f"d{next(_counter):07d}", materials, fmt)
    with debug_mode():
        fc.run_case(case, CASE_TIMEOUT)


# -- the long campaign ------------------------------------------------------------------------
def _campaign(kind: str, count: int, start: int, seed: int, materials, root: Path, stats: dict) -> None:
    build = fc.config_case if kind == "config" else fc.data_case
    for i in range(start, start + count):
        chooser = fc.RandomChooser(seed * 1_000_003 + (0 if kind == "config" else 500_000_017) + i)
        folder = root / f"{kind}{i}"
        case = build(chooser, folder, materials)
        faulthandler.dump_traceback_later(CASE_TIMEOUT * 3, exit=True)  # a hang inside C code
        t0 = time.perf_counter()
        try:
            with debug_mode():
                result = fc.run_case(case, CASE_TIMEOUT)
        except Hang as exc:
            stats["hangs"].append({"kind": kind, "index": i, "case": case.description, "error": str(exc)})
        except AssertionError as exc:
            stats["violations"].append({"kind": kind, "index": i, "case": case.description, "error": str(exc)[:2000]})
        except Exception as exc:  # noqa: BLE001 - a traceback: counted and reported
            stats["tracebacks"].append({"kind": kind, "index": i, "case": case.description,
                                        "error": "".join(traceback.format_exception(exc))[-3000:]})
        else:
            stats["exit_codes"][str(result.code)] += 1
            if "failed numerically in" in result.error:
                stats["numeric_failures_in_fits"].append(result.error[:300])
            stats["json_files_checked"] += result.json_files
            if result.code:
                stats["errors"][_error_kind(result.error)] += 1
        finally:
            faulthandler.cancel_dump_traceback_later()
        stats["cases"][kind] += 1
        stats["by_input"][case.description[0]] += 1  # "base small", "format gds_raw", ...
        if time.perf_counter() - t0 > stats["slowest_s"]:
            stats["slowest_s"], stats["slowest_case"] = time.perf_counter() - t0, [kind, i, *case.description]
        _tidy(folder)


def _error_kind(line: str) -> str:
    """A coarse label of an error line: the words after the last ': ' that names a path or key."""
    text = line.removeprefix("mbus-run: error: ")
    parts = text.split(": ")
    return (parts[-1] if len(parts) == 1 else parts[-1] if len(parts[-1]) > 20 else parts[-2] + ": " + parts[-1])[:50]


def _tidy(folder: Path) -> None:
    import shutil

    shutil.rmtree(folder, ignore_errors=True)


@pytest.mark.slow
def test_fuzz_campaign(tmp_path_factory):
    n_configs = int(os.environ.get("MBUS_FUZZ_CONFIGS", 1000))
    n_data = int(os.environ.get("MBUS_FUZZ_DATA", 500))
    start = int(os.environ.get("MBUS_FUZZ_START", 0))
    seed = int(os.environ.get("MBUS_FUZZ_SEED", 2024))
    report = Path(os.environ.get("MBUS_FUZZ_REPORT", Path(tempfile.gettempdir()) / "mbus-fuzz-report.json"))
    materials = fc.Materials(tmp_path_factory.mktemp("materials"))
    root = tmp_path_factory.mktemp("campaign")
    stats = {"cases": collections.Counter(), "by_input": collections.Counter(), "exit_codes": collections.Counter(),
             "errors": collections.Counter(),
             "tracebacks": [], "hangs": [], "violations": [], "numeric_failures_in_fits": [],
             "json_files_checked": 0, "slowest_s": 0.0, "slowest_case": None}
    t0 = time.perf_counter()
    _campaign("config", n_configs, start, seed, materials, root, stats)
    _campaign("data", n_data, start, seed, materials, root, stats)
    stats["wall_time_s"] = round(time.perf_counter() - t0, 1)
    stats.update(seed=seed, start=start, case_timeout_s=CASE_TIMEOUT,
                 errors=dict(stats["errors"].most_common(40)), cases=dict(stats["cases"]),
                 by_input=dict(stats["by_input"]),
                 exit_codes=dict(stats["exit_codes"]))
    report.write_text(json.dumps(stats, indent=1, default=str))
    print(f"\nfuzz campaign: {stats['cases']} cases in {stats['wall_time_s']} s (seed {seed}, from {start}); "
          f"exit codes {stats['exit_codes']}; tracebacks {len(stats['tracebacks'])}, hangs {len(stats['hangs'])}, "
          f"violations {len(stats['violations'])}; numeric failures inside fits reported as EstimationError "
          f"{len(stats['numeric_failures_in_fits'])}; JSON files checked {stats['json_files_checked']}; "
          f"slowest case {stats['slowest_s']:.1f} s; report {report}")
    problems = stats["tracebacks"] + stats["hangs"] + stats["violations"]
    assert not problems, json.dumps(problems[:5], indent=1, default=str)
