"""Shared by the reliability and fuzz tests: small fast configs, data files of every supported
format, an in-process ``mbus-run`` with a per-case time limit, and the checks every case must
pass (exit code, one-line error, strict JSON, nothing written outside the allowed paths)."""
from __future__ import annotations

import contextlib
import copy
import io
import json
import os
import signal
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from mbus_framework.cli import main
from mbus_framework.engine.simulation import simulate
from mbus_framework.interfaces.sample import Sample
from mbus_framework.pipeline.storage import atomic_write_npz, write_waveforms
from mbus_plugins.excitations.prbs import Prbs, PrbsOptions
from mbus_plugins.instruments.shots import ProcessingOptions, Shot, save_excitation, save_shot, write_acquisition
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions

REPO = Path(__file__).resolve().parents[1]
SAMPLE = {"length": 0.05, "diameter": 0.0254, "density": 1000.0}
TRUTH = {"k_sigma": 3.0e8, "b_sigma": 15.0, "k_tau": 5.0e7, "b_tau": 12.0}
PRBS = {"order": 5, "bit_width": 2.5e-6, "amplitude": 1.0, "sample_rate": 2.0e6, "n_samples": 200}
FAST_SOLVER = {"name": "scipy_lm", "options": {"strategy": {"n_starts": 2, "time_scale_points": 12, "bands": [0.3]}}}

SMALL: dict[str, Any] = {
    "title": "small",
    "sample": SAMPLE,
    "model": {"name": "kelvin_voigt", "options": {"n_elements": 3}},
    "excitation": {"name": "prbs", "options": PRBS},
    "backend": {"name": "simulated", "options": {"truth": TRUTH, "noise": {"relative_std": 0.05}, "seed": 1}},
    "solver": FAST_SOLVER,
    "output": {"plots": False},
}

CALIBRATION: dict[str, Any] = {
    "title": "small calibration",
    "sample": {"length": 0.02, "diameter": 0.0254, "density": 998.0},
    "model": {"name": "kelvin_voigt"},
    "excitation": {"name": "prbs", "options": {"order": 5, "bit_width": 0.4e-6, "amplitude": 1.0,
                                                 "sample_rate": 25.0e6, "periods": 2}},
    "backend": {"name": "simulated", "options": {
        "wave": {"sound_speed": 1482.0}, "transducers": {"centre_frequency": 0.5e6, "bandwidth": 0.4e6},
        "noise": {"relative_std": 0.01}, "seed": 3}},
    "calibration": {"lengths": [0.0, 0.005, 0.01], "output": "calibration.npz"},
    "output": {"plots": False},
}


def config(base: dict[str, Any] | None = None, **sections: Any) -> dict[str, Any]:
    """A deep copy of ``base`` (default SMALL) with top-level ``sections`` replaced."""
    out = copy.deepcopy(SMALL if base is None else base)
    out.update(copy.deepcopy(sections))
    return out


def write_yaml(path: Path, data: dict[str, Any]) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


# -- data files of every format ------------------------------------------------------------
def designed():
    return Prbs(PrbsOptions(**PRBS)).waveform()


def simulated_record() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    w = designed()
    model = KelvinVoigtChain(Sample(**SAMPLE), KelvinVoigtOptions(n_elements=3))
    y = simulate(model, list(TRUTH.values()), w.u, w.dt)
    y = y + 0.02 * np.sqrt(np.mean(y**2)) * np.random.default_rng(5).standard_normal(y.size)
    return w.t, w.u, y


def write_tuy_csv(folder: Path) -> Path:
    return write_waveforms(folder / "record.csv", *simulated_record())


def write_tuy_npz(folder: Path) -> Path:
    t, u, y = simulated_record()
    return atomic_write_npz(folder / "record.npz", t=t, u=u, y=y)


GDS_PRE = 37  # scope samples before the burst
GDS_N = 400


