"""From sheet rows to fit tasks: resolve each sample's run config, validate it in-process
(the run-config stages 1 and 2 and the initial values, as ``mbus-run`` does before it acquires),
group replicates, and key each task by the content hash of what it fits."""
from __future__ import annotations

import copy
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mbus_framework.campaigns.hashing import content_key, input_digests
from mbus_framework.campaigns.paths import resolve_paths
from mbus_framework.campaigns.problems import Problems
from mbus_framework.campaigns.sheet import DATA, SheetRow
from mbus_framework.campaigns.spec import Campaign
from mbus_framework.errors import MbusError
from mbus_framework.pipeline.components import build_components
from mbus_framework.pipeline.config import apply_overrides, validate_structure

AVERAGED, FITTED, JOINT, AUTO = "averaged", "fitted", "joint", "auto"
#: campaign.replicates -> the task's ``replicates`` (one task per sample for all but "fit")
MODES = {"average": AVERAGED, "fit": FITTED, "joint": JOINT, "auto": AUTO}


@dataclass(frozen=True)
class SampleTask:
    """One fit of a campaign (what a Dask worker receives).

    ``configs`` holds one resolved run config, or one per replicate when the replicate records
    are averaged before a single fit. ``key`` is the content hash used to resume; ``inputs`` the
    ``(absolute path, SHA-256)`` of every file the fit reads, as the client saw them; ``attempt``
    the token of the campaign run that sent the task (a result is committed only while it is
    the campaign folder's current one).
    """

    label: str
    sample_id: str
    replicate: int | None
    replicates: str
    n_replicates: int
    configs: tuple[dict[str, Any], ...]
    replicate_numbers: tuple[int, ...]
    source: str
    run_dir: str
    plots: bool
    key: str
    groups: dict[str, Any] = field(default_factory=dict)
    covariates: dict[str, Any] = field(default_factory=dict)
    parameter_names: tuple[str, ...] = ()
    property_names: tuple[str, ...] = ()
    sample: dict[str, float] = field(default_factory=dict)
    inputs: tuple[tuple[str, str], ...] = ()
    attempt: str = ""
    units: dict[str, str] = field(default_factory=dict)  # parameter and property name -> unit


def run_label(sample_id: str, replicate: int | None = None) -> str:
    """A run-folder name for a sample (and replicate): letters, digits, ``_.-`` only."""
    name = re.sub(r"[^A-Za-z0-9_.-]+", "_", sample_id).strip("_.") or "sample"
    return name if replicate is None else f"{name}-r{replicate}"


def plan_campaign(campaign: Campaign, out_dir: str | Path, plots: bool | None = None,
                  problems: Problems | None = None) -> list[SampleTask]:
    """Every fit of ``campaign`` in sheet order; raises :class:`CampaignError` listing every
    problem (those already in ``problems`` first)."""
    problems = problems if problems is not None else Problems()
    resolved: dict[int, tuple[dict, Any]] = {}
    unattributed: dict[str, list[str]] = {}
    base = resolve_paths(copy.deepcopy(campaign.base), campaign.base_source.parent)
    for i, row in enumerate(campaign.rows):
        got = _resolve(campaign, base, row, problems, unattributed)
        if got is not None:
            resolved[i] = got
    for message, where in unattributed.items():
        rows = "every row" if len(where) == len(campaign.rows) else ", ".join(where[:5]) + (" ..." if len(where) > 5 else "")
        problems.add(f"{campaign.base_source}: {message} (for {rows} of the sheet)")
    by_sample: dict[str, list[int]] = {}
    for i, row in enumerate(campaign.rows):
        by_sample.setdefault(row.sample_id, []).append(i)
    for members in by_sample.values():
        _check_replicates(campaign, members, resolved, problems)
    tasks: list[SampleTask] = []
    labels: dict[str, str] = {}
    runs = Path(out_dir).resolve() / "runs"
    for sample_id, members in by_sample.items():
        members = sorted(members, key=lambda i: campaign.rows[i].replicate)
        if any(i not in resolved for i in members):
            continue
        units = [[i] for i in members] if campaign.spec.replicates == "fit" else [members]
        for unit in units:
            task = _task(campaign, [campaign.rows[i] for i in unit], [resolved[i] for i in unit], len(members), runs, plots)
            other = labels.setdefault(task.label, sample_id)
            if other != sample_id:
                problems.add(f"{campaign.rows[unit[0]].at('sample_id')}: samples '{other}' and '{sample_id}' both "
                             f"give the run folder name '{task.label}'; rename one")
            tasks.append(task)
    problems.raise_if_any()
    return tasks


