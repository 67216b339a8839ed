"""Imports follow use (issue 24): a single run loads neither the campaign machinery (Dask) nor the
analyses' libraries (scikit-learn, statsmodels, pandas); matplotlib only when it plots PNGs;
``mbus-run --help`` loads nothing numerical and ``--list-plugins`` no plugin's run-time
dependencies. A simulated potato run needs neither scipy.signal nor scipy.stats (mbus has its own
Welch spectrum and shift register, and uses scipy.special for quantiles); transducer filters
still import scipy.signal where a rig has them.

Each check runs a real command in a fresh interpreter and reads its ``sys.modules``.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
POTATO = ROOT / "configs" / "potato.yaml"

# Never in a single run: campaigns, Dask, the analyses' libraries.
NEVER = ("mbus_framework.campaigns", "dask", "distributed", "sklearn", "statsmodels", "pandas")
# Loaded by scipy's ``from numpy import *`` unless deferred (mbus_framework.startup): unused by a run.
UNUSED = ("numpy.f2py.crackfortran", "charset_normalizer", "numpy.testing._private.utils",
          "numpy.polynomial.polynomial",
          # scipy.optimize's ``from scipy import spatial`` (for shgo), made lazy too: with it scipy.constants
          "scipy.spatial._qhull", "scipy.spatial.transform", "scipy.constants")
# Not needed by a simulated fit with the LM solver: CasADi (the collocation solver), python-control
# (state-space export), the studies and the analyses.
OTHER_TOOLS = ("casadi", "control", "mbus_framework.studies", "mbus_framework.analysis", "mbus_framework.joint",
               "mbus_framework.substitution")
# --help and --version: nothing numerical at all.
HEAVY = (*NEVER, "scipy.stats", "numpy", "scipy", "matplotlib", "pydantic", "mbus_framework.estimation.problem")
# --list-plugins imports each plugin module (their classes carry the summaries), but not what a
# plugin needs only when it runs: plotting, scipy.signal, scipy.ndimage, CasADi.
PLUGIN_LIST = (*NEVER, "scipy.stats", "matplotlib", "scipy.signal", "scipy.ndimage", "casadi")

_PROBE = """
import json, sys
from mbus_framework.cli import main
try:
    status = main(sys.argv[1:])
except SystemExit as exc:
    status = exc.code
print("\\n@@MODULES@@" + json.dumps([status, sorted(sys.modules)]))
"""


def _modules(args: list[str], code: str = _PROBE, env: dict[str, str] | None = None) -> tuple[int, set[str]]:
    done = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, cwd=ROOT,
                          timeout=300, env=None if env is None else {**os.environ, **env})
    assert "@@MODULES@@" in done.stdout, done.stderr[-2000:]
    status, names = json.loads(done.stdout.rpartition("@@MODULES@@")[2])
    return status, set(names)


def _loaded(modules: set[str], packages: tuple[str, ...]) -> list[str]:
    return sorted(m for m in modules if any(m == p or m.startswith(p + ".") for p in packages))


@pytest.mark.parametrize("flag", ["--help", "--version"])
def test_help_imports_nothing_heavy(flag):
    status, modules = _modules([flag])
    assert status == 0
    assert _loaded(modules, HEAVY) == []


def test_plugin_list_imports_no_plugin_runtime_dependencies():
    status, modules = _modules(["--list-plugins"])
    assert status == 0
    assert "mbus_plugins.solvers.scipy_lm" in modules  # it did look at the plugins
    assert _loaded(modules, PLUGIN_LIST) == []


_FORKS = """
import json, os, sys
forks = []
_fork = os.fork
def fork():
    forks.append(1)
    return _fork()
os.fork = fork
from mbus_framework.cli import main
status = main(sys.argv[1:])
print("\\n@@MODULES@@" + json.dumps([status, sorted(sys.modules) + [f"@forks={len(forks)}"]]))
"""


def test_single_run_with_default_svg_figures_imports_no_matplotlib_and_forks_nothing(tmp_path):
    """The default figures are SVG drawn in the run's own process: no matplotlib, no helper forked."""
    status, modules = _modules([str(POTATO), "-o", str(tmp_path / "run"), "-q"], _FORKS)
    assert status == 0
    assert (tmp_path / "run" / "report.html").is_file() and (tmp_path / "run" / "fit.svg").is_file()
    assert not list((tmp_path / "run").glob("*.png"))
    assert _loaded(modules, ("matplotlib", *NEVER, "scipy.signal", "scipy.stats", *UNUSED, *OTHER_TOOLS)) == []
    assert "@forks=0" in modules


@pytest.mark.parametrize("helpers", ["1", "0"])
def test_single_run_with_plots_imports_only_what_it_uses(tmp_path, helpers):
    """PNG figures (``output.figures: png``): with the forked figure helpers (Linux) the run's own
    process never imports matplotlib; drawing in process (``MBUS_FIGURE_WORKERS=0``) goes
    through the Agg canvas, not pyplot."""
    status, modules = _modules([str(POTATO), "-o", str(tmp_path / "run"), "-q", "--set", "output.figures=png"],
                               env={"MBUS_FIGURE_WORKERS": helpers})
    assert status == 0
    assert (tmp_path / "run" / "report.html").is_file() and (tmp_path / "run" / "fit.png").is_file()
    assert _loaded(modules, (*NEVER, "scipy.signal", "scipy.stats", *UNUSED, *OTHER_TOOLS)) == []
    if helpers == "1" and sys.platform.startswith("linux"):
        assert _loaded(modules, ("matplotlib",)) == []  # the helpers drew every figure
    else:
        assert "matplotlib.figure" in modules  # it did plot, through the Agg canvas ...
        assert "matplotlib.pyplot" not in modules  # ... without pyplot's global state


