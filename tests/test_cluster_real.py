"""Campaigns on real Dask clusters started as separate processes (``dask scheduler`` and
``dask worker``, as a user starts them): paths resolved on the client (a decoy file in the
worker's current directory is never read), one-line errors instead of hangs (no workers, a
worker without mbus, nothing listening), Ctrl-C before the first fit, stale attempts and a
second run on the same folder, and the plain-tcp warning."""
from __future__ import annotations

import copy
import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pandas as pd
import pytest
import yaml

from campaign_helpers import (BASE, ENV, draw_truths, free_port, processes, scheduler_cmd, simulate_record,
                              wait_listening, worker_cmd, write_campaign)
from mbus_framework.campaigns import run_campaign
from mbus_framework.campaigns.attempt import ATTEMPT_FILE, CampaignLock
from mbus_framework.campaigns.cluster import ClusterError, insecure_warning
from mbus_framework.campaigns.plan import plan_campaign
from mbus_framework.campaigns.worker import MARKER, run_task
from mbus_framework.cli import main
from mbus_framework.errors import RunFolderError

PROPS = ["E_sigma", "eta_sigma", "E_tau", "eta_tau"]


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """A scheduler and one nanny-started worker (as the docs say), the worker's current
    directory holding decoys at the campaign's relative paths: (address, worker cwd)."""
    root = tmp_path_factory.mktemp("cluster")
    cwd = root / "worker-cwd"
    for name in ("rec/base.csv", "rec/b.csv", "cal/wave.csv"):
        (cwd / name).parent.mkdir(parents=True, exist_ok=True)
        (cwd / name).write_text("t,u,y\n0,0,0\n1e-7,1,decoy\n")  # unreadable: any read fails the row
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    worker = worker_cmd(address, root / "dask-worker")
    with processes(scheduler_cmd(port), logs=root / "logs"):
        wait_listening(port)
        with processes(worker, cwd=cwd, logs=root / "wlogs"):
            yield address, cwd


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.slow
def test_relative_paths_are_resolved_on_the_client_and_a_decoy_is_never_read(tmp_path, cluster):
    from distributed import Client

    address, cwd = cluster
    truths = dict(zip("ab", draw_truths(2, seed=61)))
    project = tmp_path / "project"
    simulate_record(project / "rec" / "base.csv", truths["a"], seed=1)
    simulate_record(project / "rec" / "b.csv", truths["b"], seed=2)
    base = copy.deepcopy(BASE)
    base["backend"] = {"name": "file", "options": {"path": "rec/base.csv"}}  # relative to base.yaml
    del base["excitation"]
    rows = [{"sample_id": "a", "cultivar": "x"},
            {"sample_id": "b", "cultivar": "x", "backend.options.path": "rec/b.csv"}]  # relative to the sheet
    path = write_campaign(project, rows, base=base)
    assert not (Path.cwd() / "rec" / "base.csv").exists()

    result = run_campaign(path, tmp_path / "out", scheduler=address)
    assert result.failed == [], result.table["error"].tolist()
    table = result.table.set_index("sample_id")
    for sid, truth in truths.items():  # each row fitted its own record, not the decoy
        for p in PROPS:
            assert abs(table.loc[sid, p] - truth[p]) <= 4 * table.loc[sid, f"{p}_se"], (sid, p)
    with Client(address, timeout=30) as c:
        worker_pids = set(c.run(os.getpid).values())
        assert all(c.run(lambda dask_worker: dask_worker.mbus_malloc_tuned).values())  # the worker plugin ran
    for sid, name in (("a", "base.csv"), ("b", "b.csv")):
        run = tmp_path / "out" / "runs" / sid
        assert json.loads((run / MARKER).read_text())["worker"]["pid"] in worker_pids
        real = project / "rec" / name
        inputs = json.loads((run / "measurement.json").read_text())["inputs"]
        assert inputs == [{"path": str(real.resolve()), "sha256": _sha(real)}]
        saved = yaml.safe_load((run / "config.yaml").read_text())
        assert saved["backend"]["options"]["path"] == str(real.resolve())  # the folder re-runs on its own
    assert not list((tmp_path / "out" / "runs").glob(".*"))  # no work folder left behind


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    errors = [line for line in err if line.startswith("mbus-run: error:")]
    assert len(errors) == 1 and "Traceback" not in "\n".join(err), err
    return errors[0]


