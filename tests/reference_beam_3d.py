"""Independent spatial beam dynamics of the Table 8 arm with prescribed joints (Exudyn).

A test oracle for casflex's modal model on moves with q1 (issue 19): the two links are
3-D geometrically exact (Simo–Reissner) beams, ``exudyn.ObjectBeamGeometricallyExact``
(two-node elements interpolated on SE(3), with torsion, shear and axial strain), driven
along prescribed joint angles. It imports nothing from casflex; the arm's geometry, the
section and the material are written here from Table 8 (problems/arm2link.toml).

Model
-----
* Geometry (modified DH, Table 8): joint 1 turns about the vertical ``z0``; the shoulder
  frame is ``Rz(q1) Rx(−90°) Rz(q2)``, link 1 runs 1 m along its ``x``; the elbow frame
  at link 1's end is turned by ``Rz(q3)`` and link 2 runs 1 m along its ``y`` (at q = 0
  the arm is an L: link 1 along ``x0``, link 2 down ``−z0``).
* Sections: 7 mm in the plane of q2 and q3, 5 mm along their axes; aluminium. Beam
  frame (Exudyn): ``x`` along the beam, ``y`` the 7 mm side, ``z`` the 5 mm side (the
  joint axis). Stiffness ``diag(EA, κGA, κGA, GJ, EI_y, EI_z)``, ``κ = 5/6``, St-Venant
  ``J`` of the rectangle (series below); inertia ``ρA`` and ``ρ diag(I_p, I_y, I_z)``
  (the rotary inertia and the shear of bending, absent from an Euler–Bernoulli beam,
  lower the first bending frequencies by 3.9e-5 in the plane and 2.0e-5 along the
  joint axis: Timoshenko's frequency equation, test_spatial_reference.py).
* Prescribed joints: a massive turntable (mass and inertia 1, it does not load the
  beams) turned by ``q1`` about ``z0``; link 1's first node clamped to it with the twist
  ``Rx(−90°)`` and the relative rotation ``q2``; link 2's first node clamped to link 1's
  last node with the relative rotation ``q3`` — generic joints with time-dependent
  offsets (index-3 constraints), the joint motion exact at every step.
* Time integration: Exudyn's implicit generalised-α with spectral radius ``rho_inf``
  (1: no numerical damping).

Tip deflection: the position of link 2's last node minus the rigid tip at the same
joint angles, in the base frame [m].
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: Timoshenko shear coefficient of a rectangle
SHEAR_COEFFICIENT = 5.0 / 6.0


def torsion_constant(long: float, short: float, terms: int = 60) -> float:
    """St-Venant torsion constant of a solid rectangle ``long × short`` [m^4] (series
    solution of the Prandtl stress function, Timoshenko & Goodier §109)."""
    b, c = 0.5 * long, 0.5 * short
    n = np.arange(1, 2 * terms, 2, dtype=float)
    s = np.sum(np.tanh(n * np.pi * b / (2.0 * c)) / n**5)
    return (2.0 * c) ** 3 * (2.0 * b) / 3.0 * (1.0 - 192.0 * c / (np.pi**5 * b) * s)


@dataclass(frozen=True)
class Beam:
    """A uniform rectangular beam: length [m], sides in the joints' plane and along the
    joint axis [m], E, G [Pa], ρ [kg/m³]."""

    length: float = 1.0
    side_in_plane: float = 0.007
    side_along_axis: float = 0.005
    E: float = 69.0e9
    G: float = 26.9e9
    rho: float = 2700.0

    @property
    def area(self) -> float:
        return self.side_in_plane * self.side_along_axis

    @property
    def I_y(self) -> float:
        """About the beam's y (the 7 mm side): resists deflection along the joint axis."""
        return self.side_in_plane * self.side_along_axis**3 / 12.0

    @property
    def I_z(self) -> float:
        """About the beam's z (the joint axis): resists deflection in the joints' plane."""
        return self.side_along_axis * self.side_in_plane**3 / 12.0

    @property
    def J(self) -> float:
        return torsion_constant(max(self.side_in_plane, self.side_along_axis),
                                min(self.side_in_plane, self.side_along_axis))


TABLE8 = Beam()


