"""``mbus-run``: run an identification from a YAML config.

    mbus-run CONFIG [-o OUTDIR] [--set dotted.key=value ...] [--no-plots] [--quiet]
    mbus-run CAMPAIGN.yaml [-o DIR] [--workers N] [--scheduler ADDRESS]
    mbus-run --list-plugins

A plain fit goes through the Python API (:func:`mbus_framework.run_config`), so the command line and
Python produce the same run folder. User errors (bad config, bad data, instrument failure) print
one line and exit non-zero (2 for input errors, 3 for instruments); Ctrl-C exits 130 and SIGTERM
143, with the run folder marked ``interrupted``. An unexpected exception (a bug) prints one line
too, naming the file that holds its traceback, and exits 70; ``MBUS_DEBUG=1`` lets it through as
a traceback.
"""
from __future__ import annotations

import argparse
import os
import sys

# The engine's matrices are small: threaded BLAS only adds hand-off cost (about 25x slower
# under load on a 2-core machine). Set before numpy is imported; the user's setting wins.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
from contextlib import contextmanager
from typing import Iterator, NoReturn, Sequence

from mbus_framework import __version__
from mbus_framework.errors import MbusError


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="mbus-run",
        description="Model-based ultrasound identification of viscoelastic materials.",
    )
    p.add_argument("config", nargs="?", help="run configuration (YAML)")
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    p.add_argument("-o", "--out", metavar="OUTDIR", help="output folder (default: runs/<time>-<config>)")
    p.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config key, e.g. --set solver.options.strategy.n_starts=4 (repeatable)",
    )
    p.add_argument("--list-plugins", action="store_true", help="show registered plugins and where they come from")
    p.add_argument(
        "--study",
        metavar="KIND",
        help="run a study over the config instead of one fit: monte_carlo, element_sweep, repeatability",
    )
    p.add_argument(
        "--study-option",
        dest="study_options",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="study option, e.g. --study-option n_runs=20 (repeatable)",
    )
    p.add_argument(
        "--compare-models",
        metavar="NAMES",
        help="fit several models (comma-separated names) to the same data and rank them",
    )
    p.add_argument(
        "--design-excitation",
        action="store_true",
        help="rank candidate excitations by D-optimality for the config's model and transducer band",
    )
    p.add_argument("--workers", type=int, metavar="N", help="campaigns and studies: Dask LocalCluster worker processes (default: one per core)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="campaigns and studies: run on the Dask cluster at this address (tcp://host:8786)")
    p.add_argument("--timeout", type=float, metavar="S", help="campaigns: seconds to wait for the scheduler and its first worker (default 15)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the run in OUTDIR (and an existing calibration.output file)")
    p.add_argument("--no-plots", action="store_true", help="do not draw figures (report.html without plots)")
    p.add_argument("-q", "--quiet", action="store_true", help="print only the output folder")
    return p


def list_plugins() -> str:
    """One line per plugin (third-party summaries and sources folded and cut to fit)."""
    from mbus_framework.errors import one_line
    from mbus_framework.interfaces.registry import MAX_NAME, default_registry

    reg = default_registry()
    lines = []
    for kind in reg.entries:
        lines.append(f"{kind}s:")
        for name in reg.names(kind):
            e = reg.entries[kind][name]
            lines.append(f"  {name:<22} {one_line(e.spec.summary, 160)}  [{e.source}]")
        if not reg.entries[kind]:
            lines.append("  (none)")
    if reg.broken:
        lines.append("broken plugins (skipped):")
        for b in reg.broken:
            lines.append(f"  {one_line(b.name, MAX_NAME):<22} {b.error}  [{b.source}]")
    if reg.clashes:
        lines.append("name clashes (these names are unusable until one provider is removed):")
        lines += [f"  {one_line(message, 400)}" for message in reg.clashes.values()]
    return "\n".join(lines)


def _special_mode(args, progress) -> str | None:
    """Studies, model comparison, excitation design and calibration runs; None for a plain fit."""
    if args.study:
        from mbus_framework.studies.options import parse_study_options
        from mbus_framework.studies.runner import run_study

        result = run_study(
            args.study, args.config, args.overrides, args.out, progress, distributed=True, workers=args.workers,
            scheduler=args.scheduler, **parse_study_options(args.study_options)
        )
        return result.text
    if args.compare_models:
        from mbus_framework.studies.compare import run_comparison

        names = [n.strip() for n in args.compare_models.split(",") if n.strip()]
        _table, text = run_comparison(
            args.config, names, args.overrides, out_dir=args.out, progress=progress, plots=False if args.no_plots else None
        )
        return text
    if args.design_excitation:
        from mbus_framework.studies.design import run_design

        return run_design(args.config, args.overrides, args.out)
    from mbus_framework.pipeline.config import load_config

    if load_config(args.config, args.overrides).calibration is not None:
        from mbus_framework.studies.transducer_calibration import run_calibration

        return run_calibration(args.config, args.overrides, args.out, progress, overwrite=args.overwrite)
    return None


def entry() -> NoReturn:
    """The ``mbus-run`` command: :func:`main`, then the process ends at once (:func:`finish`)."""
    finish(main())


def finish(code: int) -> NoReturn:
    """End the process with ``code`` without Python's teardown, which frees the module graph of
    numpy, scipy and pydantic one object at a time (0.1-0.3 s after a run is done). The atexit
    handlers still run and stdout and stderr are flushed; every file mbus writes is closed (and
    synced) by then and the figure helpers are reaped. While a thread other than the main one is
    alive (Dask's, a plugin's), or where ``atexit._run_exitfuncs`` is missing, the teardown runs
    as usual."""
    import atexit
    import threading

    run_exit_handlers = getattr(atexit, "_run_exitfuncs", None)
    if threading.active_count() > 1 or run_exit_handlers is None:
        sys.exit(code)
    run_exit_handlers()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError, AttributeError):  # closed, or a reader gone (EPIPE)
            pass
    os._exit(code)


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)  # --help and --version exit here, before any heavy import
    from mbus_framework.pipeline import figure_workers
    from mbus_framework.pipeline.interrupts import handling

    try:
        with handling(), _one_line_warnings():
            return _main(args)
    finally:
        figure_workers.discard()  # not a plotting run after all (campaign, error, output.plots: false)