def _scope_channels():
    w = designed()
    u = np.zeros(GDS_N)
    u[GDS_PRE:GDS_PRE + w.u.size] = 0.5 * w.u
    model = KelvinVoigtChain(Sample(**SAMPLE), KelvinVoigtOptions(n_elements=3))
    y = simulate(model, list(TRUTH.values()), u, w.dt)
    return w.dt, u, y


def _gds_header(n: int, source: str, scale: str, period: str, extra=()) -> list[str]:
    rows = [f"Memory Length,{n},", "Trigger Level,0.100V,", f"Source,{source},", "Vertical Units,V,",
            f"Vertical Scale,{scale},", "Vertical Position,0.000E+00,", "Horizontal Units,S,",
            "Horizontal Scale,5.000E-05,", f"Sampling Period,{period},", "Firmwave,V1.12,"]
    return rows + list(extra)


def write_gds_pair(folder: Path, layout: str = "raw") -> tuple[Path, Path]:
    """Two GDS-2000 CSV exports (CH1 excitation, CH2 response), raw-code or time,value layout."""
    dt, u, y = _scope_channels()
    paths = []
    for name, volts, scale in (("CH1", u, 0.2), ("CH2", y, max(float(np.max(np.abs(y))) / 3.5, 1e-9))):
        path = folder / f"A0001{name}.CSV"
        if layout == "raw":
            codes = np.round(volts / scale * 25).astype(int)
            lines = _gds_header(codes.size, name, f"{scale:.3E}", f"{dt:.3E}") + [f"{c}," for c in codes]
        else:
            t = -GDS_PRE * dt + np.arange(volts.size) * dt
            lines = _gds_header(volts.size, name, f"{scale:.3E}", f"{dt:.3E}", ["Mode,Detail,"])
            lines += [f"{ti:.6E},{v:.6E}" for ti, v in zip(t, volts)]
        path.write_text("\r\n".join(lines) + "\r\n", encoding="latin-1")
        paths.append(path)
    return paths[0], paths[1]


def write_lab_run(folder: Path, shots: int = 2, status: str = "complete", requested: int | None = None) -> Path:
    """A run folder as the ``lab`` backend leaves it (shots/, status.json), from simulated shots."""
    w = designed()
    dt, u, y = _scope_channels()
    shot_dir = folder / "shots"
    points = np.round(w.u * 2047).astype(np.int16)
    save_excitation(shot_dir, w.t, w.u, points, w.sample_rate, 1)
    rng = np.random.default_rng(2)
    for i in range(1, shots + 1):
        uv, yv = 0.02, max(float(np.max(np.abs(y))) / 3.5, 1e-9)
        u_raw = np.round((u + 1e-3 * rng.standard_normal(u.size)) / uv * 25).astype(np.int16)
        y_raw = np.round((y + 1e-3 * yv * rng.standard_normal(y.size)) / yv * 25).astype(np.int16)
        save_shot(shot_dir, i, Shot(dt, u_raw * uv / 25, y_raw * yv / 25, u_raw, y_raw, {
            "index": i, "u_volts_per_div": uv, "y_volts_per_div": yv, "counts_per_division": 25.0,
            "u_channel": 1, "y_channel": 2}))
    write_acquisition(shot_dir, {
        "status": status, "shots_requested": requested or shots, "shots_saved": shots,
        "processing": ProcessingOptions().model_dump(mode="json"), "instruments": {},
        "error": None if status == "complete" else "GDS-2062: read CH1: short read (simulated)"})
    (folder / "status.json").write_text(json.dumps({"status": "failed" if status != "complete" else "done"}))
    return folder


def file_backend(path: Path, **options: Any) -> dict[str, Any]:
    return {"name": "file", "options": {"path": str(path), **options}}


# -- running mbus-run in-process -------------------------------------------------------------
class Hang(BaseException):
    """A case ran past its time limit (a BaseException: nothing in mbus may swallow it)."""


@dataclass
class Outcome:
    code: int
    out: str
    err: str
    seconds: float = 0.0
    converted: list[str] = field(default_factory=list)


