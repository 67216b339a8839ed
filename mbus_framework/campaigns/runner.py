"""Running a campaign: validate everything, reuse finished fits, fit the rest on Dask, write
the table, the group summary and the plots.

Campaign folder (default ``<base output.directory>/<campaign name>``, so a re-run continues)::

    campaign.json                  what ran: counts, timing, groups, the cluster
    properties.csv / .parquet      the campaign table, one row per sample (or replicate)
    samples.csv / .parquet         replicates: fit only: per-sample mean, SD and SE of the mean
    replicates.csv / .parquet      replicates fitted jointly: per replicate its gain, delay and own fit
    group_summary.csv / .txt       Tables 4.2/4.3 layout
    plots/<property>_by_group.png
    report.html                    one self-contained page: counts, summary, failures, warnings, plots
    runs/<sample>[-r<k>]/          each fit's usual run folder (+ campaign_row.json when done)
"""
from __future__ import annotations

import datetime as _dt
import importlib.util
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from mbus_framework import __version__
from mbus_framework.campaigns.attempt import CampaignLock
from mbus_framework.campaigns.executor import dask_client, run_all, sigint_ignored
from mbus_framework.campaigns.html_report import write_campaign_report
from mbus_framework.campaigns.joint_replicates import replicate_rows
from mbus_framework.campaigns.plan import FITTED, SampleTask, plan_campaign
from mbus_framework.campaigns.problems import Problems
from mbus_framework.campaigns.progress import CampaignProgress
from mbus_framework.campaigns.replicates import aggregate_replicates
from mbus_framework.campaigns.report import CAMPAIGN_JSON, GroupReport, group_report
from mbus_framework.campaigns.rows import failed_row
from mbus_framework.campaigns.spec import Campaign, load_campaign
from mbus_framework.campaigns.table import build_table, parameter_names, property_names, write_table
from mbus_framework.campaigns.worker import read_marker, run_task
from mbus_framework.pipeline.storage import atomic_write_json
from mbus_framework.studies.common import machine_info


class CampaignInterrupted(KeyboardInterrupt):
    """Ctrl-C during a campaign: unfinished fits were cancelled; ``result`` holds what finished."""

    def __init__(self, result: "CampaignResult"):
        super().__init__(f"interrupted: {result.n_done} of {len(result.tasks)} fits finished; run again to continue")
        self.result = result


@dataclass
class CampaignResult:
    """What a campaign produced. ``table`` is the campaign table (pandas DataFrame);
    ``fit_phase_s`` the wall time from the first fit submitted to the last one back (cluster
    start-up, validation and the outputs excluded), ``wall_time_s`` the whole campaign's."""

    campaign: Campaign
    out_dir: Path
    tasks: list[SampleTask]
    table: Any
    fitted: list[str] = field(default_factory=list)
    reused: list[str] = field(default_factory=list)
    report: GroupReport | None = None
    files: dict[str, Path] = field(default_factory=dict)
    interrupted: bool = False
    wall_time_s: float = 0.0
    fit_phase_s: float = 0.0

    @property
    def failed(self) -> list[str]:
        """Labels of the rows with an error."""
        if self.table is None or not len(self.table):
            return []
        return list(self.table.loc[self.table["error"].notna(), "run_dir"])

    @property
    def n_done(self) -> int:
        return len(self.fitted) + len(self.reused)


def default_out_dir(campaign: Campaign) -> Path:
    output = campaign.base.get("output") if isinstance(campaign.base.get("output"), dict) else {}
    return Path(output.get("directory") or "runs") / campaign.name


def run_campaign(
    path: str | Path,
    out_dir: str | Path | None = None,
    *,
    overrides: list[str] | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    client: Any = None,
    plots: bool | None = None,
    progress: bool | None = None,
    timeout: float | None = None,
) -> CampaignResult:
    """Run every sample of the campaign file ``path`` (see the module docstring).

    ``overrides`` (``--set`` style) apply to the base config; ``workers``/``scheduler`` beat the
    campaign's keys; ``client`` is an existing ``distributed.Client`` to use as it is; ``plots``
    (None: the config's ``output.plots``) is for each sample's run folder; ``progress``
    (None: on a terminal) shows the bar; ``timeout`` (None: the campaign's ``timeout``, else
    15 s) bounds the waits for a scheduler and its first worker. Every problem of the campaign file, the sheet and the
    samples' run configs is raised (:class:`CampaignError`) before anything is fitted. Ctrl-C
    cancels the unfinished fits, writes what finished and raises :class:`CampaignInterrupted`.
    The campaign folder is locked for the run (a second run on it is refused); fits left running
    by an earlier, interrupted run cannot overwrite this run's (:mod:`.attempt`).
    """
    t0 = time.perf_counter()
    problems = Problems()
    campaign = load_campaign(path, overrides, problems)
    out = Path(out_dir) if out_dir is not None else default_out_dir(campaign)
    tasks = plan_campaign(campaign, out, plots, problems)
    with CampaignLock(out) as lock:
        tasks = [replace(t, attempt=lock.token) for t in tasks]
        return _run(campaign, out, tasks, workers, scheduler, client, progress, t0,
                    campaign.spec.timeout if timeout is None else timeout)


