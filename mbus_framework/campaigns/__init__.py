"""Campaigns: many samples from a sample sheet, fitted on Dask, gathered in one table.

    from mbus_framework.campaigns import run_campaign, group_report
    result = run_campaign("configs/campaigns/liquids.yaml", workers=2)
    result.table                       # pandas DataFrame (docs/campaign-table.md)
    group_report("runs/liquids")       # group summary, text and plot paths

See docs/campaigns.md (use), docs/campaign-format.md (file format) and docs/campaign-table.md.
"""
from mbus_framework.campaigns.problems import CampaignError
from mbus_framework.campaigns.report import GroupReport, group_report
from mbus_framework.campaigns.runner import CampaignInterrupted, CampaignResult, run_campaign, summary_text
from mbus_framework.campaigns.spec import Campaign, is_campaign_file, load_campaign

__all__ = [
    "Campaign",
    "CampaignError",
    "CampaignInterrupted",
    "CampaignResult",
    "GroupReport",
    "group_report",
    "is_campaign_file",
    "load_campaign",
    "run_campaign",
    "summary_text",
]
