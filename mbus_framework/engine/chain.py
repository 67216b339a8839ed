"""Chains of masses assembled from link constitutive laws.

A *link* joins two nodes (two masses, or a mass and the fixed surroundings/receiver) and
transmits a force F that depends on the relative displacement delta = x_a - x_b, its rate
and, for Maxwell-type laws, on internal states q (the link's own hidden deformations):

    F     = k delta + b delta' + sum_j c_j q_j                        (force law)
    q_j'  = sum_l a_jl q_l + e_j delta + f_j delta'                   (internal dynamics)

A :class:`LinkLaw` returns these coefficients (:class:`LinkMatrices`) from its parameter
values with arithmetic only, so every chain built from it evaluates on floats, complex
numbers (complex-step derivatives) and CasADi symbols (collocation) alike.

Built-in laws (each link's spring k [N/m], dashpot b [N s/m]):

* :class:`KelvinVoigtLaw`  spring parallel dashpot: F = k delta + b delta'.
* :class:`MaxwellLaw`      spring in series with dashpot; q = spring elongation e:
  F = k e,  e' = delta' - (k/b) e.  Relaxation time tau = b/k.
* :class:`StandardLinearSolidLaw` (Zener) spring k parallel to a Maxwell arm (k1, b1):
  F = k delta + k1 e1,  e1' = delta' - (k1/b1) e1.
* :class:`GeneralizedMaxwellLaw` (Prony series, K arms): F = k delta + sum_j k_j e_j,
  e_j' = delta' - (k_j/b_j) e_j; relaxation stiffness k(t) = k + sum_j k_j exp(-t/tau_j).

Taking the arm's *spring elongation* (not the dashpot displacement) as the internal state
keeps the force k e free of cancellation when a spring is made very stiff.

:func:`assemble_chain` builds A, B, C, D for n masses m_1..m_n: normal link i joins mass i
and mass i+1, normal link n joins mass n and the receiver (a fixed wall), shear link i ties
mass i to the stationary surroundings. The force u acts on mass 1 and the output is the
force through the last normal link into the receiver. States are
z = [x_1..x_n, x_1'..x_n', q...]; the displacements are left out when no force depends on
them (all links purely Maxwell-type), which removes the rigid-body integrators.
:class:`ChainModel` turns a normal law and a shear law into a complete medium model.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar, Mapping, Sequence

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from mbus_framework.engine.arrays import zeros_like_params
from mbus_framework.interfaces.model import MediumModel, Parameter, Property, StateSpace
from mbus_framework.engine.physics import first_arrival_time

# --------------------------------------------------------------------------------------
# Link laws
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LinkParameter:
    """One coefficient of a link law.

    symbol:        short name, e.g. ``"k"``; the chain parameter is ``symbol_direction``
    unit:          SI unit of the coefficient
    description:   what it is
    time_exponent: value -> value c**e when the dynamics run c times faster (Parameter)
    property_symbol, property_unit: the material property it converts to (``"E"``, ``"Pa"``)
    geometric:     True when property = geometry factor of the direction * value (moduli
                   and viscosities, eqs. 3.32-3.38); False for geometry-free values
                   (relaxation times, exponents) which convert as property = value.
    """

    symbol: str
    unit: str
    description: str
    time_exponent: float
    property_symbol: str
    property_unit: str
    geometric: bool = True
    property_description: str = ""


def stiffness(symbol: str, description: str, property_symbol: str = "E", where: str = "") -> LinkParameter:
    """A spring constant [N/m] converting to an elastic modulus [Pa]."""
    return LinkParameter(symbol, "N/m", description, 2.0, property_symbol, "Pa", True,
                         ("elastic modulus " + where).strip())


def damping(symbol: str, description: str, property_symbol: str = "eta", where: str = "") -> LinkParameter:
    """A dashpot coefficient [N s/m] converting to a viscosity [Pa s]."""
    return LinkParameter(symbol, "N s/m", description, 1.0, property_symbol, "Pa s", True,
                         ("viscosity " + where).strip())


@dataclass
class LinkMatrices:
    """Coefficients of one link (see module docstring); ``None`` marks an absent term.

    k, b: direct stiffness and damping; c[j]: force per internal state j; a[j][l]: internal
    dynamics; e[j], f[j]: how delta and delta' drive internal state j.
    """

    k: Any = None
    b: Any = None
    c: Sequence[Any] = ()
    a: Sequence[Sequence[Any]] = ()
    e: Sequence[Any] | None = None
    f: Sequence[Any] | None = None

    @property
    def n_internal(self) -> int:
        return len(self.c)

    def uses_displacement(self) -> bool:
        return self.k is not None or (self.e is not None and any(v is not None for v in self.e))


class LinkLaw(ABC):
    """A linear viscoelastic constitutive law between two nodes.

    Subclasses set ``name``, ``summary``, ``parameters`` (tuple of :class:`LinkParameter`)
    and implement :meth:`matrices` (arithmetic only) and :meth:`typical`.
    """

    name: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    parameters: tuple[LinkParameter, ...] = ()

    @abstractmethod
    def matrices(self, p: Sequence[Any]) -> LinkMatrices:
        """Link coefficients from parameter values ``p`` (ordered as ``parameters``)."""

    @abstractmethod
    def typical(self, k_ref: float, b_ref: float) -> list[float]:
        """Typical parameter values given a reference stiffness and damping of the link."""

    # -- numeric diagnostics (float parameters only) ------------------------------------
    def impedance(self, p: Sequence[float], s: np.ndarray) -> np.ndarray:
        """Z(s) = F(s)/delta(s) = k + b s + c (sI - a)^-1 (e + f s) [N/m]."""
        m = self.matrices([float(v) for v in p])
        s = np.asarray(s, dtype=complex)
        z = np.zeros_like(s) + (m.k or 0.0) + (m.b or 0.0) * s
        if m.n_internal:
            a = np.array(m.a, dtype=float)
            c = np.array(m.c, dtype=float)
            e = np.array([v or 0.0 for v in (m.e or [0.0] * m.n_internal)], dtype=float)
            f = np.array([v or 0.0 for v in (m.f or [0.0] * m.n_internal)], dtype=float)
            eye = np.eye(m.n_internal)
            for idx, sv in np.ndenumerate(s):
                z[idx] += c @ np.linalg.solve(sv * eye - a, e + f * sv)
        return z

    def instantaneous_stiffness(self, p: Sequence[float]) -> float:
        """High-frequency spring constant k + c.f [N/m] (dashpots act rigid)."""
        m = self.matrices([float(v) for v in p])
        k = float(m.k or 0.0)
        if m.n_internal and m.f is not None:
            k += sum(float(c) * float(f or 0.0) for c, f in zip(m.c, m.f))
        return k

    def relaxation_times(self, p: Sequence[float]) -> dict[str, float]:
        """Relaxation times [s] of the internal states, named ``tau`` or ``tau1, tau2...``."""
        m = self.matrices([float(v) for v in p])
        if not m.n_internal:
            return {}
        lam = np.linalg.eigvals(np.array(m.a, dtype=float))
        taus = sorted(-1.0 / lam.real)
        if len(taus) == 1:
            return {"tau": float(taus[0])}
        return {f"tau{j + 1}": float(t) for j, t in enumerate(taus)}


class KelvinVoigtLaw(LinkLaw):
    """Spring k parallel to dashpot b: F = k delta + b delta' (no internal state)."""

    name = "kelvin_voigt"
    summary = "spring parallel dashpot"
    parameters = (stiffness("k", "spring constant"), damping("b", "dashpot coefficient"))

    def matrices(self, p):
        return LinkMatrices(k=p[0], b=p[1])

    def typical(self, k_ref, b_ref):
        return [k_ref, b_ref]


