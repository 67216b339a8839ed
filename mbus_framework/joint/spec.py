"""Which parameters are shared and which are per record (declared by name, checked in one line)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

from mbus_framework.errors import ConfigError
from mbus_framework.estimation.nuisance import DELAY, GAIN
from mbus_framework.suggest import did_you_mean

NUISANCE = (GAIN, DELAY)


@dataclass(frozen=True)
class JointSpec:
    """``shared``: property names common to all records (in the model's order); ``per_record``:
    the other property names, each estimated per record; ``nuisance``: nuisance parameters
    (input_gain, delay) estimated per record."""

    shared: tuple[str, ...]
    per_record: tuple[str, ...]
    nuisance: tuple[str, ...]

    @classmethod
    def declare(cls, property_names: Sequence[str], shared: Sequence[str] | None,
                per_record: Sequence[str] | None, where: str = "joint") -> "JointSpec":
        """Check a declaration against the model's ``property_names``: unknown names, a name both
        shared and per record, a nuisance parameter declared shared are one-line ConfigErrors.
        ``shared`` None shares every property not declared per record."""
        props = list(property_names)
        per = list(per_record or [])
        for key, names in (("shared", shared or []), ("per_record", per)):
            if isinstance(names, str) or not all(isinstance(n, str) for n in names):
                raise ConfigError(f"{where}.{key}: must be a list of names")
            seen = set()
            for name in names:
                if name in seen:
                    raise ConfigError(f"{where}.{key}: {name} is listed twice")
                seen.add(name)
                if name in NUISANCE and key == "shared":
                    raise ConfigError(f"{where}.shared: {name} is a nuisance parameter of each record's rig; "
                                      f"declare it under per_record (or fix it in the nuisance section)")
                if name not in props and name not in NUISANCE:
                    hint = did_you_mean(name, props + list(NUISANCE))
                    raise ConfigError(f"{where}.{key}: {name}: not a property of this model{hint}; "
                                      f"properties: {', '.join(props)}")
        if shared is not None:
            both = [n for n in shared if n in per]
            if both:
                raise ConfigError(f"{where}: {both[0]} is declared both shared and per_record; choose one")
            shared_set = set(shared)
        else:
            shared_set = {n for n in props if n not in per}
        if not shared_set:
            raise ConfigError(f"{where}.shared: no shared property: a joint fit needs at least one")
        return cls(
            shared=tuple(n for n in props if n in shared_set),
            per_record=tuple(n for n in props if n not in shared_set),
            nuisance=tuple(n for n in NUISANCE if n in per),
        )
