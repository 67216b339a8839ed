"""The convergence benchmark's bookkeeping of issue 28's warning rule (benchmarks/convergence_benchmark.py)."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

spec = importlib.util.spec_from_file_location(
    "convergence_benchmark", Path(__file__).resolve().parents[1] / "benchmarks" / "convergence_benchmark.py")
bench = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bench)


def case(index, ok, warned, se):
    return {"index": index, "name": f"c{index}", "ok": ok, "warned": warned, "error": None,
            "warnings": ["w"] if warned else [], "reported_relative_se": se}


@pytest.mark.parametrize("cases, false_alarms, missed", [
    ([case(0, True, False, {"a": 0.01, "b": 0.049})], 0, 0),             # quiet good fit
    ([case(1, True, True, {"a": 0.01, "b": 0.02})], 1, 0),               # a warning on a good fit
    ([case(2, False, True, {"a": 0.01})], 0, 0),                         # a failed fit may warn
    ([case(3, True, False, {"a": 0.30})], 0, 1),                         # > 20 % and silent
    ([case(4, True, False, {"a": None})], 0, 1),                         # no SE at all counts as > 20 %
    ([case(5, True, False, {"a": 0.10})], 0, 0),                         # between the thresholds: free
])
def test_warning_rule_counts_false_alarms_and_misses(cases, false_alarms, missed):
    r = bench.warning_rule(cases)
    assert r["of_which_warned"] == false_alarms and len(r["false_alarms"]) == false_alarms
    assert r["of_which_not_warned"] == missed and len(r["missed"]) == missed