class MaxwellLaw(LinkLaw):
    """Spring k in series with dashpot b; internal state e = spring elongation [m].

    F = k e,  e' = delta' - (k/b) e.  Relaxation time tau = b/k; F(s) = k b s/(b s + k) delta(s).
    """

    name = "maxwell"
    summary = "spring in series with dashpot"
    parameters = (stiffness("k", "series spring constant"), damping("b", "series dashpot coefficient"))

    def matrices(self, p):
        k, b = p[0], p[1]
        return LinkMatrices(c=[k], a=[[-k / b]], f=[1.0])

    def typical(self, k_ref, b_ref):
        return [k_ref, b_ref]


class GeneralizedMaxwellLaw(LinkLaw):
    """Equilibrium spring k parallel to K Maxwell arms (k_j, b_j) (Prony series).

    F = k delta + sum_j k_j e_j,  e_j' = delta' - (k_j/b_j) e_j,  tau_j = b_j/k_j.
    Relaxation stiffness k(t) = k + sum_j k_j exp(-t/tau_j); unrelaxed k + sum_j k_j.
    """

    name = "generalized_maxwell"
    summary = "spring parallel to K Maxwell arms (Prony series)"

    def __init__(self, n_arms: int = 2):
        if n_arms < 1:
            raise ValueError("a generalized Maxwell link needs at least one arm")
        self.n_arms = int(n_arms)
        arms = []
        for j in range(1, self.n_arms + 1):
            arms.append(stiffness(f"k{j}", f"spring of Maxwell arm {j}", f"E{j}", f"of Maxwell arm {j}"))
            arms.append(damping(f"b{j}", f"dashpot of Maxwell arm {j}", f"eta{j}", f"of Maxwell arm {j}"))
        self.parameters = (stiffness("k", "equilibrium (relaxed) spring constant", "E", "(relaxed)"), *arms)

    def matrices(self, p):
        K = self.n_arms
        ks = [p[1 + 2 * j] for j in range(K)]
        bs = [p[2 + 2 * j] for j in range(K)]
        a = [[(-ks[j] / bs[j]) if j == l else 0.0 for l in range(K)] for j in range(K)]
        return LinkMatrices(k=p[0], c=ks, a=a, f=[1.0] * K)

    def arm_order(self, p: Sequence[float]) -> list[int]:
        """Indices into ``p`` putting the interchangeable arms in order of relaxation time
        (arm 1 fastest). The arms are symmetric: a fit may return them in any order."""
        taus = [float(p[2 + 2 * j]) / float(p[1 + 2 * j]) for j in range(self.n_arms)]
        order = [0]
        for j in sorted(range(self.n_arms), key=lambda j: taus[j]):
            order += [1 + 2 * j, 2 + 2 * j]
        return order

    def typical(self, k_ref, b_ref):
        """Half the stiffness relaxes over K arms with relaxation times a decade apart."""
        K = self.n_arms
        out = [k_ref / 2.0]
        for j in range(K):
            kj = k_ref / (2.0 * K)
            tau = (b_ref / k_ref) * 10.0 ** (j - (K - 1) / 2.0)
            out += [kj, kj * tau]
        return out


