"""What a run checks before it allocates, simulates or fits anything, and how failures of
plugins and of the numerics inside a fit reach the user.

* **Parameter values** (``model.initial``, ``model.fixed``, a simulated rig's ``truth``) must
  be finite and inside each parameter's physical range (stiffness and damping > 0, ...).
* **Records** (the designed excitation, every measurement) must be finite, uniformly sampled,
  at least 16 samples long, with |values| <= :data:`MAX_MAGNITUDE` (the fit sums squares: 1e154
  squared is already infinite, and no force or voltage of a rig is anywhere near 1e100).
* **Resources**: the memory of a fit grows with the record length N, the model's state count
  n_x and its parameter count p; :func:`fit_bytes` estimates it and a run that would need more
  than the memory available stops before allocating it, naming the key to change. The global
  search's own counts (``solver.options.strategy``) are bounded by the work they cause.
* **Plugins**: an exception raised inside a third-party plugin's code (its ``__init__``,
  ``state_space``, ``acquire``, ...) becomes one :class:`PluginError` line naming the plugin
  and where it came from (set ``MBUS_DEBUG=1`` to see the traceback). Built-in plugins are
  part of mbus: their exceptions stay tracebacks, so bugs are found, not hidden.
* **Numerics inside a fit** that still fail (a singular matrix, an overflow in a library
  routine) end as one :class:`EstimationError` line naming the solver.
"""
from __future__ import annotations

import os
from contextlib import contextmanager
from typing import TYPE_CHECKING, Iterator

import numpy as np

from mbus_framework.errors import (
    ConfigError,
    DataError,
    EstimationError,
    MbusError,
    PluginError,
    ResourceError,
    one_line,
)

if TYPE_CHECKING:  # pragma: no cover
    from mbus_framework.interfaces.backend import Measurement
    from mbus_framework.interfaces.excitation import Waveform
    from mbus_framework.interfaces.model import MediumModel
    from mbus_framework.interfaces.registry import Registry
    from mbus_framework.pipeline.components import Components

MAX_MAGNITUDE = 1e100
"""Largest |value| accepted in a record (input or output)."""
MIN_SAMPLES = 16
BUILTIN_PACKAGES = ("mbus_framework", "plugins")
STRATEGY_LIMITS = {
    "n_starts": (1000, "each start is a local fit (0.1-10 s): more than 1000 would run for hours"),
    "time_scale_points": (10_000, "each point simulates the model once; 40 resolve the arrival time"),
    "coordinate_scan": (100, "each sweep simulates the model tens of times per parameter"),
    "stage_max_nfev": (100_000, "a stage that needs more evaluations has not converged"),
    "confirm": (1000, "at most n_starts starts can agree"),
}


# -- parameter values ------------------------------------------------------------------------
MAX_DECADES = 15
"""How far (orders of magnitude) a log-scale parameter may lie from the model's typical value."""


def check_parameters(model: "MediumModel", values: dict[str, float], where: str) -> None:
    """Every value finite and inside its parameter's range (log-scale parameters > 0), and a
    log-scale one within :data:`MAX_DECADES` orders of magnitude of the model's typical value
    for this sample (typical moduli are ~1e9 Pa: 15 decades span every material, from gels to
    diamond, with room to spare; beyond them the chain's time constants over- or underflow)."""
    by_name = {p.name: p for p in model.parameters}
    for name, value in values.items():
        p = by_name.get(name)
        if p is None:
            continue
        value = float(value)
        low_ok = value > p.lower if p.log_scale and p.lower <= 0 else value >= p.lower
        if not np.isfinite(value) or not low_ok or value > p.upper:
            lower = "(" if p.log_scale and p.lower <= 0 else "["
            raise ConfigError(
                f"{where}.{name}: {value:g} {p.unit} is outside the physical range {lower}{p.lower:g}, {p.upper:g}] of "
                f"{p.description or name}")
        if p.log_scale and p.typical > 0 and abs(np.log10(value / p.typical)) > MAX_DECADES:
            raise ConfigError(
                f"{where}.{name}: {value:g} {p.unit} is more than {MAX_DECADES} orders of magnitude from the typical "
                f"{p.typical:.3g} {p.unit} of this model and sample; no material is that far from it")


