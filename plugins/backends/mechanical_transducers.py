"""Mechanical virtual transducer pair: lumped piezo element and face plates around the sample.

Selected by ``backend.options.transducers.kind: mechanical`` (the default ``kind: filter`` is the
band-pass pair of :mod:`mbus_plugins.backends.transducers`). Where the filter pair multiplies
the medium's response by G_T G_R (eq. 5.2), this pair is mechanics in series with the sample
(Section 6.3: "the transducer materials should add to the elasticity and damping of the
system"): one heterogeneous chain

    backing | piezo | plates | sample | plates | piezo | mount        (1-D column, area A)

with A = pi D^2 / 4 the transducer element's face (D = 25.4 mm for the A301S, Section 3.4.3).

Layers
------
Each layer (thickness t [m], density rho [kg/m^3], longitudinal sound speed c [m/s], loss
factor delta [-], n elements) is a uniform lumped chain like the sample's (eqs. 3.1-3.13):

    element mass       m_e = rho A t / n                         [kg]
    element spring     k_e = rho c^2 A / (t / n)                 [N/m]
    element dashpot    b_e = k_e delta / omega_0                 [N s/m]

(a Kelvin-Voigt element whose loss factor Im E*/Re E* is delta at omega_0 = 2 pi f_0). Node
masses are half of each adjacent element's mass. The sample keeps its model's own nodes, links
and shear links (the fitted model's truth); the transmitter's face node is the sample's first
node (its face plate's half element mass is added there) and the sample's last normal link
ends on the receiver's face node instead of the rigid receiver wall.

Defaults (an A301S-like immersion pair from the dissertation's rig, Sections 3.4.3, 3.4.4, 5.4
and 6.2.2, and handbook materials; the shipped configs/campaigns/potatoes_uncompensated.yaml states
them):

* piezo: PZT-5A, rho = 7750 kg/m^3, c = 4350 m/s, a half-wave plate at f_0 = 0.5 MHz
  (t = c / (2 f_0) = 4.35 mm), delta = 1/Q_m = 1/75; 10 elements.
* plates: one quarter-wave layer matched to water, Z_m = sqrt(Z_p Z_w) = 7.07 MRayl,
  c = 3000 m/s (alumina-filled epoxy), rho = Z_m / c, t = c / (4 f_0) = 1.5 mm, delta = 0.02;
  8 elements. The 0.6 cm acrylic holding plate of Section 6.2.2 is fastened to the casing beside
  the face ("full contact with the sample"), so it is not in the column; give it as a plate to
  put it there.
* backing: a dashpot b_B = Z_B A to the stationary casing behind each piezo, Z_B = rho c of
  the piezo = 33.7 MRayl (fully damped, broadband).
* drive ``faces`` and receiver_mount ``backing`` (below): two identical transducers. Their
  face-to-face -6 dB band is 0.31-0.59 MHz against the A301S's documented 0.3-0.7 MHz
  (tested).

Elements shorter than a twentieth of a wavelength at f_0 keep the lumped layers' cut-off
(2 c n / (2 pi t): 3.2 MHz for the piezo, 5.1 MHz for the matching layer) well above the band;
the options reject elements longer than a quarter wavelength.

Transduction
------------
As in the sample's own chain, a force enters at one end and the force at the other end is
read. The generator voltage V sets F = e33 (A / t_p) V [N] in the transmitter's piezo
(e33 [C/m^2]); ``drive: faces`` (default) applies the field's stress as +F on the piezo's front
node and -F on its back node (Mason's 1-D model), ``drive: back_face`` as F on its back node
alone (the reaction into the casing). A backing dashpot b_B = Z_B A ties the back node to the
stationary casing and absorbs what runs backwards. ``receiver_mount: backing`` (default): the
receiver is an identical transducer on its own backing; ``rigid``: its piezo's back face rests
on a rigid mount (the chain's wall; one transducer was mounted statically on the chamber,
Section 3.4.3). The receiver's open-circuit voltage follows the mean stress in its piezo,
V_o = g33 t_p <F> / A [V] (g33 [V m/N]), <F> the mean force over the piezo's element links
(k_e delta_x + b_e delta_v each), i.e. its thickness change u(t_p) - u(0). PZT-5A: e33 = 15.8
C/m^2, g33 = 24.8e-3 V m/N. With stiff, light layers, back-face drive, a rigid mount and no
backing, the record is e33 g33 times the sample's own (force in at its first node, force out
into a rigid wall). Clamped at the back and pushed at the face, u(x) ~ sin(k x), which vanishes
at k t_p = pi: a rigidly mounted half-wave receiver is deaf at f_0 = c / (2 t_p) (tested).

Everything is one continuous state space (z = [x, x', q], built by
:func:`mbus_framework.engine.chain.assemble_chain` with the input and output rows above),
simulated exactly like the sample alone.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from mbus_framework.engine.chain import LinkMatrices, assemble_chain
from mbus_framework.errors import ConfigError
from mbus_framework.interfaces.model import StateSpace


class Layer(BaseModel):
    """One solid layer of a transducer in the wave path (see the module docstring)."""

    model_config = ConfigDict(extra="forbid")
    name: str = Field("layer", description="what the layer is (recorded in the metadata)")
    thickness: float = Field(gt=0, le=0.1, description="thickness t [m]")
    density: float = Field(gt=0, description="density rho [kg/m^3]")
    sound_speed: float = Field(gt=0, description="longitudinal sound speed c [m/s]")
    loss_factor: float = Field(0.0, ge=0, le=1.0, description="loss factor delta = Im E*/Re E* at the centre frequency")
    n_elements: int = Field(2, ge=1, le=60, description="lumped elements n")


def _pzt5a() -> Layer:
    return Layer(name="PZT-5A piezo element (half-wave at 0.5 MHz)", thickness=4.35e-3, density=7750.0,
                 sound_speed=4350.0, loss_factor=1 / 75, n_elements=10)


def _matching_layer() -> list[Layer]:
    return [Layer(name="quarter-wave matching layer", thickness=1.5e-3, density=2357.0, sound_speed=3000.0,
                  loss_factor=0.02, n_elements=8)]


class MechanicalTransducerOptions(BaseModel):
    """``backend.options.transducers`` with ``kind: mechanical`` (see the module docstring)."""

    model_config = ConfigDict(extra="forbid")
    kind: Literal["mechanical"]
    name: str = Field("virtual A301S pair, matched and backed (mechanical)", description="identity of the pair")
    diameter: float = Field(0.0254, gt=0, le=0.5, description="element diameter D [m] (A301S: 25.4 mm)")
    centre_frequency: float = Field(0.5e6, ge=1e3, le=1e9, description="f_0 where loss factors apply [Hz]")
    piezo: Layer = Field(default_factory=_pzt5a, description="the active element (closest to the backing)")
    plates: list[Layer] = Field(default_factory=_matching_layer, description="layers between piezo and sample, "
                                "piezo side first")
    backing_impedance: float = Field(3.37e7, gt=0, le=1e20, description="backing acoustic impedance Z_B [Pa s/m]")
    transmit_constant: float = Field(15.8, gt=0, description="piezo e33 [C/m^2]: F = e33 A / t_p V")
    receive_constant: float = Field(24.8e-3, gt=0, description="piezo g33 [V m/N]: V = g33 t_p <F> / A")
    drive: Literal["back_face", "faces"] = Field("faces", description="back_face: F on the transmitter piezo's "
                                                 "back node; faces: +F on its front node and -F on its back node")
    receiver_mount: Literal["rigid", "backing"] = Field("backing", description="rigid: the receiver piezo's back face "
                                                        "on a rigid wall; backing: on a dashpot Z_B A like the "
                                                        "transmitter's (two identical transducers)")

    @model_validator(mode="after")
    def _thin_elements(self):
        for where, layer in [("piezo", self.piezo)] + [(f"plates.{i}", p) for i, p in enumerate(self.plates)]:
            wavelength = layer.sound_speed / self.centre_frequency
            if layer.thickness / layer.n_elements > wavelength / 4:
                raise ValueError(f"{where}.n_elements: elements of {layer.thickness / layer.n_elements:g} m are longer "
                                 f"than a quarter wavelength ({wavelength / 4:g} m at {self.centre_frequency:g} Hz); "
                                 f"raise n_elements")
        return self


@dataclass(frozen=True)
class _Element:
    mass: float  # [kg]
    link: LinkMatrices  # Kelvin-Voigt: k [N/m], b [N s/m]


class MechanicalTransducerPair:
    """Transmitter and receiver as lumped chains around a chain medium (module docstring)."""

    def __init__(self, options: MechanicalTransducerOptions):
        self.options = options
        self.area = np.pi * options.diameter**2 / 4.0

    @property
    def name(self) -> str:
        return self.options.name

    def layer_elements(self, layer: Layer) -> list[_Element]:
        """n elements: m_e = rho A t/n [kg], k_e = rho c^2 A n/t [N/m], b_e = k_e delta/omega_0 [N s/m]."""
        n = layer.n_elements
        m = layer.density * self.area * layer.thickness / n
        k = layer.density * layer.sound_speed**2 * self.area * n / layer.thickness
        b = k * layer.loss_factor / (2 * np.pi * self.options.centre_frequency)
        return [_Element(m, LinkMatrices(k=k, b=b)) for _ in range(n)]

    def transmitter(self) -> list[_Element]:
        """Elements from the backing to the sample face: piezo first, then the plates."""
        out = self.layer_elements(self.options.piezo)
        for p in self.options.plates:
            out += self.layer_elements(p)
        return out

    @property
    def n_piezo(self) -> int:
        return self.options.piezo.n_elements

    @property
    def backing(self) -> float:
        """Backing dashpot b_B = Z_B A [N s/m]."""
        return self.options.backing_impedance * self.area

    @property
    def transmit_gain(self) -> float:
        """e33 A / t_p [N/V]."""
        return self.options.transmit_constant * self.area / self.options.piezo.thickness

    @property
    def receive_gain(self) -> float:
        """g33 t_p / A [V/N]."""
        return self.options.receive_constant * self.options.piezo.thickness / self.area

    def around(self, medium) -> "TransducedChain":
        if not (hasattr(medium, "masses") and hasattr(medium, "_link_matrices")):
            raise ConfigError("backend.options.transducers: kind mechanical needs a chain medium model (masses and "
                              f"links); '{getattr(medium, 'name', type(medium).__name__)}' is not one")
        return TransducedChain(self, medium)

    def alone(self) -> "TransducedChain":
        """The two transducers face to face (no sample between)."""
        return TransducedChain(self, None)

    def response(self, f: np.ndarray) -> np.ndarray:
        """Face-to-face pair V_o / V at frequencies f [Hz] (what a zero-length calibration measures)."""
        A, B, C, D = self.alone().state_space(np.zeros(0))
        eye = np.eye(A.shape[0])
        return np.array([(C @ np.linalg.solve(2j * np.pi * fk * eye - A, B) + D).item() for fk in np.atleast_1d(f)])

    def band(self, level_db: float = -6.0) -> tuple[float, float]:
        """(lowest, highest) frequency [Hz] where the face-to-face |V_o / V| is within ``level_db`` of its peak."""
        f = np.linspace(0, 4 * self.options.centre_frequency, 4001)[1:]
        mag = np.abs(self.response(f))
        keep = np.nonzero(mag >= mag.max() * 10 ** (level_db / 20))[0]
        return float(f[keep[0]]), float(f[keep[-1]])

    def describe(self) -> dict:
        out = {"name": self.name, **self.options.model_dump(exclude={"name"})}
        out["area_m2"] = self.area
        out["transmit_gain_n_per_v"] = self.transmit_gain
        out["receive_gain_v_per_n"] = self.receive_gain
        out["band_6db_hz"] = list(self.band())
        return out


class TransducedChain:
    """backing | transmitter | medium chain | receiver | mount as one model-like object
    (``state_space(theta)`` of the medium's parameters)."""

    def __init__(self, pair: MechanicalTransducerPair, medium):
        self.pair, self.medium = pair, medium

    def state_space(self, theta) -> StateSpace:
        pair = self.pair
        tx = pair.transmitter()
        rx = list(reversed(tx))  # the mirror: sample face first, piezo last
        if self.medium is not None:
            laws = self.medium._link_matrices(np.asarray(theta, dtype=float))
            s_masses = [float(m) for m in self.medium.masses()]
            n = len(s_masses)
            s_normal, s_shear = [None] * n, [None] * n
            for suffix, lm in laws:
                if suffix == "sigma":
                    s_normal = [lm] * n
                else:
                    s_shear = [lm] * n
        else:
            s_masses, s_normal, s_shear = [], [], []
        # Nodes: transmitter back .. (one per transmitter element), sample nodes, receiver face ..
        # (one per receiver element); element masses shared half and half between their two
        # nodes (the receiver's last half element rests on the mount). Without a sample the
        # transmitter's last element ends on the receiver's face node. Normal link j joins node j
        # and j + 1; the last (the receiver piezo's back element) ends on the rigid mount.
        nt = len(tx)
        backed = pair.options.receiver_mount == "backing"
        extra = 1 if backed else 0  # the receiver piezo's back node (on its backing, not on a wall)
        masses = [0.0] * nt + s_masses + [0.0] * (len(rx) + extra)
        for e, el in enumerate(tx):  # element e joins node e and node e + 1
            masses[e] += el.mass / 2
            masses[e + 1] += el.mass / 2
        off = nt + len(s_masses)
        for r, el in enumerate(rx):
            masses[off + r] += el.mass / 2
            if off + r + 1 < len(masses):
                masses[off + r + 1] += el.mass / 2
        normal = [el.link for el in tx] + s_normal + [el.link for el in rx]
        shear = [LinkMatrices(b=pair.backing)] + [None] * (nt - 1) + s_shear + [None] * len(rx)
        if backed:  # the back node rests on the backing dashpot only: no link to the wall
            normal.append(LinkMatrices(k=0.0, b=0.0))
            shear.append(LinkMatrices(b=pair.backing))
        A, B, C, D = assemble_chain(masses, normal, shear, np.zeros(1))
        A = np.asarray(A, dtype=float)
        nn = len(masses)
        # Input: F = e33 A / t_p V on the transmitter's back node, or +F on the piezo's front
        # node and -F on its back node (the piezo's own stress, Mason's 1-D model).
        B = np.zeros((A.shape[0], 1))
        if pair.options.drive == "faces":
            B[nn, 0] = -pair.transmit_gain / masses[0]
            B[nn + pair.n_piezo, 0] = pair.transmit_gain / masses[pair.n_piezo]
        else:
            B[nn, 0] = pair.transmit_gain / masses[0]
        # Output: g33 t_p / A times the mean force over the receiver piezo's element links.
        C = np.zeros((1, A.shape[0]))
        w = pair.receive_gain / pair.n_piezo
        last = nn - extra  # one past the receiver piezo's last element link
        for j in range(last - pair.n_piezo, last):
            lm = normal[j]
            C[0, j] += w * lm.k
            C[0, nn + j] += w * lm.b
            if j + 1 < nn:
                C[0, j + 1] -= w * lm.k
                C[0, nn + j + 1] -= w * lm.b
        return StateSpace(A, B, C, np.zeros((1, 1)))
