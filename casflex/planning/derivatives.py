"""The implicit collocation interval of :func:`casflex.planning.plan_move` as calls of one
point function, so that its derivatives can come from that small function's.

At every collocation point the implicit dynamics are one function ``φ`` of the point's
state, joint accelerations and the interval length (:func:`implicit_point_function`);
the interval (:func:`implicit_collocation_function`) adds only linear terms (the
collocation polynomial's derivative, the interval's torque). With
``derivatives="points"`` the planner's Jacobian and Hessian blocks come from ``φ``'s own
(:func:`casflex.planning.assembly.point_split`): a function a ``K``-th of the interval's
size, which compiles to C in seconds where the interval's did not (move 1 of the design
study: 103 MB of C, not compiled in 5 min).
"""

from __future__ import annotations

import os
from collections.abc import Callable

import casadi as ca
import numpy as np

from casflex._validate import number
from casflex.model import FlexibleModel, TableProvider
from casflex.planning.assembly import PointSplit, point_split
from casflex.planning.scenarios import with_provider

__all__ = ["default_derivatives", "point_compiler", "QUICK_FLAGS", "OPTIMISED_FLAGS",
           "implicit_point_function", "implicit_collocation_function",
           "collocation_matrices", "static_lookup"]


def default_derivatives(transcription: str = "collocation", solver: str = "ipopt") -> str:
    """The fastest derivatives of :func:`casflex.planning.plan_move` that ``transcription``
    and ``solver`` take: ``"points"`` with collocation and Ipopt, ``"casadi"`` otherwise.

    What ``casflex plan`` and the design job's ``[planner]`` use when not told
    (``plan_move``'s own default stays ``"casadi"``, which needs no C compiler). On move 1
    of the design study the whole ``casflex plan`` took 84 s with ``"points"`` where
    ``"casadi"`` had not finished in 17 min (``benchmarks/README_planning.md``, session 20).

    Parameters
    ----------
    transcription : str
        :data:`casflex.planning.TRANSCRIPTIONS`.
    solver : str
        :data:`casflex.planning.SOLVERS`.

    Returns
    -------
    str
        One of :data:`casflex.planning.DERIVATIVES`.

    Examples
    --------
    >>> default_derivatives("collocation", "ipopt"), default_derivatives("shooting")
    ('points', 'casadi')
    """
    return "points" if transcription == "collocation" and solver == "ipopt" else "casadi"


#: compiler flags of the point function's quick build (move 1 of the design study: 6 s of
#: ``cc``) and of its optimised build (85 s of ``cc``; the Jacobian and Hessian 3x faster,
#: 124 and 125 against 384 and 326 us per point; ``benchmarks/README_planning.md``,
#: session 21)
QUICK_FLAGS = ("-O0",)
OPTIMISED_FLAGS = ("-Os",)


def point_compiler(derivatives: str, cache_dir: str | os.PathLike | bool | None = None,
                   log: Callable[[str], None] | None = None, *,
                   background: bool | None = None) -> Callable[[list], list] | None:
    """``compile_function`` of :func:`casflex.planning.plan_move` for ``derivatives``.

    For ``"points"``: the point function's Jacobian and Hessian compiled to C and cached
    (:func:`casflex.codegen.compile_cached`). The optimised build (:data:`OPTIMISED_FLAGS`)
    makes every Ipopt iteration cheaper but takes a minute or two of the compiler on a
    large model, the quick one (:data:`QUICK_FLAGS`) seconds; so when the optimised
    library is not in the cache yet, the quick one is used and, with ``background``, the
    optimised one is built by a detached process
    (:func:`casflex.codegen.tiered_compiler`, :func:`casflex.codegen.compile_in_background`).
    Every later NLP that the function
    compiles for — a restart, a continuation's next problem, a later run — takes the
    optimised library once it is there. The returned function's ``builds`` list records
    the flags each call used.

    ``None`` — the functions are evaluated by CasADi's virtual machine — for other
    derivatives, without a cache (``cache_dir=False``) or without a C compiler (then
    ``log`` says so).

    Parameters
    ----------
    derivatives : str
        The plan's derivatives (:data:`casflex.planning.DERIVATIVES`).
    cache_dir : str, pathlib.Path, None or False
        Cache root (``None``: the default cache; ``False``: no cache, nothing compiled).
    log : callable, optional
        ``log(message)``: told when there is no C compiler and when an optimised build
        starts in the background.
    background : bool, optional
        Build the optimised library in the background when it is missing (else: the
        quick build only, until something else puts the optimised one in the cache);
        default: yes unless ``$CASFLEX_BACKGROUND_BUILDS`` is ``"0"``.

    Returns
    -------
    callable or None

    Examples
    --------
    >>> point_compiler("casadi") is None, point_compiler("points", cache_dir=False) is None
    (True, True)
    """
    if derivatives != "points" or cache_dir is False:
        return None
    from casflex.codegen.jit import tiered_compiler

    # cse: the derivatives without the work automatic differentiation repeats (move 1's
    # point Jacobian 74 387 -> 33 067 instructions, 2.5x faster compiled; the same values
    # to the last bit), eliminated only when a library is built: seconds on these graphs
    return tiered_compiler("plan_points", quick_flags=QUICK_FLAGS,
                           optimised_flags=OPTIMISED_FLAGS, cache_dir=cache_dir, log=log,
                           background=background, what="the planner's derivatives",
                           cse=True)