def bang_bang(a0: float, a1: float, duration: float, t: float) -> float:
    """Angle ``a0 -> a1`` [rad] with bang-bang acceleration over ``duration`` [s]."""
    if t <= 0.0:
        return a0
    if t >= duration:
        return a1
    acc = 4.0 * (a1 - a0) / duration**2
    if t <= 0.5 * duration:
        return a0 + 0.5 * acc * t**2
    return a1 - 0.5 * acc * (duration - t) ** 2


@dataclass(frozen=True)
class JointMove:
    """All three joints from ``q0`` to ``qf`` [rad] with bang-bang acceleration in
    ``duration`` [s]; ``settle`` [s] simulated after it."""

    q0: tuple[float, float, float]
    qf: tuple[float, float, float]
    duration: float
    settle: float = 3.0

    @property
    def t_end(self) -> float:
        return self.duration + self.settle

    def __call__(self, t: float) -> np.ndarray:
        return np.array([bang_bang(a, b, self.duration, t)
                         for a, b in zip(self.q0, self.qf, strict=True)])


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


#: beam frames in the DH frames: link 1 (x2, y2, z2); link 2 (y3, x3, −z3)
BEAM1_IN_DH = np.eye(3)
BEAM2_IN_DH = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def rigid_frames(q: np.ndarray, length1: float = 1.0, length2: float = 1.0):
    """Rigid arm at the joint angles ``q``: shoulder rotation, elbow position and
    rotation, tip position (base frame)."""
    shoulder = _rz(q[0]) @ _rx(-0.5 * np.pi) @ _rz(q[1])
    elbow_p = shoulder @ np.array([length1, 0.0, 0.0])
    elbow = shoulder @ _rz(q[2])
    return shoulder, elbow_p, elbow, elbow_p + elbow @ np.array([0.0, length2, 0.0])


def _section(beam: Beam):
    import exudyn as exu

    section = exu.BeamSection()
    GA = SHEAR_COEFFICIENT * beam.G * beam.area
    section.stiffnessMatrix = np.diag([beam.E * beam.area, GA, GA, beam.G * beam.J,
                                       beam.E * beam.I_y, beam.E * beam.I_z])
    section.inertia = beam.rho * np.diag([beam.I_y + beam.I_z, beam.I_y, beam.I_z])
    section.massPerLength = beam.rho * beam.area
    return section


def _ep(R):
    from exudyn.rigidBodyUtilities import RotationMatrix2EulerParameters

    return list(RotationMatrix2EulerParameters(R))