def _resolve(campaign: Campaign, base: dict, row: SheetRow, problems: Problems, unattributed: dict[str, list[str]]):
    """The validated run config of one row (mapping and RunConfig), or None after adding a problem;
    ``base`` is the campaign's base config with its paths made absolute, and so are the row's."""
    data = copy.deepcopy(base)
    if row.data is not None:
        backend = data.get("backend") if isinstance(data.get("backend"), dict) else {}
        if backend.get("name") == "file":
            backend = {**backend, "options": {**(backend.get("options") or {}), "path": str(row.data)}}
        else:
            backend = {"name": "file", "options": {"path": str(row.data)}}
        data["backend"] = backend
    try:
        for key, text in row.overrides.items():
            data = apply_overrides(data, [f"{key}={text}"], where=row.at(key))
        data = resolve_paths(data, row.folder, unchanged_from=base)
        config = validate_structure(data, row.where)
        c = build_components(config, row.where)
        if config.model.initial:
            c.model.theta_from_mapping(config.model.initial, f"{row.where}: model.initial")
    except MbusError as exc:
        message = str(exc)
        prefix = f"{row.where}: "
        if not message.startswith(prefix):
            problems.add(message)
            return None
        rest = message[len(prefix):]
        column = _blame(rest.split(":")[0].split(" ")[0], row)
        if column is None:
            unattributed.setdefault(rest, []).append(row.where.rpartition(": ")[2])
        else:
            problems.add(f"{row.at(column)}: {rest.removeprefix(column + ': ')}")
        return None
    return config.model_dump(mode="json"), c


def _blame(path: str, row: SheetRow) -> str | None:
    """The sheet column whose value the failing config key path came from, if any."""
    columns = list(row.overrides) + ([DATA] if row.data is not None else [])
    for column in columns:
        key = "backend.options.path" if column == DATA else column
        if path == key or path.startswith(key + ".") or key.startswith(path + "."):
            return column
    return None


def _check_replicates(campaign: Campaign, members: list[int], resolved, problems: Problems) -> None:
    """Replicates of one sample (rows ``members``) share its group labels; replicates averaged
    (``average``, ``auto``) share every setting but the backend (each is its own record), jointly
    fitted ones (``joint``) every setting but the backend and the sample geometry; being one fit,
    they share their covariates."""
    i = members[0]
    first = campaign.rows[i]
    mode = campaign.spec.replicates
    averaged = mode != "fit" and len(members) > 1
    ignored = ("backend", "output", "sample") if mode == "joint" else ("backend", "output")
    for j in members[1:]:
        row = campaign.rows[j]
        for name, value in row.groups.items():
            if value != first.groups.get(name):
                problems.add(f"{row.at(name)}: sample '{row.sample_id}' is '{first.groups.get(name)}' on "
                             f"{first.where.rpartition(': ')[2]} but '{value}' here; a sample has one group label")
        if not averaged:
            continue
        for name, value in row.covariates.items():
            if value != first.covariates.get(name):
                problems.add(f"{row.at(name)}: replicates of sample '{row.sample_id}' are combined into one fit "
                             f"(campaign.replicates: {mode}), so they share one value ({first.covariates.get(name)!r} "
                             f"on {first.where.rpartition(': ')[2]})")
        if i in resolved and j in resolved and _without(resolved[i][0], ignored) != _without(resolved[j][0], ignored):
            keys = sorted(k for k in set(row.overrides) | set(first.overrides)
                          if not k.startswith("backend.") and row.overrides.get(k) != first.overrides.get(k))
            but = "the backend, data and sample" if mode == "joint" else "the backend and data"
            problems.add(f"{row.at(keys[0] if keys else 'sample_id')}: replicates of sample '{row.sample_id}' are "
                         f"combined into one fit (campaign.replicates: {mode}), so they must share every setting "
                         f"but {but}; {first.where.rpartition(': ')[2]} differs")


def _without(config: dict, keys: tuple[str, ...]) -> dict:
    return {k: v for k, v in config.items() if k not in keys}


def _task(campaign: Campaign, rows: list[SheetRow], resolved: list[tuple[dict, Any]], n_replicates: int,
          runs: Path, plots: bool | None) -> SampleTask:
    first, (config, components) = rows[0], resolved[0]
    averaged = campaign.spec.replicates != "fit"
    replicate = None if averaged else first.replicate
    label = run_label(first.sample_id, replicate)
    configs = tuple(c for c, _ in resolved)
    numbers = tuple(r.replicate for r in rows)
    source = str(campaign.base_source.parent / f"{campaign.path.name}[{label}]")
    model = components.model
    inputs = input_digests(configs)
    return SampleTask(
        label=label,
        sample_id=first.sample_id,
        replicate=replicate,
        replicates=MODES[campaign.spec.replicates],
        n_replicates=n_replicates,
        configs=configs,
        replicate_numbers=numbers,
        source=source,
        run_dir=str(runs / label),
        plots=config["output"]["plots"] if plots is None else bool(plots),
        key=content_key(configs, numbers, campaign.spec.replicates, inputs),
        inputs=inputs,
        groups=dict(first.groups),
        covariates=dict(first.covariates),
        parameter_names=tuple(model.parameter_names),
        property_names=tuple(p.name for p in model.properties),
        units={p.name: p.unit for p in [*model.parameters, *model.properties]},
        sample=dict(config["sample"]),
    )
