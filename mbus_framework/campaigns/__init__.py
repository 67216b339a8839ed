"""Campaigns: many samples from a sample sheet, fitted on Dask, gathered in one table.

    from mbus_framework.campaigns import run_campaign, group_report
    result = run_campaign("configs/campaigns/liquids.yaml", workers=2)
    result.table                       # pandas DataFrame (docs/campaign-table.md)
    group_report("runs/liquids")       # group summary, text and plot paths

See docs/campaigns.md (use), docs/campaign-format.md (file format) and docs/campaign-table.md.
"""
from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
    from mbus_framework.campaigns.problems import CampaignError  # noqa: F401
    from mbus_framework.campaigns.report import GroupReport, group_report  # noqa: F401
    from mbus_framework.campaigns.runner import CampaignInterrupted, CampaignResult, run_campaign, summary_text  # noqa: F401
    from mbus_framework.campaigns.spec import Campaign, is_campaign_file, load_campaign  # noqa: F401

# Public name -> the module defining it. Imported on first use (PEP 562), so that asking whether a
# file is a campaign (mbus-run does, for every config) does not load Dask and the report.
_WHERE = {
    "CampaignError": "problems",
    "GroupReport": "report",
    "group_report": "report",
    "CampaignInterrupted": "runner",
    "CampaignResult": "runner",
    "run_campaign": "runner",
    "summary_text": "runner",
    "Campaign": "spec",
    "is_campaign_file": "spec",
    "load_campaign": "spec",
}
__all__ = sorted(_WHERE)


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        return getattr(import_module(f"mbus_framework.campaigns.{_WHERE[name]}"), name)
    raise AttributeError(f"module 'mbus_framework.campaigns' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