class SpatialArm:
    """The Table 8 arm as two chains of ``n_elements`` geometrically exact beam elements.

    Parameters
    ----------
    beams : tuple of Beam
        Link 1 and link 2.
    n_elements : int
        Elements per link.
    """

    def __init__(self, beams: tuple[Beam, Beam] = (TABLE8, TABLE8), n_elements: int = 16):
        self.beams, self.n_elements = beams, int(n_elements)

    def _build(self, mbs, q_of_t):
        import exudyn as exu
        from exudyn.itemInterface import (
            GenericJoint,
            MarkerNodeRigid,
            NodePointGround,
            NodeRigidBodyEP,
            ObjectBeamGeometricallyExact,
            ObjectRigidBody,
        )

        q0 = q_of_t(0.0)
        shoulder, elbow_p, elbow, _ = rigid_frames(q0, self.beams[0].length,
                                                   self.beams[1].length)
        ground = mbs.AddMarker(MarkerNodeRigid(nodeNumber=mbs.AddNode(NodePointGround())))
        table_R = _rz(q0[0])
        table = mbs.AddNode(NodeRigidBodyEP(referenceCoordinates=[0.0, 0.0, 0.0]
                                            + _ep(table_R)))
        mbs.AddObject(ObjectRigidBody(mass=1.0, inertia=[1, 1, 1, 0, 0, 0],
                                      nodeNumber=table))

        def offset(index):
            def f(mbs, t, item, params):
                return [0.0, 0.0, 0.0, 0.0, 0.0, float(q_of_t(t)[index])]
            return f

        mbs.AddObject(GenericJoint(
            markerNumbers=[ground, mbs.AddMarker(MarkerNodeRigid(nodeNumber=table))],
            offsetUserFunction=offset(0)))
        chains = []
        for k, (beam, origin, R_dh, in_dh) in enumerate((
                (self.beams[0], np.zeros(3), shoulder, BEAM1_IN_DH),
                (self.beams[1], elbow_p, elbow, BEAM2_IN_DH))):
            R = R_dh @ in_dh
            h = beam.length / self.n_elements
            nodes = [mbs.AddNode(NodeRigidBodyEP(
                referenceCoordinates=list(origin + R[:, 0] * h * i) + _ep(R)))
                for i in range(self.n_elements + 1)]
            section = _section(beam)
            for i in range(self.n_elements):
                mbs.AddObject(ObjectBeamGeometricallyExact(
                    nodeNumbers=[nodes[i], nodes[i + 1]], length=h,
                    sectionData=section))
            chains.append(nodes)
            if k == 0:  # shoulder: the turntable's frame twisted by Rx(−90°), then q2
                parent = mbs.AddMarker(MarkerNodeRigid(
                    nodeNumber=table, localHT=exu.HT(rotation=_rx(-0.5 * np.pi),
                                                     translation=[0.0, 0.0, 0.0])))
            else:  # elbow: link 1's end frame (DH frame 2 moved along x), then q3
                parent = mbs.AddMarker(MarkerNodeRigid(
                    nodeNumber=chains[0][-1], localHT=exu.HT(rotation=BEAM1_IN_DH.T,
                                                            translation=[0.0, 0.0, 0.0])))
            child = mbs.AddMarker(MarkerNodeRigid(
                nodeNumber=nodes[0], localHT=exu.HT(rotation=in_dh.T,
                                                    translation=[0.0, 0.0, 0.0])))
            mbs.AddObject(GenericJoint(markerNumbers=[parent, child],
                                       offsetUserFunction=offset(k + 1)))
        return chains

    def static(self, q: tuple[float, float, float], accel, newton_tol: float = 1e-6
               ) -> dict[str, np.ndarray]:
        """Static deflection at the joint angles ``q`` [rad] under a uniform body-force
        field ``accel`` [m/s², base frame] (gravity-like: ``ρA accel`` per length, as
        consistent nodal forces of the linear elements, half an element's at each end).
        ``{"tip", "elbow"}``: displacements from the rigid arm [m]; ``"elbow_rotation"``:
        rotation vector of link 1's end section from its rigid orientation [rad] (base
        frame). ``newton_tol`` [N]: above the residual's round-off (:func:`cantilever`).
        """
        import exudyn as exu
        from exudyn.itemInterface import LoadForceVector, MarkerNodeRigid
        from exudyn.rigidBodyUtilities import RotationMatrix2RotationVector

        q = tuple(float(x) for x in q)
        SC = exu.SystemContainer()
        mbs = SC.AddSystem()
        chains = self._build(mbs, JointMove(q, q, 1.0))
        accel = np.asarray(accel, dtype=float)
        for chain, beam in zip(chains, self.beams, strict=True):
            h = beam.length / self.n_elements
            for i, node in enumerate(chain):
                share = 0.5 if i in (0, len(chain) - 1) else 1.0
                mbs.AddLoad(LoadForceVector(
                    markerNumber=mbs.AddMarker(MarkerNodeRigid(nodeNumber=node)),
                    loadVector=list(beam.rho * beam.area * h * share * accel)))
        mbs.Assemble()
        s = exu.SimulationSettings()
        s.solution.file.write = False
        s.linearSolver.solverType = exu.LinearSolverType.EigenSparse
        s.staticSolver.newton.absoluteTolerance = newton_tol
        s.staticSolver.numberOfLoadSteps = 10
        s.staticSolver.verboseMode = 0
        mbs.SolveStatic(s)
        shoulder, elbow_p, _, tip = rigid_frames(np.asarray(q), self.beams[0].length,
                                                 self.beams[1].length)

        def position(node):
            return np.asarray(mbs.GetNodeOutput(node, exu.OutputVariableType.Position))

        R = np.reshape(mbs.GetNodeOutput(chains[0][-1], exu.OutputVariableType.RotationMatrix),
                       (3, 3))
        turn = R @ (shoulder @ BEAM1_IN_DH).T
        return {"tip": position(chains[1][-1]) - tip, "elbow": position(chains[0][-1]) - elbow_p,
                "elbow_rotation": np.asarray(RotationMatrix2RotationVector(turn))}

    def simulate(self, move: JointMove, dt: float = 1e-3, rho_inf: float = 1.0,
                 newton_tol: float = 1e-7, t_end: float | None = None
                 ) -> dict[str, np.ndarray]:
        """Run ``move`` to ``t_end`` (default its end); ``{"t", "tip", "tip_rigid", "q"}``
        sampled every ``dt`` [s, m]. ``newton_tol``: the Newton iterations' absolute
        tolerance [N] (the beams' reaction forces are ~1 N; 1e-8 and below is under the
        round-off of the axial forces, EA/h ~ 1e7 N, on 16 elements and more)."""
        import exudyn as exu
        from exudyn.itemInterface import SensorNode

        SC = exu.SystemContainer()
        mbs = SC.AddSystem()
        chains = self._build(mbs, move)
        sensor = mbs.AddSensor(SensorNode(nodeNumber=chains[1][-1], storeInternal=True,
                                          outputVariableType=exu.OutputVariableType.Position))
        mbs.Assemble()
        s = exu.SimulationSettings()
        steps = int(round((move.t_end if t_end is None else t_end) / dt))
        s.timeIntegration.numberOfSteps = steps
        s.timeIntegration.endTime = steps * dt
        s.timeIntegration.generalizedAlpha.spectralRadius = rho_inf
        s.timeIntegration.verboseMode = 0
        s.timeIntegration.newton.absoluteTolerance = newton_tol
        s.solution.file.write = False
        s.solution.sensors.writePeriod = dt
        s.linearSolver.solverType = exu.LinearSolverType.EigenSparse
        mbs.SolveDynamic(s)
        data = mbs.GetSensorStoredData(sensor)
        t = data[:, 0]
        q = np.array([move(x) for x in t])
        rigid = np.array([rigid_frames(x, self.beams[0].length,
                                       self.beams[1].length)[3] for x in q])
        return {"t": t, "tip": data[:, 1:4], "tip_rigid": rigid, "q": q}


