"""Small campaigns for the campaign tests: a potato-like simulated rig made fast (4 elements,
short records, 2 starts), sheets written from rows, and recorded t,u,y files simulated
independently of the campaign code (engine + PRBS + numpy noise)."""
from __future__ import annotations

import csv
import os
import socket
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import yaml

#: Potato-like media the tests draw from: within x/÷1.5 of configs/potato.yaml's truth (the
#: Table 6.2 "after compensation" means, eta_tau at its minimum), where all four are identifiable.
POTATO_RANGE = {k: (v / 1.5, v * 1.5) for k, v in
                {"E_sigma": 2.42e10, "eta_sigma": 7.18e3, "E_tau": 6.56e9, "eta_tau": 5.14e3}.items()}

BASE = {
    "title": "test potato",
    "sample": {"length": 0.03, "diameter": 0.0254, "density": 1080.0},
    "model": {"name": "kelvin_voigt", "options": {"n_elements": 4}},
    "excitation": {"name": "prbs", "options": {"order": 9, "bit_width": 0.4e-6, "amplitude": 1.0,
                                               "sample_rate": 25.0e6, "n_samples": 800}},
    "backend": {"name": "simulated", "options": {
        "truth": {"E_sigma": 2.42e10, "eta_sigma": 7.18e3, "E_tau": 6.56e9, "eta_tau": 5.14e3},
        "noise": {"relative_std": 0.03}, "seed": 7}},
    "solver": {"name": "scipy_lm", "options": {"strategy": {"n_starts": 2}}},
    "output": {"plots": False},
}


def draw_truths(n: int, seed: int) -> list[dict[str, float]]:
    """n media drawn log-uniformly from :data:`POTATO_RANGE`."""
    rng = np.random.default_rng(seed)
    return [{k: float(np.exp(rng.uniform(np.log(lo), np.log(hi)))) for k, (lo, hi) in POTATO_RANGE.items()}
            for _ in range(n)]


def write_sheet(path: Path, rows: list[dict]) -> Path:
    columns: list[str] = []
    for r in rows:
        columns += [k for k in r if k not in columns]
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=columns, lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
    return path


def write_campaign(folder: Path, rows: list[dict], *, groups=("cultivar",), covariates=(), replicates="average",
                   base: dict | None = None, name: str = "campaign") -> Path:
    """base.yaml, samples.csv and <name>.yaml in ``folder``; returns the campaign file."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "base.yaml").write_text(yaml.safe_dump(base or BASE, sort_keys=False))
    write_sheet(folder / "samples.csv", rows)
    campaign = {"campaign": {"title": f"test {name}", "base": "base.yaml", "samples": "samples.csv",
                             "groups": list(groups), "covariates": list(covariates), "replicates": replicates}}
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(campaign, sort_keys=False))
    return path


def truth_columns(truth: dict[str, float]) -> dict[str, str]:
    return {f"backend.options.truth.{k}": repr(v) for k, v in truth.items()}


def simulate_record(path: Path, truth: dict[str, float], seed: int, n_samples: int = 800, noise: float = 0.03) -> Path:
    """A recorded t,u,y CSV of the test rig's medium, made with the engine directly."""
    from mbus_framework.engine.simulation import simulate
    from mbus_framework.interfaces.sample import Sample
    from mbus_plugins.excitations.prbs import Prbs, PrbsOptions
    from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions

    s = BASE["sample"]
    model = KelvinVoigtChain(Sample(s["length"], s["diameter"], s["density"]), KelvinVoigtOptions(n_elements=4))
    wave = Prbs(PrbsOptions(order=9, bit_width=0.4e-6, amplitude=1.0, sample_rate=25.0e6, n_samples=n_samples)).waveform()
    theta = model.from_properties(truth)
    y0 = simulate(model, np.asarray(theta, float), wave.u, wave.t[1] - wave.t[0])
    y = y0 + np.random.default_rng(seed).normal(0.0, noise * np.sqrt(np.mean(y0**2)), y0.shape)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, np.column_stack([wave.t, wave.u, y]), delimiter=",", header="t,u,y", comments="", fmt="%.17g")
    return path


# -- Dask processes started as a user starts them (``dask scheduler``, ``dask worker``) ---------
SCHEDULER = [sys.executable, "-m", "distributed.cli.dask_scheduler"]  # `dask scheduler` of this Python
WORKER = [sys.executable, "-m", "distributed.cli.dask_worker"]
ENV = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "MPLBACKEND": "Agg"}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextmanager
def processes(*commands, cwd=None, logs: Path):
    """Start each command (list of argv) as its own process; stop them all on exit."""
    logs.mkdir(parents=True, exist_ok=True)
    procs, files = [], []
    try:
        for i, cmd in enumerate(commands):
            files.append(open(logs / f"{i}.log", "w"))
            procs.append(subprocess.Popen(cmd, stdout=files[-1], stderr=subprocess.STDOUT, env=ENV, cwd=cwd))
        yield procs
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in reversed(procs):
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
        for f in files:
            f.close()


def scheduler_cmd(port: int) -> list[str]:
    return [*SCHEDULER, "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"]


def worker_cmd(address: str, local_directory: Path, *extra: str) -> list[str]:
    """``dask worker ADDRESS --nworkers 1 --nthreads 1`` as docs/campaigns.md says: one
    single-threaded worker process, started by Dask's nanny."""
    return [*WORKER, address, "--nworkers", "1", "--nthreads", "1", "--no-dashboard",
            "--local-directory", str(local_directory), *extra]


def wait_listening(port: int, timeout: float = 60.0) -> None:
    """Return once something accepts TCP connections on 127.0.0.1:``port``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return
        except OSError:
            time.sleep(0.1)
    raise AssertionError(f"no scheduler on port {port}")