def _prestart(args: argparse.Namespace) -> dict | None:
    """Start-up of a run: the fast paths of :mod:`mbus_framework.startup`, then the config's YAML
    read (once: :func:`_png_figures` and :func:`_config_kind` both look at it; None when it is not
    a readable YAML mapping, which the full validation then reports). For a run that may plot, the
    figure helper is forked as soon as that is known, so that it imports matplotlib and the
    figures' modules on the second core while this process imports scipy, pydantic and the
    plugins (:mod:`~mbus_framework.pipeline.figure_workers`)."""
    from mbus_framework.startup import cheap_scipy_notes, collector_paused, defer_unused_numpy, defer_unused_scipy

    defer_unused_numpy()  # imports numpy; before scipy loads (numpy.f2py, .testing, ... about 0.1 s of CPU)
    defer_unused_scipy()  # scipy.spatial, which scipy.optimize imports for shgo (about 0.04 s)
    cheap_scipy_notes()  # before scipy.special, .fft, .linalg, .optimize load (about 0.15 s of CPU)
    with collector_paused():  # start-up: reading the config loads pydantic and the config models
        from mbus_framework.pipeline.config import config_mapping_or_none

        data = config_mapping_or_none(args.config)
    plotting = not (args.no_plots or args.study or args.compare_models or args.design_excitation)
    if plotting and _png_figures(args, data):  # forked after the pause: the helper inherits a running collector
        from mbus_framework.pipeline import figure_workers

        figure_workers.prestart()
    return data


def _png_figures(args: argparse.Namespace, data: dict | None) -> bool:
    """True when the config mapping ``data`` (or a ``--set output.figures=...``) asks for PNG
    figures, drawn by the forked helpers; the default SVG figures are drawn in this process and
    need none."""
    output = (data or {}).get("output")
    fmt = output.get("figures", "svg") if isinstance(output, dict) else "svg"
    for item in args.overrides:
        key, _, value = item.partition("=")
        if key.strip() == "output.figures":
            fmt = value.strip()
    return fmt == "png"


@contextmanager
def _one_line_warnings() -> Iterator[None]:
    """Python warnings (numpy's overflow notes, ...) as one stderr line each, no source line."""
    import warnings

    from mbus_framework.errors import one_line

    def show(message, category, filename, lineno, file=None, line=None):  # noqa: ARG001
        print(f"mbus-run: warning: {one_line(str(message), 300)} ({category.__name__}, "
              f"{os.path.basename(filename)}:{lineno})", file=sys.stderr)

    with warnings.catch_warnings():
        warnings.showwarning = show
        yield