def check_run(c: "Components") -> None:
    """Up-front checks of a built run: parameter values, nuisance values, search counts, memory."""
    source = c.source
    model = c.model
    if c.config.model.initial:
        theta = model.theta_from_mapping(c.config.model.initial, f"{source}: model.initial")
        check_parameters(model, dict(zip(model.parameter_names, theta)), f"{source}: model.initial")
    check_parameters(model, dict(c.config.model.fixed), f"{source}: model.fixed")
    gain = c.config.nuisance.input_gain.value
    if gain is not None and not gain > 0:
        raise ConfigError(f"{source}: nuisance.input_gain.value: {gain:g} must be > 0 (force per recorded input unit)")
    delay = c.config.nuisance.delay.value
    if delay is not None and not delay >= 0:
        raise ConfigError(f"{source}: nuisance.delay.value: {delay:g} s must be >= 0 (a trigger offset)")
    strategy = getattr(c.solver.options, "strategy", None)
    for key, (ceiling, reason) in STRATEGY_LIMITS.items():
        value = getattr(strategy, key, None)
        if isinstance(value, int) and value > ceiling:
            raise ResourceError(f"{source}: solver.options.strategy.{key}: {value} is more than {ceiling} ({reason})")
    for key, value in dict(c.solver.options).items():
        if key.endswith("tol") and isinstance(value, float) and value < np.finfo(float).eps:
            raise ConfigError(f"{source}: solver.options.{key}: {value:g} is below the machine epsilon "
                              f"{np.finfo(float).eps:.3g}; no solver can meet a tolerance finer than round-off")
    seed = getattr(strategy, "seed", None)
    if isinstance(seed, int) and seed < 0:
        raise ConfigError(f"{source}: solver.options.strategy.seed: {seed} must be >= 0 (numpy seeds are non-negative)")
    grid = getattr(c.excitation, "grid", None)
    if callable(grid):
        with plugin_failures(c.registry, source):
            n, rate = grid()
        est = getattr(c.config, "estimation", None)
        fitted = int(n)
        if est is not None and est.window is not None:
            fitted = min(fitted, int((est.window[1] - est.window[0]) * rate) + 1)
        fitted //= max(getattr(est, "decimate", 1), 1)
        check_memory(c, fitted, "excitation.options (n_samples, duration or periods)", float(1.0 / rate))


# -- resources -------------------------------------------------------------------------------
FIT_OVERHEAD_BYTES = 32 * 2**20
"""Memory of a fit that does not grow with the record (modules, caches, the start design)."""


def fit_bytes(n_samples: int, n_states: int, n_parameters: int) -> int:
    """Upper estimate of a fit's peak memory [bytes]: 32 MiB + 8 bytes x N x (64 + 4 n_x (p + 1)).

    64 doubles per sample cover the record, residuals, Jacobian columns and FFT buffers
    (measured 80-100 bytes per sample in all); 4 n_x (p + 1) the state and sensitivity kernels
    of the simulation's doubling path (the modal path needs less).
    """
    return int(FIT_OVERHEAD_BYTES + 8 * n_samples * (64 + 4 * n_states * (n_parameters + 1)))


