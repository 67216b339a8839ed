"""Studies of Chapter 3: many identification runs over one base config, one table and plot.

Three kinds, each ``run_study(kind, config, overrides, out_dir, progress, **options)``:

``monte_carlo``
    The same simulated measurement repeated over noise seeds (``backend.options.seed``). Per
    parameter and per material property: bias, RMS error, the mean of the runs' own standard
    errors, the coverage of the truth by the runs' 95 % intervals, and the Cramer-Rao bound
    (CRB = sigma^2 (J^T J)^-1 at the truth, sigma the known noise std) with the ratio
    RMS error / CRB (1 for an efficient, unbiased estimator).
``element_sweep``
    One fixed data record fitted with n = 2..40 elements (Figs. 3.10-3.11): the material
    properties against n and the n from which each property settles (every later estimate
    within ``tolerance`` of it). By default the record comes from a fine chain (40 elements)
    of the config's true medium, so the truth is one medium, not one n. A coarse chain cannot
    match that record and its cost has more local minima, so each n is also refitted from its
    finer neighbour's estimate (``warm_start``) and the lower cost is kept.
``repeatability``
    Different PRBS realisations of the same bandwidth (``excitation.options.shift``, and a new
    noise seed for a simulated rig): each property's mean and std/mean (Table 3.2).

Member runs run in this process, or on Dask distributed (``distributed=True``, ``workers``,
``scheduler`` or ``client``; ``mbus-run --study`` always does): a LocalCluster with one worker
process per core by default, the same executor as campaigns (:mod:`mbus_framework.campaigns`),
with the same numbers.

Every study writes into its folder ``<kind>.csv`` (the table), ``<kind>.json`` (summary,
table, options, the compact record of every run), ``<kind>.png`` (plot) and ``runs/<label>/``
with each run's ``result.json`` and ``config.yaml`` (the whole run folder with
``keep_runs=true``). Runs are executed without plots and without their own progress display.

From the command line (``mbus-run CONFIG --study KIND --study-option key=value``), options
are parsed by :func:`parse_study_options` and validated per kind (unknown keys rejected with
a "did you mean").
"""
from __future__ import annotations

import datetime as _dt
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from mbus_framework import __version__
from mbus_framework.estimation.problem import Progress
from mbus_framework.pipeline.config import load_config
from mbus_framework.pipeline.folder_report import write_folder_report
from mbus_framework.pipeline.storage import (
    atomic_write_json,
    atomic_write_text,
)
from mbus_framework.studies.common import (
    StudyResult,
    _Context,
    _save_figure,
    machine_info,
    table_csv,
)
from mbus_framework.studies.element_sweep import _element_sweep
from mbus_framework.studies.monte_carlo import _monte_carlo
from mbus_framework.studies.options import validate_study_options
from mbus_framework.studies.repeatability import _repeatability


# ---------------------------------------------------------------------------------------
# Entry point
# ---------------------------------------------------------------------------------------
def run_study(
    kind: str,
    config_path: str | Path,
    overrides: list[str] | None = None,
    out_dir: str | Path | None = None,
    progress: Progress | None = None,
    *,
    distributed: bool = False,
    workers: int | None = None,
    scheduler: str | None = None,
    client: Any = None,
    **options: Any,
) -> StudyResult:
    """Run study ``kind`` over the base config (with ``--set``-style ``overrides``).

    ``out_dir`` defaults to ``<output.directory>/<date-time>-<config>-<kind>``. ``options``
    are the kind's options (see ``MonteCarloOptions``, ``ElementSweepOptions``,
    ``RepeatabilityOptions``); bad options raise :class:`ConfigError`. The member runs go to
    Dask when ``distributed`` is true or ``workers``, ``scheduler`` or ``client`` (an existing
    ``distributed.Client``) is given; otherwise they run one after another in this process.
    """
    opts = validate_study_options(kind, options)
    overrides = list(overrides or [])
    config = load_config(config_path, overrides)  # fail early on a bad base config
    if out_dir is None:
        stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
        out_dir = Path(config.output.directory) / f"{stamp}-{Path(config_path).stem}-{kind}"
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    study = {"monte_carlo": _monte_carlo, "element_sweep": _element_sweep, "repeatability": _repeatability}[kind]
    on_dask = distributed or client is not None or workers is not None or scheduler is not None
    with _executor(on_dask, workers, scheduler, client) as dask:
        ctx = _Context(kind, str(config_path), overrides, out, progress, opts, client=dask)
        try:
            if dask is not None:
                ctx.plan_ahead(study)
            rows, summary, runs, text, fig = study(ctx)
        finally:
            ctx.cancel_pending()
    text += f"\n\n  written to {out}/: {kind}.csv (table), {kind}.json (summary and every run), " + (
        f"{kind}.png (plot), runs/ (each run's result.json)" if fig is not None else "runs/")
    summary = {
        "kind": kind,
        "config": str(config_path),
        "overrides": overrides,
        "options": opts.model_dump(mode="json"),
        "created": _dt.datetime.now().isoformat(timespec="seconds"),
        "mbus_version": __version__,
        "machine": machine_info(),
        "wall_time_s": time.perf_counter() - t0,
        **summary,
        "table": rows,
        "runs": runs,
    }
    files = {
        "csv": atomic_write_text(out / f"{kind}.csv", table_csv(rows)),
        "json": atomic_write_json(out / f"{kind}.json", summary),
        "text": atomic_write_text(out / f"{kind}.txt", text + "\n"),
    }
    if fig is not None:
        files["png"] = _save_figure(fig, out / f"{kind}.png")
    files["report"] = write_folder_report(out, f"mbus study: {kind.replace('_', ' ')}", text, str(config_path))
    return StudyResult(kind, out, rows, summary, runs, text, files)


@contextmanager
def _executor(on_dask: bool, workers: int | None, scheduler: str | None, client: Any):
    """The campaigns' Dask client (None: run in this process)."""
    if not on_dask:
        yield None
        return
    from mbus_framework.campaigns.executor import dask_client

    with dask_client(workers, scheduler, client) as dask:
        yield dask
