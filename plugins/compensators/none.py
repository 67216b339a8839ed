"""``none`` compensator: fit the record as measured."""
from __future__ import annotations

from mbus_framework.interfaces.backend import Measurement
from mbus_framework.interfaces.compensator import Compensator
from mbus_framework.interfaces.hookspecs import CompensatorSpec, hookimpl


class NoCompensation(Compensator):
    """Leaves the measurement unchanged."""

    summary = "no transducer compensation"

    def apply(self, measurement: Measurement) -> Measurement:
        return measurement


@hookimpl
def mbus_compensators():
    return [CompensatorSpec("none", NoCompensation, NoCompensation.summary)]
