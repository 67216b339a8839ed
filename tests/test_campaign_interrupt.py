"""Ctrl-C while a campaign writes its outputs: the outputs are written once more, undisturbed,
campaign.json says "interrupted", and the table holds every finished row. Ctrl-C while the
LocalCluster starts: the worker processes ignore it (no traceback) and the client stops at once."""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time

import pandas as pd
import psutil
import pytest

from campaign_helpers import BASE, ENV, write_campaign
from mbus_framework.campaigns import CampaignInterrupted, run_campaign
from mbus_framework.campaigns import runner
from mbus_framework.campaigns.quiet_start import (HEARTBEAT_ERROR, quiet_heartbeat_errors, start_cluster,
                                                workers_ignore_sigint)


def test_ctrl_c_while_the_table_is_written(tmp_path, monkeypatch):
    rows = [{"sample_id": f"s{i}", "cultivar": "xy"[i % 2], "backend.options.seed": i} for i in range(3)]
    path = write_campaign(tmp_path, rows)
    out = tmp_path / "out"
    first = run_campaign(path, out, workers=1)
    assert first.failed == [] and len(first.table) == 3
    (out / "properties.csv").unlink()

    calls = []
    real = runner.write_table

    def interrupted_once(*args, **kwargs):
        calls.append(1)
        if len(calls) == 1:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(runner, "write_table", interrupted_once)
    with pytest.raises(CampaignInterrupted) as caught:
        run_campaign(path, out)  # every fit reused: only the outputs are written
    assert caught.value.result.interrupted and sorted(caught.value.result.reused) == ["s0", "s1", "s2"]
    assert json.loads((out / "campaign.json").read_text())["status"] == "interrupted"
    table = pd.read_csv(out / "properties.csv")
    assert table["sample_id"].tolist() == ["s0", "s1", "s2"]
    assert table["E_sigma"].tolist() == first.table["E_sigma"].tolist()


def test_processes_spawned_for_a_local_cluster_start_with_ctrl_c_ignored():
    """The spawn wrapper: a child started inside the block has SIGINT ignored from its start (no
    handler of ours runs in it), one started after it gets what this process would pass on:
    Python's KeyboardInterrupt handler, or SIGINT ignored when this process was itself started
    with it ignored (a background job of a non-interactive shell, ``nohup``)."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    inherited = signal.SIG_IGN if signal.getsignal(signal.SIGINT) == signal.SIG_IGN else signal.default_int_handler
    ctx = multiprocessing.get_context("spawn")
    with workers_ignore_sigint(), ProcessPoolExecutor(1, mp_context=ctx) as pool:
        assert pool.submit(signal.getsignal, signal.SIGINT).result(timeout=120) == signal.SIG_IGN
    with ProcessPoolExecutor(1, mp_context=ctx) as pool:
        assert pool.submit(signal.getsignal, signal.SIGINT).result(timeout=120) == inherited


@pytest.mark.parametrize("moment", ["workers starting",
                                    pytest.param("first fit running", marks=pytest.mark.slow)])  # ~20 s: closing waits for the fit
def test_ctrl_c_on_a_local_cluster_prints_no_worker_traceback(tmp_path, moment):
    """Ctrl-C at a terminal (SIGINT to the whole process group) while the LocalCluster's worker
    processes are still importing, or while the first fit runs: no worker traceback, no Dask
    error or log line, exit 130, campaign.json "interrupted", no process of the campaign left."""
    base = json.loads(json.dumps(BASE))
    base["excitation"]["options"]["n_samples"] = 2000  # about 1 s per fit
    rows = [{"sample_id": f"s{i}", "cultivar": "x", "backend.options.seed": i} for i in range(2)]
    path = write_campaign(tmp_path, rows, base=base)
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "mbus_framework.cli", str(path), "-o", str(out), "--workers", "2"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            env=ENV)
    parent, deadline = psutil.Process(proc.pid), time.monotonic() + 180
    started = (lambda: _spawned(parent)) if moment == "workers starting" else (lambda: list(out.glob("runs/.s*")))
    while not started():
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.005)
    if moment == "workers starting":
        time.sleep(0.3)  # the workers are importing Python, numpy, distributed (seconds)
    workers = _spawned(parent)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err and " - distributed." not in err, err
    assert re.fullmatch(r"mbus-run: interrupted: [012] of 2 fits finished; run again to continue",
                        err.strip().splitlines()[-1]), err
    assert json.loads((out / "campaign.json").read_text())["status"] == "interrupted"
    assert not [w for w in workers if w.is_running() and w.status() != psutil.STATUS_ZOMBIE]


def test_a_local_cluster_worker_drops_only_the_heartbeat_error(caplog):
    """A LocalCluster's scheduler is in the client's process: a worker still busy when the client
    closes it may heartbeat once more; that one error line (with its traceback) is dropped."""
    import logging

    logger = logging.getLogger("test-heartbeat")
    quiet = quiet_heartbeat_errors(logger)
    try:
        with caplog.at_level(logging.INFO, logger="test-heartbeat"):
            logger.error(HEARTBEAT_ERROR)
            logger.error("Unexpected exception during heartbeat. Closing worker.")
    finally:
        logger.removeFilter(quiet)
    assert [r.getMessage() for r in caplog.records] == ["Unexpected exception during heartbeat. Closing worker."]


def _spawned(parent) -> list:
    """The multiprocessing (spawn) children of ``parent``: the LocalCluster's worker processes."""
    found = []
    for child in parent.children(recursive=True):
        try:
            if "--multiprocessing-fork" in child.cmdline():
                found.append(child)
        except psutil.Error:  # gone, or a zombie
            pass
    return found


def test_a_local_cluster_that_cannot_start_is_a_one_line_error(monkeypatch):
    """The cluster is built in a helper thread: its error still reaches the caller as before."""
    import distributed

    from mbus_framework.campaigns.cluster import ClusterError
    from mbus_framework.campaigns.executor import dask_client

    def refused(**kwargs):
        raise OSError(98, "Address already in use")

    monkeypatch.setattr(distributed, "LocalCluster", refused)
    with pytest.raises(ClusterError, match=r"^cannot start a Dask LocalCluster of 1 worker processes: \[Errno 98\] "
                                           r"Address already in use$"):
        with dask_client(workers=1):
            pass
    assert start_cluster(dict, workers=1) == {"workers": 1}