def _main(args: argparse.Namespace) -> int:
    from mbus_framework.pipeline import interrupts

    try:
        if args.list_plugins:
            print(list_plugins())
            return 0
        if not args.config:
            _parser().print_usage(sys.stderr)
            print("mbus-run: error: a CONFIG file is required (or --list-plugins)", file=sys.stderr)
            return 2
        kind = _config_kind(_prestart(args))
        if kind == "campaign":
            from mbus_framework.campaigns.cli import run_from_cli
            from mbus_framework.pipeline import figure_workers

            figure_workers.discard()  # the campaign's fits run (and plot) in Dask's workers
            return run_from_cli(args)
        if kind == "substitution":
            from mbus_framework.substitution.command import run_from_cli as run_substitution

            return run_substitution(args)
        if kind == "joint":
            from mbus_framework.joint.files import run_joint_config

            joint = run_joint_config(args.config, args.overrides, args.out, overwrite=args.overwrite)
            print(joint.run_dir if args.quiet else joint.summary())
            return 0
        from mbus_framework.api import run_config
        from mbus_framework.pipeline.progress import make_long_progress, make_progress
        from mbus_framework.startup import collector_paused

        progress = None if args.quiet else make_progress()
        # a study runs for minutes: progress lines with an ETA in logs too, not only on a terminal
        special = _special_mode(args, None if args.quiet else (make_long_progress() if args.study else progress))
        if special is not None:
            print(special)
            return 0
        with collector_paused():  # start-up: run_config's modules (scipy, the engine, the estimation)
            import mbus_framework.pipeline.run  # noqa: F401
        result = run_config(args.config, args.overrides, args.out, progress=progress if progress is not None else False,
                            plots=False if args.no_plots else None, overwrite=args.overwrite)
        print(result.run_dir if args.quiet else result.summary())
        return 0
    except MbusError as exc:
        print(f"mbus-run: error: {exc.one_line()}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt as exc:
        print(f"mbus-run: {str(exc) or 'interrupted'}", file=sys.stderr)
        return interrupts.exit_status()
    except OSError as exc:
        if exc.filename is None:  # not about a file the user named: a bug, reported below
            return _internal_error(exc)
        from mbus_framework.errors import one_line

        print(f"mbus-run: error: {one_line(str(exc.filename), 300)}: {exc.strerror or type(exc).__name__}",
              file=sys.stderr)
        return 2
    except Exception as exc:  # noqa: BLE001 - last resort: a bug, reported in one line
        if _caused_by_interrupt(exc):  # e.g. "ImportError: initialization failed" when Ctrl-C hits an import
            print("mbus-run: interrupted", file=sys.stderr)
            return interrupts.exit_status()
        return _internal_error(exc)


def _caused_by_interrupt(exc: BaseException) -> bool:
    """True when a Ctrl-C (or SIGTERM) is in ``exc``'s chain of causes."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def _config_kind(data: dict | None) -> str | None:
    """``campaign``, ``substitution`` or ``joint`` for those configs (``data``, a config file's YAML
    mapping, with a top-level ``campaign:`` or ``joint:`` section, or ``experiment: substitution``),
    else None (also for ``data`` None: not a readable YAML mapping); checked from the YAML alone,
    as :func:`mbus_framework.campaigns.spec.is_campaign_file`,
    :func:`mbus_framework.substitution.config.is_substitution_file` and
    :func:`mbus_framework.joint.config.is_joint_file` do, so that a single run imports none of
    those packages (nor Dask)."""
    if data is None:
        return None
    if "campaign" in data:
        return "campaign"
    if data.get("experiment") == "substitution":
        return "substitution"
    return "joint" if "joint" in data else None


def _internal_error(exc: Exception) -> int:
    if os.environ.get("MBUS_DEBUG"):
        raise exc
    print(f"mbus-run: internal error: {_bug_report(exc)}", file=sys.stderr)
    return 70


def _bug_report(exc: Exception) -> str:
    """One line for an unexpected exception; its traceback goes to a file named in the line."""
    import tempfile
    import traceback

    from mbus_framework.errors import one_line

    text = "".join(traceback.format_exception(exc))
    try:
        with tempfile.NamedTemporaryFile("w", prefix="mbus-traceback-", suffix=".txt", delete=False) as fh:
            fh.write(text)
        where = f"traceback in {fh.name}"
    except OSError:
        where = "run with MBUS_DEBUG=1 for the traceback"
    return one_line(f"{type(exc).__name__}: {exc}", 300) + f" (a bug in mbus; {where}; please report it)"


if __name__ == "__main__":  # pragma: no cover
    entry()
