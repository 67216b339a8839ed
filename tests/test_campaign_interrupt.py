"""Ctrl-C while a campaign writes its outputs: the outputs are written once more, undisturbed,
campaign.json says "interrupted", and the table holds every finished row."""
from __future__ import annotations

import json

import pandas as pd
import pytest

from campaign_helpers import write_campaign
from mbus_framework.campaigns import CampaignInterrupted, run_campaign
from mbus_framework.campaigns import runner


def test_ctrl_c_while_the_table_is_written(tmp_path, monkeypatch):
    rows = [{"sample_id": f"s{i}", "cultivar": "xy"[i % 2], "backend.options.seed": i} for i in range(3)]
    path = write_campaign(tmp_path, rows)
    out = tmp_path / "out"
    first = run_campaign(path, out, workers=1)
    assert first.failed == [] and len(first.table) == 3
    (out / "properties.csv").unlink()

    calls = []
    real = runner.write_table

    def interrupted_once(*args, **kwargs):
        calls.append(1)
        if len(calls) == 1:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(runner, "write_table", interrupted_once)
    with pytest.raises(CampaignInterrupted) as caught:
        run_campaign(path, out)  # every fit reused: only the outputs are written
    assert caught.value.result.interrupted and sorted(caught.value.result.reused) == ["s0", "s1", "s2"]
    assert json.loads((out / "campaign.json").read_text())["status"] == "interrupted"
    table = pd.read_csv(out / "properties.csv")
    assert table["sample_id"].tolist() == ["s0", "s1", "s2"]
    assert table["E_sigma"].tolist() == first.table["E_sigma"].tolist()