class StandardLinearSolidLaw(GeneralizedMaxwellLaw):
    """Zener: spring k parallel to one Maxwell arm (k1, b1) (a one-arm Prony series).

    F = k delta + k1 e1,  e1' = delta' - (k1/b1) e1.  Relaxed stiffness k, unrelaxed
    k + k1, relaxation time tau1 = b1/k1 (at constant strain), retardation time
    b1 (k + k1)/(k k1) (at constant stress).
    """

    name = "sls"
    summary = "spring parallel to a Maxwell arm (Zener)"

    def __init__(self):
        super().__init__(1)

    def typical(self, k_ref, b_ref):
        return [k_ref / 2.0, k_ref / 2.0, b_ref]


def link_law(name: str, n_arms: int = 2) -> LinkLaw:
    """A built-in link law by name: kelvin_voigt, maxwell, sls, generalized_maxwell."""
    if name == "kelvin_voigt":
        return KelvinVoigtLaw()
    if name == "maxwell":
        return MaxwellLaw()
    if name == "sls":
        return StandardLinearSolidLaw()
    if name == "generalized_maxwell":
        return GeneralizedMaxwellLaw(n_arms)
    from mbus_framework.suggest import did_you_mean

    raise ValueError(f"unknown link law '{name}'{did_you_mean(name, LINK_LAW_NAMES)}; choose one of: "
                     + ", ".join(LINK_LAW_NAMES))