def static_lookup(model: FlexibleModel) -> FlexibleModel:
    """``model`` with its tables read by local B-splines whose coefficients are static
    data (:class:`casflex.model.TableProvider` ``lookup="static"``, what the model's C
    bundle uses).

    The same spline to the rounding of its fit (≈ 1e-14 of the values). Compiled, the
    ``casadi.interpolant`` lookups put the coefficient tables in the C of every
    derivative: the point function's Jacobian and Hessian on move 1 of the design study
    are 93 MB of C with them, 27 MB (12 s of ``cc -O0``) with these. A model without a
    table is returned as it is.

    Parameters
    ----------
    model : casflex.model.FlexibleModel

    Returns
    -------
    casflex.model.FlexibleModel

    Examples
    --------
    >>> from casflex.model import PointwiseProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> static_lookup(model) is model
    True
    """
    p = model.provider
    if isinstance(p, TableProvider) and p.lookup == "interpolant":
        model = with_provider(model, TableProvider(p.table, p.method, lookup="static"))
    return model


def collocation_matrices(degree: int) -> tuple[np.ndarray, np.ndarray]:
    """``C[r, j] = l_r'(τ_j)`` and ``D[r] = l_r(1)`` of the Lagrange basis through 0 and
    the ``degree`` Gauss–Legendre points (interval fractions).

    Parameters
    ----------
    degree : int
        Collocation points per interval.

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        ``C`` (``degree + 1`` square) and ``D`` (``degree + 1``) [1 / interval, 1].

    Examples
    --------
    >>> C, D = collocation_matrices(1)   # the midpoint rule: p' = 2 (x_c - x_0)
    >>> C[:, 1].tolist(), D.tolist()
    ([-2.0, 2.0], [-1.0, 2.0])
    """
    tau_c = np.r_[0.0, ca.collocation_points(degree, "legendre")]
    C = np.zeros((degree + 1, degree + 1))
    D = np.zeros(degree + 1)
    for r in range(degree + 1):
        coeff = np.array([1.0])
        for s in range(degree + 1):
            if s != r:
                coeff = np.convolve(coeff, [1.0, -tau_c[s]]) / (tau_c[r] - tau_c[s])
        D[r] = np.polyval(coeff, 1.0)
        C[r] = np.polyval(np.polyder(coeff), tau_c)
    return C, D


