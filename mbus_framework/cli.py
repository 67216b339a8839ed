"""``mbus-run``: run an identification from a YAML config.

    mbus-run CONFIG [-o OUTDIR] [--set dotted.key=value ...] [--no-plots] [--quiet]
    mbus-run --list-plugins

User errors (bad config, bad data, instrument failure) print one line and exit non-zero
(2 for input errors, 3 for instruments); a Python traceback means a bug.
"""
from __future__ import annotations

import argparse
import sys
from typing import Sequence

from .errors import MbusError


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="mbus-run",
        description="Model-based ultrasound identification of viscoelastic materials.",
    )
    p.add_argument("config", nargs="?", help="run configuration (YAML)")
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
    p.add_argument("--no-plots", action="store_true", help="do not write PNG figures")
    p.add_argument("-q", "--quiet", action="store_true", help="print only the output folder")
    return p


def list_plugins() -> str:
    from .registry import default_registry

    reg = default_registry()
    lines = []
    for kind in reg.entries:
        lines.append(f"{kind}s:")
        for name in reg.names(kind):
            e = reg.entries[kind][name]
            lines.append(f"  {name:<22} {e.spec.summary}  [{e.source}]")
        if not reg.entries[kind]:
            lines.append("  (none)")
    if reg.broken:
        lines.append("broken plugins (skipped):")
        for b in reg.broken:
            lines.append(f"  {b.name:<22} {b.error}  [{b.source}]")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        if args.list_plugins:
            print(list_plugins())
            return 0
        if not args.config:
            _parser().print_usage(sys.stderr)
            print("mbus-run: error: a CONFIG file is required (or --list-plugins)", file=sys.stderr)
            return 2
        from .progress import make_progress
        from .report import summary_text
        from .run import execute

        progress = None if args.quiet else make_progress()
        outcome = execute(
            args.config,
            args.overrides,
            args.out,
            progress=progress,
            plots=False if args.no_plots else None,
        )
        print(outcome.run_dir if args.quiet else summary_text(outcome.result, outcome.run_dir))
        return 0
    except MbusError as exc:
        print(f"mbus-run: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("mbus-run: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