LINK_LAW_NAMES = ("kelvin_voigt", "maxwell", "sls", "generalized_maxwell")

# --------------------------------------------------------------------------------------
# Assembly
# --------------------------------------------------------------------------------------


def assemble_chain(
    masses: Sequence[float],
    normal_links: Sequence[LinkMatrices],
    shear_links: Sequence[LinkMatrices | None],
    like,
) -> StateSpace:
    """State-space model of a chain of n masses [kg] (arithmetic only).

    normal_links[i] joins mass i and mass i+1 (i < n-1); normal_links[n-1] joins mass n-1
    and the receiver wall. shear_links[i] (or None) ties mass i to the surroundings.
    ``like`` is any array of the parameter type (float, complex or CasADi object array).

    Equations: M x'' = e_1 u - sum_links g F_link with g the link's incidence vector
    (delta = g.x), internal states as in the module docstring, y = F of normal link n-1.
    """
    n = len(masses)
    if len(normal_links) != n or len(shear_links) != n:
        raise ValueError("need one normal link and one (possibly None) shear link per mass")
    inv_m = 1.0 / np.asarray(masses, dtype=float)
    links: list[tuple[int, int | None, LinkMatrices]] = []
    for i, lm in enumerate(normal_links):
        links.append((i, i + 1 if i < n - 1 else None, lm))
    for i, lm in enumerate(shear_links):
        if lm is not None:
            links.append((i, None, lm))
    need_x = any(lm.uses_displacement() for _, _, lm in links)
    nx = n if need_x else 0
    nq = sum(lm.n_internal for _, _, lm in links)
    ns = nx + n + nq
    A = zeros_like_params((ns, ns), like)
    # Stiffness and damping matrices accumulated link by link (normal links first, then
    # shear), then A[v, x] = -M^-1 K, A[v, v] = -M^-1 B (eq. 3.8).
    K = zeros_like_params((n, n), like) if need_x else None
    Bd = zeros_like_params((n, n), like)
    for i, j, lm in links:
        if lm.k is not None:
            _stamp(K, i, j, lm.k)
        if lm.b is not None:
            _stamp(Bd, i, j, lm.b)
    for i in range(n):
        if need_x:
            A[i, nx + i] = 1.0
            A[nx + i, :n] = -K[i, :] * inv_m[i]
        A[nx + i, nx : nx + n] = -Bd[i, :] * inv_m[i]
    # Internal states.
    off = nx + n
    wall_q = off
    for index, (i, j, lm) in enumerate(links):
        K_int = lm.n_internal
        if index == n - 1:  # the last normal link: into the receiver
            wall_q = off
        for r in range(K_int):
            qr = off + r
            A[nx + i, qr] = A[nx + i, qr] - lm.c[r] * inv_m[i]
            if j is not None:
                A[nx + j, qr] = A[nx + j, qr] + lm.c[r] * inv_m[j]
            for l in range(K_int):
                if not _is_zero(lm.a[r][l]):
                    A[qr, off + l] = lm.a[r][l]
            if lm.e is not None and lm.e[r] is not None:
                A[qr, i] = A[qr, i] + lm.e[r]
                if j is not None:
                    A[qr, j] = A[qr, j] - lm.e[r]
            if lm.f is not None and lm.f[r] is not None:
                A[qr, nx + i] = A[qr, nx + i] + lm.f[r]
                if j is not None:
                    A[qr, nx + j] = A[qr, nx + j] - lm.f[r]
        off += K_int
    B = zeros_like_params((ns, 1), like)
    B[nx, 0] = inv_m[0]
    C = zeros_like_params((1, ns), like)
    wall = normal_links[n - 1]
    if wall.k is not None:
        C[0, n - 1] = wall.k
    if wall.b is not None:
        C[0, nx + n - 1] = wall.b
    for r in range(wall.n_internal):
        C[0, wall_q + r] = wall.c[r]
    D = zeros_like_params((1, 1), like)
    return StateSpace(A, B, C, D)


