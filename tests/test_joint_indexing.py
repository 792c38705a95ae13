"""One joint-index rule per side (DEVELOPING.md, issue 18): the Python API is 0-based, files
and the CLI are 1-based and the CLI converts at its boundary.

Every public function or class of casflex that takes a joint index (a parameter named
``joint``, ``joints`` or ``shape_joints``) is listed here; a new one fails
:func:`test_every_joint_parameter_is_known` until it is added, with its docstring saying
"0-based" and, where the index can be observed, a behavioural check below.
"""

import importlib
import inspect
import pkgutil
import re

import numpy as np
import pytest
from matplotlib.figure import Figure

import casflex
from casflex import control
from casflex.plotting import plot_accessibility, plot_sweep

JOINT_PARAMETERS = ("joint", "joints", "shape_joints")

#: qualified name -> parameter, every public callable that takes 0-based joint indexes
KNOWN = {
    "casflex.modal.fits.joint_box": "joints",
    "casflex.modal.term_fits.fit_model_terms": "joints",
    "casflex.control.accessibility.accessibility_map": "joints",
    "casflex.control.accessibility.robot_accessibility_map": "joints",
    "casflex.control.perturbation.GainSchedule": "joints",
    "casflex.control.perturbation.GainSchedule.from_gains": "joints",
    "casflex.control.perturbation.gain_schedule": "joints",
    "casflex.control.perturbation.schedule_axes": "joints",
    "casflex.estimation.plant.FlexiblePlant": "shape_joints",
    "casflex.modal.fits.ChebyshevFit": "shape_joints",
    "casflex.modal.fits.fit_chebyshev": "joints",
    "casflex.modal.sweep.frequency_sweep": "joint",
    "casflex.modal.tables.ModalTable": "shape_joints",
    "casflex.modal.tables.build_table": "joints",
    "casflex.model.build.default_grid": "joints",
    "casflex.model.providers.ConstantProvider": "shape_joints",
    "casflex.model.providers.PointwiseProvider": "shape_joints",
    "casflex.plotting.plot_accessibility": "joints",
    "casflex.plotting.plot_sweep": "joint",
}

#: parameters of those names that are not joint indexes
NOT_INDEXES = {"casflex.robot.Link": "joint"}  # the joint's kind, "revolute" or "fixed"


def _public_callables():
    """(qualified name, object) of everything in a casflex module's ``__all__`` (classes
    with their public methods), the CLI's verbs excepted (they are 1-based)."""
    names = ["casflex"] + [m.name for m in pkgutil.walk_packages(casflex.__path__, "casflex.")
                           if not m.name.startswith(("casflex.commands", "casflex.cli"))]
    found = {}
    for module_name in names:
        module = importlib.import_module(module_name)
        for name in getattr(module, "__all__", ()):
            obj = getattr(module, name, None)
            members = [obj]
            if inspect.isclass(obj):
                members += [getattr(obj, k) for k in vars(obj) if not k.startswith("_")]
            for f in members:
                f = getattr(f, "__func__", f)
                if callable(f) and hasattr(f, "__qualname__"):
                    found[f"{f.__module__}.{f.__qualname__}"] = f
    return found


def _joint_parameters():
    out = {}
    for qualname, f in _public_callables().items():
        try:
            parameters = inspect.signature(f).parameters
        except (TypeError, ValueError):
            continue
        for p in parameters:
            if p in JOINT_PARAMETERS and NOT_INDEXES.get(qualname) != p:
                out[qualname] = p
    return out


def test_every_joint_parameter_is_known():
    assert _joint_parameters() == KNOWN


