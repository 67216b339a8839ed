"""Campaigns on real Dask clusters: a LocalCluster of worker processes (shared by the module's
tests; the Ctrl-C test's mbus-run starts and stops its own), a scheduler started separately and
reached by address, Ctrl-C half-way and a re-run, a corrupt file among good ones, averaged
against fitted replicates, and studies through the same executor."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import psutil
import pytest

from campaign_helpers import (BASE, draw_truths, free_port, processes, scheduler_cmd, simulate_record, truth_columns,
                              worker_cmd, write_campaign)
from mbus_framework.campaigns import run_campaign
from mbus_framework.campaigns.executor import dask_client
from mbus_framework.campaigns.worker import MARKER
from mbus_framework.cli import main

PROPS = ["E_sigma", "eta_sigma", "E_tau", "eta_tau"]
STUDY = Path(__file__).parent / "data" / "studies_small.yaml"


@pytest.fixture(scope="module")
def client():
    """One LocalCluster (2 single-threaded worker processes) shared by this module's tests."""
    with dask_client(workers=2) as c:
        yield c


def replicate_rows(truths: list[dict], replicates: list[int]) -> list[dict]:
    rows, seed = [], 100
    for i, (truth, n) in enumerate(zip(truths, replicates)):
        for r in range(1, n + 1):
            seed += 1
            rows.append({"sample_id": "abc"[i], "replicate": r, "cultivar": "xy"[i % 2], "firmness": f"{1 + i}.5",
                         "backend.options.seed": seed, **truth_columns(truth)})
    return rows


def within(table: pd.DataFrame, truths: dict[str, dict], k: float = 4.0) -> None:
    """Every fitted property within k standard errors of its sample's truth."""
    for _, row in table.iterrows():
        for p in PROPS:
            assert abs(row[p] - truths[row["sample_id"]][p]) <= k * row[f"{p}_se"], (row["sample_id"], p)


@pytest.fixture(scope="module")
def averaged_run(tmp_path_factory, client):
    """The campaign of 3 samples (2, 2 and 1 records) with replicates averaged, on the module's
    LocalCluster."""
    folder = tmp_path_factory.mktemp("averaged")
    truths = draw_truths(3, seed=21)
    path = write_campaign(folder, replicate_rows(truths, [2, 2, 1]), covariates=["firmness"])
    result = run_campaign(path, folder / "out", client=client)
    return result, dict(zip("abc", truths)), folder