@pytest.mark.slow
def test_a_scheduler_without_workers_is_a_one_line_error(tmp_path, capsys):
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    path = write_campaign(tmp_path, [{"sample_id": "a", "cultivar": "x"}])
    with processes(scheduler_cmd(port), logs=tmp_path / "logs"):
        wait_listening(port)
        status = main([str(path), "-o", str(tmp_path / "out"), "--scheduler", address, "--timeout", "2"])
    assert status == 2
    line = _one_error_line(capsys)
    assert f"the Dask scheduler at {address} has no workers (none joined within 2 s)" in line
    meta = json.loads((tmp_path / "out" / "campaign.json").read_text())
    assert meta["status"] == "failed" and "has no workers" in meta["error"]


BLOCKED_WORKER = """
import sys
sys.modules["mbus_framework"] = None  # this worker has no mbus
from distributed.cli.dask_worker import main
sys.argv = ["dask-worker", *sys.argv[1:]]
main()
"""


@pytest.mark.slow
def test_a_worker_without_mbus_is_a_one_line_error(tmp_path, capsys):
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    path = write_campaign(tmp_path, [{"sample_id": "a", "cultivar": "x"}])
    worker = [sys.executable, "-c", BLOCKED_WORKER, address, "--no-nanny", "--nthreads", "1", "--no-dashboard",
              "--local-directory", str(tmp_path / "dask-worker")]
    with processes(scheduler_cmd(port), logs=tmp_path / "logs"):
        wait_listening(port)
        with processes(worker, logs=tmp_path / "wlogs"):
            status = main([str(path), "-o", str(tmp_path / "out"), "--scheduler", address, "--timeout", "60"])
    assert status == 2
    line = _one_error_line(capsys)
    assert f"of {address} cannot import mbus" in line and "install mbus" in line
    assert json.loads((tmp_path / "out" / "campaign.json").read_text())["status"] == "failed"


def test_an_unreachable_scheduler_fails_at_once(tmp_path, capsys):
    path = write_campaign(tmp_path, [{"sample_id": "a", "cultivar": "x"}])
    address = f"tcp://127.0.0.1:{free_port()}"  # nothing listens: connection refused
    with pytest.raises(ClusterError, match=f"cannot connect to the Dask scheduler at {address}: Connection refused"):
        run_campaign(path, tmp_path / "out", scheduler=address, timeout=600)  # refused: no wait for the timeout
    assert json.loads((tmp_path / "out" / "campaign.json").read_text())["status"] == "failed"
    assert main([str(path), "-o", str(tmp_path / "out"), "--scheduler", address]) == 2
    assert "Connection refused" in _one_error_line(capsys)


def test_ctrl_c_before_the_first_fit_finishes(tmp_path):
    """SIGINT as soon as the campaign says "running" (cluster starting or first fit running):
    exit 130, campaign.json "interrupted", a table of the rows that finished (maybe none)."""
    base = json.loads(json.dumps(BASE))
    base["excitation"]["options"]["n_samples"] = 2000
    path = write_campaign(tmp_path, [{"sample_id": f"s{i}", "cultivar": "x", "backend.options.seed": i}
                                     for i in range(4)], base=base)
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "mbus_framework.cli", str(path), "-o", str(out), "--workers", "1"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            env=ENV)
    deadline = time.monotonic() + 120
    while not (out / "campaign.json").exists():
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.01)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "internal error" not in err and "run again to continue" in err
    assert json.loads((out / "campaign.json").read_text())["status"] == "interrupted"
    finished = {m.parent.name for m in out.glob(f"runs/*/{MARKER}")}
    table = pd.read_csv(out / "properties.csv") if finished else None
    assert finished == set() or set(table["sample_id"]) == finished
    assert (out / "properties.csv").exists()


def _planned(tmp_path):
    path = write_campaign(tmp_path, [{"sample_id": "a", "cultivar": "x"}])
    out = tmp_path / "out"
    from mbus_framework.campaigns.spec import load_campaign as load

    return path, out, plan_campaign(load(path), out)[0]


