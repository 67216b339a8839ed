"""Every variable of a MATLAB ``.mat`` file by name: level 5 (MATLAB 5 ... 7.2, the default
``save`` format) through :func:`scipy.io.loadmat`, v7.3 (HDF5) through ``h5py`` when installed.
Shared by the file backend (:mod:`mbus_plugins.backends.mat_file`) and the substitution
experiment (:mod:`mbus_framework.substitution.record`); a bad file is one :class:`DataError` line."""
from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from mbus_framework.errors import DataError
from mbus_framework.pipeline.storage import read_regular_file

HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def load_mat(path: Path) -> dict[str, np.ndarray]:
    """Every variable of a ``.mat`` file (level 5 via scipy, v7.3 via h5py), by name."""
    data = read_regular_file(path, "MATLAB file")
    if data[512:520] == HDF5_SIGNATURE or data[:8] == HDF5_SIGNATURE:
        return _load_hdf5(path, data)
    from scipy.io import loadmat

    try:
        raw = loadmat(io.BytesIO(data), squeeze_me=False, mat_dtype=False)
    except NotImplementedError:  # scipy's words for v7.3 without the HDF5 signature where expected
        return _load_hdf5(path, data)
    except Exception as exc:  # noqa: BLE001 - scipy raises ValueError, TypeError, OSError, ...
        detail = " ".join(str(exc).split())[:100] or type(exc).__name__
        raise DataError(f"{path}: not a readable MATLAB .mat file ({detail})") from None
    return {k: v for k, v in raw.items() if not k.startswith("__")}


def _load_hdf5(path: Path, data: bytes) -> dict[str, np.ndarray]:
    try:
        import h5py
    except ImportError:
        raise DataError(f"{path}: MATLAB v7.3 (HDF5) file; reading it needs h5py (pip install h5py), "
                        f"or re-save it in MATLAB with save(..., '-v7')") from None
    out: dict[str, np.ndarray] = {}
    try:
        with h5py.File(io.BytesIO(data), "r") as f:
            for name, item in f.items():
                if isinstance(item, h5py.Dataset) and not name.startswith("#"):
                    out[name] = np.asarray(item[()]).T  # MATLAB writes column-major: transpose back
    except Exception as exc:  # noqa: BLE001
        raise DataError(f"{path}: not a readable MATLAB v7.3 file ({' '.join(str(exc).split())[:100]})") from None
    return out
