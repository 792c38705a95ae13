"""Symbolic rigid–flexible equations of motion of a serial arm (dissertation §3.3).

The model has joint variables ``q`` (n) and mass-normalised modal amplitudes ``δ`` (m),
``X = [q; δ]``, and follows eq. 118:

``M(X) Ẍ + C(X, Ẋ) Ẋ + G(X) + D Ẋ = [τ; 0]``

with ``M = [[M_qq, M_qδ], [M_qδᵀ, M_δδ]]``, ``M_δδ = I`` at δ = 0 (eq. 114), ``C``
from the Christoffel symbols of ``M`` (eq. 106), ``G = ∂V/∂X`` from the gravitational
and elastic potential (eq. 107–109, ``K_δδ = Ω²``) and modal damping
``D = diag(0, 2ζΩ)``. Everything is built with CasADi ``SX``; the configuration-dependent
modal quantities come from a *provider*.

Kinematics (eq. 63–65, Book-style)
----------------------------------
The walk over the DH rows is the one of :mod:`casflex.tmm.chain`, with the elastic
transforms inserted: a flexible row's beam is replaced by its base pose ``T_b`` (the
local beam frame, z along the neutral axis — the role of the dissertation's modified
``A_i``) followed by the end transform ``E_b(δ) = [[I + [ϑ_b(δ)×], L e_z + w_b(δ)],
[0, 1]]`` (:mod:`casflex.modal.integrals`), and a joint spring adds its rotation
``φ(δ)`` to the joint angle. ``A_i(q, δ)`` is the transform of row ``i`` and
``T_i = A_1 ⋯ A_i`` the pose of DH frame ``i`` (at the end of row ``i``, deflections
included). The joint axes of the motors are the DH ``z_i`` axes carried by the
deflected structure.

Kinetic energy and mass matrix (eq. 66–95, 102–105)
---------------------------------------------------
Every piece (flexible link with its tip body, or tip body of a rigid row) has a base pose
``T`` and, in that frame, pseudo-inertia integrals ``C0``, ``C1_j``, ``C2_jk``
(:mod:`casflex.modal.integrals`). With ``Ψ(δ) = C0 + Σ δ_j (C1_j + C1_jᵀ) + Σ δ_j δ_k C2_jk``
and ``D_k(δ) = C1_k + Σ_j δ_j C2_jk`` the kinetic energy ``½ Σ ∫ Tr(Ḟ J Ḟᵀ)`` (eq. 72)
gives, with ``∂_a = ∂/∂X_a``,

``M_ab = Σ Tr(∂_aT Ψ ∂_bTᵀ) + Tr(∂_aT D_b Tᵀ) + Tr(T D_aᵀ ∂_bTᵀ) + Tr(T C2_ab Tᵀ)``

(the ``D`` terms only for modal ``b`` resp. ``a``, the last term for modal ``a`` and
``b``), plus the motor inertias on the diagonal of ``M_qq`` (eq. 67; the rotor turns with
``q̇_i``). This is the dissertation's eq. 90–92 written with Jacobians of the poses (eq.
85–88 are the chain rule of ``T``) and with ``∂T/∂δ`` included, because the base of an
outboard link moves with the deflection of the inboard ones.

The model keeps ``M`` to **first order in δ** (``delta_order=1``, default):
``M(q, δ) ≈ M(q, 0) + Σ δ_j ∂M/∂δ_j(q, 0)``, the terms the Christoffel symbols need
(eq. 106: "although δ is assumed to be negligible, its derivatives ... must be
included"); ``delta_order=0`` gives the dissertation's ``M(q)``. The modal block
(``modal_mass``) is

* ``"first_order"`` (default): ``M_δδ = I + Σ δ_j ∂M_δδ/∂δ_j`` — eq. 114 at δ = 0, plus
  the first-order terms that come from the end transforms of the inboard links. They are
  of the same order as the first-order terms of ``M_qq`` and ``M_qδ``; dropping them
  while keeping those (``"identity"``) can make ``M`` indefinite already at small δ,
  because with locked-joint modes the residual joint inertia
  ``M_qq − M_qδ M_qδᵀ`` is small (3e-4 kg m² against 0.2 kg m² for the Table 8 arm
  without motor inertia, four modes);
* ``"identity"``: ``M_δδ ≡ I``, eq. 118 literally (exact with ``delta_order=0``);
* ``"kinematic"``: the block the kinematics compute, ``M_δδ(q, 0)`` included. At a
  configuration where the tables are exact this is the TMM's modal mass, i.e. the
  identity up to quadrature round-off (the tests use it to check the link-local
  deflections and end transforms); with shapes frozen at another configuration
  (:class:`~casflex.model.providers.ConstantProvider`) it is the only choice that keeps
  ``M`` a true kinetic energy.

The modal quantities must belong to the configuration at which the model is evaluated
(tables over the shape joints): the identity of eq. 114 holds only there.

Potential energy
----------------
``V = −gᵀ Σ T Ψ e_4 + ½ δᵀ Ω(q)² δ`` (eq. 97, 99), the gravitational part kept to the
same order in δ as ``M``. ``G = ∂V/∂X`` gives ``g_q`` (eq. 107), ``g_δ`` (eq. 108) and
``Ω² δ``; its ``q`` rows also contain ``½ δᵀ ∂Ω²/∂q δ`` (second order, omitted in eq.
112), kept so that ``T + V`` is conserved when Ω depends on the configuration.

A full modal stiffness block (a rotated, smooth mode basis)
-----------------------------------------------------------
When the provider offers ``stiffness`` ``K̃(q)`` and ``stiffness_root`` ``Ω̃(q)``
(the smooth basis of :mod:`casflex.modal.subspace`, quantities by
:mod:`casflex.modal.rotated`), the elastic potential is ``½ δᵀK̃δ`` and the damping
``D = 2ζ Ω̃`` with ``Ω̃ = sqrtm(K̃)`` (``full_stiffness`` is then True). This damping is
chosen because it is the modal damping ``2ζ diag(ω)`` of the eigenmodes seen in the
rotated basis (``Ω̃ = R diag(ω) Rᵀ`` when ``K̃ = R diag(ω²) Rᵀ``): the model is the
eigen-basis model under a change of modal coordinates, and it reduces to it exactly when
``K̃`` is diagonal. ``Ω̃`` is tabulated (symmetric square root at each grid point) rather
than formed symbolically, so it is smooth wherever ``K̃`` is. ``omega`` is then the
basis' Rayleigh frequencies ``sqrt(diag K̃)``, not the natural frequencies (the
eigenvalues of ``K̃``).

Provider interface
------------------
An object with ``shape_joints`` (indices into ``q`` of the joints the modal quantities
depend on) and ``function(name) -> casadi.Function`` mapping the vector of those joint
values to the quantity ``name`` of :func:`casflex.modal.integrals.configuration_quantities`,
returned as a column vector holding the array flattened in C (row-major) order
(:mod:`casflex.model.providers`: constant and pointwise quantities, and the B-spline
interpolants of the modal tables). The interpolants are called on SX symbols; the
resulting graph is never built in MX and expanded.

Modes follow the configuration through the tables. By default (``shape_rates=False``)
velocities contain no ``∂w/∂q q̇ δ`` terms (eq. 70), as in the dissertation.

Rates of the mode shapes (``shape_rates=True``)
-----------------------------------------------
The deflection ``Σ δ_j w_j(s; q)`` of a link is a Ritz expansion on a basis that moves
with the shape joints, so the velocity of a point also has the part
``Σ δ_j ∂w_j/∂q q̇``. With the option, ``M`` gets, to the same first order in δ,

* the shape-joint derivatives of the inboard end transforms and joint springs inside
  the pose Jacobians (the base of link 2 moves with ``∂w_1(L)/∂q q̇ δ``): the Jacobians
  differentiate the tabulated ``end_u``, ``end_theta``, ``spring_phi`` as well;
* the link's own part ``Tr(∂_aT (Σ_k δ_k ∂C1_k/∂q) Tᵀ)`` in the shape-joint row and
  column (``∫ L0 J ∂L_kᵀ = ∂C1_k/∂q``, from the tables' B-spline derivatives).

* the link's own mode ``j`` against the rate of its own shapes,
  ``M_δ_j q += Σ_k δ_k ∫ Tr(L_j J ∂L_kᵀ/∂q)`` (the base pose drops out of the trace),
  from the shapes sampled at Gauss points inside each link (``sample_u``,
  ``sample_theta``, :func:`~casflex.modal.integrals.rate_samples`) and their B-spline
  derivatives along the shape joints.

With these, ``M`` is the kinetic energy of the moving shapes to first order in δ (tested
against the energy of the sampled points).

Foreshortening: geometric stiffening (``foreshortening=True``)
--------------------------------------------------------------
The first-order ``M`` has no δ² part in ``½ q̇ᵀ M_qq q̇``, so the δ rows miss every term
linear in δ and quadratic in q̇: the centrifugal softening (the δ² part of Ψ) and the
stiffening of a beam pulled by its own inertia (Kane, Ryan & Banerjee 1987). The
stiffening comes from the beam's shortening as it bends: a section at ``s`` moves back
along the beam by ``½ Σ δ_j δ_k S_jk(s)``, ``S_jk(s) = ∫₀ˢ ϑ_j⊥·ϑ_k⊥`` (the slope of an
Euler–Bernoulli beam's local deflection is ``ϑ × e_z``). With the option

* the section frames are ``L(s; δ) = L0 + Σ δ_j L_j + ½ Σ δ_j δ_k L_jk``,
  ``L_jk = [[0, −S_jk(s) e_z], [0, 0]]``, so Ψ gains ``Σ δ_j δ_k (C2_jk + ½(G_jk +
  G_jkᵀ))`` and ``D_k`` gains ``Σ_j δ_j G_jkᵀ`` with ``G_jk = ∫ L_jk J L0ᵀ`` (two
  entries per pair, ``∫ ρA S_jk`` and ``∫ ρA s S_jk``, and the tip body's share);
* the end transforms are of second order: rotation ``exp[ϑ×]`` to δ², the end pulled in
  by ``½ δᵀ S(L) δ`` (so the outboard links, the tip and the sensor points shorten too);
* ``M_qq`` is kept to **second order** in δ, the rest of ``M`` to first, and the
  gravitational potential to second order (gravity's own geometric stiffness).

The δ rows are then complete to first order in δ for any joint motion (tested against
the Southwell coefficients of a rotating cantilever: ``ω² + 1.193 Ω²`` bending along the
rotation axis, ``ω² + 0.193 Ω²`` in the plane of rotation). ``S_jk`` and ``G_jk`` come
from the shapes sampled inside the links (``sample_theta``, 16 Gauss points) at the
model's configuration; the sections' rotations stay of first order (their inertia is
torsional only) and the second-order terms of the moving shapes themselves
(``½ ∫ ρ |Σ δ ∂w/∂q q̇|²``) are not included. ``M_δδ`` keeps its first-order part from
these kinematics.

Cost and fidelity
-----------------
Both options are off by default: they cost time (``benchmarks/README_fidelity.md``,
measured side by side: ``shape_rates`` 1.34× the instructions of the modal rows,
1.6–2.0× the ``poly`` simulation of move 1, the EKF step unchanged; with
``foreshortening`` as well 1.9× the instructions of the modal rows, 1.3× the EKF
step's instructions, ~4× the ``poly`` simulation of move 1, whose configuration arrays
then carry the δ² coefficients of ``M_qq``) and the dissertation's moves do not need them. On
fast moves with large elbow travel they are what brings the model to an independent
nonlinear beam model (ANCF, ``tests/reference_beam_dynamics.py``): with both, peak,
residual and time history within 1.3 % where the default model is off by up to 25 %.
On Table 9 move 3 (q1 turns by π in 2 s; 239 mm of tip deflection, 17 % of the tip's
radius) against a 3-D geometrically exact beam model (``tests/reference_beam_3d.py``)
neither variant is within 5 % of the peak all along (gap 7.5 % default, 5.4 % with both
and a peak 2.8 % too large); the same move in 4 s is within 3 % with either. What is left
is the kinematics truncated at δ²: statically, across the plane, the model is 2.5 % too
soft at the same 254 mm (``tests/model/test_spatial_static.py``), while a model in the
same five modes whose rods are rebuilt exactly from the modal strains is within 0.07 % of
the reference, and within a 0.14 % gap on move 3 (``tests/exact_ritz.py``,
``tests/model/test_elastica_stiffening.py``); the quartic curvature terms alone close
only a third of it, and the out-of-plane modes' second-order tip terms are short.
``simulate_prescribed(method="poly")`` takes the δ² part of ``M_qq`` as exact arrays of
its own (:func:`casflex.simulate.poly.configuration_function`).

Exact kinematics in strain coordinates (``kinematics="exact"``)
---------------------------------------------------------------
The option that closes Table 9 move 3 (issue 19). The modes, δ, ``K = Ω²`` and the
damping stay; each flexible link is rebuilt from the modes' strains (curvature, twist
rate and axial strain scaled by δ) by a short chain of small rotations through the 16
Gauss points the tables already sample (``sample_u``, ``sample_theta``), and its mass
sits on those points (with the sections' torsional inertia) and on the tip body riding
the exact end frame (:mod:`casflex.model.strain_kinematics`). ``M``, the bias forces
and gravity follow from these point masses exactly in δ; the end transforms, hence the
outboard links and the tip, are exact too. To first order in δ the model is the
default one (``M`` at δ = 0 to 5e-14, the tip Jacobian to 1e-14). The modal block is the
rods' own (``modal_mass`` defaults to ``"kinematic"`` here: 1e-4 from the identity
between the 1.5° grid's points); ``"first_order"`` forces the identity at δ = 0 at about
twice the cost; ``"identity"``, ``delta_order=0`` and ``foreshortening`` are refused (the
rods shorten by themselves). With ``shape_rates=True`` the velocities also
differentiate the tabulated shapes along the shape joints (the complete kinetic
energy of the moving basis).

Fidelity (5 modes, 1.5° table, stored independent references): Table 9 move 3 against
the 3-D geometrically exact beams, peak −0.006 %, residual −0.01 %, gap 0.13 % of the
peak (default kinematics: gap 5.4 % at best); statically across the plane +0.06 % at
254 mm (default +2.5 %); with ``shape_rates`` the planar ANCF moves (move 2, elbow 2 rad
in 1 s and 2 s) within 0.1 % / 0.12 % / 0.31 % (peak / residual / gap, worst of the
three). Without ``shape_rates`` the planar elbow moves still miss (gap up to 38 %): the
shapes' rates matter there, the exact kinematics on Table 9 move 3.

Cost (``benchmarks/README_fidelity.md``): ~8× the SX instructions of the modal rows
(``dddelta`` 0.23 M against 30 k), so the option is off by default. ``method="rk4"``,
``functions()`` and the sensors take it: an accelerometer rides the exact rod
(:func:`~casflex.model.strain_kinematics.rod_point`; its measurement graph is ~55× the
truncated one) and the strain sensors' curvature is linear in δ, exact here. The EKF
plant (``tabulate_plant``) takes it when the joints it expands in Fourier series leave
the modal block ``M_δδ(q, 0)`` unchanged — the exact model's block follows the rods, so
the elbow must be a shape joint (a table) or ``modal_mass="first_order"`` be chosen;
otherwise it refuses with a :class:`~casflex.errors.ModelError`.
``simulate_prescribed(method="poly")`` takes it cut at degree 2 in δ
(:mod:`casflex.simulate.exact_poly`, at any mode count up to its graph budget, 8 modes
measured): the truncation, 0.10 % of the peak on Table 9 move 3, and at 5 modes 2–6× the
CPU of RK4 on the exact rows (moves 3 and 1), so the CLI (``casflex simulate``) and the design job
simulate it by RK4 (``codegen.compile = false``).
C code: :func:`casflex.codegen.exact_forward`, verified on one mode; compiling the
3-mode bundle at ``-O2`` takes ~150 s of CPU (README_fidelity.md).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from casflex.errors import ModelError
from casflex.modal.integrals import (
    QUANTITY_KEYS,
    RATE_KEYS,
    RATE_SAMPLES,
    pseudo_inertia,
    quantity_shapes,
    rate_samples,
    rigid_pseudo_inertias,
)
from casflex.modal.normalize import gauss_legendre
from casflex.model.strain_kinematics import KINEMATICS, point_mass_terms, rod_nodes

if TYPE_CHECKING:
    from casflex.robot import Robot

__all__ = ["FlexibleModel"]


# ------------------------------------------------------------------ symbolic helpers


def _rx(a):
    c, s = ca.cos(a), ca.sin(a)
    return ca.blockcat([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1]])


def _rz(a):
    c, s = ca.cos(a), ca.sin(a)
    return ca.blockcat([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])


def _trans(v):
    T = ca.SX.eye(4)
    T[0, 3], T[1, 3], T[2, 3] = v[0], v[1], v[2]
    return T


def _rot4(R):
    T = np.eye(4)
    T[:3, :3] = R
    return ca.DM(T)


def _skew(v):
    return ca.blockcat([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def _mat4(v, offset):
    """4 × 4 SX from 16 C-order entries of the column vector ``v`` at ``offset``."""
    return ca.reshape(v[offset:offset + 16], 4, 4).T


def _vec(A):
    return ca.reshape(A, -1, 1)


def _taylor(expr, delta, order):
    """Taylor polynomial of ``expr`` in ``delta`` about 0, of degree ``order`` (0, 1 or 2)."""
    base = ca.substitute(expr, delta, ca.SX.zeros(delta.shape))
    if order == 0 or delta.numel() == 0:
        return base
    eps = ca.SX.sym("eps")
    scaled = ca.substitute(expr, delta, eps * delta)
    d1 = ca.jacobian(_vec(scaled), eps)
    out = base + ca.reshape(ca.substitute(d1, eps, 0), expr.shape)
    if order >= 2:
        d2 = ca.jacobian(d1, eps)
        out += 0.5 * ca.reshape(ca.substitute(d2, eps, 0), expr.shape)
    return out


def _zero_mask(provider, name, size):
    """Boolean mask of the entries of quantity ``name`` that are identically zero."""
    report = getattr(provider, "zero_entries", None)
    mask = np.zeros(size, dtype=bool) if report is None else \
        np.asarray(report(name), dtype=bool).ravel()
    if mask.shape != (size,):
        raise ModelError(f"provider.zero_entries({name!r}) has {mask.size} entries; "
                         f"expected {size}")
    return mask


_GRAVITY_DEFAULT = "robot"


class FlexibleModel:
    """Rigid–flexible model of a serial arm built from a robot and a modal provider.

    Parameters
    ----------
    robot : casflex.robot.Robot
    provider : object
        ``shape_joints`` and ``function(name)`` (the provider interface of
        :mod:`casflex.model.providers`).
    gravity : array_like, None or "robot"
        Gravity vector in the base frame [m/s²]; ``"robot"`` (default) takes
        ``robot.gravity``; ``None`` switches gravity off.
    damping_ratio : float, optional
        Modal damping ratio ζ (default ``robot.damping_ratio``).
    delta_order : {1, 0}
        Order in δ kept in ``M`` and in the gravitational potential (module docstring).
    modal_mass : {"first_order", "identity", "kinematic"}, optional
        The modal block of ``M`` (module docstring); default ``"first_order"``
        (``"kinematic"`` with ``kinematics="exact"``).
    shape_rates : bool
        Keep the velocity terms of mode shapes that change with the shape joints
        (module docstring; default off). Needs ``delta_order=1`` and a provider with the
        ``sample_u``/``sample_theta`` quantities (every provider of
        :mod:`casflex.model.providers` built from
        :func:`~casflex.modal.integrals.configuration_quantities`).
    foreshortening : bool
        Keep the beams' shortening and ``M_qq`` to second order in δ: the geometric
        (centrifugal) stiffening of fast moves (module docstring; default off). Needs
        ``delta_order=1`` and the ``sample_theta`` quantity.
    kinematics : {"truncated", "exact"}
        ``"truncated"`` (default): the modal displacements added to the undeformed
        links, to first order in δ (second with ``foreshortening``). ``"exact"``: each
        flexible link rebuilt from the modes' strains, ``M`` and the bias forces exact in
        δ (module docstring; large deflections; ~8× the cost). Needs the
        ``sample_u``/``sample_theta`` quantities; ``modal_mass`` then defaults to
        ``"kinematic"``.

    Attributes
    ----------
    n, m : int
        Number of joints and of modes.
    q, dq, delta, ddelta, tau : casadi.SX
        Symbols: joint variables [rad], rates [rad/s], modal amplitudes [√kg m], their
        rates, joint torques [N m].
    M, C, G, K, D : casadi.SX
        Mass matrix (n+m, n+m), Coriolis matrix (n+m, n+m), generalised potential
        forces ∂V/∂X (n+m,), modal stiffness Ω² (m, m), modal damping 2ζΩ (m, m)
        (``K̃`` and ``2ζ sqrtm(K̃)`` with a full stiffness block).
    full_stiffness : bool
        The provider offers ``stiffness``/``stiffness_root`` (module docstring) and the
        model uses them.
    gravity_forces : casadi.SX
        ∂V_g/∂X (eq. 107–108) alone.
    kinetic, potential : casadi.SX
        Energies [J].
    A, T : list of casadi.SX
        Row transforms A_i(q, δ) and poses T_i(q, δ) of the DH frames (4 × 4).
    bodies : list of dict
        Every inertial piece: ``kind``, ``row``, base pose ``T``.

    Examples
    --------
    >>> from casflex.model import PointwiseProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0.5], count=2),
    ...                       gravity=None)
    >>> f = model.functions()
    >>> M = f["mass"]([0.1, 0.2, 0.5], [0, 0]).full()
    >>> M.shape, bool(np.allclose(M[3:, 3:], np.eye(2)))
    ((5, 5), True)
    >>> f["tip"]([0, 0, 0], [0, 0]).full().ravel().round(6).tolist()
    [1.0, 0.0, -1.0]
    """

    def __init__(self, robot: Robot, provider: Any,
                 gravity: ArrayLike | str | None = _GRAVITY_DEFAULT,
                 damping_ratio: float | None = None, delta_order: int = 1,
                 modal_mass: str | None = None, *, shape_rates: bool = False,
                 foreshortening: bool = False, kinematics: str = "truncated") -> None:
        if delta_order not in (0, 1):
            raise ModelError(f"delta_order must be 0 or 1; got {delta_order!r}")
        self.robot = robot
        self.provider = provider
        n = self.n = robot.n_joints
        shape_joints = tuple(provider.shape_joints)
        for j in shape_joints:
            if not 0 <= j < n:
                raise ModelError(f"provider shape joint {j} out of range: robot "
                                 f"'{robot.name}' has {n} joints")
        m = self.m = int(provider.function("omega").size1_out(0))
        if gravity is None:
            g = np.zeros(3)
        elif isinstance(gravity, str) and gravity == _GRAVITY_DEFAULT:
            g = np.asarray(robot.gravity, dtype=float)
        else:
            g = np.asarray(gravity, dtype=float)
        if g.shape != (3,) or not np.all(np.isfinite(g)):
            raise ModelError(f"gravity must be a finite 3-vector [m/s^2]; got {gravity!r}")
        self.gravity = g
        zeta = robot.damping_ratio if damping_ratio is None else float(damping_ratio)
        if not 0.0 <= zeta < 1.0:
            raise ModelError(f"damping_ratio must lie in [0, 1); got {zeta}")
        self.damping_ratio = zeta
        self.delta_order = delta_order
        if modal_mass is None:  # the exact kinematics' own modal block (module docstring)
            modal_mass = "kinematic" if kinematics == "exact" else "first_order"
        if modal_mass not in ("first_order", "identity", "kinematic"):
            raise ModelError("modal_mass must be 'first_order', 'identity' or 'kinematic'; "
                             f"got {modal_mass!r}")
        self.modal_mass = modal_mass
        self.shape_rates = bool(shape_rates)
        if self.shape_rates and delta_order == 0:
            raise ModelError("shape_rates=True needs delta_order=1: its terms are of first "
                             "order in delta and would all be dropped")
        self.foreshortening = bool(foreshortening)
        if self.foreshortening and delta_order == 0:
            raise ModelError("foreshortening=True needs delta_order=1: it keeps M_qq to "
                             "second order in delta, the rest of M to first")
        if kinematics not in KINEMATICS:
            raise ModelError(f"kinematics must be one of {', '.join(map(repr, KINEMATICS))}; "
                             f"got {kinematics!r}")
        self.kinematics = kinematics
        if kinematics == "exact":
            for bad, why in ((delta_order == 0, "delta_order=0: M is exact in delta"),
                             (self.foreshortening, "foreshortening=True: the exact rods "
                              "shorten as they bend already"),
                             (modal_mass == "identity", "modal_mass='identity': it would "
                              "drop the modal mass the exact kinematics compute")):
                if bad:
                    raise ModelError(f"kinematics='exact' does not go with {why}")
        self._reads_samples = self.shape_rates or self.foreshortening or kinematics == "exact"

        self.q = ca.SX.sym("q", n)
        self.dq = ca.SX.sym("dq", n)
        self.delta = ca.SX.sym("delta", m)
        self.ddelta = ca.SX.sym("ddelta", m)
        self.tau = ca.SX.sym("tau", n)
        self.X = ca.vertcat(self.q, self.delta)
        self.dX = ca.vertcat(self.dq, self.ddelta)
        self.q_shape = ca.vertcat(*[self.q[j] for j in shape_joints]) if shape_joints \
            else ca.SX(0, 1)

        self._quantities(provider)
        self._kinematics()
        self._dynamics()

    # -------------------------------------------------------------- provider data

    def _quantities(self, provider):
        expected = quantity_shapes(self.robot, self.m)
        self.Q = {}
        self._pieces = {}
        placeholders, values = [], []
        # one interpolant call for every tabulated quantity when the provider offers it
        evaluate = getattr(provider, "evaluate", None)
        # (the shapes sampled inside the links only when the model reads them: the spline
        # computes every output it holds)
        self.table_values = None if evaluate is None else evaluate(
            self.q_shape, [k for k in provider.names
                           if self._reads_samples or k not in RATE_KEYS])
        for name in QUANTITY_KEYS + (RATE_KEYS if self._reads_samples else ()):
            f = provider.function(name)
            size = int(np.prod(expected[name]))
            if f.numel_out(0) != size:
                raise ModelError(f"provider quantity {name!r} has {f.numel_out(0)} entries; "
                                 f"expected shape {expected[name]} ({size} entries) for "
                                 f"robot '{self.robot.name}' with {self.m} modes")
            # the kinematics use placeholders: pose Jacobians must not differentiate the
            # tables (eq. 70 has no ∂w/∂q q̇ δ term); the values go in afterwards, so that
            # the Christoffel symbols do see M's dependence on the shape joints
            # entries the provider reports as zero over its whole domain (a planar mode
            # has no out-of-plane displacement, C2 has no translational row, ...) enter as
            # constant zeros: CasADi drops the products they would feed (5 modes, Table 8
            # arm: 80 % of C2, 70 % of C1)
            zero = _zero_mask(provider, name, size)
            symbols = ca.SX.sym(name, size)
            self.Q[name] = ca.vertcat(*[0 if zero[i] else symbols[i] for i in range(size)]) \
                if size else symbols
            keep = np.flatnonzero(~zero)
            placeholders.append(symbols[keep.tolist()] if keep.size else ca.SX(0, 1))
            if not size:
                value = ca.SX(0, 1)
            elif self.table_values is not None and name in self.table_values:
                value = self.table_values[name]
            else:
                value = ca.SX(f(self.q_shape))
            values.append(value[keep.tolist()] if keep.size else ca.SX(0, 1))
            self._pieces[name] = (placeholders[-1], values[-1], value)
            if name == "omega":
                self.omega = value
        self._placeholders = ca.vertcat(*placeholders)
        self._values = ca.vertcat(*values)
        offered = set(getattr(provider, "names", ()))
        self.full_stiffness = "stiffness" in offered
        if self.full_stiffness:
            self._full_stiffness = tuple(self._matrix_quantity(provider, name)
                                         for name in ("stiffness", "stiffness_root"))

    def _matrix_quantity(self, provider, name):
        """The (m, m) quantity ``name`` at the model's shape joints (C-order entries)."""
        m = self.m
        if name not in set(getattr(provider, "names", ())):
            raise ModelError(f"the provider has a 'stiffness' but no {name!r}: the modal "
                             "damping 2ζ·sqrtm(K̃) of a rotated basis needs both")
        f = provider.function(name)
        if f.numel_out(0) != m * m:
            raise ModelError(f"provider quantity {name!r} has {f.numel_out(0)} entries; "
                             f"expected ({m}, {m}) for {m} modes")
        value = (self.table_values[name] if self.table_values is not None
                 and name in self.table_values else ca.SX(f(self.q_shape)))
        return ca.reshape(value, m, m).T

    def _fill(self, expr):
        """Replace the table placeholders by the provider's functions of the shape joints."""
        return ca.substitute(expr, self._placeholders, self._values)

    # -------------------------------------------------------------- kinematics

    def _shortening(self, b, link):
        """Foreshortening of beam ``b``: ``S_jk(L) = ∫₀ᴸ ϑ_j⊥·ϑ_k⊥ ds`` (m × m) and the
        4 × 4 ``G_jk = ∫ L_jk J L0ᵀ`` with ``L_jk = [[0, −S_jk(s) e_z], [0, 0]]``, from the
        shapes sampled at the Gauss points (``sample_theta``; the slope of an
        Euler–Bernoulli beam's local deflection is ``ϑ × e_z``)."""
        m, Q = self.m, self.Q
        L, rA = link.length, link.mass_per_length
        xg, wg = gauss_legendre(RATE_SAMPLES)
        s, w = 0.5 * L * (xg + 1.0), 0.5 * L * wg
        S = RATE_SAMPLES + 1
        th = Q["sample_theta"]
        SL = ca.SX.zeros(m, m)
        I0 = ca.SX.zeros(m, m)  # ∫ ρA S ds
        I1 = ca.SX.zeros(m, m)  # ∫ ρA s S ds
        for p in range(RATE_SAMPLES):
            t = [th[((b * S + p) * m + j) * 3:((b * S + p) * m + j) * 3 + 2] for j in range(m)]
            c = ca.SX.zeros(m, m)
            for j in range(m):
                for k in range(j, m):
                    c[j, k] = c[k, j] = ca.dot(t[j], t[k])
            SL += w[p] * c
            I0 += w[p] * rA * (L - s[p]) * c
            I1 += w[p] * rA * 0.5 * (L**2 - s[p]**2) * c
        tip = None
        if not link.tip.is_empty:
            L0 = np.eye(4)
            L0[2, 3] = L
            tip = (pseudo_inertia(link.tip.mass, link.tip.inertia,
                                  link.tip.com_offset)[3, :] @ L0.T)
        G = [[None] * m for _ in range(m)]
        for j in range(m):
            for k in range(j, m):
                Gjk = ca.SX.zeros(4, 4)
                Gjk[2, 2], Gjk[2, 3] = -I1[j, k], -I0[j, k]
                if tip is not None:
                    Gjk[2, :] += -SL[j, k] * ca.DM(tip).T
                G[j][k] = G[k][j] = Gjk
        return SL, G

    def _beam_end(self, b, L, SL=None):
        """End transform E_b(δ) of beam b in its local frame; with the shortening ``SL``
        (``foreshortening=True``) to second order in δ."""
        m, Q, d = self.m, self.Q, self.delta
        u = ca.SX.zeros(3)
        th = ca.SX.zeros(3)
        for j in range(m):
            k = (b * m + j) * 3
            u += d[j] * Q["end_u"][k:k + 3]
            th += d[j] * Q["end_theta"][k:k + 3]
        E = ca.SX.eye(4)
        E[:3, :3] = ca.SX.eye(3) + _skew(th)
        if SL is not None and m:
            # the rotation to second order (exp[ϑ×]) and the end pulled in by the bending
            E[:3, :3] += 0.5 * _skew(th) @ _skew(th)
            u[2] -= 0.5 * d.T @ SL @ d
        E[0, 3], E[1, 3], E[2, 3] = u[0], u[1], L + u[2]
        return E

    def rebuilt_kinematics(self) -> FlexibleModel:
        """A shallow copy of the model with its own link transforms (``A``, ``T``,
        ``bodies``, ``tip``) rebuilt from its quantities ``Q``, the model itself left as
        it is. The sensor models use it to build kinematics on placeholder quantities
        (:func:`casflex.sensors.kinematic_measurement` with ``lean=True``).

        Examples
        --------
        >>> from casflex.model import PointwiseProvider
        >>> from casflex.robot import load
        >>> robot = load("problems/arm2link.toml")
        >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, -0.5], count=2))
        >>> clone = model.rebuilt_kinematics()
        >>> clone.T is not model.T, clone.T[-1].shape == model.T[-1].shape
        (True, True)
        """
        import copy

        clone = copy.copy(self)
        clone.__dict__.pop("_functions_memo", None)  # built from the original's kinematics
        clone._kinematics()
        return clone

    def _kinematics(self):
        robot, m, Q = self.robot, self.m, self.Q
        pseudo = {row: (kind, J) for kind, row, J in rigid_pseudo_inertias(robot)}
        joint_of_row = {row: k for k, row in enumerate(robot.joint_rows)}
        T_prev = ca.SX.eye(4)
        self.A, self.T, self.bodies = [], [], []
        ib = isp = 0
        for row, link in enumerate(robot.links):
            A = _rx(link.alpha)  # the row's own factors, T_i = T_{i-1} A_i
            if link.beam_along == "a":
                P = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
                P4 = _rot4(P @ _rz_np(link.section_angle))
                A = self._beam(A @ P4, T_prev, row, link, ib, pseudo) @ P4.T
                ib += 1
            elif link.a != 0.0:
                A = A @ _trans([link.a, 0.0, 0.0])
            theta = link.theta
            if row in joint_of_row:
                theta = theta + self.q[joint_of_row[row]]
            if link.joint_stiffness is not None:
                phi = 0
                for j in range(m):
                    phi += self.delta[j] * Q["spring_phi"][isp * m + j]
                theta = theta + phi
                isp += 1
            A = A @ _rz(theta)
            if link.beam_along == "d":
                P4 = _rot4(_rz_np(link.section_angle))
                A = self._beam(A @ P4, T_prev, row, link, ib, pseudo) @ P4.T
                ib += 1
            elif link.d != 0.0:
                A = A @ _trans([0.0, 0.0, link.d])
            T = T_prev @ A
            if not link.flexible and row in pseudo:
                self.bodies.append(self._body("body", row, T, pseudo[row][1], None))
            self.A.append(A)
            self.T.append(T)
            T_prev = T
        self.tip = T[:3, 3]

    def _beam(self, A, T_prev, row, link, b, pseudo):
        """Append the body of beam ``b`` (base pose ``T_prev @ A``) and return ``A`` times
        its end transform (truncated or exact kinematics)."""
        m = self.m
        if self.kinematics == "exact":
            rod = rod_nodes(link, b, self.Q["sample_u"], self.Q["sample_theta"], self.delta)
            body = self._body("beam", row, T_prev @ A, pseudo[row][1], b)
            body["rod"] = rod
            self.bodies.append(body)
            return A @ rod["end"]
        sh = self._shortening(b, link) if self.foreshortening and m else None
        self.bodies.append(self._body("beam", row, T_prev @ A, pseudo[row][1], b, sh))
        return A @ self._beam_end(b, link.length, sh and sh[0])

    def _body(self, kind, row, T, J0, b, shortening=None):
        m, Q = self.m, self.Q
        body = {"kind": kind, "row": row, "T": T, "C0": ca.DM(J0), "beam": b,
                "G": None if shortening is None else shortening[1]}
        if b is not None and m:
            body["C1"] = [_mat4(Q["C1"], (b * m + j) * 16) for j in range(m)]
            body["C2"] = [[_mat4(Q["C2"], ((b * m + j) * m + k) * 16) for k in range(m)]
                          for j in range(m)]
        else:
            body["C1"], body["C2"] = [], []
        return body

    # -------------------------------------------------------------- dynamics

    def _energy_terms(self):
        """Mass matrix and gravitational potential, with the pieces that cannot contribute
        to order ``delta_order`` left out (the caller truncates the rest)."""
        n, m = self.n, self.m
        N = n + m
        X, d = self.X, self.delta
        M = ca.SX.zeros(N, N)
        Vg = ca.SX(0)
        gh = ca.DM(np.r_[self.gravity, 0.0])
        order = self.delta_order
        if self.kinematics == "exact":
            q1 = self.q[0] if n and 0 not in self.provider.shape_joints else None  # _q1_free
            M, self._point_bias, Vg = point_mass_terms(
                self.bodies, X, self.dX, self.gravity, self._fill if self.shape_rates else None, q1)
            for k, row in enumerate(self.robot.joint_rows):
                M[k, k] += self.robot.links[row].motor_inertia
            return M, Vg
        rates = self._shape_rate_terms() if self.shape_rates and m else None
        for body in self.bodies:
            # the pose to one order more than M: ∂T/∂δ must be right to `order`
            T = _taylor(body["T"], d, order + 1)
            C0, C1, C2 = body["C0"], body["C1"], body["C2"]
            Psi = ca.SX(C0)
            D = []
            G = body.get("G")
            for k in range(len(C1)):
                Dk = ca.SX(C1[k])
                if order:
                    Psi += d[k] * (C1[k] + C1[k].T)
                    for j in range(len(C1)):
                        Dk += d[j] * C2[j][k]
                        if G is not None:
                            # the δ² part of Ψ only for M_qq's second order (foreshortening)
                            Psi += d[j] * d[k] * (C2[j][k] + 0.5 * (G[j][k] + G[j][k].T))
                            Dk += d[j] * G[j][k].T
                D.append(Dk)
            # Tr(A Ψ Bᵀ) = Σ_r A[r, :] Ψ B[r, :]ᵀ over the three rows of a pose derivative
            # (the last row of a homogeneous transform is constant)
            for r in range(3):
                Tr_ = T[r, :].T  # 4 x 1
                JT = ca.jacobian(Tr_, X)  # 4 x N
                if rates is not None:
                    # the end transforms of inboard links follow the shape joints
                    Ppose, dPdX = rates["pose"]
                    JT = JT + ca.jacobian(Tr_, Ppose) @ dPdX
                M += JT.T @ Psi @ JT
                if rates is not None and body["beam"] is not None:
                    # the link's own shapes follow the shape joints: ∫ L J ∂L/∂qᵀ
                    # = Σ_k δ_k ∂C1_k/∂q to first order in δ
                    for col, dC1 in rates["dC1"]:
                        E = ca.SX.zeros(4, 4)
                        for k in range(m):
                            E += d[k] * _mat4(dC1, (body["beam"] * m + k) * 16)
                        B = JT.T @ (E @ Tr_)  # N x 1
                        M[:, col] += B
                        M[col, :] += B.T
                if D:
                    B = JT.T @ ca.horzcat(*[Dk @ Tr_ for Dk in D])  # N x m
                    M[:, n:] += B
                    M[n:, :] += B.T
                    for j in range(m):
                        for k in range(m):
                            M[n + j, n + k] += Tr_.T @ C2[j][k] @ Tr_
            if rates is not None and body["beam"] is not None:
                self._add_inside_link_rates(M, body, rates)
            Vg -= gh.T @ T @ Psi[:, 3]
        for k, row in enumerate(self.robot.joint_rows):
            M[k, k] += self.robot.links[row].motor_inertia
        return M, Vg

    def _add_inside_link_rates(self, M, body, rates):
        """``M_δq += Σ_k δ_k ∫ Tr(L_j J ∂L_kᵀ/∂q)``: a link's own mode j against the rate
        of its own shapes. The base pose drops out (``Tr(T A Tᵀ) = tr A[:3, :3]`` for an
        ``A`` with zero last row and column; its δ-dependence is of second order)."""
        n, m, d = self.n, self.m, self.delta
        b = body["beam"]
        s, J = rate_samples(self.robot.links[body["row"]])
        S = s.size
        rows = []  # per sample: the 3 × 4 top block of L_j, flattened by rows (12 × m)
        for p in range(S):
            cols = []
            for j in range(m):
                k = ((b * S + p) * m + j) * 3
                Lj = ca.horzcat(_skew(rates["samples"]["sample_theta"][k:k + 3]),
                                rates["samples"]["sample_u"][k:k + 3])
                cols.append(_vec(Lj.T))
            rows.append(ca.horzcat(*cols))
        for col in rates["shape_cols"]:
            H = ca.SX.zeros(m, m)
            for p in range(S):
                dA = ca.reshape(ca.jacobian(_vec(rows[p]), self.q[col]), 12, m)
                H += rows[p].T @ (ca.DM(np.kron(np.eye(3), J[p])) @ dA)
            B = H @ d  # B_j = Σ_k δ_k H_jk
            M[n:, col] += B
            M[col, n:] += B.T

    def _shape_rate_terms(self):
        """What the ``∂w/∂q q̇ δ`` velocity terms need: the pose placeholders with the
        Jacobian of their values, and ``∂C1/∂q`` per shape joint."""
        ph, vals = [], []
        for name in ("end_u", "end_theta", "spring_phi"):
            p, v, _ = self._pieces[name]
            ph.append(p)
            vals.append(v)
        Ppose, Vpose = ca.vertcat(*ph), ca.vertcat(*vals)
        dC1 = [(j, ca.jacobian(self._pieces["C1"][2], self.q[j]))
               for j in self.provider.shape_joints]
        samples = {}
        for name in ("sample_u", "sample_theta"):
            size = self._pieces[name][2].numel()
            zero = _zero_mask(self.provider, name, size)
            value = self._pieces[name][2]
            samples[name] = ca.vertcat(*[0 if zero[i] else value[i] for i in range(size)])
        return {"pose": (Ppose, ca.jacobian(Vpose, self.X)), "dC1": dC1,
                "samples": samples, "shape_cols": tuple(self.provider.shape_joints)}

    def _dynamics(self):
        n, m = self.n, self.m
        X, dX, d = self.X, self.dX, self.delta
        M, Vg = self._energy_terms()
        M, Vg = self._fill(M), self._fill(Vg)
        self.A = [self._fill(A) for A in self.A]
        self.T = [self._fill(T) for T in self.T]
        self.tip = self._fill(self.tip)
        for body in self.bodies:
            body["T"] = self._fill(body["T"])
        if self.foreshortening:  # (refused with the exact kinematics)
            # the δ rows need T to second order in δ where it multiplies q̇ q̇ only: M_qq
            Mqq = _taylor(M[:n, :n], d, 2)
            M = _taylor(M, d, self.delta_order)
            M[:n, :n] = Mqq
        elif self.kinematics != "exact":  # the exact M is exact in δ
            M = _taylor(M, d, self.delta_order)
        M = 0.5 * (M + M.T)
        self._q1_free = bool(n) and 0 not in self.provider.shape_joints
        if self._q1_free:
            # Joint 1 turns the whole moving structure about an axis fixed in the base (it is
            # not a shape joint: nothing massive or elastic lies inboard of it), and kinetic
            # energy is invariant under that rotation, so M does not depend on q1. Setting
            # q1 = 0 removes its trigonometric terms (they cancel only numerically) and the
            # Christoffel symbols' derivatives with respect to it.
            M = ca.substitute(M, self.q[0], 0)
        if self.modal_mass == "identity":
            M[n:, n:] = ca.SX.eye(m)
        elif self.modal_mass == "first_order":
            self._point_modal_block = M[n:, n:]
            M[n:, n:] = M[n:, n:] - ca.substitute(M[n:, n:], d, ca.SX.zeros(m)) + ca.SX.eye(m)
        if self.kinematics != "exact":
            Vg = _taylor(Vg, d, 2 if self.foreshortening else self.delta_order)
        if self.full_stiffness and m:  # a rotated basis: ½ δᵀK̃δ, D = 2ζ sqrtm(K̃)
            self.K, root = self._full_stiffness
            self.D = 2.0 * self.damping_ratio * root
            Ve = 0.5 * ca.dot(d, self.K @ d)
        else:
            w2 = self.omega**2
            self.K = ca.diag(w2) if m else ca.SX(0, 0)
            self.D = ca.diag(2.0 * self.damping_ratio * self.omega) if m else ca.SX(0, 0)
            Ve = 0.5 * ca.dot(w2, d**2) if m else ca.SX(0)
        self.M = M
        self.gravity_forces = ca.gradient(Vg, X)
        self.potential = Vg + Ve
        self.G = ca.gradient(self.potential, X)
        self.kinetic = 0.5 * dX.T @ M @ dX
        if self.kinematics == "exact":
            Cdx = self._exact_bias(M)
        else:
            # C Ẋ without forming C: d/dt(M Ẋ) at Ẍ = 0 minus ∂T/∂X (the Christoffel sum)
            Cdx = ca.jtimes(M @ dX, X, dX) - ca.gradient(self.kinetic, X)
        damp = ca.vertcat(ca.SX.zeros(n), self.D @ self.ddelta) if m else ca.SX.zeros(n)
        self.h = Cdx + self.G + damp  # everything but M Ẍ and the input
        rhs = ca.vertcat(self.tau, ca.SX.zeros(m)) - self.h
        self.ddX = self._solve(M, rhs)
        # prescribed joint motion: given q̈, solve the δ rows for δ̈, then τ (eq. 118)
        self.ddq = ca.SX.sym("ddq", n)
        h_q, h_d = self.h[:n], self.h[n:]
        Mqq, Mqd, Mdd = M[:n, :n], M[:n, n:], M[n:, n:]
        if m:
            r = -(Mqd.T @ self.ddq) - h_d
            dddelta = r if self.modal_mass == "identity" else ca.solve(Mdd, r)
        else:  # rigid: no modal rows (slicing a 1 × 1 h would give 1 × 0, not 0 × 1)
            dddelta = ca.SX(0, 1)
        self.prescribed_dddelta = dddelta
        self.prescribed_tau = Mqq @ self.ddq + Mqd @ dddelta + h_q

    @property
    def C(self) -> ca.SX:
        """The Coriolis matrix ``C(X, Ẋ)`` from the Christoffel symbols of ``M`` (built on
        first use: the equations of motion use ``C Ẋ`` without forming it)."""
        C = self.__dict__.get("_coriolis")
        if C is None and self.kinematics == "exact":
            # the points' C = Jᵀ W J̇ = ½ ∂(C Ẋ)/∂Ẋ (strain_kinematics.point_mass_terms),
            # plus the Christoffel matrix of the modal block's correction (modal_mass)
            C = self._fill(0.5 * ca.jacobian(self._point_bias, self.dX))
            fixed = self._modal_correction()
            if fixed is not None:
                n, X, dX = self.n, self.X, self.dX
                E = ca.diagcat(ca.SX.zeros(n, n), fixed)
                Edot = ca.reshape(ca.jacobian(_vec(E), X) @ dX, n + self.m, n + self.m)
                Jac = ca.jacobian(E @ dX, X)
                C = C + 0.5 * (Edot + Jac - Jac.T)
            C = self._coriolis = ca.substitute(C, self.q[0], 0) if self._q1_free else C
        if C is None:
            N, M, X, dX = self.n + self.m, self.M, self.X, self.dX
            Mdot = ca.reshape(ca.jacobian(_vec(M), X) @ dX, N, N)
            Jac = ca.jacobian(M @ dX, X)
            C = self._coriolis = 0.5 * (Mdot + Jac - Jac.T)
        return C

    def _modal_correction(self):
        """``I − M_δδ(q, 0)``, the change ``modal_mass="first_order"`` makes to the exact
        kinematics' modal block (None when it makes none)."""
        if self.modal_mass != "first_order" or not self.m:
            return None
        return self.M[self.n:, self.n:] - self._point_modal_block

    def _exact_bias(self, M):
        """``C Ẋ`` of the exact kinematics from the points' kinetic energy (Lagrange's
        ``d/dt ∂T/∂Ẋ − ∂T/∂X`` at ``Ẍ = 0``, no derivative of ``M``), plus that of the
        configuration-dependent correction ``M_δδ(q, 0) → I`` of ``modal_mass``."""
        X, dX, n = self.X, self.dX, self.n
        h = self._fill(self._point_bias)
        fixed = self._modal_correction()
        if fixed is not None:
            p = fixed @ self.ddelta
            h = h + ca.jtimes(ca.vertcat(ca.SX.zeros(n), p), X, dX) \
                - ca.gradient(0.5 * ca.dot(self.ddelta, p), X)
        return h

    def _solve(self, M, rhs):
        n, m = self.n, self.m
        if not (self.modal_mass == "identity" and m):
            return ca.solve(M, rhs)
        Mqq, Mqd = M[:n, :n], M[:n, n:]
        rq, rd = rhs[:n], rhs[n:]
        ddq = ca.solve(Mqq - Mqd @ Mqd.T, rq - Mqd @ rd)
        return ca.vertcat(ddq, rd - Mqd.T @ ddq)

    # -------------------------------------------------------------- functions

    def functions(self) -> dict[str, ca.Function]:
        """The model as named casadi Functions.

        Returns
        -------
        dict of str to casadi.Function
            ``mass (q, delta) -> M``; ``coriolis (q, delta, dq, ddelta) -> C``;
            ``gravity (q, delta) -> g`` (∂V_g/∂X, eq. 107–108); ``potential_forces
            (q, delta) -> G``; ``stiffness (q) -> K``; ``damping (q) -> D``;
            ``forward (q, dq, delta, ddelta, tau) -> (ddq, dddelta)``;
            ``ode (x, tau) -> xdot`` with ``x = [q; delta; dq; ddelta]``;
            ``prescribed (q, dq, ddq, delta, ddelta) -> (tau, dddelta)``;
            ``energy (q, dq, delta, ddelta) -> (kinetic, potential, energy)``;
            ``frames (q, delta) -> (T1, ..., Tn_rows)``; ``tip (q, delta) -> p``;
            ``dddelta (q, dq, ddq, delta, ddelta) -> dddelta`` (the flexible part of
            ``prescribed``); ``ode_w (x, tau, w) -> xdot`` with a generalized force ``w``
            on every coordinate. Built once per model; each call returns a new dict of
            the same Functions.

        Examples
        --------
        >>> from casflex.model import rigid_provider
        >>> from casflex.robot import load
        >>> robot = load("problems/arm2link.toml")
        >>> f = FlexibleModel(robot, rigid_provider(robot), gravity=None).functions()
        >>> f["forward"].name_in()
        ['q', 'dq', 'delta', 'ddelta', 'tau']
        """
        memo = self.__dict__.get("_functions_memo")
        if memo is None:
            memo = self._functions_memo = self._build_functions()
        return dict(memo)

    def _build_functions(self):
        q, dq, d, dd, tau = self.q, self.dq, self.delta, self.ddelta, self.tau
        n = self.n
        x = ca.vertcat(q, d, dq, dd)
        w = ca.SX.sym("w", n + self.m)
        rows = [f"T{i + 1}" for i in range(len(self.T))]
        return {
            "mass": ca.Function("mass", [q, d], [self.M], ["q", "delta"], ["M"]),
            "coriolis": ca.Function("coriolis", [q, d, dq, dd], [self.C],
                                    ["q", "delta", "dq", "ddelta"], ["C"]),
            "gravity": ca.Function("gravity", [q, d], [self.gravity_forces],
                                   ["q", "delta"], ["g"]),
            "potential_forces": ca.Function("potential_forces", [q, d], [self.G],
                                            ["q", "delta"], ["G"]),
            "stiffness": ca.Function("stiffness", [q], [self.K], ["q"], ["K"]),
            "damping": ca.Function("damping", [q], [self.D], ["q"], ["D"]),
            "forward": ca.Function("forward", [q, dq, d, dd, tau],
                                   [self.ddX[:n], self.ddX[n:]],
                                   ["q", "dq", "delta", "ddelta", "tau"],
                                   ["ddq", "dddelta"]),
            "ode": ca.Function("ode", [x, tau], [ca.vertcat(dq, dd, self.ddX)],
                               ["x", "tau"], ["xdot"]),
            "prescribed": ca.Function("prescribed", [q, dq, self.ddq, d, dd],
                                      [self.prescribed_tau, self.prescribed_dddelta],
                                      ["q", "dq", "ddq", "delta", "ddelta"],
                                      ["tau", "dddelta"]),
            "energy": ca.Function("energy", [q, dq, d, dd],
                                  [self.kinetic, self.potential,
                                   self.kinetic + self.potential],
                                  ["q", "dq", "delta", "ddelta"],
                                  ["kinetic", "potential", "energy"]),
            "frames": ca.Function("frames", [q, d], list(self.T), ["q", "delta"], rows),
            "tip": ca.Function("tip", [q, d], [self.tip], ["q", "delta"], ["p"]),
            "dddelta": ca.Function("dddelta", [q, dq, self.ddq, d, dd],
                                   [self.prescribed_dddelta],
                                   ["q", "dq", "ddq", "delta", "ddelta"], ["dddelta"]),
            # a generalized force w on every coordinate (disturbances): M Ẍ + h = [τ; 0] + w
            "ode_w": ca.Function("ode_w", [x, tau, w],
                                 [ca.vertcat(dq, dd, ca.solve(self.M, ca.vertcat(
                                     tau, ca.SX.zeros(self.m)) + w - self.h))],
                                 ["x", "tau", "w"], ["xdot"]),
        }


def _rz_np(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