def test_a_campaign_runs_on_a_local_cluster_of_worker_processes(averaged_run, client):
    result, truths, _ = averaged_run
    out = result.out_dir
    markers = {d.name: json.loads((d / MARKER).read_text()) for d in (out / "runs").iterdir()}
    assert sorted(markers) == ["a", "b", "c"]
    workers = set(client.run(os.getpid).values())
    assert len(workers) == 2 and os.getpid() not in workers
    # fits are sent to the workers ahead, not queued on the scheduler one round trip at a time
    assert client.run_on_scheduler(lambda dask_scheduler: dask_scheduler.WORKER_SATURATION) == float("inf")
    assert {m["worker"]["pid"] for m in markers.values()} <= workers  # fitted in the cluster's worker processes
    meta = json.loads((out / "campaign.json").read_text())
    assert meta["status"] == "finished" and meta["fitted"] == 3 and meta["failed"] == 0
    assert meta["cluster"]["workers"] == 2
    table = pd.read_parquet(out / "properties.parquet")
    params = ["k_sigma", "b_sigma", "k_tau", "b_tau"]
    assert list(table.columns) == [  # docs/campaign-table.md
        "sample_id", "cultivar", "replicate", "replicates", "n_replicates", "sample_length", "sample_diameter",
        "sample_density", *params, *(f"{p}_se" for p in params), *PROPS, *(f"{p}_se" for p in PROPS),
        *(f"{p}_ci_low" for p in PROPS), *(f"{p}_ci_high" for p in PROPS), "nrmse", "success", "warnings", "error",
        *(f"true_{p}" for p in params), *(f"true_{p}" for p in PROPS), "firmness", "run_dir", "fit_time_s"]
    assert {c: str(t) for c, t in table.dtypes.items() if str(t) != "float64"} == {
        "sample_id": "string", "cultivar": "string", "replicate": "Int64", "replicates": "string",
        "n_replicates": "int64", "success": "bool", "warnings": "string", "error": "string", "run_dir": "string"}
    assert table["sample_id"].tolist() == ["a", "b", "c"] and table["error"].isna().all()
    for _, row in table.iterrows():  # the table is each run's result.json
        res = json.loads((out / row["run_dir"] / "result.json").read_text())
        for p in PROPS:
            assert row[p] == res["properties"][p]
            assert row[f"{p}_se"] == res["uncertainty"]["property_standard_errors"][p]
            assert [row[f"{p}_ci_low"], row[f"{p}_ci_high"]] == res["uncertainty"]["property_ci95"][p]
            assert row[f"true_{p}"] == pytest.approx(truths[row["sample_id"]][p], rel=1e-12)
        assert row["nrmse"] == res["fit"]["nrmse"] and row["success"] == res["solver"]["success"]
    within(table, truths)
    assert table["firmness"].tolist() == [1.5, 2.5, 3.5]
    assert (out / "group_summary.csv").exists() and sorted(p.name for p in (out / "plots").iterdir()) == sorted(
        f"{p}_by_group.png" for p in PROPS)
    page = campaign_page(out)
    assert len(page.all("img")) == len(PROPS)  # every property by group, embedded
    assert "Group summary" in page.plain and "failed" in page.plain
    assert "E_sigma mean (SD %)" in page.plain and "error of each group mean against the mean truth" in page.plain
    links = sorted(a["href"] for a in page.all("a") if a["href"].endswith("report.html"))
    assert links == [f"runs/{s}/report.html" for s in "abc"] and all((out / h).is_file() for h in links)


