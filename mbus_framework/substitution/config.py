"""``experiment: substitution`` configs: a plate in water, a reference shot without it.

    experiment: substitution
    data: ../../examples/real/thetascan/VW100a.mat   # relative to this file
    law: constant_q                                   # or a list of laws to rank, or "all"

Optional keys: ``column`` (of a 2-D sample variable, default 0 = normal incidence),
``variables`` (mapping reference/sample/time/thickness/density/temperature to the file's names),
``thickness`` [m], ``density`` [kg/m^3], ``temperature_C`` (override the file), ``passes``
(2 = double through-transmission), ``reverberations`` (true: exact plate transmission),
``band_dB`` (lines within this many dB of the reference's peak, default 30), ``title``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from mbus_framework.errors import ConfigError
from mbus_framework.substitution.chains import ALL_LAWS as LAWS
from mbus_framework.substitution.record import DEFAULT_VARIABLES

KEY = "experiment"
KIND = "substitution"
_KEYS = {"experiment", "data", "law", "column", "variables", "thickness", "density", "temperature_C", "passes",
         "reverberations", "band_dB", "title", "output"}


@dataclass
class SubstitutionConfig:
    path: Path
    source: Path
    laws: list[str]
    column: int = 0
    variables: dict[str, str] = field(default_factory=dict)
    overrides: dict[str, float] = field(default_factory=dict)
    passes: int = 2
    reverberations: bool = True
    band_dB: float = 30.0
    title: str = ""
    output_directory: str = "runs"


def is_substitution_file(path: str | Path) -> bool:
    from mbus_framework.pipeline.config import config_mapping_or_none

    data = config_mapping_or_none(path)
    return isinstance(data, dict) and data.get(KEY) == KIND


def load(path: str | Path, overrides: list[str] | None = None) -> SubstitutionConfig:
    """Read and check a substitution config; every error is one line naming the key."""
    from mbus_framework.pipeline.config import read_yaml

    source = Path(path)
    raw = dict(read_yaml(source))
    for item in overrides or []:
        key, sep, value = item.partition("=")
        if not sep:
            raise ConfigError(f"--set {item!r}: expected KEY=VALUE")
        import yaml

        raw[key.strip()] = yaml.safe_load(value)
    unknown = sorted(set(raw) - _KEYS)
    if unknown:
        raise ConfigError(f"{source}: unknown key(s) {', '.join(unknown)}; known: {', '.join(sorted(_KEYS))}")
    if "data" not in raw:
        raise ConfigError(f"{source}: data: missing (the .mat file holding the reference and sample shots)")
    data = Path(str(raw["data"])).expanduser()
    if not data.is_absolute():
        data = (source.parent / data).resolve()
    if not data.is_file():
        raise ConfigError(f"{source}: data: {raw['data']}: file not found (looked for {data})")
    laws = check_laws(raw.get("law", "constant_q"), str(source))
    variables = raw.get("variables") or {}
    if not isinstance(variables, dict) or set(variables) - set(DEFAULT_VARIABLES):
        raise ConfigError(f"{source}: variables: map any of {', '.join(DEFAULT_VARIABLES)} to the file's variable names")
    values = {}
    for key in ("thickness", "density", "temperature_C"):
        if key in raw:
            values[key] = _number(source, key, raw[key], positive=key != "temperature_C")
    column = raw.get("column", 0)
    passes = raw.get("passes", 2)
    if not isinstance(column, int) or isinstance(column, bool):
        raise ConfigError(f"{source}: column: expected an integer, got {column!r}")
    if passes not in (1, 2):
        raise ConfigError(f"{source}: passes: 1 (through-transmission) or 2 (double through-transmission), got {passes!r}")
    band = _number(source, "band_dB", raw.get("band_dB", 30.0), positive=True)
    output = raw.get("output") or {}
    return SubstitutionConfig(
        path=data, source=source, laws=laws, column=column, variables={str(k): str(v) for k, v in variables.items()},
        overrides=values, passes=int(passes), reverberations=bool(raw.get("reverberations", True)), band_dB=band,
        title=str(raw.get("title", "")), output_directory=str(output.get("directory", "runs")) if isinstance(output, dict) else "runs",
    )


def check_laws(law, source: str, key: str = "law") -> list[str]:
    """The law names ``law`` asks for (a name, a list, or "all"), each known; one-line error."""
    laws = list(LAWS) if law == "all" else ([law] if isinstance(law, str) else list(law or []))
    if "all" in laws:  # a list naming "all" besides others: every law, then the others
        laws = list(dict.fromkeys([*LAWS, *(x for x in laws if x != "all")]))
    bad = [x for x in laws if x not in LAWS and not _registered(str(x))]
    if bad or not laws:
        where = f"{source}: {key}" if key == "law" else key
        raise ConfigError(f"{where}: {', '.join(map(str, bad)) or 'empty'}: choose from {', '.join(LAWS)}, "
                          f"model:<registered chain or frequency-response model>, or 'all'")
    return laws


def _registered(name: str) -> bool:
    """``model:<name>`` naming a registered model usable here (chains, frequency-response laws)."""
    from mbus_framework.substitution.chains import MODEL_PREFIX, registered_law

    if not name.startswith(MODEL_PREFIX):
        return False
    try:
        registered_law(name[len(MODEL_PREFIX):])
    except (ValueError, KeyError):
        return False
    return True


def _number(source: Path, key: str, value, positive: bool) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{source}: {key}: expected a number, got {value!r}") from None
    if positive and not x > 0:
        raise ConfigError(f"{source}: {key}: must be positive, got {value!r}")
    return x
