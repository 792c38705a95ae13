"""Models with shifted natural frequencies and the static state of a model at rest.

The robust planner and the verification at a frequency error need the same model with
its stiffness scaled so that every natural frequency is off by a factor ``1 + r``: the
modal stiffness is ``Ω²`` (:class:`casflex.model.FlexibleModel`), so scaling the
provider's ``omega`` by ``1 + r`` scales the stiffness by ``(1 + r)²`` and leaves the
mode shapes, the mass matrix and the kinematics as they are. :mod:`casflex.model` has no
such option, so :class:`ScaledFrequencyProvider` wraps the model's provider here.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from casflex._validate import number
from casflex.model import FlexibleModel

__all__ = ["ScaledFrequencyProvider", "frequency_shifted_model", "modal_guess",
           "collocated_modal_guess", "static_deflection", "tip_jacobian", "with_provider"]


class ScaledFrequencyProvider:
    """A provider whose natural frequencies are those of ``provider`` times ``factor``.

    Parameters
    ----------
    provider : object
        A provider of :mod:`casflex.model.providers`.
    factor : float
        Frequency factor ``1 + r`` (> 0).

    Examples
    --------
    >>> from casflex.model import PointwiseProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> p = PointwiseProvider(robot, [0.0], count=1)
    >>> s = ScaledFrequencyProvider(p, 1.1)
    >>> round(float(s.function("omega")([])) / float(p.function("omega")([])), 12)
    1.1
    """

    def __init__(self, provider: Any, factor: float) -> None:
        self.provider = provider
        self.factor = number(factor, "factor", low=0.0, low_open=True)
        self.shape_joints = tuple(provider.shape_joints)
        if not hasattr(provider, "evaluate"):
            # the model asks getattr(provider, "evaluate", None): no batched evaluation
            self.evaluate = None

    # the frequency-like quantities and their power of the frequency: ω, and in a rotated
    # (smooth) basis the full modal stiffness K̃ and its root Ω̃ = sqrtm(K̃)
    _powers = {"omega": 1, "stiffness": 2, "stiffness_root": 1}

    def __getattr__(self, name: str) -> Any:
        # zero_entries, names, ...: as the wrapped provider has them (evaluate is below)
        if name in ("provider", "factor", "shape_joints"):
            raise AttributeError(name)
        return getattr(self.provider, name)

    def function(self, name: str) -> ca.Function:
        """The wrapped provider's function ``name``; ``omega`` (and ``stiffness_root``) scaled by
        ``factor``, ``stiffness`` by ``factor²``.

        Parameters
        ----------
        name : str
            A quantity of :func:`casflex.modal.integrals.configuration_quantities`.

        Examples
        --------
        >>> from casflex.model import PointwiseProvider
        >>> from casflex.robot import load
        >>> p = PointwiseProvider(load("problems/onelink.toml"), [0.0], count=1)
        >>> ScaledFrequencyProvider(p, 2.0).function("omega").name()
        'omega_scaled'
        """
        f = self.provider.function(name)
        if name not in self._powers:
            return f
        args = [ca.SX.sym(f"x{i}", f.sparsity_in(i)) for i in range(f.n_in())]
        return ca.Function(f"{name}_scaled", args,
                           [self.factor ** self._powers[name] * f(*args)])

    def evaluate(self, q_shape: ca.SX, names: Sequence[str] | None = None
                 ) -> dict[str, ca.SX]:
        """The quantities at ``q_shape`` (the wrapped provider's), ``omega`` scaled.

        Parameters
        ----------
        q_shape : casadi.SX
            The shape joints [rad].
        names : sequence of str, optional
            The quantities wanted (default all; as the wrapped provider's ``evaluate``).

        Examples
        --------
        >>> from casflex.model import build_model
        >>> from casflex.robot import load
        >>> model, _ = build_model(load("problems/arm2link.toml"), n_modes=1,
        ...                        grid=[np.radians([0, 10, 20, 30])], cache_dir=False,
        ...                        processes=1)
        >>> v = ScaledFrequencyProvider(model.provider, 1.5).evaluate(ca.DM([0.0]))
        >>> round(float(ca.evalf(v["omega"])), 3)
        12.461
        """
        values = dict(self.provider.evaluate(q_shape) if names is None
                      else self.provider.evaluate(q_shape, names))
        for name, power in self._powers.items():
            if name in values:
                values[name] = self.factor ** power * values[name]
        return values


def frequency_shifted_model(model: FlexibleModel, error: float) -> FlexibleModel:
    """``model`` with every natural frequency multiplied by ``1 + error``.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    error : float
        Relative frequency error ``r`` (> -1): the stiffness is scaled by ``(1 + r)²``.

    Returns
    -------
    casflex.model.FlexibleModel
        Same robot, gravity, damping ratio, ``delta_order`` and ``modal_mass``; ``model``
        itself for ``error == 0``.

    Examples
    --------
    >>> from casflex.model import PointwiseProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> K = frequency_shifted_model(model, -0.1).functions()["stiffness"]([0.0])
    >>> round(float(K) / float(model.functions()["stiffness"]([0.0])), 12)
    0.81
    """
    error = number(error, "frequency error", low=-1.0, low_open=True)
    if error == 0.0:
        return model
    return with_provider(model, ScaledFrequencyProvider(model.provider, 1.0 + error))


def with_provider(model: FlexibleModel, provider: Any) -> FlexibleModel:
    """``model`` with its modal quantities from ``provider`` (same robot and options).

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    provider : object
        A provider of :mod:`casflex.model.providers` (or a wrapper of one).

    Returns
    -------
    casflex.model.FlexibleModel
        Same robot, gravity, damping ratio, ``delta_order``, ``modal_mass``,
        ``shape_rates``, ``foreshortening`` and ``kinematics``.

    Examples
    --------
    >>> from casflex.model import PointwiseProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> with_provider(model, model.provider).delta_order == model.delta_order
    True
    """
    return FlexibleModel(model.robot, provider, gravity=model.gravity,
                         damping_ratio=model.damping_ratio, delta_order=model.delta_order,
                         modal_mass=model.modal_mass, shape_rates=model.shape_rates,
                         foreshortening=model.foreshortening, kinematics=model.kinematics)


def static_deflection(model: FlexibleModel, q: ArrayLike) -> np.ndarray:
    """Modal amplitudes of the arm at rest at ``q``: ``Ω² δ + g_δ(q, δ) = 0``.

    Zero without gravity. With gravity the modal rows of the potential forces are affine
    in δ (``delta_order`` 0 or 1), so one Newton step from δ = 0 solves them exactly; a
    second step checks it.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    q : array_like, shape (n,)
        Joint values [rad].

    Returns
    -------
    numpy.ndarray, shape (m,)
        δ [√kg m].

    Examples
    --------
    >>> from casflex.model import PointwiseProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> static_deflection(model, [0.3]).tolist()
    [0.0]
    """
    n, m = model.n, model.m
    q = np.asarray(q, dtype=float).ravel()
    d = np.zeros(m)
    if not m or not np.any(model.gravity):
        return d
    G = model.functions()["potential_forces"]
    dsym = ca.SX.sym("d", m)
    r = G(q, dsym)[n:]
    jac = ca.Function("jac", [dsym], [r, ca.jacobian(r, dsym)])
    for _ in range(2):
        res, J = jac(d)
        d = d - np.linalg.solve(J.full(), res.full().ravel())
    return d


def tip_jacobian(model: FlexibleModel, q: ArrayLike) -> np.ndarray:
    """Tip displacement per unit modal amplitude at ``q``: ``∂tip/∂δ`` at δ = 0.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    q : array_like, shape (n,)
        Joint values [rad].

    Returns
    -------
    numpy.ndarray, shape (3, m)
        [m / (√kg m)].

    Examples
    --------
    >>> from casflex.model import PointwiseProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> tip_jacobian(model, [0.0]).round(3).ravel().tolist()
    [0.0, 6.506, 0.0]
    """
    d = ca.SX.sym("d", model.m)
    tip = model.functions()["tip"](np.asarray(q, dtype=float).ravel(), d)
    J = ca.Function("J", [d], [ca.jacobian(tip, d)])(np.zeros(model.m))
    return np.asarray(J.full(), dtype=float).reshape(3, model.m)


def modal_guess(model: FlexibleModel, reference: Any, T: float, steps: int,
                node_steps: np.ndarray, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Modal states ``[δ, δ̇]`` of ``model`` driven by the joint motion of ``reference``
    from static equilibrium at its start: the initial guess of a scenario's modal rows.

    Each frequency-shifted model of a robust plan gets its own guess this way; a copy of
    the nominal model's modal states would start Ipopt from states that violate the
    shifted model's dynamics by the whole frequency error.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
        The scenario's model (e.g. from :func:`frequency_shifted_model`).
    reference : move-like
        Joint motion with ``duration`` and ``sample`` (a ``Move``, ``ShapedMove`` or
        ``PlannedMove``).
    T : float
        Time simulated [s].
    steps : int
        RK4 steps over ``T`` of the prescribed-motion simulator.
    node_steps : ndarray of int
        Step indices of the nodes.
    times : ndarray
        Further times [s] (collocation points), interpolated linearly between steps.

    Returns
    -------
    nodes : ndarray, shape (len(node_steps), 2 m)
        ``[δ, δ̇]`` [√kg m, √kg m/s] at the nodes.
    points : ndarray, shape (len(times), 2 m)
        The same at ``times``.

    Examples
    --------
    >>> from casflex.model import PointwiseProvider
    >>> from casflex.moves import Move
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> stiff = frequency_shifted_model(model, 0.1)
    >>> move = Move([0.0], [0.5], 0.4, settle=0.0)
    >>> nodes, points = modal_guess(stiff, move, 0.4, 400, np.arange(0, 401, 100),
    ...                             np.array([0.05, 0.15]))
    >>> nodes.shape, points.shape
    ((5, 2), (2, 2))
    """
    from casflex.simulate import simulate_prescribed

    q0 = np.asarray(reference.sample(0.0)[0], dtype=float).ravel()
    run = simulate_prescribed(model, reference, dt=T / steps, t_end=T,
                              delta0=static_deflection(model, q0))
    modal = np.hstack([run.delta, run.ddelta])
    nodes = modal[np.minimum(node_steps, run.t.size - 1)]
    points = np.stack([np.interp(times, run.t, col) for col in modal.T], axis=1) \
        if len(times) else np.zeros((0, modal.shape[1]))
    return nodes, points


def collocated_modal_guess(G: ca.Function, factors: Sequence[float], nodes: np.ndarray,
                           points: np.ndarray, accelerations: np.ndarray,
                           torques: np.ndarray, h: float,
                           guesses: Sequence[tuple[np.ndarray, np.ndarray]]
                           ) -> list[tuple[np.ndarray, np.ndarray]]:
    """The scenarios' modal rows that solve the collocation equations of ``G`` under the
    given nominal rows: the start of a robust problem's scenario rows from a plan.

    The prescribed-motion simulation (:func:`modal_guess`) is the exact motion of a
    shifted model; on a plan's collocation grid (ω h up to 1) it misses the collocation
    equations: on move 1 of the design study by 9 % of a row's scale. Here the scenario
    rows are solved from the collocation equations instead, interval by interval
    (Newton, started at ``guesses``; the initial state kept), so that from a plan (whose
    nominal rows solve their own equations) every defect of the robust problem starts at
    round-off (2e-11 on move 1, in 0.25 s; benchmarks/README_planning.md, session 29).

    Parameters
    ----------
    G : casadi.Function
        The interval function of
        :func:`casflex.planning.derivatives.implicit_collocation_function` with the
        scenarios (inputs ``x, Xc, Ac, tau, h, s``).
    factors : sequence of float
        Frequency factors ``1 + r`` of the scenarios (``G``'s input ``s``).
    nodes : ndarray, shape (N + 1, 2 (n + m))
        The nominal rows at the nodes.
    points : ndarray, shape (N degree, 2 (n + m))
        The nominal rows at the collocation points, interval by interval.
    accelerations : ndarray, shape (N degree, n)
        Joint accelerations at the points [rad/s²].
    torques : ndarray, shape (N, n)
        Torque of each interval [N m].
    h : float
        Interval length [s].
    guesses : sequence of (ndarray, ndarray)
        Per scenario its rows ``[δ, δ̇]`` at the nodes and at the points (as
        :func:`modal_guess` returns them): Newton's start, the first node kept.

    Returns
    -------
    list of (ndarray, ndarray)
        Per scenario its rows at the nodes and at the points.

    Raises
    ------
    RuntimeError
        Newton did not converge on an interval (CasADi's rootfinder).

    Examples
    --------
    A scenario at factor 1 is the nominal model: its rows are the plan's own modal rows.

    >>> from casflex.model import PointwiseProvider
    >>> from casflex.planning import plan_move
    >>> from casflex.planning.derivatives import implicit_collocation_function
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> plan = plan_move(model, [0.0], [1.0], torque_limit=0.1, intervals=20, end=2e-3)
    >>> G, _ = implicit_collocation_function(model, 1, 3)
    >>> k, h = np.repeat(np.arange(20), 3), plan.duration / 20
    >>> x, xdot = (np.asarray(a).T for a in plan.propagator(
    ...     k, np.tile(ca.collocation_points(3, "legendre"), 20) * h))
    >>> start = (np.zeros((21, 2)), np.zeros((60, 2)))
    >>> [(rows_at_nodes, _)] = collocated_modal_guess(
    ...     G, [1.0], plan.node_x, x, xdot[:, 2:3], plan.node_tau, h, [start])
    >>> bool(np.allclose(rows_at_nodes, plan.node_x[:, [1, 3]], rtol=0, atol=1e-9))
    True
    """
    degree, n = G.size2_in(1), G.size1_in(2)
    nominal = nodes.shape[1]
    rows = G.size1_in(0) - nominal
    xs, xn = ca.SX.sym("xs", rows), ca.SX.sym("xn", nominal)
    Xcn, Xcs = ca.SX.sym("Xcn", nominal, degree), ca.SX.sym("Xcs", rows, degree)
    Ac, u, hs = ca.SX.sym("Ac", n, degree), ca.SX.sym("u", n), ca.SX.sym("h")
    defects, _, end = G(ca.vertcat(xn, xs), ca.vertcat(Xcn, Xcs), Ac, u, hs,
                        ca.DM(list(factors)))
    given = ca.vertcat(xs, xn, ca.vec(Xcn), ca.vec(Ac), u, hs)
    # the scenario rows' equations are linear in them but for the small velocity terms:
    # Newton converges in a few steps from the simulated rows
    solve = ca.rootfinder("scenario_points", "newton",
                          ca.Function("defects", [ca.vec(Xcs), given],
                                      [ca.vec(defects[nominal:, :])]),
                          {"abstol": 1e-13, "max_iter": 30})
    step_end = ca.Function("end", [ca.vec(Xcs), given], [end[nominal:]])
    N = torques.shape[0]
    start_nodes = np.hstack([g[0] for g in guesses])
    start_points = np.hstack([g[1] for g in guesses])
    out_nodes, out_points = np.empty((N + 1, rows)), np.empty((N * degree, rows))
    out_nodes[0] = start_nodes[0]
    for k in range(N):
        at = slice(k * degree, (k + 1) * degree)
        given_k = np.concatenate([out_nodes[k], nodes[k], points[at].ravel(),
                                  accelerations[at].ravel(), torques[k], [h]])
        z = solve(start_points[at].ravel(), given_k)
        out_points[at] = np.asarray(z).reshape(degree, rows)
        out_nodes[k + 1] = np.asarray(step_end(z, given_k)).ravel()
    each = rows // len(guesses)
    return [(out_nodes[:, each * i:each * (i + 1)], out_points[:, each * i:each * (i + 1)])
            for i in range(len(guesses))]
