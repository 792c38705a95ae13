"""The modal-table entries of the sensor signals: the lean measurement's tables.

The kinematic measurement of :mod:`casflex.sensors` needs a few of a table model's
entries (27 of 158 for two accelerometers on the Table 8 arm) and their first and second
time derivatives along the shape joints. With ``lean=True`` the measurement is built with
those entries as placeholder coordinates (:func:`placeholder_kinematics`) and filled
afterwards from one B-spline of just the entries it uses (:func:`fill_entries`), or left
as inputs for a caller that looks them up together with its own tables
(:func:`entry_columns`; :func:`casflex.sensors.measurement_with_entries`).

These are the helpers of :mod:`casflex.sensors` (no public API of their own: use
:func:`casflex.sensors.kinematic_measurement` with ``lean=True`` or
:func:`casflex.sensors.measurement_with_entries`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

if TYPE_CHECKING:
    from casflex.model import FlexibleModel

__all__: list[str] = []  # helpers of casflex.sensors


def lean_applicable(model: FlexibleModel) -> bool:
    """Whether the model's quantities come from a modal table over at least one shape joint
    (the lean measurement applies)."""
    provider = getattr(model, "provider", None)
    return (getattr(model, "table_values", None) is not None
            and getattr(provider, "table", None) is not None
            and hasattr(provider, "method") and hasattr(model, "rebuilt_kinematics")
            and len(provider.shape_joints) > 0)


def placeholder_kinematics(model: FlexibleModel, shared: dict) -> tuple:
    """The model's kinematics with its table quantities as symbols (not yet filled), the
    sensor-point quantities ``shared`` (the provider's, ``casflex.sensors``) as symbols,
    and the column of all those symbols: ``(model clone, point data, V)``."""
    clone = model.rebuilt_kinematics()  # its own A, T, bodies; the model is left as it is
    data, syms = {}, []
    for name in sorted(model.Q):
        col = model.Q[name]
        syms += [col[i] for i in range(col.numel()) if col[i].is_symbolic()]
    for key in sorted(shared):
        if key in model.Q:  # the shapes sampled inside the links: the model's placeholders
            data[key] = model.Q[key]
            continue
        # entries vanishing over the whole grid stay constant zeros, as in the model
        sym = ca.SX.sym(key, shared[key].numel())
        zero = model.provider.zero_entries(key) if shared[key].numel() else []
        data[key] = ca.vertcat(*[0 if z else sym[i] for i, z in enumerate(zero)]) \
            if len(zero) else ca.SX(0, 1)
        syms += [sym[i] for i, z in enumerate(zero) if not z]
    return clone, data, ca.vertcat(*syms)


def entry_columns(model: FlexibleModel, outs: list, V: ca.SX, Vd: ca.SX,
                  Vdd: ca.SX) -> tuple[list[int], np.ndarray]:
    """The placeholders of ``V`` that ``outs`` use (through ``V``, its rates ``Vd`` or
    ``Vdd``) and their values on the table's grid: ``(indices into V, grid shape + (k,))``."""
    table = model.provider.table
    where = {}
    for name, col in model.Q.items():
        for i in range(col.numel()):
            if col[i].is_symbolic():
                where[col[i].element_hash()] = (name, i)
    used = set(e.element_hash() for e in ca.symvar(ca.vertcat(*outs)))
    need = [k for k in range(V.numel())
            if {V[k].element_hash(), Vd[k].element_hash(), Vdd[k].element_hash()} & used]
    cols = []
    for k in need:
        name_i = where.get(V[k].element_hash())
        if name_i is None:  # a sensor-point quantity: "<key>_<i>"
            key, _, idx = V[k].name().rpartition("_")
            name_i = (key, int(idx))
        name, i = name_i
        data = table.omega if name == "omega" and "omega" not in table.values \
            else table.values[name]
        data = np.asarray(data, dtype=float)
        cols.append(data.reshape(table.shape + (-1,))[..., i])
    return need, (np.stack(cols, axis=-1) if cols else np.zeros(table.shape + (0,)))


def fill_entries(model: FlexibleModel, outs: list, V: ca.SX, Vd: ca.SX, Vdd: ca.SX,
                 lookup: str = "interpolant") -> list:
    """Fill the placeholders ``V`` (and rates ``Vd``, ``Vdd``) of ``outs`` with one
    B-spline of the entries the signals use (the model's grid, periodicity and method:
    the same interpolant restricted to those entries) and its derivatives along the
    shape joints: ``V̇ = J q̇_s``, ``V̈ = (∂(J q̇_s)/∂q_s) q̇_s + J q̈_s``."""
    from casflex.modal.tables import ModalTable

    need, cols = entry_columns(model, outs, V, Vd, Vdd)
    if not need:
        return outs
    table = model.provider.table
    sub = ModalTable(grid=table.grid, shape_joints=table.shape_joints,
                     values={"sensor_entries": cols}, omega=table.omega,
                     periodic=table.periodic).function("sensor_entries",
                                                       method=model.provider.method,
                                                       lookup=lookup)
    qs, dqs = model.q_shape, ca.vertcat(*[model.dq[j] for j in model.provider.shape_joints])
    ddqs = ca.vertcat(*[model.ddq[j] for j in model.provider.shape_joints])
    val = ca.SX(sub(qs))
    J = ca.jacobian(val, qs)
    rate = J @ dqs
    rate2 = ca.jtimes(rate, qs, dqs) + J @ ddqs
    return ca.substitute(outs, [V[need], Vd[need], Vdd[need]], [val, rate, rate2])