#: A case still running after this many seconds is a hang, whatever ``timeout`` a test asks
#: for: a wall-clock limit near a case's real duration is a flake on a loaded machine (timing
#: belongs in benchmarks/); pytest-timeout guards the whole test as well.
HANG_FLOOR_S = 300.0


def run_cli(argv: list[str], timeout: float = 60.0) -> Outcome:
    """``mbus-run argv`` in this process, stdout and stderr captured; a run longer than
    max(``timeout``, :data:`HANG_FLOOR_S`) seconds raises :class:`Hang`."""
    import time

    timeout = max(float(timeout), HANG_FLOOR_S)

    def alarm(signum, frame):
        raise Hang(f"mbus-run {' '.join(map(str, argv))[:300]} ran longer than {timeout:g} s")

    out, err = io.StringIO(), io.StringIO()
    previous = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, timeout)
    t0 = time.perf_counter()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main([str(a) for a in argv])
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    return Outcome(code, out.getvalue(), err.getvalue(), time.perf_counter() - t0)


def error_lines(err: str) -> list[str]:
    return [line for line in err.splitlines() if not line.startswith("mbus-run: warning: ")]


def assert_clean_outcome(o: Outcome, names: list[str], config_text: str = "") -> None:
    """Exit 0, or exit 2/3 with exactly one error line that names one of ``names`` (file or key),
    or names what ``config_text`` (a mutated config) gives as a path."""
    assert "Traceback" not in o.err, o.err
    assert all(line.startswith("mbus-run: ") for line in o.err.splitlines()), o.err
    if o.code == 0:
        assert error_lines(o.err) == [], o.err
        return
    assert o.code in (2, 3), (o.code, o.err)
    lines = error_lines(o.err)
    assert len(lines) == 1, o.err
    line = lines[0]
    assert line.startswith("mbus-run: error: "), line
    assert len(line) <= 1100, line[:300]
    subject = line.removeprefix("mbus-run: error: ").split(": ")[0]
    assert any(n and n in line for n in names) or (subject and subject in config_text), (names, line)


def strict_json(path: Path) -> Any:
    """Parse ``path`` as RFC 8259 JSON: NaN, Infinity and -Infinity are refused."""
    def refuse(token):
        raise ValueError(f"{path}: non-standard JSON token {token}")

    return json.loads(path.read_text(encoding="utf-8"), parse_constant=refuse)


def tree(root: Path) -> dict[str, tuple[int, int]]:
    """Every file under ``root`` (hidden ones included) -> (size, mtime_ns); symlinks not followed."""
    found = {}
    for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
        for name in filenames + [d for d in dirnames if os.path.islink(os.path.join(dirpath, d))]:
            p = os.path.join(dirpath, name)
            try:
                st = os.lstat(p)
            except OSError:
                continue
            found[os.path.relpath(p, root)] = (st.st_size, st.st_mtime_ns)
    return found


def changed(before: dict, after: dict) -> list[str]:
    return sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))


def check_writes(before: dict, after: dict, allowed: list[str]) -> None:
    """Every new or changed path lies under one of the ``allowed`` relative prefixes."""
    bad = [p for p in changed(before, after)
           if not any(p == a or p.startswith(a.rstrip("/") + "/") for a in allowed)]
    assert bad == [], f"written outside the run folder and the configured paths: {bad[:5]}"


def check_json_files(root: Path) -> int:
    """Parse every ``*.json`` under ``root`` strictly; returns how many there were."""
    count = 0
    for path in root.rglob("*.json"):
        if path.is_file() and not path.is_symlink():
            strict_json(path)
            count += 1
    return count


def python_env() -> dict[str, str]:
    """Environment for ``mbus-run`` subprocesses (headless, single-threaded BLAS)."""
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONUNBUFFERED="1")
    env.pop("MBUS_DEBUG", None)
    return env


MBUS_RUN = [sys.executable, "-m", "mbus_framework.cli"]