def _stamp(mat, i: int, j: int | None, value) -> None:
    """Add value * g g^T for delta = x_i - x_j (j None: the other end is fixed)."""
    mat[i, i] = mat[i, i] + value
    if j is not None:
        mat[j, j] = mat[j, j] + value
        mat[i, j] = mat[i, j] - value
        mat[j, i] = mat[j, i] - value


def _is_zero(v) -> bool:
    return isinstance(v, (int, float)) and v == 0.0


def _slots(lm: LinkMatrices) -> list:
    """The coefficients of a link in a fixed order (absent terms left out)."""
    out = [v for v in (lm.k, lm.b) if v is not None] + list(lm.c) + [v for row in lm.a for v in row]
    for vec in (lm.e, lm.f):
        out += [v for v in (vec or ()) if v is not None]
    return out


def _structure(lm: LinkMatrices) -> tuple:
    """Which terms of a link are present (what :func:`assemble_chain` branches on)."""
    present = lambda vec: None if vec is None else tuple(v is not None for v in vec)  # noqa: E731
    return (lm.k is not None, lm.b is not None, lm.n_internal, tuple(len(r) for r in lm.a), present(lm.e), present(lm.f))


def _with_slots(lm: LinkMatrices, values) -> LinkMatrices:
    """A link of the same structure with its coefficients replaced by ``values`` (in
    :func:`_slots` order)."""
    it = iter(values)
    take = lambda v: None if v is None else next(it)  # noqa: E731
    k, b = take(lm.k), take(lm.b)
    c = [next(it) for _ in lm.c]
    a = [[next(it) for _ in row] for row in lm.a]
    e = None if lm.e is None else [take(v) for v in lm.e]
    f = None if lm.f is None else [take(v) for v in lm.f]
    return LinkMatrices(k, b, c, a, e, f)


@dataclass
class CompiledAssembly:
    """:func:`assemble_chain` for numeric coefficients as the linear map it is: every entry
    of A, B, C, D is a constant plus a sum of link coefficients v_s times constants,

        M(v) = M_0 + sum_s v_s M_s,

    with M_0 the assembly at v = 0 and M_s = M(e_s) - M_0 (assembled once per structure).
    Float or complex coefficients (complex-step derivatives) give the same matrices as the
    element-by-element assembly, to round-off."""

    base: np.ndarray  # (size,): A, B, C, D flattened and concatenated at v = 0
    slopes: np.ndarray  # (m, size): M_s flattened likewise
    shapes: tuple[tuple[int, ...], ...]

    @classmethod
    def build(cls, model: "ChainModel", laws: list[tuple[str, LinkMatrices]]) -> "CompiledAssembly":
        counts = [len(_slots(lm)) for _, lm in laws]
        m = sum(counts)

        def assembled(v: np.ndarray) -> list[np.ndarray]:
            parts, start = [], 0
            for (suffix, lm), c in zip(laws, counts):
                parts.append((suffix, _with_slots(lm, [float(x) for x in v[start : start + c]])))
                start += c
            return [np.asarray(x, dtype=float) for x in model._assemble(parts, np.zeros(1))]

        base = assembled(np.zeros(m))
        flat = lambda ms: np.concatenate([x.ravel() for x in ms])  # noqa: E731
        slopes = np.array([flat(assembled(np.eye(m)[s])) - flat(base) for s in range(m)]).reshape(m, -1)
        return cls(flat(base), slopes, tuple(x.shape for x in base))

    def evaluate(self, v: np.ndarray) -> StateSpace:
        """The matrices at coefficients ``v`` (in :func:`_slots` order, links concatenated)."""
        flat = self.base + v @ self.slopes
        out, start = [], 0
        for shape in self.shapes:
            size = shape[0] * shape[1]
            out.append(flat[start : start + size].reshape(shape))
            start += size
        return StateSpace(*out)


def end_half_masses(element_mass: float, n: int) -> np.ndarray:
    """Eq. 3.13: m_1 = m_n = m/2, interior m (n = 1: the single mass is m/2)."""
    m = np.full(n, element_mass)
    m[0] = m[-1] = element_mass / 2.0
    return m


# --------------------------------------------------------------------------------------
# Uniform chain model
# --------------------------------------------------------------------------------------


class ChainOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    n_elements: int = Field(10, ge=1, le=400, description="number of elements n")


