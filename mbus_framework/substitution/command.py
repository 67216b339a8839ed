"""``mbus-run CONFIG`` for ``experiment: substitution`` configs: read, analyse, write a run folder
(config.yaml, result.json, dispersion.csv, dispersion.png, report.html) and print the summary."""
from __future__ import annotations

import shutil
from pathlib import Path

from mbus_framework.errors import DataError
from mbus_framework.substitution import config as cfg
from mbus_framework.substitution.analysis import SubstitutionAnalysis, analyse
from mbus_framework.substitution.record import read_mat
from mbus_framework.substitution.report import (plot_dispersion, result_dict, summary, write_dispersion_csv, write_html,
                                                write_ranking_csv)


def run(path: str | Path, overrides: list[str] | None = None, out: str | Path | None = None, *,
        plots: bool = True, overwrite: bool = False, laws: list[str] | None = None) -> tuple[SubstitutionAnalysis, Path]:
    """Run the analysis a config describes into a run folder; returns (analysis, folder).
    ``laws`` (``--compare-models``) replaces the config's law list; the ranking goes to compare.csv."""
    from mbus_framework.pipeline.run_folder import RunFolder
    from mbus_framework.pipeline.storage import atomic_write_json

    c = cfg.load(path, overrides)
    if laws is not None:
        c.laws = cfg.check_laws(laws, str(c.source), key="--compare-models")
    try:
        record = read_mat(c.path, column=c.column, variables=c.variables, overrides=c.overrides, passes=c.passes)
        analysis = analyse(record, c.laws, reverberations=c.reverberations, band_dB=c.band_dB)
    except ValueError as exc:
        raise DataError(str(exc)) from None
    if out is None:
        folder = RunFolder.create(parent=c.output_directory, source=Path(path).stem, overwrite=overwrite)
    else:
        folder = RunFolder.create(out, overwrite=overwrite)
    with folder:
        d = folder.path
        shutil.copyfile(c.source, d / "config.yaml")
        result = result_dict(analysis, c.title)
        result["config"] = {"data": str(c.path), "laws": c.laws, "column": c.column, "band_dB": c.band_dB,
                            "reverberations": c.reverberations}
        atomic_write_json(d / "result.json", result)
        write_dispersion_csv(analysis, d / "dispersion.csv")
        if len(analysis.fits) > 1:
            write_ranking_csv(analysis, d / "compare.csv")
        if plots:
            plot_dispersion(analysis, d / "dispersion.png")
        write_html(analysis, d / "report.html", d / "dispersion.png" if plots else None)
        (d / "summary.txt").write_text(summary(analysis) + "\n")
    return analysis, folder.path


def run_from_cli(args) -> int:
    names = getattr(args, "compare_models", None)
    laws = [n.strip() for n in names.split(",") if n.strip()] if names else None
    if laws == ["all"]:
        laws = "all"
    analysis, run_dir = run(args.config, args.overrides, args.out, plots=not args.no_plots, overwrite=args.overwrite,
                            laws=laws)
    print(run_dir if args.quiet else summary(analysis, run_dir))
    return 0