def test_averaged_and_fitted_replicates(averaged_run, client):
    averaged, truths, folder = averaged_run
    a = averaged.table.set_index("sample_id")
    assert a["replicates"].tolist() == ["averaged"] * 3 and a["replicate"].isna().all()
    assert a["n_replicates"].tolist() == [2, 2, 1]
    run_a = averaged.out_dir / "runs" / "a"
    recs = [np.loadtxt(run_a / "replicates" / f"r{r}" / "measurement.csv", delimiter=",", skiprows=1) for r in (1, 2)]
    fitted_data = np.loadtxt(run_a / "measurement.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(fitted_data[:, 1:], (recs[0][:, 1:] + recs[1][:, 1:]) / 2, rtol=1e-15, atol=1e-300)
    assert not (averaged.out_dir / "runs" / "c" / "replicates").exists()  # one record: fitted as it is

    path = write_campaign(folder / "fit", replicate_rows(list(truths.values()), [2, 2, 1]), covariates=["firmness"],
                          replicates="fit")
    fitted = run_campaign(path, folder / "fit" / "out", client=client)
    f = fitted.table
    assert f["sample_id"].tolist() == ["a", "a", "b", "b", "c"] and f["replicate"].tolist() == [1, 2, 1, 2, 1]
    assert f["replicates"].tolist() == ["fitted"] * 5 and f["n_replicates"].tolist() == [2, 2, 2, 2, 1]
    within(f, truths)
    # the same record either way (same seed, same truth)
    assert (fitted.out_dir / "runs" / "a-r2" / "measurement.csv").read_bytes() == (
        run_a / "replicates" / "r2" / "measurement.csv").read_bytes()
    # averaging two records halves the noise variance: the averaged fit's SE is ~1/sqrt(2) of a replicate's
    for p in PROPS:
        assert a.loc["a", f"{p}_se"] < 0.85 * f.loc[f["sample_id"] == "a", f"{p}_se"].mean()
    samples = pd.read_csv(fitted.out_dir / "samples.csv").set_index("sample_id")
    for p in PROPS:
        assert samples.loc["a", p] == pytest.approx(f.loc[f["sample_id"] == "a", p].mean(), rel=1e-12)
        assert samples.loc["a", f"{p}_sd"] == pytest.approx(f.loc[f["sample_id"] == "a", p].std(ddof=1), rel=1e-12)
    assert samples.loc["c", "n_fitted"] == 1


def test_a_corrupt_file_fails_its_row_only_and_resume_follows_the_content(tmp_path, client, capsys):
    truths = dict(zip(["s0", "s1", "s2", "s3"], draw_truths(4, seed=33)))
    for i, (sid, truth) in enumerate(truths.items()):
        simulate_record(tmp_path / "rec" / f"{sid}.csv", truth, seed=i)
    good = (tmp_path / "rec" / "s2.csv").read_text()
    lines = good.splitlines()
    lines[300] = lines[300].rsplit(",", 1)[0] + ",0.1.2"  # a damaged number in the middle of the file
    (tmp_path / "rec" / "s2.csv").write_text("\n".join(lines) + "\n")
    rows = [{"sample_id": sid, "cultivar": "x", "data": f"rec/{sid}.csv", "sample.length": "0.03"} for sid in truths]
    path = write_campaign(tmp_path, rows)
    out = tmp_path / "out"

    first = run_campaign(path, out, client=client)
    assert first.failed == ["runs/s2"]
    t = first.table.set_index("sample_id")
    assert "s2.csv" in t.loc["s2", "error"] and np.isnan(t.loc["s2", "E_sigma"]) and not t.loc["s2", "success"]
    ok = first.table[first.table["error"].isna()]
    assert ok["sample_id"].tolist() == ["s0", "s1", "s3"]
    within(ok, truths)
    assert "1 failed" in _summary(first)
    page = campaign_page(out)
    assert "Failed rows" in page.plain and "s2.csv" in page.plain

    # A re-run with nothing changed fits nothing (no cluster is even started), exit status 1.
    assert main([str(path), "-o", str(out)]) == 1
    printed = capsys.readouterr().out
    assert "0 run now, 4 reused from an earlier run, 1 failed" in printed and "s2: " in printed

    # Repair the file and change one override cell: exactly those two samples are fitted again.
    (tmp_path / "rec" / "s2.csv").write_text(good)
    rows[0]["sample.length"] = "0.0301"
    write_campaign(tmp_path, rows)
    second = run_campaign(path, out, client=client)
    assert sorted(second.fitted) == ["s0", "s2"] and sorted(second.reused) == ["s1", "s3"]
    assert second.failed == [] and len(second.table) == 4
    s0 = second.table.set_index("sample_id").loc["s0"]
    assert s0["sample_length"] == 0.0301
    within(second.table[second.table["sample_id"] != "s0"], truths)


def campaign_page(out: Path):
    """The campaign's report.html, parsed; self-contained (nothing fetched: no scripts, style
    sheets or frames, every image a data URI; links only to sections and the runs' reports)."""
    from test_report import Page

    page = Page((out / "report.html").read_text(encoding="utf-8"))
    assert not page.all("script") and not page.all("link") and not page.all("iframe")
    assert all(img["src"].startswith("data:image/png;base64,") for img in page.all("img"))
    assert all(a["href"].startswith("#") or a["href"].endswith("/report.html") for a in page.all("a"))
    assert len(page.all("table")) >= 2  # counts and the group summary
    return page


def _summary(result) -> str:
    from mbus_framework.campaigns import summary_text

    return summary_text(result)


def start_half_way(tmp_path):
    """(campaign path, out folder, mbus-run process) of a 10-sample campaign on its own
    1-worker LocalCluster, returned once at least 2 samples are fitted."""
    base = json.loads(json.dumps(BASE))
    base["excitation"]["options"]["n_samples"] = 2000  # ~1 s per fit, so there is a half-way
    rows = [{"sample_id": f"s{i:02d}", "cultivar": "x", "backend.options.seed": i} for i in range(10)]
    path = write_campaign(tmp_path, rows, base=base)
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "mbus_framework.cli", str(path), "-o", str(out), "--workers", "1"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            env={**os.environ, "MPLBACKEND": "Agg"})
    deadline = time.monotonic() + 240
    while len(list(out.glob(f"runs/*/{MARKER}"))) < 2:
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.05)
    return path, out, proc


