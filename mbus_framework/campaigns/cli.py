"""``mbus-run CAMPAIGN.yaml [-o DIR] [--workers N] [--scheduler ADDRESS] [--timeout S]``.

Exit status: 0 when every sample was fitted, 1 when some failed (the summary and the table's
``error`` column say which), 2 for an invalid campaign (every problem printed, one per line),
130 after Ctrl-C and 143 after SIGTERM (a re-run continues where this one stopped).
"""
from __future__ import annotations

import logging
import signal
import sys
import threading

from mbus_framework.campaigns.problems import CampaignError
from mbus_framework.campaigns.runner import CampaignInterrupted, run_campaign, summary_text


def run_from_cli(args) -> int:
    """Run the campaign named by ``args.config`` with the ``mbus-run`` options."""
    other = [flag for flag, on in (("--study", args.study), ("--compare-models", args.compare_models),
                                   ("--design-excitation", args.design_excitation)) if on]
    if other:
        print(f"mbus-run: error: {args.config}: {other[0]} runs on a run config, not on a campaign file", file=sys.stderr)
        return 2
    terminated: list[int] = []
    previous = _terminate_as_interrupt(terminated)
    try:
        with _dask_errors_only():
            result = run_campaign(
                args.config,
                args.out,
                overrides=args.overrides,
                workers=args.workers,
                scheduler=args.scheduler,
                timeout=getattr(args, "timeout", None),
                plots=False if args.no_plots else None,
                progress=False if args.quiet else None,
            )
    except CampaignError as exc:
        for line in exc.lines:
            print(f"mbus-run: error: {line}", file=sys.stderr)
        return exc.exit_code
    except CampaignInterrupted as exc:
        print(summary_text(exc.result) if not args.quiet else exc.result.out_dir, file=sys.stderr)
        print(f"mbus-run: {exc}" + (" (SIGTERM)" if terminated else ""), file=sys.stderr)
        return 143 if terminated else 130
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    print(result.out_dir if args.quiet else summary_text(result))
    return 1 if result.failed else 0


def _dask_errors_only():
    """Dask's own log lines at ERROR and above only, for the whole run: a LocalCluster shows
    only those while it runs, and its INFO lines of connections closing after a Ctrl-C (with a
    traceback) are not the user's business."""
    from distributed.utils import silence_logging_cmgr

    return silence_logging_cmgr(logging.ERROR)


def _terminate_as_interrupt(terminated: list[int]):
    """SIGTERM stops a campaign as Ctrl-C does (cancel, close the cluster, keep what finished);
    ``terminated`` records that it came."""

    def handler(signum, frame):
        terminated.append(signum)
        raise KeyboardInterrupt

    if threading.current_thread() is not threading.main_thread():
        return None
    return signal.signal(signal.SIGTERM, handler)
