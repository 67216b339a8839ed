"""Mechanical virtual transducer pair (``transducers.kind: mechanical``): the composite chain
transducer | sample | transducer against an independent second-order assembly simulated with
scipy.signal, the vanishing-transducer limit, the face-to-face pair, and option errors."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import signal as sps

from mbus_framework.engine.simulation import simulate
from mbus_framework.errors import ConfigError
from mbus_framework.interfaces.backend import AcquisitionContext
from mbus_framework.interfaces.plugin_manager import new_plugin_manager
from mbus_framework.interfaces.registry import Registry
from mbus_framework.interfaces.sample import Sample
from mbus_framework.pipeline.config import validate_options
from mbus_plugins.backends.mechanical_transducers import MechanicalTransducerOptions, MechanicalTransducerPair
from mbus_plugins.excitations.prbs import Prbs, PrbsOptions
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions

SAMPLE = Sample(0.03, 0.0254, 1080.0)
PROPS = {"E_sigma": 2.42e10, "eta_sigma": 7.18e3, "E_tau": 6.56e9, "eta_tau": 5.14e3}
N_SAMPLE = 4
PIEZO = dict(name="pzt", thickness=4.35e-3, density=7750.0, sound_speed=4350.0, loss_factor=0.02, n_elements=3)
PLATE = dict(name="acrylic", thickness=6e-3, density=1190.0, sound_speed=2750.0, loss_factor=0.03, n_elements=5)
Z_B, E33, G33, F0 = 1.0e7, 15.8, 24.8e-3, 0.5e6


@pytest.fixture(scope="module")
def registry() -> Registry:
    return Registry.from_manager(new_plugin_manager())


@pytest.fixture(scope="module")
def waveform():
    return Prbs(PrbsOptions(order=8, bit_width=0.4e-6, sample_rate=25e6, n_samples=2000)).waveform()


def model() -> KelvinVoigtChain:
    return KelvinVoigtChain(SAMPLE, KelvinVoigtOptions(n_elements=N_SAMPLE))


def options(**over) -> dict:
    """A small test pair; back-face drive into a rigid mount unless ``over`` says otherwise (the
    configuration whose limits are simplest to state)."""
    return {"kind": "mechanical", "piezo": PIEZO, "plates": [PLATE], "backing_impedance": Z_B,
            "transmit_constant": E33, "receive_constant": G33, "centre_frequency": F0,
            "drive": "back_face", "receiver_mount": "rigid", **over}


def reference_record(u: np.ndarray, dt: float, drive: str = "back_face", mount: str = "rigid") -> np.ndarray:
    """Independent reference: M x'' + C x' + K x = f written out node by node from the physical
    description (layers, slice, backing, mount), discretised by scipy.signal.cont2discrete (ZOH)
    and run by scipy.signal.dlsim. ``drive``: force on the transmitter piezo's back node, or +F
    on its front node and -F on its back node; ``mount``: the receiver piezo ends on a rigid wall,
    or on a node of its own tied to the casing by the backing dashpot Z_B A."""
    A_face = np.pi * 0.0254**2 / 4
    w0 = 2 * np.pi * F0

    def layer(d):  # (element mass, spring, dashpot) repeated n times
        n = d["n_elements"]
        k = d["density"] * d["sound_speed"] ** 2 * A_face * n / d["thickness"]
        return [(d["density"] * A_face * d["thickness"] / n, k, k * d["loss_factor"] / w0)] * n

    tx = layer(PIEZO) + layer(PLATE)
    rx = tx[::-1]
    n = N_SAMPLE
    m_s = SAMPLE.density * A_face * SAMPLE.length / n  # eq. 3.13: half masses at the ends
    k_s = PROPS["E_sigma"] * A_face * n / SAMPLE.length
    b_s = PROPS["eta_sigma"] * A_face * n / SAMPLE.length
    k_t, b_t = PROPS["E_tau"] * np.pi * 0.0254, PROPS["eta_tau"] * np.pi * 0.0254
    nodes = len(tx) + n + len(rx) + (1 if mount == "backing" else 0)
    mass = np.zeros(nodes)
    springs = []  # (node i, node j or None for the mount, k, b)
    for e, (m, k, b) in enumerate(tx):
        mass[e] += m / 2
        mass[e + 1] += m / 2
        springs.append((e, e + 1, k, b))
    s0 = len(tx)
    for i in range(n):
        mass[s0 + i] += m_s / 2 if i in (0, n - 1) else m_s
        springs.append((s0 + i, s0 + i + 1, k_s, b_s))
    r0 = s0 + n
    for r, (m, k, b) in enumerate(rx):
        mass[r0 + r] += m / 2
        if r0 + r + 1 < nodes:
            mass[r0 + r + 1] += m / 2
        springs.append((r0 + r, r0 + r + 1 if r0 + r + 1 < nodes else None, k, b))
    K, C = np.zeros((nodes, nodes)), np.zeros((nodes, nodes))
    for i, j, k, b in springs:
        for mat, v in ((K, k), (C, b)):
            mat[i, i] += v
            if j is not None:
                mat[j, j] += v
                mat[i, j] -= v
                mat[j, i] -= v
    for i in range(s0, s0 + n):  # the slice's shear links to the surroundings
        K[i, i] += k_t
        C[i, i] += b_t
    C[0, 0] += Z_B * A_face  # the transmitter's backing
    if mount == "backing":
        C[-1, -1] += Z_B * A_face  # the receiver's backing
    Minv = np.diag(1 / mass)
    A = np.block([[np.zeros((nodes, nodes)), np.eye(nodes)], [-Minv @ K, -Minv @ C]])
    B = np.zeros((2 * nodes, 1))
    force = E33 * A_face / PIEZO["thickness"]
    if drive == "faces":
        front = PIEZO["n_elements"]
        B[nodes, 0], B[nodes + front, 0] = -force / mass[0], force / mass[front]
    else:
        B[nodes, 0] = force / mass[0]
    out = np.zeros((1, 2 * nodes))
    piezo = springs[-PIEZO["n_elements"]:]
    for i, j, k, b in piezo:  # V = g33 t / A * mean force in the receiver's piezo
        w = G33 * PIEZO["thickness"] / A_face / len(piezo)
        out[0, i] += w * k
        out[0, nodes + i] += w * b
        if j is not None:
            out[0, j] -= w * k
            out[0, nodes + j] -= w * b
    Ad, Bd, Cd, Dd, _ = sps.cont2discrete((A, B, out, np.zeros((1, 1))), dt, method="zoh")
    _, y, _ = sps.dlsim((Ad, Bd, Cd, Dd, dt), u)
    return y[:, 0]


def acquire(registry, waveform, transducers, noise=0.0):
    cls = registry.get("backend", "simulated").implementation
    opts = {"truth": PROPS, "transducers": transducers, "noise": {"relative_std": noise}}
    backend = cls(validate_options(cls.Options, opts, "backend.options"))
    return backend, backend.acquire(AcquisitionContext(waveform, SAMPLE, model(), registry))


@pytest.mark.parametrize("drive, mount", [("back_face", "rigid"), ("faces", "rigid"), ("back_face", "backing"),
                                          ("faces", "backing")])
def test_composite_record_matches_an_independent_state_space_reference(registry, waveform, drive, mount):
    backend, m = acquire(registry, waveform, options(drive=drive, receiver_mount=mount))
    ref = reference_record(waveform.u, waveform.dt, drive, mount)
    peak = np.max(np.abs(ref))
    assert peak > 1e-3  # a real record, not two zeros agreeing
    np.testing.assert_allclose(m.y, ref, rtol=0, atol=1e-7 * peak)
    assert m.meta["transducers"]["kind"] == "mechanical"
    assert m.meta["true_properties"]["E_sigma"] == pytest.approx(PROPS["E_sigma"])


def test_the_transducers_change_the_record(registry, waveform):
    """The pair is not a pass-through: its masses and springs delay and reshape the slice's record."""
    _, m = acquire(registry, waveform, options())
    gain = E33 * G33  # (e33 A / t)(g33 t / A)
    alone = gain * simulate(model(), model().from_properties(PROPS), waveform.u, waveform.dt)
    assert np.max(np.abs(m.y - alone)) > 0.3 * np.max(np.abs(alone))