def available_memory() -> int | None:
    """Bytes this process may still allocate: MemAvailable, capped by RLIMIT_AS (None: unknown)."""
    avail = None
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    avail = int(line.split()[1]) * 1024
                    break
    except (OSError, ValueError, IndexError):
        try:
            avail = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            avail = None
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
        if soft != resource.RLIM_INFINITY:
            with open("/proc/self/statm", encoding="ascii") as fh:
                used = int(fh.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
            room = max(soft - used, 0)
            avail = room if avail is None else min(avail, room)
    except (ImportError, OSError, ValueError, IndexError):
        pass
    return avail


def check_memory(c: "Components", n_samples: int, key: str, dt: float | None = None) -> None:
    """ResourceError naming ``key`` when a fit of ``n_samples`` would need more memory than is
    available or than ``estimation.max_memory_GiB`` allows; the message names the decimation
    factor that would fit (and, with ``dt``, the band it keeps)."""
    with plugin_failures(c.registry, c.source):
        n_states = int(c.model.n_states)
        n_params = len(c.model.parameters) + 2
    need = fit_bytes(n_samples, n_states, n_params)
    avail = available_memory()
    estimation = getattr(c.config, "estimation", None)
    allowed = getattr(estimation, "max_memory_GiB", None)
    limit = min(x for x in (avail, None if allowed is None else allowed * 2**30) if x is not None) \
        if (avail is not None or allowed is not None) else None
    if limit is None or need <= limit:
        return
    per_sample = (need - FIT_OVERHEAD_BYTES) / max(n_samples, 1)
    q = int(np.ceil(n_samples * per_sample / max(limit - FIT_OVERHEAD_BYTES, 1)))
    band = f" (keeps the band below {0.4 / (q * dt) / 1e6:.3g} MHz)" if dt else ""
    which = ("the estimation.max_memory_GiB of " + f"{allowed:g} GiB" if allowed is not None and
             (avail is None or allowed * 2**30 <= avail) else f"the {avail / 2**30:.2f} GiB available")
    raise ResourceError(
        f"{c.source}: {key}: a record of {n_samples:,} samples with a {n_states}-state model needs about "
        f"{need / 2**30:.2f} GiB to fit, more than {which}; fit part of it: estimation.decimate: {q}{band}, "
        f"or estimation.window, or use fewer model elements")


# -- records ---------------------------------------------------------------------------------
def check_arrays(t, u, y, what: str, error: type[MbusError] = DataError) -> None:
    """Finite, >= 16 samples, equal lengths, uniform increasing t, |u|, |y| <= MAX_MAGNITUDE."""
    arrays = {"t": np.asarray(t), "u": np.asarray(u), "y": np.asarray(y)}
    sizes = {k: a.size for k, a in arrays.items()}
    if any(a.ndim != 1 for a in arrays.values()) or len(set(sizes.values())) != 1:
        raise error(f"{what}: t, u and y must be 1-D and equally long (sizes {sizes})")
    n = sizes["t"]
    if n < MIN_SAMPLES:
        raise error(f"{what}: only {n} samples; need at least {MIN_SAMPLES}")
    for name, a in arrays.items():
        if not np.issubdtype(a.dtype, np.number) or np.iscomplexobj(a):
            raise error(f"{what}: {name} is not a real number array (dtype {a.dtype})")
        bad = np.flatnonzero(~np.isfinite(a))
        if bad.size:
            raise error(f"{what}: {name} has {bad.size} non-finite value(s) (first at sample {bad[0]})")
        if name != "t":
            peak = float(np.max(np.abs(a)))
            if peak > MAX_MAGNITUDE:
                raise error(f"{what}: |{name}| reaches {peak:.3g}, beyond {MAX_MAGNITUDE:g} (no rig records such "
                            f"values; their squares overflow the fit's cost)")
    steps = np.diff(arrays["t"].astype(float))
    if not np.all(steps > 0):
        raise error(f"{what}: time t is not strictly increasing")
    dt = float(np.median(steps))
    if not np.isfinite(1.0 / dt) or np.max(np.abs(steps - dt)) > 1e-6 * dt:
        raise error(f"{what}: the time step is not uniform (median {dt:.6g} s)")


def checked_waveform(c: "Components") -> "Waveform | None":
    """The designed excitation, checked (a broken third-party excitation is a PluginError);
    None when the run has no designed excitation (the input comes from the record)."""
    if getattr(c, "excitation", None) is None:
        return None
    with plugin_failures(c.registry, c.source):
        w = c.excitation.waveform()
    check_arrays(w.t, w.u, w.u, f"{c.source}: excitation '{c.config.excitation.name}'", ConfigError)
    if not np.any(w.u):
        raise ConfigError(f"{c.source}: excitation '{c.config.excitation.name}': the waveform is all zero (nothing "
                          f"excites the sample)")
    return w


def checked_measurement(m: "Measurement", c: "Components") -> "Measurement":
    """A backend's record, checked before it is saved or fitted; also its memory and delays."""
    where = f"{c.source}: backend '{c.config.backend.name}' ({m.meta.get('source', 'record')})"
    check_arrays(m.t, m.u, m.y, where)
    if not np.any(m.u):
        raise DataError(f"{where}: the input u is all zero (nothing excited the sample)")
    duration = float(m.t[-1] - m.t[0])
    n = c.config.nuisance
    if n.max_delay is not None and n.max_delay >= duration:
        raise ConfigError(f"{c.source}: nuisance.max_delay: {n.max_delay:g} s is not shorter than the record "
                          f"({duration:g} s)")
    limit = n.max_delay if n.max_delay is not None else duration / 2
    if n.delay.value is not None and n.delay.value > limit:
        raise ConfigError(f"{c.source}: nuisance.delay.value: {n.delay.value:g} s is beyond the largest delay "
                          f"searched ({limit:g} s)")
    return m


# -- failures inside plugins and fits --------------------------------------------------------
def _foreign_plugin(exc: BaseException, registry: "Registry") -> tuple[str, str, str] | None:
    """(kind, name, source) of the third-party plugin whose code raised ``exc`` (innermost frame)."""
    modules = {}
    for kind, entries in getattr(registry, "entries", {}).items():
        for name, entry in entries.items():
            module = getattr(entry.spec.implementation, "__module__", "") or ""
            if module and module.split(".")[0] not in BUILTIN_PACKAGES:
                modules[module] = (kind, name, entry.source)
    if not modules:
        return None
    found = None
    tb = exc.__traceback__
    while tb is not None:
        module = tb.tb_frame.f_globals.get("__name__", "")
        if module in modules:
            found = modules[module]
        tb = tb.tb_next
    return found


@contextmanager
def plugin_failures(registry: "Registry", source: str) -> Iterator[None]:
    """Turn an exception raised in a third-party plugin's code into one PluginError line."""
    try:
        yield
    except (MbusError, KeyboardInterrupt, SystemExit):
        raise
    except Exception as exc:
        plugin = None if os.environ.get("MBUS_DEBUG") else _foreign_plugin(exc, registry)
        if plugin is None:
            raise
        kind, name, origin = plugin
        raise PluginError(
            f"{source}: {kind} '{name}' ({origin}) failed: {one_line(f'{type(exc).__name__}: {exc}', 300)} "
            f"(a bug in that plugin; MBUS_DEBUG=1 shows the traceback)") from exc


NUMERIC_FAILURES = (ArithmeticError, FloatingPointError, ValueError, RuntimeError, np.linalg.LinAlgError)
NUMERIC_LIBRARIES = ("numpy", "scipy", "casadi")


@contextmanager
def estimation_boundary(c: "Components") -> Iterator[None]:
    """Around ``solver.solve``: running out of memory, and a numeric failure raised *inside a
    numerical library* (LAPACK not converging, scipy refusing non-finite residuals, IPOPT
    refusing an option), become one-line errors naming the solver. The same exception raised by
    mbus's own code is a bug and stays a traceback."""
    name = c.config.solver.name
    with plugin_failures(c.registry, c.source):
        try:
            yield
        except MemoryError as exc:
            raise ResourceError(f"{c.source}: solver {name}: ran out of memory ({one_line(str(exc), 200)}); shorten "
                                f"the record or use fewer model elements") from exc
        except NUMERIC_FAILURES as exc:
            library = raised_in(exc)
            if library not in NUMERIC_LIBRARIES:
                raise
            err = EstimationError(f"{c.source}: solver {name}: the fit failed numerically in {library} "
                                  f"({one_line(f'{type(exc).__name__}: {exc}', 300)})")
            err.converted_from = exc
            raise err from exc


def raised_in(exc: BaseException) -> str:
    """Top-level package of the innermost Python frame of ``exc``'s traceback."""
    name, tb = "", exc.__traceback__
    while tb is not None:
        name = str(tb.tb_frame.f_globals.get("__name__", ""))
        tb = tb.tb_next
    return name.split(".")[0]