def test_single_run_without_plots_does_not_import_matplotlib(tmp_path):
    status, modules = _modules([str(POTATO), "-o", str(tmp_path / "run"), "-q", "--no-plots"])
    assert status == 0 and (tmp_path / "run" / "result.json").is_file()
    assert _loaded(modules, (*NEVER, "matplotlib", *UNUSED)) == []


def test_deferred_numpy_submodules_are_the_real_modules_when_used():
    """numpy.testing and numpy.polynomial, made lazy at start-up, are not run by scipy's
    ``from numpy import *`` and work as soon as something uses them."""
    code = """
import json, sys
from mbus_framework.startup import defer_unused_numpy
deferred = defer_unused_numpy()
import scipy.linalg, scipy.optimize
before = [m for m in ("numpy.testing._private.utils", "numpy.polynomial.polynomial") if m in sys.modules]
import numpy as np
from numpy.testing import assert_allclose
assert_allclose(np.polynomial.Polynomial([1, 2])(3.0), 7.0)
ok = {"numpy.testing", "numpy.polynomial"} <= set(deferred) and "numpy.polynomial.polynomial" in sys.modules
print("\\n@@MODULES@@" + json.dumps([int(not ok), before]))
"""
    status, before = _modules([], code)
    assert status == 0 and before == set()


def test_deferred_f2py_is_the_real_module_when_used():
    """numpy.f2py, made lazy at start-up (mbus_framework.startup), is not run by scipy's
    ``from numpy import *`` but works as soon as something uses it."""
    code = """
import json, sys
from mbus_framework.startup import defer_unused_numpy
deferred = "numpy.f2py" in defer_unused_numpy(("numpy.f2py",))
import scipy.linalg, scipy.optimize
before = "numpy.f2py.crackfortran" in sys.modules
import numpy.f2py
from numpy.f2py import crackfortran
print("\\n@@MODULES@@" + json.dumps([int(not (deferred and callable(numpy.f2py.run_main))), [str(before)]]))
"""
    status, flags = _modules([], code)
    assert status == 0 and flags == {"False"}


def test_deferred_scipy_spatial_is_the_real_module_when_used():
    """scipy.spatial, made lazy at start-up, is not run by scipy.optimize's import but works (and
    shgo, which uses it) as soon as something uses it."""
    code = """
import json, sys
from mbus_framework.startup import defer_unused_numpy, defer_unused_scipy
defer_unused_numpy()
deferred = defer_unused_scipy()
import numpy as np
import scipy.optimize
before = [m for m in ("scipy.spatial._qhull", "scipy.constants") if m in sys.modules]
import scipy.spatial.distance
from scipy.spatial import Delaunay
d = float(scipy.spatial.distance.cdist(np.zeros((1, 2)), np.ones((1, 2)))[0, 0])
tri = Delaunay(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]))
x = scipy.optimize.shgo(lambda x: (x[0] - 1) ** 2 + (x[1] + 0.5) ** 2, [(-2, 2), (-2, 2)]).x
ok = deferred == ["scipy.spatial"] and abs(d - 2 ** 0.5) < 1e-15 and tri.simplices.shape == (1, 3) \\
    and np.allclose(x, [1.0, -0.5], atol=1e-6)
print("\\n@@MODULES@@" + json.dumps([int(not ok), before]))
"""
    status, before = _modules([], code)
    assert status == 0 and before == set()


def test_api_fit_imports_only_what_it_uses(tmp_path):
    status, _ = _modules([str(POTATO), "-o", str(tmp_path / "run"), "-q", "--no-plots"])
    assert status == 0
    code = f"""
import json, sys
import numpy as np
import mbus_framework as mbus
t, u, y = np.loadtxt({str(tmp_path / "run" / "measurement.csv")!r}, delimiter=",", skiprows=1, unpack=True)[:3]
result = mbus.fit(t, u, y, sample={{"length": 0.03, "diameter": 0.0254, "density": 1080.0}}, plots=False)
print("\\n@@MODULES@@" + json.dumps([int(not result.success), sorted(sys.modules)]))
"""
    status, modules = _modules([], code)
    assert status == 0
    assert _loaded(modules, (*NEVER, "matplotlib")) == []


def test_special_config_files_are_still_recognised(tmp_path):
    """The command line's own check agrees with the campaign, substitution and joint packages'."""
    from mbus_framework.campaigns.spec import is_campaign_file
    from mbus_framework.cli import _config_kind
    from mbus_framework.joint.config import is_joint_file
    from mbus_framework.pipeline.config import config_mapping_or_none
    from mbus_framework.substitution.config import is_substitution_file

    def _special_kind(path: str) -> str | None:  # the command line's check of a config file
        return _config_kind(config_mapping_or_none(path))

    files = {"campaign": "campaign:\n  base: base.yaml\n", "substitution": "experiment: substitution\n",
             "joint": "joint:\n  records: []\n", "other_experiment": "experiment: other\njoint: {}\n",
             "bad": "campaign: [\n", "list": "- campaign\n"}
    paths = [POTATO, tmp_path / "missing.yaml", ROOT / "pyproject.toml"]
    for name, text in files.items():
        (tmp_path / f"{name}.yaml").write_text(text)
        paths.append(tmp_path / f"{name}.yaml")
    for path in paths:
        kind = _special_kind(str(path))
        assert (kind == "campaign") == is_campaign_file(path), path
        if kind != "campaign":
            assert (kind == "substitution") == is_substitution_file(path), path
            if kind != "substitution":
                assert (kind == "joint") == is_joint_file(path), path
    assert [_special_kind(str(tmp_path / f"{n}.yaml")) for n in ("campaign", "substitution", "joint", "other_experiment")] \
        == ["campaign", "substitution", "joint", "joint"]