@pytest.mark.parametrize("scale, limit", [(1e2, 0.15), (1e3, 0.015), (1e4, 0.0015)])
def test_stiff_light_transducers_give_the_sample_record(registry, waveform, scale, limit):
    """Layers 'scale' times lighter and stiffer (density / scale, sound speed x scale), no
    backing: the record tends to e33 g33 times the slice alone, the error falling as 1/scale."""
    light = lambda d: {**d, "density": d["density"] / scale, "sound_speed": d["sound_speed"] * scale}  # noqa: E731
    _, m = acquire(registry, waveform, options(piezo=light(PIEZO), plates=[light(PLATE)], backing_impedance=1e-6))
    alone = E33 * G33 * simulate(model(), model().from_properties(PROPS), waveform.u, waveform.dt)
    err = np.max(np.abs(m.y - alone)) / np.max(np.abs(alone))
    assert err < limit


def test_face_to_face_response_and_describe():
    pair = MechanicalTransducerPair(MechanicalTransducerOptions(**options()))
    f = np.array([10.0, 2e5, 5e5])
    h = pair.response(f)
    # At low frequency the stack is a rigid rod into the mount: V_o / V -> e33 g33.
    assert abs(h[0]) == pytest.approx(E33 * G33, rel=1e-3)
    d = pair.describe()
    assert d["transmit_gain_n_per_v"] * d["receive_gain_v_per_n"] == pytest.approx(E33 * G33)
    lo, hi = d["band_6db_hz"]
    assert 0 < lo < hi