def _run(campaign: Campaign, out: Path, tasks: list[SampleTask], workers, scheduler, client, progress, t0: float,
         timeout: float | None) -> CampaignResult:
    """Fit what is not finished yet, then write the outputs; campaign.json never stays "running"."""
    rows: dict[str, dict] = {}
    result = CampaignResult(campaign, out, tasks, None)
    todo = []
    for task in tasks:
        stored = read_marker(task.run_dir, task.key)
        if stored is not None:
            rows[task.label] = stored
            result.reused.append(task.label)
        else:
            todo.append(task)
    cluster = {"scheduler": scheduler or campaign.spec.scheduler, "workers": workers or campaign.spec.workers}
    _write_meta(result, cluster, "running", t0)

    def done(task: SampleTask, value: Any) -> None:
        if isinstance(value, BaseException):
            rows[task.label] = failed_row(task, f"the Dask task failed: {type(value).__name__}: {value}",
                                          str(Path("runs") / task.label))
        elif value.get("stale"):
            rows[task.label] = failed_row(task, "superseded: another run of this campaign folder took over",
                                          str(Path("runs") / task.label))
        else:
            rows[task.label] = value["row"]
        result.fitted.append(task.label)
        bar.finished(rows[task.label]["error"] is not None)

    reused = f" ({len(result.reused)} reused)" if result.reused else ""
    try:
        with CampaignProgress(len(todo), f"{campaign.name}{reused}", progress) as bar:
            if todo:
                with dask_client(cluster["workers"], cluster["scheduler"], client, timeout) as dask:
                    cluster["workers"] = len(dask.scheduler_info(n_workers=-1).get("workers", {})) or cluster["workers"]
                    if importlib.util.find_spec("bokeh") is not None:  # the dashboard needs bokeh
                        cluster["dashboard"] = getattr(dask, "dashboard_link", None)
                    t_fits = time.perf_counter()
                    try:
                        run_all(dask, run_task, todo, done, name=lambda t: t.label, group=f"mbus-{campaign.name}")
                    finally:
                        result.fit_phase_s = time.perf_counter() - t_fits
    except KeyboardInterrupt:
        result.interrupted = True
    except BaseException as exc:
        _write_meta(result, cluster, "failed", t0, error=str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
        raise
    if result.interrupted:
        _collect_finished(result, rows, todo)
    try:
        _finish(result, rows, cluster, t0)
    except KeyboardInterrupt:  # Ctrl-C while writing the outputs: write them once more, undisturbed
        result.interrupted = True
        with sigint_ignored():
            _collect_finished(result, rows, todo)
            _finish(result, rows, cluster, t0)
    if result.interrupted:
        raise CampaignInterrupted(result)
    return result


def _collect_finished(result: CampaignResult, rows: dict[str, dict], todo: list[SampleTask]) -> None:
    """Rows of fits that finished on a worker while the client was stopping."""
    for task in todo:
        stored = read_marker(task.run_dir, task.key) if task.label not in rows else None
        if stored is not None:
            rows[task.label] = stored
            result.fitted.append(task.label)


def _finish(result: CampaignResult, rows: dict[str, dict], cluster: dict, t0: float) -> None:
    """Write the table(s), the group summary and campaign.json from the rows that finished
    (an empty table, and no summary, when none did)."""
    campaign, out = result.campaign, result.out_dir
    spec = campaign.spec
    result.table = build_table([rows[t.label] for t in result.tasks if t.label in rows], spec.groups, spec.covariates)
    result.files.update(write_table(result.table, out))
    if len(result.table) and result.tasks[0].replicates == FITTED:
        quantities = parameter_names(result.table) + property_names(result.table)
        quantities += [c for c in result.table.columns if c.startswith("true_")]
        samples = aggregate_replicates(result.table, ["sample_id", *spec.groups], quantities)
        result.files.update(write_table(samples, out, "samples"))
    per_replicate = replicate_rows(result.table, out) if len(result.table) else []
    if per_replicate:
        import pandas as pd

        result.files.update(write_table(pd.DataFrame(per_replicate), out, "replicates"))
    if len(result.table):
        result.report = group_report(result.table, spec.groups, out, campaign.title, units=result.tasks[0].units)
        result.files.update(result.report.files)
        result.files.update({f"plot_{k}": v for k, v in result.report.plots.items()})
    result.wall_time_s = time.perf_counter() - t0
    result.files["report_html"] = write_campaign_report(result)
    result.files["campaign_json"] = _write_meta(result, cluster, "interrupted" if result.interrupted else "finished", t0)


def _write_meta(result: CampaignResult, cluster: dict, status: str, t0: float, error: str | None = None) -> Path:
    c = result.campaign
    table = result.table
    return atomic_write_json(result.out_dir / CAMPAIGN_JSON, {
        "campaign": str(c.path),
        "title": c.title,
        "status": status,
        **({"error": error} if error else {}),
        "created": _dt.datetime.now().isoformat(timespec="seconds"),
        "mbus_version": __version__,
        "base": str(c.base_source),
        "groups": c.spec.groups,
        "covariates": c.spec.covariates,
        "replicates": c.spec.replicates,
        **({"replicates_chosen": _choices(table)} if table is not None and "replicates_reason" in table else {}),
        "n_fits": len(result.tasks),
        "units": dict(result.tasks[0].units) if result.tasks else {},
        "fitted": len(result.fitted),
        "reused": len(result.reused),
        "failed": len(result.failed) if table is not None else None,
        "failed_runs": result.failed if table is not None else None,
        "wall_time_s": time.perf_counter() - t0,
        "fit_phase_s": result.fit_phase_s,
        "cluster": {k: v for k, v in cluster.items() if v is not None},
        "machine": machine_info(),
    })


def replicates_how(result: CampaignResult) -> str:
    """How the replicates were combined; for ``auto``/``joint``, how many samples each way."""
    mode = result.campaign.spec.replicates
    if mode == "average":
        return "replicates averaged before fitting"
    if mode == "fit":
        return "each replicate fitted"
    table = result.table
    multi = table[table["n_replicates"] > 1] if table is not None and len(table) else []
    joint = int((multi["replicates"] == "joint").sum()) if len(multi) else 0
    averaged = int((multi["replicates"] == "averaged").sum()) if len(multi) else 0
    return (f"replicates: {mode}: {joint} sample(s) fitted jointly (per-replicate gain and delay), {averaged} "
            f"averaged before fitting")


def _choices(table) -> dict[str, str]:
    """Per sample with several replicates: what ``auto``/``joint`` did, and why."""
    multi = table[table["n_replicates"] > 1]
    return {str(s): f"{m} ({r})" for s, m, r in zip(multi["sample_id"], multi["replicates"], multi["replicates_reason"])}


def summary_text(result: CampaignResult) -> str:
    """What ``mbus-run CAMPAIGN`` prints at the end."""
    c = result.campaign
    how = replicates_how(result)
    failed = result.failed
    lines = [
        f"mbus campaign: {c.title}",
        f"  {len(result.tasks)} fits ({how}): {len(result.fitted)} run now, {len(result.reused)} reused from an "
        f"earlier run, {len(failed)} failed" + ("; INTERRUPTED, run again to continue" if result.interrupted else ""),
    ]
    if failed:
        errors = dict(zip(result.table["run_dir"], result.table["error"]))
        for run in failed[:10]:
            lines.append(f"    {Path(run).name}: {errors[run]}")
        if len(failed) > 10:
            lines.append(f"    ... and {len(failed) - 10} more (column 'error' of properties.csv)")
    if c.spec.replicates in ("auto", "joint") and result.table is not None and "replicates_reason" in result.table:
        chosen = _choices(result.table)
        for sample, how_chosen in list(chosen.items())[:10]:
            lines.append(f"    {sample}: {how_chosen}")
        if len(chosen) > 10:
            lines.append(f"    ... and {len(chosen) - 10} more (columns 'replicates', 'replicates_reason' of properties.csv)")
    if result.report is not None and len(result.table):
        lines += ["", result.report.text]
    lines += ["", f"  written to {result.out_dir}/: report.html, properties.csv, properties.parquet, group_summary.csv, "
                  f"plots/, runs/ ({result.wall_time_s:.1f} s)"]
    return "\n".join(lines)
