"""Run-directory files, written atomically (temp file in the same folder, then rename), and
input files read with limits.

Nothing already measured is lost: waveforms are saved before any fit starts, and a crash
mid-write leaves either the old file or the new one, never half of one; Ctrl-C and SIGTERM
are held back while a file is written (:func:`mbus_framework.pipeline.interrupts.deferred`).

JSON is strict (RFC 8259): a non-finite float is written as ``null`` and its key path is
listed under ``"non_finite_values"`` (``{"uncertainty.condition": "inf"}``), so every JSON
parser reads the file and nobody mistakes a missing number for a value.

Inputs (configs, data files) are read by :func:`read_regular_file`: regular files only (a FIFO,
``/dev/zero`` or a folder is refused before anything blocks or grows) and at most a given size.
"""
from __future__ import annotations

import io
import json
import math
import os
import stat
import tempfile
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from mbus_framework.errors import DataError, MbusError
from mbus_framework.pipeline.interrupts import deferred

NON_FINITE_KEY = "non_finite_values"
MAX_DATA_BYTES = 512 * 2**20
"""Largest data file (and largest total of the arrays in an NPZ, uncompressed) read [bytes]."""
TMP_SUFFIX = ".tmp"
"""Suffix of the temporary files of atomic writes (``.<name>.<random>.tmp``)."""


def _file_mode() -> int:
    """The mode ``open()`` gives a new file: 0666 less the process umask (0644 with umask 022)."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; parent folders are created. The file gets the
    mode of a plainly created file (as the umask says), not mkstemp's private 0600."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    mode = _file_mode()
    with deferred():  # a signal waits until the file is whole and the temp file gone
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=TMP_SUFFIX)
        try:
            os.fchmod(fd, mode)
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
    return path


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    return atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | os.PathLike, obj: Any) -> Path:
    """Strict JSON: non-finite floats become null, listed under ``"non_finite_values"``."""
    return atomic_write_text(path, strict_json(obj) + "\n")


def strict_json(obj: Any, indent: int | None = 2) -> str:
    """``obj`` as RFC 8259 JSON (see the module docstring for non-finite floats)."""
    found: dict[str, str] = {}
    clean = _finite_or_null(to_jsonable(obj), "", found)
    if found and isinstance(clean, dict):
        clean[NON_FINITE_KEY] = {**clean.get(NON_FINITE_KEY, {}), **found}
    return json.dumps(clean, indent=indent, allow_nan=False)


def _finite_or_null(obj: Any, where: str, found: dict[str, str]) -> Any:
    if isinstance(obj, float) and not math.isfinite(obj):
        found[where or "(top level)"] = "nan" if math.isnan(obj) else ("inf" if obj > 0 else "-inf")
        return None
    if isinstance(obj, dict):
        return {k: _finite_or_null(v, f"{where}.{k}" if where else k, found) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_finite_or_null(v, f"{where}[{i}]", found) for i, v in enumerate(obj)]
    return obj


def atomic_write_npz(path: str | os.PathLike, **arrays: np.ndarray) -> Path:
    import io

    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return atomic_write_bytes(path, buf.getvalue())


def write_waveforms(path: str | os.PathLike, t, u, y) -> Path:
    """Save a record as CSV with header ``t,u,y`` (the format the ``file`` backend reads)."""
    data = np.column_stack([t, u, y])
    # the text of np.savetxt(fmt="%.17g", delimiter=","), formatted in one operation (half its time)
    rows = ("%.17g,%.17g,%.17g\n" * len(data)) % tuple(data.ravel().tolist())
    return atomic_write_text(path, "t,u,y\n" + rows)


def to_jsonable(obj: Any) -> Any:
    """Convert numpy scalars/arrays (recursively) to plain Python for JSON."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, (np.floating,)):
        return float(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, Path):
        return str(obj)
    return obj


def read_regular_file(path: str | os.PathLike, what: str = "file", max_bytes: int = MAX_DATA_BYTES,
                      error: type[MbusError] = DataError) -> bytes:
    """The bytes of a regular file of at most ``max_bytes``; anything else raises ``error``.

    Opened without blocking and checked with ``fstat`` before reading: a FIFO (which would
    block forever), a device such as ``/dev/zero`` (which never ends), a folder or a symlink
    loop is a one-line error naming the path, as is a missing or unreadable file.
    """
    path = Path(path)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_BINARY", 0)
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        raise error(f"{path}: {what} not found") from None
    except OSError as exc:
        raise error(f"{path}: cannot open {what} ({exc.strerror or type(exc).__name__})") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            kind = "a folder" if stat.S_ISDIR(info.st_mode) else (
                "a FIFO" if stat.S_ISFIFO(info.st_mode) else (
                    "a device" if stat.S_ISCHR(info.st_mode) or stat.S_ISBLK(info.st_mode) else "a special file"))
            raise error(f"{path}: cannot read {what}: it is {kind}, not a regular file")
        if info.st_size > max_bytes:
            raise error(f"{path}: {what} is {info.st_size / 2**20:.1f} MiB, more than the {max_bytes / 2**20:g} MiB "
                        f"limit")
        chunks, total = [], 0
        while True:
            chunk = os.read(fd, min(1 << 20, max_bytes + 1 - total))
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
            if total > max_bytes:
                raise error(f"{path}: {what} grew beyond the {max_bytes / 2**20:g} MiB limit while being read")
        return b"".join(chunks)
    except OSError as exc:
        raise error(f"{path}: cannot read {what} ({exc.strerror or type(exc).__name__})") from None
    finally:
        os.close(fd)


def read_npz(path: str | os.PathLike, what: str = "NPZ file", max_bytes: int = MAX_DATA_BYTES,
             error: type[MbusError] = DataError) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` (no pickles), checked before anything is decompressed.

    The sum of the arrays' uncompressed sizes must stay below ``max_bytes`` (a 1 MB zip can
    hold gigabytes of zeros); a corrupt archive or array is a one-line error naming the file.
    """
    data = read_regular_file(path, what, max_bytes, error)
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            total = sum(info.file_size for info in archive.infolist())
        if total > max_bytes:
            raise error(f"{path}: {what} unpacks to {total / 2**20:.1f} MiB, more than the {max_bytes / 2**20:g} MiB "
                        f"limit")
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            return {name: z[name] for name in z.files}
    except MbusError:
        raise
    except Exception as exc:  # noqa: BLE001 - zipfile/numpy raise many kinds for corrupt files
        raise error(f"{path}: not a readable {what} ({type(exc).__name__}: {_short(exc)})") from None


def _short(exc: BaseException) -> str:
    from mbus_framework.errors import one_line

    return one_line(str(exc), 120)