def implicit_point_function(model: FlexibleModel, scenarios: int = 0) -> ca.Function:
    """``φ(w) = [h ẋa; τ]`` at one collocation point, ``w = [xa; q̈; h; s]``.

    ``xa`` is the nominal state ``[q; δ; q̇; δ̇]`` and the modal state ``[δ_k; δ̇_k]`` of
    each of ``scenarios`` frequency-shifted models; ``s`` their frequency factors
    ``1 + r_k``, an input rather than constants, so that the robust problems of a
    continuation (other ``r``, the same function) share one compiled library. The modal
    accelerations come from the model's prescribed-motion form (``prescribed``: ``δ̈``
    from the modal rows of ``M Ẍ + h = [τ; 0]`` given ``q̈``, then ``τ`` from the joint
    rows); a scenario's from the same rows with its stiffness ``s² K`` and damping
    ``s D`` (:func:`casflex.planning.frequency_shifted_model`, where only ``K`` and ``D``
    depend on the frequencies):
    ``δ̈_k = dddelta(q, q̇, q̈, δ_k, δ̇_k) − M_δδ(q, δ_k)⁻¹ ((s² − 1) K δ_k + (s − 1) D δ̇_k)``.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    scenarios : int
        Frequency-shifted scenarios (0: the nominal model alone).

    Returns
    -------
    casadi.Function
        SX; ``w`` of ``nxa + n + 1 + scenarios`` entries [SI units of the states, rad/s²,
        s, -], output ``nxa + n`` entries (``h ẋa`` in state units, ``τ`` in N m).

    Examples
    --------
    >>> from casflex.model import PointwiseProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> phi = implicit_point_function(model)
    >>> phi.size1_in(0), phi.size1_out(0)
    (6, 5)
    >>> implicit_point_function(model, 2).size1_in(0)   # two modal states, two factors
    12
    """
    n, m = model.n, model.m
    nx = 2 * (n + m)
    k_scen = int(number(scenarios, "scenarios", low=0, integer=True))
    if k_scen and not m:
        raise ValueError("implicit_point_function: scenarios need modes")
    nxa = nx + 2 * m * k_scen
    f = model.functions()
    pres = f["prescribed"]
    w = ca.SX.sym("w", nxa + n + 1 + k_scen)
    xj, a, h = w[:nxa], w[nxa:nxa + n], w[nxa + n]
    factors = w[nxa + n + 1:]
    q, d, dq, dd = xj[:n], xj[n:n + m], xj[n + m:2 * n + m], xj[2 * n + m:nx]
    tau, ddd = pres(q, dq, a, d, dd)
    xdot = [dq, dd, a, ddd]
    if k_scen:
        K, D = f["stiffness"](q), f["damping"](q)
    for k in range(k_scen):
        z = xj[nx + 2 * m * k:nx + 2 * m * (k + 1)]
        s = factors[k]
        Mdd = f["mass"](q, z[:m])[n:, n:]
        shift = (s * s - 1.0) * (K @ z[:m]) + (s - 1.0) * (D @ z[m:])
        xdot += [z[m:], f["dddelta"](q, dq, a, z[:m], z[m:]) - ca.solve(Mdd, shift)]
    return ca.Function("implicit_point", [w], [ca.vertcat(h * ca.vertcat(*xdot), tau)])


def implicit_collocation_function(model: FlexibleModel, scenarios: int, degree: int
                                  ) -> tuple[ca.Function, PointSplit]:
    """``G(x, Xc, Ac, τ, h, s) -> (defects, torque_defects, x_end)``: Gauss–Legendre
    collocation of ``degree`` points on one interval of length ``h`` (torque ``τ``
    constant) with implicit dynamics, and its split into calls of
    :func:`implicit_point_function`.

    The state is the polynomial of ``degree`` through ``x`` at 0 and ``Xc`` at the
    collocation points; the joint accelerations ``Ac`` there are variables.
    ``defects = h ẋ(t_j) − p'(t_j)``, ``torque_defects = τ(x_j, q̈_j) − τ`` at the points,
    ``x_end`` the polynomial at the end of the interval. No ``(n + m)`` square system is
    solved symbolically, so the derivatives are a fraction of the explicit form's. ``s``
    holds the frequency factors ``1 + r_k`` of the scenarios (a column of ``scenarios``
    entries, the same for every interval).

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    scenarios : int
        Frequency-shifted scenarios, whose modal rows take the same ``q̈``.
    degree : int
        Collocation points per interval.

    Returns
    -------
    (casadi.Function, casflex.planning.assembly.PointSplit)
        ``G`` (SX) and its split (outputs 0 and 1: the defects).

    Examples
    --------
    >>> from casflex.model import PointwiseProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> G, split = implicit_collocation_function(model, 0, 3)
    >>> G.name_out(), G.name_in()[-1], split.inputs.shape
    (['defects', 'torque', 'xf'], 's', (3, 6))
    """
    n = model.n
    phi = implicit_point_function(model, scenarios)
    nxa = phi.size1_in(0) - n - 1 - scenarios
    C, D = collocation_matrices(degree)
    x = ca.SX.sym("x", nxa)
    Xc = ca.SX.sym("Xc", nxa, degree)
    Ac = ca.SX.sym("Ac", n, degree)
    u = ca.SX.sym("tau", n)
    h = ca.SX.sym("h")
    factors = ca.SX.sym("s", scenarios)
    Y = ca.SX.sym("Y", nxa + n, degree)  # φ at the points
    P = ca.horzcat(x, Xc)
    defects = ca.horzcat(*[Y[:nxa, j - 1] - P @ C[:, j] for j in range(1, degree + 1)])
    torque = Y[nxa:, :] - ca.repmat(u, 1, degree)
    points = [ca.vertcat(Xc[:, j], Ac[:, j], h, factors) for j in range(degree)]
    G, split = point_split("implicit_collocation", [x, Xc, Ac, u, h, factors], points, phi,
                           Y, [defects, torque, P @ D], [0, 1])
    G = ca.Function(G.name(), G.sx_in(), G.call(G.sx_in()),
                    ["x", "Xc", "Ac", "tau", "h", "s"], ["defects", "torque", "xf"])
    try:
        G = G.expand()
    except RuntimeError:
        pass
    return G, split