@pytest.mark.parametrize("qualname", sorted(KNOWN))
def test_joint_parameter_documented_0_based(qualname):
    f = _public_callables()[qualname]
    doc = inspect.getdoc(f) or ""
    name = KNOWN[qualname]
    match = re.search(rf"^(?:\w+, )*{name}(?:, \w+)* : .*\n((?:    .*\n?)*)", doc,
                      re.MULTILINE)
    assert match, f"{qualname}: parameter {name!r} is not documented"
    text = match.group(0)
    assert "0-based" in text and "1-based" not in text, f"{qualname}: {text}"


def test_accessibility_map_and_its_plot_read_the_same_tuple():
    """The same 0-based tuple ``(1, 2)`` means q2 and q3 to the map and to its plot."""
    from casflex.model import FlexibleModel, PointwiseProvider
    from casflex.robot import load

    robot = load("problems/arm2link.toml")
    model = FlexibleModel(robot, PointwiseProvider(robot, [0.0, 0.0, 0.0], 2), gravity=None)
    a1, a2 = np.array([0.2, 1.1]), np.array([-0.7, 0.4, 2.0])
    axes, index = control.accessibility_map(model, joints=(1, 2), axes=(a1, a2))
    # the map's [k, i, j] is a_k at q2 = a1[i], q3 = a2[j]: the direct evaluation
    Q = np.array([[0.0, x, y] for x in a1 for y in a2])
    direct = control.accessibility(model, Q).reshape(a1.size, a2.size, model.m)
    np.testing.assert_allclose(index, np.moveaxis(direct, -1, 0), rtol=1e-12, atol=0)
    fig = plot_accessibility(axes, index, joints=(1, 2))
    assert (fig.axes[0].get_ylabel(), fig.axes[0].get_xlabel()) == ("q2 [deg]", "q3 [deg]")


def test_plot_sweep_joint_is_0_based():
    fig = plot_sweep([0.0, 0.1], [[1.0], [1.1]], joint=0)
    assert fig.axes[0].get_xlabel() == "q1 [deg]"


def test_cli_converts_joints_at_its_boundary(monkeypatch, tmp_path, capsys):
    """``casflex accessibility --joints 2 3`` hands (1, 2) to the library and to the plot;
    ``casflex sweep --joint 3`` hands 2 to the sweep and to its plot."""
    import casflex.modal.sweep
    import casflex.plotting
    from casflex.cli import main

    seen = {}

    def fake_map(robot, joints, step, **kwargs):
        seen["map"] = tuple(joints)
        axis = np.linspace(-np.pi, np.pi, 8, endpoint=False)
        return [axis, axis], np.ones((1, 8, 8))

    def fake_plot(axes, index, joints=(1, 2), fig=None):
        seen["plot"] = tuple(joints)
        return Figure()

    monkeypatch.setattr(control, "robot_accessibility_map", fake_map)
    monkeypatch.setattr(casflex.plotting, "plot_accessibility", fake_plot)
    assert main(["accessibility", "problems/arm2link.toml", "--joints", "2", "3",
                 "--plot", str(tmp_path / "a.png"), "--json"]) == 0
    assert seen == {"map": (1, 2), "plot": (1, 2)}
    assert '"joints": [2, 3]' in capsys.readouterr().out  # printed 1-based

    real_sweep = casflex.modal.sweep.frequency_sweep

    def spy_sweep(robot, qs, count, **kwargs):
        seen["sweep"] = kwargs["joint"]
        return real_sweep(robot, qs, count, **kwargs)

    def spy_plot(q, omega, joint, tracked=False, **kwargs):
        seen["sweep_plot"] = joint
        return Figure()

    monkeypatch.setattr(casflex.modal.sweep, "frequency_sweep", spy_sweep)
    monkeypatch.setattr(casflex.plotting, "plot_sweep", spy_plot)
    assert main(["sweep", "problems/arm2link.toml", "--joint", "3", "--from", "0", "--to",
                 "1deg", "--step", "1deg", "--modes", "1", "--processes", "1", "--plot",
                 str(tmp_path / "s.png")]) == 0
    assert seen["sweep"] == 2 and seen["sweep_plot"] == 2
