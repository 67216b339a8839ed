"""The Python API: fit arrays or run a config, and work with the result.

    >>> import mbus_framework as mbus
    >>> t, u, y = mbus.load_record("examples/recorded/potato_tuy.csv")
    >>> result = mbus.fit(t, u, y, sample={"length": 0.03, "diameter": 0.0254, "density": 1080.0})

:func:`fit` fits arrays in memory (nothing is written unless ``out_dir`` is given);
:func:`run_config` runs a YAML config (or a mapping) into a run folder, as ``mbus-run`` does;
:func:`load_record` reads t,u,y files, GDS-2000 CSV export pairs and lab run folders;
:class:`Result` holds the estimates, warnings, fit quality, figures and tables.
"""
from mbus_framework.api.fitting import Record, fit, load_record, run_config
from mbus_framework.api.result import Estimate, Result

__all__ = ["Estimate", "Record", "Result", "fit", "load_record", "run_config"]
