"""``mbus-analyze``: analyses of a campaign table.

    mbus-analyze classify TABLE --by COLUMN [...]
    mbus-analyze calibrate TABLE [...]
    mbus-analyze apply-calibration TABLE --calibration FILE [...]
    mbus-analyze crispness TABLE --scores PANEL [...]
    mbus-analyze predict TABLE --model FILE [...]

Each subcommand lives in its own module, which provides ``add_arguments(parser)`` and
``run(args) -> int``. User errors print one line and exit 2, as in ``mbus-run``. The command
(:func:`entry`) starts and ends as ``mbus-run`` does: the fast paths of
:mod:`mbus_framework.startup` before the subcommand runs, and no interpreter teardown after it.
"""
from __future__ import annotations

import argparse
import importlib
import os
import sys
from typing import NoReturn, Sequence

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from mbus_framework import __version__
from mbus_framework.errors import MbusError

#: subcommand -> (module under mbus_framework.analysis, one-line help)
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "classify": ("classify.command", "k-means and LDA (leave-one-out) by group, Tables 4.4/4.5"),
    "calibrate": ("calibrate.command", "regress MBUS estimates on conventional tests, Table 6.1"),
    "apply-calibration": ("calibrate.command", "convert MBUS estimates with a saved calibration"),
    "crispness": ("crispness.command", "predict sensory scores with an LM-trained network, Ch. 7"),
    "predict": ("crispness.command", "score new samples with a saved crispness model"),
}


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="mbus-analyze", description="Analyses of an mbus campaign table.")
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_text) in SUBCOMMANDS.items():
        sp = sub.add_parser(name, help=help_text, description=help_text)
        try:
            mod = importlib.import_module(f"{__package__}.{module}")
        except ModuleNotFoundError as exc:
            if exc.name != f"{__package__}.{module}":
                raise
            sp.set_defaults(_unavailable=name)
            continue
        mod.add_arguments(sp, name) if _takes_name(mod) else mod.add_arguments(sp)
        sp.set_defaults(_run=mod.run)
    return p


def _takes_name(mod) -> bool:
    import inspect

    return len(inspect.signature(mod.add_arguments).parameters) >= 2


def entry() -> NoReturn:
    """The ``mbus-analyze`` command: :func:`main` with the start-up fast paths, then the process
    ends at once (:func:`mbus_framework.cli.finish`), also after ``--help`` and usage errors."""
    from mbus_framework.cli import finish

    try:
        code = main(fast_start=True)
    except SystemExit as exc:  # argparse: --help, --version, a usage error
        if not isinstance(exc.code, int):
            raise
        code = exc.code
    finish(code)


def main(argv: Sequence[str] | None = None, *, fast_start: bool = False) -> int:
    """Parse ``argv`` and run the subcommand; its exit status. With ``fast_start`` (the command
    line), :func:`fast_start_paths` is applied once the arguments are parsed."""
    parser = _parser()
    args = parser.parse_args(argv)
    if not args.command:
        parser.print_usage(sys.stderr)
        print("mbus-analyze: error: a COMMAND is required", file=sys.stderr)
        return 2
    if getattr(args, "_unavailable", None):
        print(f"mbus-analyze: error: '{args.command}' is not available in this version", file=sys.stderr)
        return 2
    if fast_start:
        fast_start_paths()
    try:
        return int(args._run(args) or 0)
    except MbusError as exc:
        print(f"mbus-analyze: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("mbus-analyze: interrupted", file=sys.stderr)
        return 130


def fast_start_paths() -> None:
    """The process-local start-up fast paths of :mod:`mbus_framework.startup`, as ``mbus-run``
    applies them: numpy's unused submodules and scipy.spatial made lazy (scikit-learn and
    statsmodels load scipy.spatial on first use; the lazy module is then the real one) and scipy's
    docstring notes added without numpydoc's parse. Applied after parsing, so that ``--help``
    does not pay for them; the subcommands' modules load numpy but not scipy at that point."""
    from mbus_framework.startup import cheap_scipy_notes, defer_unused_numpy, defer_unused_scipy

    defer_unused_numpy()  # before scipy's array-API namespace runs ``from numpy import *``
    defer_unused_scipy()
    cheap_scipy_notes()  # before scipy.special, .linalg, .optimize, .stats load


if __name__ == "__main__":  # pragma: no cover
    entry()