@dataclass(frozen=True)
class Direction:
    """A link direction of a chain: the parameter suffix and the direction's link law."""

    suffix: str  # "sigma" (normal) or "tau" (shear)
    law: LinkLaw


class ChainModel(MediumModel):
    """A homogeneous chain (eqs. 3.1-3.21 generalised) from a normal and a shear link law.

    Subclasses set ``Options`` (with ``n_elements``) and override :meth:`normal_law` /
    :meth:`shear_law` (or set the class attributes ``normal`` / ``shear``). Parameters are
    the normal law's coefficients suffixed ``_sigma`` followed by the shear law's suffixed
    ``_tau``. Properties (eqs. 3.32-3.38): normal moduli/viscosities = (L/n)/(pi D^2/4) times
    the coefficient, shear = coefficient / (pi D); geometry-free coefficients pass through.
    """

    Options: ClassVar[type[BaseModel]] = ChainOptions
    normal: ClassVar[LinkLaw | None] = None
    shear: ClassVar[LinkLaw | None] = None

    # -- structure --------------------------------------------------------------------
    def normal_law(self) -> LinkLaw:
        return self.normal

    def shear_law(self) -> LinkLaw | None:
        """The class's ``shear`` law, or the one named by an option ``shear_link``."""
        name = getattr(self.options, "shear_link", None)
        if name is None:
            return self.shear
        if name == "same":
            return self.normal_law()
        if name == "none":
            return None
        return link_law(name, int(getattr(self.options, "n_arms", 2)))

    def directions(self) -> list[Direction]:
        out = [Direction("sigma", self.normal_law())]
        if self.shear_law() is not None:
            out.append(Direction("tau", self.shear_law()))
        return out

    @property
    def n(self) -> int:
        return int(self.options.n_elements)

    @property
    def element_length(self) -> float:
        return self.sample.length / self.n

    @property
    def element_mass(self) -> float:
        """m = rho (pi D^2/4) L / n [kg]."""
        return self.sample.mass / self.n

    def masses(self) -> np.ndarray:
        return end_half_masses(self.element_mass, self.n)

    def geometry_factor(self, suffix: str) -> float:
        """Property per coefficient: (L/n)/(pi D^2/4) normal [1/m], 1/(pi D) shear [1/m]."""
        if suffix == "sigma":
            return self.element_length / self.sample.area
        return 1.0 / self.sample.circumference

    def coefficient_to_property(self, suffix: str, value: float) -> float:
        """E = (L/n)/(pi D^2/4) k (eqs. 3.32, 3.36) or E = k/(pi D) (eqs. 3.37, 3.38)."""
        if suffix == "sigma":
            return self.geometry_factor("sigma") * value
        return value / self.sample.circumference

    def property_to_coefficient(self, suffix: str, value: float) -> float:
        """Inverse of :meth:`coefficient_to_property`."""
        if suffix == "sigma":
            return value / self.geometry_factor("sigma")
        return value * self.sample.circumference

    def reference_link(self, suffix: str) -> tuple[float, float]:
        """Reference stiffness/damping: E ~ 2 GPa, eta ~ 1 kPa s per normal element;
        shear stiffness a tenth of that (the Kelvin-Voigt chain's typical values)."""
        k = 2.0e9 * self.sample.area / self.element_length
        b = 1.0e3 * self.sample.area / self.element_length
        return (k, b) if suffix == "sigma" else (k / 10.0, b)

    def _slices(self) -> list[tuple[Direction, slice]]:
        out, start = [], 0
        for d in self.directions():
            out.append((d, slice(start, start + len(d.law.parameters))))
            start += len(d.law.parameters)
        return out

    # -- MediumModel interface ----------------------------------------------------------
    @property
    def parameters(self):
        out = []
        for d in self.directions():
            k_ref, b_ref = self.reference_link(d.suffix)
            typ = d.law.typical(k_ref, b_ref)
            where = "between masses" if d.suffix == "sigma" else "to the surroundings"
            kind = "normal" if d.suffix == "sigma" else "shear"
            for lp, t in zip(d.law.parameters, typ):
                out.append(
                    Parameter(f"{lp.symbol}_{d.suffix}", lp.unit, f"{kind} {lp.description} {where}",
                              0.0, np.inf, float(t), lp.time_exponent)
                )
        return tuple(out)

    @property
    def properties(self):
        out = []
        for d in self.directions():
            kind = "normal" if d.suffix == "sigma" else "shear"
            for lp in d.law.parameters:
                desc = lp.property_description or f"{lp.property_symbol} from the {lp.description}"
                out.append(Property(f"{lp.property_symbol}_{d.suffix}", lp.property_unit, f"{kind} {desc}"))
        return tuple(out)

    def state_space(self, theta) -> StateSpace:
        laws = self._link_matrices(theta)
        if isinstance(theta, np.ndarray) and theta.dtype.kind in "fc":
            v = np.array([x for _, lm in laws for x in _slots(lm)], dtype=theta.dtype)
            if np.all(np.isfinite(v)):  # non-finite values would spread through 0 * inf
                return self._compiled(laws).evaluate(v)
        return self._assemble(laws, theta)

    def state_matrices_batch(self, thetas) -> np.ndarray:
        """A (N, n, n) of :meth:`state_space` for every row of float ``thetas`` (N, p), the
        same numbers row by row: the link laws evaluated once on parameter columns (N,)
        (arithmetic laws broadcast) and each row's slots v mapped by the compiled assembly
        A(v) = A_0 + v @ A_s (per row, the product :meth:`CompiledAssembly.evaluate` forms).
        Laws that do not broadcast, a single row and non-finite rows: row by row."""
        thetas = np.asarray(thetas, dtype=float)
        if thetas.ndim != 2 or thetas.shape[0] <= 1:  # nothing to batch
            return np.array([np.asarray(self.state_space(th).A, float) for th in thetas.reshape(-1, thetas.shape[-1])])
        try:  # a law branching on values or calling float() raises on columns: row by row
            with np.errstate(all="ignore"):
                laws = self._link_matrices(list(thetas.T))
                slots = [x for _, lm in laws for x in _slots(lm)]
                V = np.empty((thetas.shape[0], len(slots)))
                for j, x in enumerate(slots):
                    V[:, j] = x
        except (TypeError, ValueError):
            return np.array([np.asarray(self.state_space(th).A, float) for th in thetas])
        compiled = self._compiled(laws)
        n = compiled.shapes[0][0]
        base, slopes = compiled.base[: n * n], compiled.slopes[:, : n * n]
        out = np.empty((thetas.shape[0], n, n))
        finite = np.all(np.isfinite(V), axis=1)
        for k in range(thetas.shape[0]):
            if finite[k]:
                out[k] = (base + V[k] @ slopes).reshape(n, n)
            else:
                with np.errstate(all="ignore"):
                    out[k] = np.asarray(self.state_space(thetas[k]).A, float)
        return out

    def _link_matrices(self, theta) -> list[tuple[str, LinkMatrices]]:
        return [(d.suffix, d.law.matrices([theta[i] for i in range(sl.start, sl.stop)])) for d, sl in self._slices()]

    def _assemble(self, laws: list[tuple[str, LinkMatrices]], like) -> StateSpace:
        n = self.n
        normal_links, shear_links = [], [None] * n
        for suffix, lm in laws:
            if suffix == "sigma":
                normal_links = [lm] * n
            else:
                shear_links = [lm] * n
        return assemble_chain(self.masses(), normal_links, shear_links, like)

    def _compiled(self, laws: list[tuple[str, LinkMatrices]]) -> "CompiledAssembly":
        """The chain's assembly as a linear map of its link coefficients, built once per
        structure of the link matrices (cached on the model)."""
        key = tuple((suffix, _structure(lm)) for suffix, lm in laws)
        cache = self.__dict__.setdefault("_compiled_assembly", {})
        if key not in cache:
            cache[key] = CompiledAssembly.build(self, laws)
        return cache[key]

    def to_properties(self, theta) -> dict[str, float]:
        theta = [float(v) for v in theta]
        out = {}
        for d, sl in self._slices():
            for lp, v in zip(d.law.parameters, theta[sl]):
                out[f"{lp.property_symbol}_{d.suffix}"] = self.coefficient_to_property(d.suffix, v) if lp.geometric else v
        return out

    def from_properties(self, properties: Mapping[str, float]) -> np.ndarray:
        out = []
        for d in self.directions():
            for lp in d.law.parameters:
                v = float(properties[f"{lp.property_symbol}_{d.suffix}"])
                out.append(self.property_to_coefficient(d.suffix, v) if lp.geometric else v)
        return np.array(out)

    def derived_properties(self, theta) -> dict[str, float]:
        """Relaxation times [s] and unrelaxed (instantaneous) moduli [Pa] per direction."""
        theta = [float(v) for v in theta]
        out = {}
        for d, sl in self._slices():
            vals = theta[sl]
            for name, tau in d.law.relaxation_times(vals).items():
                out[f"{name}_{d.suffix}"] = tau
            if d.law.matrices(vals).n_internal:
                out[f"E0_{d.suffix}"] = self.coefficient_to_property(d.suffix, d.law.instantaneous_stiffness(vals))
        return out

    def canonical_order(self, theta) -> np.ndarray:
        """Permutation idx with theta[idx] in canonical form: interchangeable Maxwell arms
        (generalized Maxwell links) sorted by relaxation time; identity otherwise."""
        theta = np.asarray(theta, dtype=float)
        idx = []
        for d, sl in self._slices():
            local = list(range(sl.start, sl.stop))
            order = d.law.arm_order(theta[sl]) if hasattr(d.law, "arm_order") else range(len(local))
            idx += [local[i] for i in order]
        return np.array(idx, dtype=int)

    def wave_speed(self, theta) -> float:
        """Low-frequency-limit speed of the unrelaxed chain (L/n) sqrt(k_inst/m) [m/s]."""
        (d, sl), *_ = self._slices()
        k_inst = d.law.instantaneous_stiffness([float(v) for v in np.asarray(theta)[sl]])
        return self.element_length * np.sqrt(k_inst / self.element_mass)

    def complex_modulus(self, theta, f) -> np.ndarray:
        """Longitudinal complex modulus the normal links stand for, M(w) = (L/n)/(pi D^2/4) Z(iw)
        [Pa] at frequencies ``f`` [Hz] (Z: a normal link's dynamic stiffness [N/m]); the
        continuum the chain discretises, whose plane wave has k = w sqrt(rho / M)."""
        (d, sl), *_ = self._slices()
        s = 2j * np.pi * np.asarray(f, dtype=float)
        return self.geometry_factor("sigma") * d.law.impedance([float(v) for v in np.asarray(theta)[sl]], s)

    def driving_point_output(self, theta) -> np.ndarray:
        """C_v with C_v z = velocity of mass 1 (for passivity checks: power = u C_v z)."""
        return driving_point_velocity_row(self.state_space(np.asarray(theta, dtype=float)))

    def initial_guess(self, t, u, y) -> np.ndarray:
        """Typical values moved along the time-scaling direction (time_exponent) until the
        chain's unrelaxed wave speed matches L / first-arrival time (Section 3.5.1):
        E_inst = rho v^2. Ratios between coefficients (damping ratios, omega tau) are kept."""
        theta = np.array([p.typical for p in self.parameters], dtype=float)
        t_arr = first_arrival_time(t, u, y)
        if t_arr is None or t_arr <= 0:
            return theta
        c = (self.sample.length / t_arr) / self.wave_speed(theta)
        expo = np.array([p.time_exponent for p in self.parameters])
        return theta * c**expo


def driving_point_velocity_row(ss: StateSpace) -> np.ndarray:
    """Row C_v with C_v z = x_1' (velocity of the driven mass) of an assembled chain.

    :func:`assemble_chain` puts the input on x_1' only (B = e_v1 / m_1), so the non-zero
    entry of B marks the driven velocity. The power the source delivers is u x_1'.
    """
    B = np.asarray(ss.B, dtype=float)
    row = np.zeros((1, B.shape[0]))
    row[0, int(np.flatnonzero(B[:, 0])[0])] = 1.0
    return row