@pytest.mark.slow  # timing: under parallel load the fits' markers can land in one burst, so 'half way' may be the end
def test_sigterm_stops_a_campaign_like_ctrl_c(tmp_path):
    """A batch scheduler's SIGTERM to mbus-run alone: the campaign stops cleanly, marks itself
    interrupted, closes its cluster and keeps what finished."""
    _, out, proc = start_half_way(tmp_path)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err
    assert err.strip().splitlines()[-1].endswith("(SIGTERM)")
    assert "run again to continue" in err and "Traceback" not in err
    assert json.loads((out / "campaign.json").read_text())["status"] == "interrupted"
    done = list(out.glob(f"runs/*/{MARKER}"))
    pids = {json.loads(m.read_text())["worker"]["pid"] for m in done}
    assert not any(psutil.pid_exists(p) and "python" in psutil.Process(p).name() for p in pids)
    assert len(pd.read_csv(out / "properties.csv")) >= 2


@pytest.mark.slow  # timing: under parallel load the fits' markers can land in one burst, so 'half way' may be the end
def test_ctrl_c_half_way_then_a_rerun_fits_only_the_missing_samples(tmp_path, client):
    path, out, proc = start_half_way(tmp_path)
    os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C at a terminal: the whole process group
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "run again to continue" in err and "Traceback" not in err
    meta = json.loads((out / "campaign.json").read_text())
    assert meta["status"] == "interrupted"
    done = {m.parent.name: (m.stat().st_mtime_ns, m.read_bytes()) for m in out.glob(f"runs/*/{MARKER}")}
    assert 2 <= len(done) < 10
    pids = {json.loads(m[1])["worker"]["pid"] for m in done.values()}  # its own LocalCluster (--workers 1) ...
    assert not any(psutil.pid_exists(p) and "python" in psutil.Process(p).name() for p in pids)  # ... is gone
    assert len(pd.read_csv(out / "properties.csv")) >= 2  # what finished is in the table already

    result = run_campaign(path, out, client=client)
    assert sorted(result.reused) == sorted(done)
    assert sorted(result.fitted) == sorted({f"s{i:02d}" for i in range(10)} - set(done))
    assert {m.parent.name: (m.stat().st_mtime_ns, m.read_bytes()) for m in out.glob(f"runs/*/{MARKER}")
            if m.parent.name in done} == done
    assert len(result.table) == 10 and result.failed == []


def test_a_campaign_runs_on_a_scheduler_started_elsewhere(tmp_path):
    from distributed import Client

    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    worker = worker_cmd(address, tmp_path / "dask-worker")
    with processes(scheduler_cmd(port), logs=tmp_path / "logs"), processes(worker, logs=tmp_path / "wlogs"):
        with Client(address, timeout=60) as c:
            c.wait_for_workers(1, timeout=120)
            worker_pids = set(c.run(os.getpid).values())
        truths = draw_truths(2, seed=44)
        rows = [{"sample_id": f"t{i}", "cultivar": "x", **truth_columns(t)} for i, t in enumerate(truths)]
        path = write_campaign(tmp_path, rows)
        result = run_campaign(path, tmp_path / "out", scheduler=address)
        assert result.failed == [] and len(result.table) == 2
        within(result.table, {f"t{i}": t for i, t in enumerate(truths)})
        for d in (tmp_path / "out" / "runs").iterdir():
            assert json.loads((d / MARKER).read_text())["worker"]["pid"] in worker_pids
        meta = json.loads((tmp_path / "out" / "campaign.json").read_text())
        assert meta["cluster"]["scheduler"] == address
        with Client(address, timeout=60) as c:  # the cluster is left as it was
            assert set(c.run(os.getpid).values()) == worker_pids


