"""Virtual transducer pair and scope for the ``simulated`` rig (Chapter 5, Fig. 5.2).

Transducers
-----------
Each transducer is a linear band-pass filter: an analog Butterworth band-pass of order N
(2N poles) with -3 dB edges f1 < f2 placed geometrically about the centre frequency f_c
(f1 f2 = f_c^2, f2 - f1 = B, the -3 dB bandwidth), scaled to the gain g at f_c, where its
phase is zero:

    H(s) = g * H_BW,N(s; 2 pi f1, 2 pi f2),      |H(i 2 pi f_c)| = g,  arg H(i 2 pi f_c) = 0.

The pair's response is G_TR = G_T G_R (eq. 5.2). Identical transducers with f_c = 0.5 MHz and
B = 0.4 MHz give the Panametrics A301S-like band 0.3-0.7 MHz of Section 3.4.4 (about -6 dB at
the edges). ``mismatch`` makes the two differ: for each of centre frequency, bandwidth and
gain a relative difference m gives the transmitter x (1 + m/2) and the receiver x (1 - m/2).

In the rig the voltage u drives the transmitter, whose output force drives the medium, whose
output force drives the receiver: y = G_R * medium * G_T * u, simulated exactly as one
continuous state-space cascade (each filter in frequency-normalised form, so the matrices stay
well scaled).

Scope
-----
An n-bit ADC maps a channel to integer codes c = clip(round(x / q), -2^(n-1), 2^(n-1) - 1)
with step q = range / 2^(n-1) and reads back c q; ``averages`` shots with independent noise are
quantised and averaged (as the GDS-2062 averaging mode does), so the Gaussian part of the
noise falls as 1/sqrt(averages) while a noise-free signal keeps its quantisation error.
``trigger_delay`` delays the excitation relative to the first recorded sample in both
channels alike (the scope starts recording before the generator fires).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from mbus_framework.interfaces.model import StateSpace


class TransducerMismatch(BaseModel):
    """Relative differences between the transmitter and the receiver."""

    model_config = ConfigDict(extra="forbid")
    centre_frequency: float = Field(0.0, gt=-1.5, lt=1.5, description="relative centre-frequency difference")
    bandwidth: float = Field(0.0, gt=-1.5, lt=1.5, description="relative bandwidth difference")
    gain: float = Field(0.0, gt=-1.5, lt=1.5, description="relative gain difference")


class TransducerPairOptions(BaseModel):
    """``backend.options.transducers``: the virtual pair between generator, medium and scope."""

    model_config = ConfigDict(extra="forbid")
    name: str = Field("virtual 0.5 MHz pair", description="identity recorded in calibration files")
    centre_frequency: float = Field(0.5e6, gt=0, description="centre frequency f_c of each transducer [Hz]")
    bandwidth: float = Field(0.4e6, gt=0, description="-3 dB bandwidth B of each transducer [Hz]")
    gain: float = Field(1.0, gt=0, description="gain at f_c of each transducer [N/V or V/N]")
    order: int = Field(2, ge=1, le=6, description="Butterworth band-pass order N of each (2N poles)")
    mismatch: TransducerMismatch = Field(default_factory=TransducerMismatch)

    @model_validator(mode="after")
    def _physical(self):
        if not 1e3 <= self.centre_frequency <= 1e9:
            raise ValueError(f"centre_frequency {self.centre_frequency:g} Hz is outside 1 kHz - 1 GHz (ultrasonic "
                             f"transducers)")
        fraction = self.bandwidth / self.centre_frequency
        if not 0.01 <= fraction < 2.0:
            raise ValueError(f"bandwidth {self.bandwidth:g} Hz is {fraction:.3g} x centre_frequency; a band-pass "
                             f"transducer's fractional bandwidth lies in [0.01, 2) (the lower -3 dB edge must stay "
                             f"above 0 Hz)")
        return self


class ScopeOptions(BaseModel):
    """``backend.options.scope``: ADC, averaging and trigger of the virtual oscilloscope."""

    model_config = ConfigDict(extra="forbid")
    bits: int = Field(8, ge=2, le=16, description="ADC resolution (the GDS-2062 has 8 bits)")
    output_range: float | None = Field(
        None, gt=0, le=1e6, description="full scale of the response channel, +-range (default 1.25 x noise-free peak); "
        "at most 1e6 (no oscilloscope channel spans a megavolt)"
    )
    input_range: float | None = Field(
        None, gt=0, le=1e6, description="full scale of the excitation channel (default 1.25 x its peak); at most 1e6"
    )
    averages: int = Field(1, ge=1, le=4096, description="shots averaged, each with independent noise")
    trigger_delay: float = Field(0.0, ge=0, description="time from the first recorded sample to the excitation [s]")


@dataclass(frozen=True)
class BandPass:
    """One transducer: Butterworth band-pass (see the module docstring)."""

    centre_frequency: float
    bandwidth: float
    gain: float
    order: int

    @property
    def edges(self) -> tuple[float, float]:
        """-3 dB edges (f1, f2) [Hz] with f1 f2 = f_c^2 and f2 - f1 = B."""
        b, fc = self.bandwidth, self.centre_frequency
        f1 = -b / 2 + np.sqrt(b**2 / 4 + fc**2)
        return float(f1), float(f1 + b)

    def _normalised_zpk(self):
        """Zeros, poles and gain of H(s / w_c), w_c = 2 pi f_c (poles of order 1)."""
        from scipy import signal as sps  # on use: scipy.signal imports scipy.stats (about 0.5 s)

        f1, f2 = self.edges
        fc = self.centre_frequency
        z, p, k = sps.butter(self.order, [f1 / fc, f2 / fc], btype="bandpass", analog=True, output="zpk")
        _, h = sps.freqs_zpk(z, p, k, [1.0])
        return z, p, k * self.gain / abs(h[0])

    def response(self, f: np.ndarray) -> np.ndarray:
        """H(i 2 pi f) at frequencies f [Hz] (complex, dimensionless times the gain unit)."""
        from scipy import signal as sps

        z, p, k = self._normalised_zpk()
        _, h = sps.freqs_zpk(z, p, k, np.asarray(f, dtype=float) / self.centre_frequency)
        return h

    def state_space(self) -> StateSpace:
        """Continuous (A, B, C, D) with A = w_c A_n, B = w_c B_n (A_n entries of order 1)."""
        from scipy import signal as sps

        z, p, k = self._normalised_zpk()
        A, B, C, D = sps.zpk2ss(z, p, k)
        wc = 2 * np.pi * self.centre_frequency
        return StateSpace(np.real(A) * wc, np.real(B) * wc, np.real(C), np.atleast_2d(np.real(D)))


class TransducerPair:
    """Transmitter and receiver band-pass filters built from :class:`TransducerPairOptions`."""

    def __init__(self, options: TransducerPairOptions):
        self.options = options
        m = options.mismatch

        def one(sign: float) -> BandPass:
            return BandPass(
                options.centre_frequency * (1 + sign * m.centre_frequency / 2),
                options.bandwidth * (1 + sign * m.bandwidth / 2),
                options.gain * (1 + sign * m.gain / 2),
                options.order,
            )

        self.transmitter, self.receiver = one(+1.0), one(-1.0)

    @property
    def name(self) -> str:
        return self.options.name

    def response(self, f: np.ndarray) -> np.ndarray:
        """G_TR(i 2 pi f) = G_T G_R (eq. 5.2)."""
        return self.transmitter.response(f) * self.receiver.response(f)

    def band(self, level_db: float = -6.0) -> tuple[float, float]:
        """(lowest, highest) frequency [Hz] where |G_TR| is within ``level_db`` of its peak."""
        hi = max(self.transmitter.edges[1], self.receiver.edges[1])
        f = np.linspace(0, 4 * hi, 40001)[1:]
        mag = np.abs(self.response(f))
        keep = np.nonzero(mag >= mag.max() * 10 ** (level_db / 20))[0]
        return float(f[keep[0]]), float(f[keep[-1]])

    def describe(self) -> dict:
        out = {"name": self.name, **self.options.model_dump(exclude={"name"})}
        out["transmitter"] = self.transmitter.__dict__.copy()
        out["receiver"] = self.receiver.__dict__.copy()
        out["band_6db_hz"] = list(self.band())
        return out

    def around(self, medium) -> "Cascade":
        """A model-like object whose state space is receiver * medium * transmitter."""
        return Cascade(self.transmitter.state_space(), medium, self.receiver.state_space())

    def alone(self) -> "Cascade":
        """The pair without a medium (receiver * transmitter)."""
        return Cascade(self.transmitter.state_space(), None, self.receiver.state_space())


def series(first: StateSpace, second: StateSpace) -> StateSpace:
    """State space of ``second`` driven by the output of ``first`` (y = second(first(u)))."""
    A1, B1, C1, D1 = (np.atleast_2d(m) for m in first)
    A2, B2, C2, D2 = (np.atleast_2d(m) for m in second)
    dtype = np.result_type(A1, A2, B1, B2, C1, C2, D1, D2, float)
    n1, n2 = A1.shape[0], A2.shape[0]
    A = np.zeros((n1 + n2, n1 + n2), dtype=dtype)
    A[:n1, :n1] = A1
    A[n1:, :n1] = B2 @ C1
    A[n1:, n1:] = A2
    B = np.vstack([B1, B2 @ D1]).astype(dtype)
    C = np.hstack([D2 @ C1, C2]).astype(dtype)
    return StateSpace(A, B, C, (D2 @ D1).astype(dtype))


class Cascade:
    """pre -> model(theta) -> post as one model for :func:`mbus_framework.engine.simulation.simulate`."""

    def __init__(self, pre: StateSpace | None, model, post: StateSpace | None):
        self.pre, self.model, self.post = pre, model, post

    def state_space(self, theta) -> StateSpace:
        ss = self.model.state_space(theta) if self.model is not None else None
        parts = [p for p in (self.pre, ss, self.post) if p is not None]
        out = parts[0]
        for nxt in parts[1:]:
            out = series(out, nxt)
        return out


def adc(x: np.ndarray, full_scale: float, bits: int) -> tuple[np.ndarray, int]:
    """(quantised copy of x, number of clipped samples) for an ADC spanning +-full_scale."""
    half = 2 ** (bits - 1)
    q = full_scale / half
    codes = np.round(np.asarray(x) / q)
    clipped = int(np.sum((codes < -half) | (codes > half - 1)))
    return np.clip(codes, -half, half - 1) * q, clipped


def adc_step(full_scale: float, bits: int) -> float:
    """Quantisation step q = full_scale / 2^(bits-1)."""
    return full_scale / 2 ** (bits - 1)
