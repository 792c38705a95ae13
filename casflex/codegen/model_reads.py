"""The model of a C bundle with only the tabulated quantities its dynamics read.

A model evaluates all of its provider's quantities in ONE combined lookup
(:meth:`casflex.model.TableProvider.evaluate`), so the generated C holds the coefficient
table of every quantity the provider offers, read or not. The forward dynamics do not
read all of them: the truncated model leaves the sensor points' quantities
(``point_*``; and ``N``, ``eps`` without foreshortening), and with the exact kinematics
(issue 19) the rods are built from ``sample_u`` and ``sample_theta`` alone, so ``C1``,
``C2``, ``N``, ``eps``, ``end_*`` and ``point_*`` (154 of the Table 8 arm's 463 entries
at 3 modes, 0.85 MB of the C) would be static data nobody reads.

:func:`reading_model` rebuilds the model with its provider's combined lookup limited to
the quantities ``M`` and ``h`` depend on (found on a probe model whose lookup returns free
symbols). The other quantities stay available through ``provider.function``; the bundle's
functions do not reference them, so their tables are not generated.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

import casadi as ca
import numpy as np

if TYPE_CHECKING:
    from casflex.model import FlexibleModel

__all__ = ["reading_model", "quantities_read"]


class _Limited:
    """``provider`` with its combined lookup limited to ``names`` (everything else,
    ``names`` included, is the provider's own)."""

    def __init__(self, provider: Any, names: Iterable[str]) -> None:
        self._provider = provider
        self._read = frozenset(names)

    def __getattr__(self, key):
        return getattr(self._provider, key)

    def evaluate(self, q_shape: ca.SX, names=None) -> dict[str, ca.SX]:
        wanted = self._provider.names if names is None else names
        return self._provider.evaluate(q_shape, [k for k in wanted if k in self._read])


class _Probe(_Limited):
    """``provider`` whose combined lookup returns free symbols (kept in ``made``)."""

    def __init__(self, provider: Any) -> None:
        super().__init__(provider, ())
        self.made: dict[str, ca.SX] = {}

    def evaluate(self, q_shape: ca.SX, names=None) -> dict[str, ca.SX]:
        wanted = self._provider.names if names is None else names
        self.made = {k: ca.SX.sym(f"tab_{k}", self._provider.function(k).nnz_out(0))
                     for k in wanted}
        return self.made


def _rebuilt(model: FlexibleModel, provider: Any) -> FlexibleModel:
    """``model`` built again on ``provider`` with the same options."""
    from casflex.model import FlexibleModel

    return FlexibleModel(model.robot, provider, gravity=np.asarray(model.gravity),
                         damping_ratio=model.damping_ratio, delta_order=model.delta_order,
                         modal_mass=model.modal_mass, shape_rates=model.shape_rates,
                         foreshortening=model.foreshortening, kinematics=model.kinematics)


def quantities_read(model: FlexibleModel) -> list[str]:
    """The provider quantities the model's ``M`` and ``h`` depend on (sorted).

    Parameters
    ----------
    model : casflex.model.FlexibleModel
        A model whose provider has a combined lookup (``evaluate``).

    Returns
    -------
    list of str

    Examples
    --------
    >>> from casflex.model import ConstantProvider, FlexibleModel
    >>> from casflex.modal.integrals import quantity_shapes
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> class Combined(ConstantProvider):   # a provider with a combined lookup
    ...     def evaluate(self, q_shape, names=None):
    ...         return {k: ca.SX(self.quantities[k].ravel()) for k in names}
    >>> shapes = quantity_shapes(robot, 1)
    >>> values = {k: np.full(s, 0.1) for k, s in shapes.items()}
    >>> values["omega"] = np.array([30.0])
    >>> quantities_read(FlexibleModel(robot, Combined(values), gravity=None))
    ['C1', 'C2', 'end_theta', 'end_u', 'omega']
    """
    provider = _Probe(model.provider)
    probe = _rebuilt(model, provider)
    free = {s.element_hash() for s in ca.symvar(ca.vertcat(ca.vec(probe.M), probe.h))}
    return sorted(k for k, v in provider.made.items()
                  if any(v[i].element_hash() in free for i in range(v.numel())))


def reading_model(model: FlexibleModel) -> FlexibleModel:
    """``model`` rebuilt with its provider's combined lookup limited to what ``M`` and
    ``h`` read (module docstring); ``model`` itself when there is nothing to leave out.

    Parameters
    ----------
    model : casflex.model.FlexibleModel

    Returns
    -------
    casflex.model.FlexibleModel
        The same dynamics (the same table values per quantity); its ``forward``,
        ``mass`` and the other functions of ``M`` and ``h`` reference only the
        quantities read.

    Examples
    --------
    >>> from casflex.modal.tables import build_table
    >>> from casflex.model import FlexibleModel, TableProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> table = build_table(robot, np.radians([0, 10, 20, 30]), 1, cache_dir=False,
    ...                     processes=1)
    >>> model = FlexibleModel(robot, TableProvider(table), gravity=None)
    >>> [k for k in model.provider.names if k not in quantities_read(model)]
    ['N', 'eps', 'sample_theta', 'sample_u', 'spring_phi']
    """
    if getattr(model.provider, "evaluate", None) is None:
        return model
    read = quantities_read(model)
    if set(read) >= set(model.provider.names):
        return model
    return _rebuilt(model, _Limited(model.provider, read))