def _clamped_beam(beam: Beam, n_elements: int):
    """A system with one beam along ``x`` of ``n_elements`` elements, its first node
    clamped to the ground: ``(system container, mbs, nodes)`` (not assembled)."""
    import exudyn as exu
    from exudyn.itemInterface import (
        GenericJoint,
        MarkerNodeRigid,
        NodePointGround,
        NodeRigidBodyEP,
        ObjectBeamGeometricallyExact,
    )

    SC = exu.SystemContainer()
    mbs = SC.AddSystem()
    h = beam.length / n_elements
    nodes = [mbs.AddNode(NodeRigidBodyEP(referenceCoordinates=[h * i, 0.0, 0.0]
                                         + _ep(np.eye(3)))) for i in range(n_elements + 1)]
    section = _section(beam)
    for i in range(n_elements):
        mbs.AddObject(ObjectBeamGeometricallyExact(nodeNumbers=[nodes[i], nodes[i + 1]],
                                                   length=h, sectionData=section))
    mbs.AddObject(GenericJoint(markerNumbers=[
        mbs.AddMarker(MarkerNodeRigid(nodeNumber=mbs.AddNode(NodePointGround()))),
        mbs.AddMarker(MarkerNodeRigid(nodeNumber=nodes[0]))]))
    return SC, mbs, nodes


def cantilever_frequencies(beam: Beam = TABLE8, n_elements: int = 16) -> np.ndarray:
    """Natural frequencies [rad/s], ascending, of the unloaded clamped beam of
    :func:`cantilever`: Exudyn's eigenvalues of its mass and tangent stiffness,
    projected on the null space of the clamp's and the Euler parameters' constraints
    (dense SVD; ``6 n_elements`` frequencies)."""
    SC, mbs, _ = _clamped_beam(beam, n_elements)
    mbs.Assemble()
    values, _ = mbs.ComputeODE2Eigenvalues(useSparseSolver=False,
                                           ignoreAlgebraicEquations=False,
                                           useAbsoluteValues=True)
    return np.sqrt(np.sort(np.abs(values)))