def test_a_stale_attempt_cannot_overwrite_a_newer_row(tmp_path):
    _, out, task = _planned(tmp_path)
    with CampaignLock(out) as newer:
        current = run_task(replace(task, attempt=newer.token))
    assert not current["stale"] and current["row"]["error"] is None
    run = Path(task.run_dir)
    before = {p.relative_to(run): p.read_bytes() for p in run.rglob("*") if p.is_file()}
    assert json.loads((run / MARKER).read_text())["attempt"] == newer.token
    stale = run_task(replace(task, attempt="0" * 32))  # an earlier run's fit, finishing late
    assert stale["stale"] and stale["row"] is None
    assert {p.relative_to(run): p.read_bytes() for p in run.rglob("*") if p.is_file()} == before
    assert (out / ATTEMPT_FILE).read_text() == newer.token
    assert not list(run.parent.glob(".*"))  # the stale work folder is gone


def test_a_second_run_on_the_same_folder_is_refused(tmp_path, capsys):
    path, out, _ = _planned(tmp_path)
    with CampaignLock(out):  # a campaign run in progress on that folder
        with pytest.raises(RunFolderError, match=f"{out}: another mbus-run is running this campaign \\(pid {os.getpid()}"):
            run_campaign(path, out)
        assert main([str(path), "-o", str(out)]) == 2
        assert "another mbus-run is running this campaign" in _one_error_line(capsys)
    assert not (out / "runs").exists()


def test_plain_tcp_off_this_machine_is_warned_about():
    assert "plain tcp://" in insecure_warning("tcp://10.20.30.40:8786")
    assert "use tls://" in insecure_warning("10.20.30.40:8786")
    assert insecure_warning("tcp://127.0.0.1:8786") is None and insecure_warning("tcp://localhost:8786") is None
    assert insecure_warning("tls://10.20.30.40:8786") is None


def self_signed(folder: Path) -> tuple[Path, Path]:
    """A self-signed certificate and key for 127.0.0.1, made here (it is also the CA)."""
    import datetime
    import ipaddress

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "mbus-test")])
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
            .serial_number(x509.random_serial_number()).not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=1))
            .add_extension(x509.SubjectAlternativeName([x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]), False)
            .add_extension(x509.BasicConstraints(ca=True, path_length=None), True)
            .sign(key, hashes.SHA256()))
    folder.mkdir(parents=True, exist_ok=True)
    cert_file, key_file = folder / "cert.pem", folder / "key.pem"
    cert_file.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    key_file.write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                           serialization.NoEncryption()))
    return cert_file, key_file


@pytest.mark.slow
def test_a_campaign_runs_on_a_tls_secured_cluster(tmp_path, monkeypatch):
    """Scheduler and worker accept TLS only; the client's certificates come from Dask's
    configuration (here its environment variables, as docs/campaigns.md shows)."""
    import dask

    cert, key = self_signed(tmp_path / "certs")
    tls = ["--tls-ca-file", str(cert), "--tls-cert", str(cert), "--tls-key", str(key)]
    port = free_port()
    address = f"tls://127.0.0.1:{port}"
    worker = worker_cmd(address, tmp_path / "dask-worker", *tls)
    truths = draw_truths(1, seed=71)
    rows = [{"sample_id": "t0", "cultivar": "x", **{f"backend.options.truth.{k}": repr(v) for k, v in truths[0].items()}}]
    path = write_campaign(tmp_path, rows)
    with processes([*scheduler_cmd(port), "--protocol", "tls", *tls], logs=tmp_path / "logs"):
        wait_listening(port)
        with processes(worker, logs=tmp_path / "wlogs"):
            with pytest.raises(ClusterError, match=f"at {address}: a tls:// address needs Dask's TLS settings"):
                run_campaign(path, tmp_path / "refused", scheduler=address, timeout=5)  # no certificates here
            env = {"DASK_DISTRIBUTED__COMM__TLS__CA_FILE": str(cert),
                   "DASK_DISTRIBUTED__COMM__TLS__CLIENT__CERT": str(cert),
                   "DASK_DISTRIBUTED__COMM__TLS__CLIENT__KEY": str(key)}
            for k, v in env.items():
                monkeypatch.setenv(k, v)
            dask.config.refresh()
            try:
                result = run_campaign(path, tmp_path / "out", scheduler=address, timeout=60)
            finally:
                for k in env:
                    monkeypatch.delenv(k)
                dask.config.refresh()
    assert result.failed == [] and len(result.table) == 1
    row = result.table.iloc[0]
    for p in PROPS:
        assert abs(row[p] - truths[0][p]) <= 4 * row[f"{p}_se"], p
    assert json.loads((tmp_path / "out" / "campaign.json").read_text())["cluster"]["scheduler"] == address