@pytest.mark.parametrize("drive", ["back_face", "faces"])
def test_a_rigidly_mounted_half_wave_receiver_is_deaf_at_its_centre_frequency(drive):
    """Receiver voltage ~ thickness change u(t_p) - u(0) of the piezo. Clamped at its back and
    driven at its face, u(x) ~ sin(k x): zero change at k t_p = pi, the half-wave frequency
    c / (2 t_p) = 0.5 MHz. On its own backing (an identical transducer) it is not."""
    f = np.linspace(0.02e6, 1.0e6, 99)
    at = np.argmin(np.abs(f - PIEZO["sound_speed"] / (2 * PIEZO["thickness"])))
    for mount, low, high in (("rigid", 0.0, 0.03), ("backing", 0.5, 1.0)):
        o = options(plates=[], piezo={**PIEZO, "n_elements": 10}, drive=drive, receiver_mount=mount)
        h = np.abs(MechanicalTransducerPair(MechanicalTransducerOptions(**o)).response(f))
        assert low <= h[at] / h.max() <= high, (mount, h[at] / h.max())


def test_shipped_uncompensated_pair_has_the_documented_a301s_band():
    """configs/campaigns/potatoes_uncompensated.yaml: two identical backed transducers with a
    water-matched quarter-wave layer, driven by the piezo's own stress: the face-to-face -6 dB band
    lies within the A301S's documented 0.3-0.7 MHz (Sections 3.4.4, 5.4) and spans most of it."""
    import yaml
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "configs/campaigns/potatoes_uncompensated.yaml"
    spec = yaml.safe_load(path.read_text())["campaign"]["run"]["backend"]["options"]["transducers"]
    pair = MechanicalTransducerPair(MechanicalTransducerOptions(**spec))
    lo, hi = pair.band()
    assert 0.27e6 < lo < 0.35e6 and 0.55e6 < hi < 0.75e6
    rigid = MechanicalTransducerPair(MechanicalTransducerOptions(**{**spec, "receiver_mount": "rigid"}))
    assert rigid.band()[1] < 0.3e6  # the same pair on a rigid mount rings below the band


def test_defaults_are_the_documented_rig():
    o = MechanicalTransducerOptions(kind="mechanical")
    assert o.piezo.thickness == pytest.approx(o.piezo.sound_speed / (2 * 0.5e6))  # half-wave at 0.5 MHz
    layer = o.plates[0]  # quarter-wave layer matched between the piezo and water (1.48 MRayl)
    assert layer.thickness == pytest.approx(layer.sound_speed / (4 * 0.5e6))
    z_piezo = o.piezo.density * o.piezo.sound_speed
    assert layer.density * layer.sound_speed == pytest.approx((z_piezo * 1.48e6) ** 0.5, rel=0.01)
    assert o.backing_impedance == pytest.approx(z_piezo, rel=0.01) and o.diameter == pytest.approx(0.0254)
    lo, hi = MechanicalTransducerPair(o).band()  # the A301S's documented 0.3-0.7 MHz (Sections 3.4.4, 5.4)
    assert 0.27e6 < lo < 0.35e6 and 0.55e6 < hi < 0.75e6


@pytest.mark.parametrize(
    "transducers, fragment",
    [
        ({"kind": "mechanical", "piezo": {"thickness": -1.0, "density": 7750, "sound_speed": 4350}},
         "backend.options.transducers: piezo.thickness"),
        ({"kind": "mechanical", "backing": 1e7}, "backend.options.transducers: backing: unknown key"),
        ({"kind": "mechanical", "plates": [{"thickness": 0.05, "density": 1190, "sound_speed": 2750}]},
         "backend.options.transducers: plates.0.n_elements"),
        ({"kind": "mechanical", "backing_impedance": -1}, "backend.options.transducers: backing_impedance"),
        ({"kind": "mechanical", "drive": "both"}, "backend.options.transducers: drive"),
        ({"kind": "mechanical", "receiver_mount": "wall"}, "backend.options.transducers: receiver_mount"),
        ({"kind": "piezo"}, "backend.options.transducers: kind: 'piezo' is not a transducer kind"),
        ({"kind": "filter", "order": 9}, "backend.options.transducers.order"),
        ({"centre_frequncy": 1e6}, "did you mean 'centre_frequency'"),
    ],
)
def test_bad_options_give_one_line_naming_the_key(registry, transducers, fragment):
    cls = registry.get("backend", "simulated").implementation
    with pytest.raises(ConfigError, match=fragment) as info:
        validate_options(cls.Options, {"truth": PROPS, "transducers": transducers}, "backend.options")
    assert "\n" not in str(info.value)


def test_kind_filter_is_the_band_pass_pair(registry):
    cls = registry.get("backend", "simulated").implementation
    a = validate_options(cls.Options, {"truth": PROPS, "transducers": {"kind": "filter"}}, "backend.options")
    b = validate_options(cls.Options, {"truth": PROPS, "transducers": {}}, "backend.options")
    assert a.transducers == b.transducers and type(a.transducers).__name__ == "TransducerPairOptions"


def test_mechanical_pair_rejects_the_plane_wave_medium(registry):
    cls = registry.get("backend", "simulated").implementation
    with pytest.raises(ConfigError, match="kind mechanical needs a chain medium"):
        validate_options(cls.Options, {"wave": {}, "transducers": {"kind": "mechanical"}}, "backend.options")