def cantilever(beam: Beam = TABLE8, n_elements: int = 16, force=(0.0, 0.0, 0.0),
               torque=(0.0, 0.0, 0.0), t_end: float | None = None, dt: float = 1e-3,
               newton_tol: float | None = None) -> dict[str, np.ndarray]:
    """One beam along ``x``, clamped at the origin, a constant tip force [N] and torque
    [N m] in the beam frame (``y`` the in-plane side, ``z`` the joint-axis side).

    ``t_end`` None: the static solution, ``{"u": tip displacement [m], "phi": tip
    rotation vector [rad]}``. Otherwise the load is applied as a step at rest and the
    free vibration about the loaded state is returned: ``{"t", "u", "phi"}`` every ``dt``.
    ``newton_tol``: the Newton iterations' absolute tolerance [N]; None: 1e-10 static,
    1e-8 dynamic. The static residual's round-off grows with the axial stiffness EA/h:
    from 32 elements in the plane (64 along the joint axis) it stays above 1e-8 N and
    the static solve fails. 1e-6 N then works: on the 0.02 N tip force at 16 elements
    it gives the 1e-10 N answer to 1e-15 relative, yet on a tip torque only to 1e-6.
    """
    import exudyn as exu
    from exudyn.itemInterface import LoadForceVector, LoadTorqueVector, MarkerNodeRigid, SensorNode
    from exudyn.rigidBodyUtilities import RotationMatrix2RotationVector

    SC, mbs, nodes = _clamped_beam(beam, n_elements)
    tip = mbs.AddMarker(MarkerNodeRigid(nodeNumber=nodes[-1]))
    mbs.AddLoad(LoadForceVector(markerNumber=tip, loadVector=list(force)))
    mbs.AddLoad(LoadTorqueVector(markerNumber=tip, loadVector=list(torque)))
    sensors = [mbs.AddSensor(SensorNode(nodeNumber=nodes[-1], storeInternal=True,
                                        outputVariableType=kind))
               for kind in (exu.OutputVariableType.Displacement,
                            exu.OutputVariableType.RotationMatrix)]
    mbs.Assemble()
    s = exu.SimulationSettings()
    s.solution.file.write = False
    s.linearSolver.solverType = exu.LinearSolverType.EigenSparse
    if t_end is None:
        s.staticSolver.newton.absoluteTolerance = 1e-10 if newton_tol is None else newton_tol
        s.staticSolver.verboseMode = 0
        mbs.SolveStatic(s)
        R = mbs.GetNodeOutput(nodes[-1], exu.OutputVariableType.RotationMatrix)
        return {"u": np.asarray(mbs.GetNodeOutput(nodes[-1],
                                                  exu.OutputVariableType.Displacement)),
                "phi": np.asarray(RotationMatrix2RotationVector(np.reshape(R, (3, 3))))}
    steps = int(round(t_end / dt))
    s.timeIntegration.numberOfSteps = steps
    s.timeIntegration.endTime = steps * dt
    s.timeIntegration.generalizedAlpha.spectralRadius = 1.0
    s.timeIntegration.newton.absoluteTolerance = 1e-8 if newton_tol is None else newton_tol
    s.timeIntegration.verboseMode = 0
    s.solution.sensors.writePeriod = dt
    mbs.SolveDynamic(s)
    u = mbs.GetSensorStoredData(sensors[0])
    R = mbs.GetSensorStoredData(sensors[1])[:, 1:].reshape(-1, 3, 3)
    phi = np.array([RotationMatrix2RotationVector(x) for x in R])
    return {"t": u[:, 0], "u": u[:, 1:4], "phi": phi}


def run_file(move: JointMove, n_elements: int = 16, dt: float = 1e-3, rho_inf: float = 1.0,
             beams: tuple[Beam, Beam] = (TABLE8, TABLE8)) -> str:
    """File name of a run in a cache: a hash of this module's source, the arguments and
    Exudyn's version."""
    import exudyn as exu

    source = Path(__file__).read_bytes()
    key = hashlib.sha256(source + repr((move, n_elements, dt, rho_inf, beams,
                                        exu.__version__)).encode()).hexdigest()
    return f"ge3d-{key[:20]}.npz"


def cached_run(move: JointMove, n_elements: int = 16, dt: float = 1e-3,
               rho_inf: float = 1.0, cache: Path | None = None,
               beams: tuple[Beam, Beam] = (TABLE8, TABLE8)) -> dict[str, np.ndarray]:
    """Tip deflection ``{"t", "d"}`` [s, m] of :meth:`SpatialArm.simulate`, stored as
    ``.npz`` under ``cache`` (:func:`run_file`)."""
    path = None if cache is None else Path(cache) / run_file(move, n_elements, dt,
                                                              rho_inf, beams)
    if path is not None and path.exists():
        with np.load(path) as z:
            return {"t": z["t"], "d": z["d"]}
    run = SpatialArm(beams, n_elements).simulate(move, dt, rho_inf)
    out = {"t": run["t"], "d": run["tip"] - run["tip_rigid"]}
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp.npz")
        np.savez_compressed(tmp, **out)
        tmp.replace(path)
    return out
