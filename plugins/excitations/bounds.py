"""Physical bounds shared by the built-in excitations' options (checked when a config is read).

No ultrasonic rig drives its transmitter with a meganewton or a megavolt, and no generator
or digitiser samples faster than 100 GS/s; records longer than 10^8 samples (800 MB per
array) are beyond what a fit can hold. Values outside these bounds are typing slips, and
would otherwise overflow (``amplitude: 1e300`` squares to infinity in the fit's cost; a record
length of ``duration x sample_rate = 1e311`` samples does not even convert to an integer).
"""
from __future__ import annotations

import math
from typing import Annotated

from pydantic import AfterValidator, Field

MAX_AMPLITUDE = 1e6
"""Largest excitation amplitude [N or V]."""
SAMPLE_RATE_RANGE = (1.0, 1e11)
"""Sample and point rates [Hz]."""
MAX_SAMPLES = 100_000_000
"""Longest record [samples]."""


def _amplitude(value: float) -> float:
    if not value <= MAX_AMPLITUDE:
        raise ValueError(f"{value:g} is above {MAX_AMPLITUDE:g} N or V (no ultrasonic rig drives its transmitter "
                         f"that hard; the fit's squared residuals would overflow)")
    return value


def _rate(value: float) -> float:
    lo, hi = SAMPLE_RATE_RANGE
    if not lo <= value <= hi:
        raise ValueError(f"{value:g} Hz is outside {lo:g}-{hi:g} Hz (no generator or digitiser samples faster "
                         f"than 100 GS/s)")
    return value


Amplitude = Annotated[float, Field(gt=0), AfterValidator(_amplitude)]
"""A peak amplitude [N or V], 0 < A <= MAX_AMPLITUDE."""
SampleRate = Annotated[float, Field(gt=0), AfterValidator(_rate)]
"""A sample or point rate [Hz] within SAMPLE_RATE_RANGE."""
RecordSamples = Annotated[int, Field(ge=16, le=MAX_SAMPLES)]
"""A record length [samples], 16..MAX_SAMPLES."""


def samples(count: float, what: str = "record") -> int:
    """``round(count)`` as an int, or ValueError when it is not a finite count up to MAX_SAMPLES."""
    if not (math.isfinite(count) and count <= MAX_SAMPLES):
        raise ValueError(f"the {what} would be {count:.3g} samples long, more than {MAX_SAMPLES:.0e} (800 MB per "
                         f"array); shorten it")
    return int(round(count))
