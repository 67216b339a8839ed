"""Make the shipped recorded-data example with mbus's own simulator.

    python examples/recorded/make_recorded_example.py [--out examples/recorded]

Writes what a lab would hand over after measuring a 3 cm potato slice (rho 1080 kg/m^3,
D 25.4 mm) whose true properties are the Table 6.2 "MBUS after compensation" means with the
minimum shear viscosity (E_sigma 2.42e10 Pa, eta_sigma 7.18e3 Pa s, E_tau 6.56e9 Pa,
eta_tau 5.14e3 Pa s), simulated by a 10-element Kelvin-Voigt chain:

* ``potato_tuy.csv``: a processed t,u,y record (header ``t,u,y``; seconds, newtons): one period
  of an order-7 PRBS of 0.4 us bits (127 bits, 50.8 us) at 25 MS/s, then the ring-down, 2500
  samples, output noise 3 % of the noise-free RMS (seed 11);
* ``A0001CH1.CSV`` and ``A0001CH2.CSV``: the same experiment as a GW Instek GDS-2062 saves it
  on its USB disk, one file per channel in the raw-sample layout (header rows, then one 8-bit
  code per row; volts = code x Vertical Scale / 25): CH1 the generator output at 0.5 V/div, CH2
  the received wave at 0.1 V/div, 25 MS/s, 4000 points, the burst starting 16 us (400 samples)
  after the record starts, 3 % output noise and 0.5 % input noise before the ADC (seed 12).
  Volts are the model's units here (1 N per V on both channels).

The files are small (about 60 kB and 2 x 20 kB) and deterministic: running the script again
reproduces them byte for byte. ``configs/recorded.yaml`` and ``configs/recorded_gds2062.yaml``
fit them with no excitation section.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from mbus_framework.plugins import AcquisitionContext, Sample, Waveform, default_registry

TRUTH = {"E_sigma": 2.42e10, "eta_sigma": 7.18e3, "E_tau": 6.56e9, "eta_tau": 5.14e3}
SAMPLE = Sample(length=0.03, diameter=0.0254, density=1080.0)
FS = 25.0e6
BIT = 0.4e-6
ORDER = 7
COUNTS_PER_DIV = 25.0


def burst(n: int) -> Waveform:
    """One PRBS period (the generator's burst), then rest: n samples at FS."""
    registry = default_registry()
    prbs = registry.get("excitation", "prbs").implementation
    period = prbs(prbs.Options(order=ORDER, bit_width=BIT, sample_rate=FS)).waveform().u
    u = np.zeros(n)
    u[: period.size] = period
    return Waveform(np.arange(n) / FS, u)


def simulate(n: int, seed: int, **backend_options):
    """The simulated backend's record of the potato for the burst (noise and scope as given)."""
    registry = default_registry()
    model = registry.get("model", "kelvin_voigt").implementation
    kv = model(SAMPLE, model.Options(n_elements=10))
    backend = registry.get("backend", "simulated").implementation
    rig = backend(backend.Options(truth=TRUTH, seed=seed, **backend_options))
    return rig.acquire(AcquisitionContext(burst(n), SAMPLE, kv, registry))


def write_tuy(path: Path) -> None:
    m = simulate(2500, seed=11, noise={"relative_std": 0.03})
    rows = "\n".join(f"{t:.6e},{u:.7g},{y:.7g}" for t, u, y in zip(m.t, m.u, m.y))
    path.write_text("t,u,y\n" + rows + "\n")


def gds_file(path: Path, codes: np.ndarray, source: str, volts_per_div: float) -> None:
    """One channel in the GDS-2000 raw-sample CSV layout (header rows of the firmware)."""
    header = [f"Memory Length,{codes.size},", "Trigger Level,0.100V,", f"Source,{source},",
              "Vertical Units,V,", f"Vertical Scale,{volts_per_div:.3E},", "Vertical Position,0.000E+00,",
              "Horizontal Units,S,", "Horizontal Scale,1.000E-05,", "Horizontal Position,0.000E+00,",
              "Horizontal Mode,Main,", f"Sampling Period,{1 / FS:.3E},", "Firmwave,V1.12,"]
    path.write_text("\r\n".join(header + [f"{c}," for c in codes]) + "\r\n")


def write_gds_pair(folder: Path) -> None:
    ch1_div, ch2_div = 0.5, 0.1
    step1, step2 = ch1_div / COUNTS_PER_DIV, ch2_div / COUNTS_PER_DIV
    # The simulated scope's 8-bit ADC has step range / 128: choose the ranges that give V/div / 25.
    scope = {"bits": 8, "input_range": 128 * step1, "output_range": 128 * step2, "trigger_delay": 400 / FS}
    m = simulate(4000, seed=12, noise={"relative_std": 0.03, "input_relative_std": 0.005}, scope=scope)
    gds_file(folder / "A0001CH1.CSV", np.round(m.u / step1).astype(int), "CH1", ch1_div)
    gds_file(folder / "A0001CH2.CSV", np.round(m.y / step2).astype(int), "CH2", ch2_div)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(Path(__file__).resolve().parent), help="output folder")
    out = Path(parser.parse_args(argv).out)
    out.mkdir(parents=True, exist_ok=True)
    write_tuy(out / "potato_tuy.csv")
    write_gds_pair(out)
    print(f"wrote {out / 'potato_tuy.csv'}, {out / 'A0001CH1.CSV'}, {out / 'A0001CH2.CSV'}; truth {TRUTH}")


if __name__ == "__main__":
    main()