def test_an_unreachable_scheduler_is_a_one_line_error(tmp_path, monkeypatch):
    from mbus_framework.campaigns import executor
    from mbus_framework.campaigns.executor import ClusterError

    monkeypatch.setattr(executor, "CONNECT_TIMEOUT_S", 1)
    path = write_campaign(tmp_path, [{"sample_id": "a", "cultivar": "x"}])
    address = f"tcp://127.0.0.1:{free_port()}"
    with pytest.raises(ClusterError, match=f"cannot connect to the Dask scheduler at {address}"):
        run_campaign(path, tmp_path / "out", scheduler=address)


def _same(a, b, rtol: float = 1e-9) -> bool:
    """Equal structures, numbers to ``rtol`` (absolute 1e-300 for zeros)."""
    import math

    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k], rtol) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y, rtol) for x, y in zip(a, b))
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        return (math.isnan(a) and math.isnan(b)) or math.isclose(a, b, rel_tol=rtol, abs_tol=1e-300)
    return a == b


def test_a_study_on_dask_gives_the_in_process_numbers(tmp_path, client):
    from mbus_framework.studies.runner import run_study

    here = run_study("monte_carlo", STUDY, [], tmp_path / "here", n_runs=2, first_seed=5)
    there = run_study("monte_carlo", STUDY, [], tmp_path / "there", n_runs=2, first_seed=5, client=client)
    # equal to round-off: the worker runs one BLAS thread, this process may run more, and a
    # reduction's order changes the last bits (1e-13 seen); a different search would differ by far more
    assert _same(there.rows, here.rows)
    assert there.summary["cramer_rao_computed"] == here.summary["cramer_rao_computed"]
    drop = ("wall_time_s", "solver_time_s")
    assert _same([{k: v for k, v in r.items() if k not in drop} for r in there.runs],
                 [{k: v for k, v in r.items() if k not in drop} for r in here.runs])
    assert sorted(p.name for p in (tmp_path / "there" / "runs").iterdir()) == ["seed-00005", "seed-00006"]
    from test_report import assert_folder_report

    assert_folder_report(tmp_path / "there", len(list((tmp_path / "there").glob("*.png"))),
                         there.text.strip().splitlines()[0].strip())


def test_a_terminal_shows_done_failed_remaining_and_eta(tmp_path):
    """mbus-run on a terminal (a pseudo-terminal here, CI unset): the campaign's bar counts
    done, failed and remaining and shows an ETA; the same run in a log prints no bar."""
    import pty
    import re

    truths = draw_truths(2, seed=5)
    for i, truth in enumerate(truths):
        simulate_record(tmp_path / "rec" / f"s{i}.csv", truth, seed=i)
    (tmp_path / "rec" / "bad.csv").write_text("t,u,y\n0,0,0\n1e-7,1,oops\n")
    rows = [{"sample_id": f"s{i}", "cultivar": "x", "data": f"rec/s{i}.csv"} for i in range(2)]
    rows.append({"sample_id": "bad", "cultivar": "x", "data": "rec/bad.csv"})
    path = write_campaign(tmp_path, rows)
    env = {k: v for k, v in os.environ.items() if k != "CI"} | {"MPLBACKEND": "Agg", "COLUMNS": "160"}
    main_fd, child_fd = pty.openpty()
    cmd = [sys.executable, "-m", "mbus_framework.cli", str(path), "-o", str(tmp_path / "tty"), "--workers", "1"]
    proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=child_fd, stderr=child_fd, env=env)
    os.close(child_fd)
    chunks = []
    while True:
        try:
            data = os.read(main_fd, 65536)
        except OSError:  # the child closed the terminal
            break
        if not data:
            break
        chunks.append(data)
    os.close(main_fd)
    assert proc.wait(timeout=240) == 1  # one row failed
    screen = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", b"".join(chunks).decode("utf-8", "replace"))
    assert re.search(r"3/3 done\s+1 failed\s+0 remaining\s+ETA", screen), screen[-2000:]
    assert "Traceback" not in screen

    logged = subprocess.run(cmd[:4] + ["-o", str(tmp_path / "log"), "--workers", "1"],
                            capture_output=True, text=True, env=env, timeout=240)
    assert logged.returncode == 1 and "remaining" not in logged.stderr + logged.stdout
