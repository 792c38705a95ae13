"""Figures of casflex.plotting: every axis labelled with its unit, a legend wherever there
are several curves and none over the data, and the content of the design-report figures.

Each figure is built from small synthetic inputs and inspected as a matplotlib Figure.
"""

import re
from types import SimpleNamespace

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg

from casflex import plotting
from casflex.shaping import FrequencyRange, zv
from casflex.simulate import SimulationResult

UNIT = re.compile(r"\[[^\]]+\]")   # "t [s]", "residual vibration [%]", "model order [–]"

T = np.linspace(0.0, 3.0, 301)
TWO_RANGES = [FrequencyRange(8.0, 10.0, 0.0, 0.05), FrequencyRange(9.5, 14.0, 0.0, 0.1)]


def _run(m=2, n=3):
    k = T.size
    wave = np.sin(np.outer(T, np.arange(1, max(m, n, 3) + 1)))
    return SimulationResult(t=T, q=wave[:, :n], dq=wave[:, :n], ddq=wave[:, :n],
                            tau=wave[:, :n], delta=1e-3 * wave[:, :m],
                            ddelta=1e-2 * wave[:, :m], tip=1e-3 * wave[:, :3],
                            tip_rigid=np.zeros((k, 3)), t_move_end=2.0)


def _figures():
    """Every figure function of casflex.plotting (but plot_accessibility, drawn by the CLI's
    owner) on synthetic data: name -> Figure."""
    from casflex.identification import CalibrationResult, identify_modes
    from casflex.robot import load
    from casflex.tmm import modes

    robot = load("problems/arm2link.toml")
    q = [0.0, 0.3, -0.5]
    m = 3
    omega = 10.0 + np.outer(np.sin(T), [1.0, 2.0, 3.0]) + [0.0, 20.0, 45.0]
    delta = 1e-3 * np.column_stack([np.sin((j + 2) * T) for j in range(m)])
    run = _run()
    shaper = zv(9.0)
    move_result = SimpleNamespace(shaper=shaper, ranges=TWO_RANGES,
                                  contributions=np.array([1.0, 0.4]), duration=shaper.duration)
    t_id = np.arange(2000) / 200.0
    y = np.exp(-0.3 * t_id) * np.cos(2 * np.pi * 4.0 * t_id) + 1e-3 * np.sin(311 * t_id)
    cal = CalibrationResult(["a"], np.ones(1), np.ones(1), np.zeros(1), np.eye(1), [True], [""],
                            np.array([[1.0, 3.0], [1.2, 3.3]]), np.array([[1.1, 3.1], [1.3, 3.2]]),
                            np.array([[1.0, 3.0], [1.2, 3.3]]), np.ones(1), 0.0, 3, None)
    comparison = SimpleNamespace(verification={"runs": {"prescribed": run}},
                                 shaped_verification={"run": run},
                                 plan=SimpleNamespace(duration=1.0, name="p"),
                                 shaped=SimpleNamespace(duration=2.0))
    return {
        "plot_modes": plotting.plot_modes(robot, q, modes(robot, q, count=2)),
        "plot_sweep": plotting.plot_sweep(T, omega, joint=2, tracked=True),
        "plot_result": plotting.plot_result(run, title="r"),
        "plot_prv": plotting.plot_prv(shaper, TWO_RANGES),
        "plot_move_shaper": plotting.plot_move_shaper(
            move_result, "move", {"unshaped": (T, np.sin(T)), "shaped": (T, 0.1 * np.sin(T))}),
        "plot_si_optimality": plotting.plot_si_optimality([0.3, 0.5], [0.301, 0.5], [0.31, 0.6]),
        "plot_digital_shaper": plotting.plot_digital_shaper(shaper, shaper, 1e-3),
        "plot_plan": plotting.plot_plan(comparison),
        "plot_frequencies_along": plotting.plot_frequencies_along(
            T, omega, "move1", ranges=[(9.0, 12.0), (28.0, 33.0), (52.0, 60.0)],
            events={"end of the planned move": 2.0, "end of the shaped move": 2.3}),
        "plot_tip_deflection": plotting.plot_tip_deflection(
            [("unshaped", T, 1e-3 * np.column_stack([np.sin(5 * T)] * 3)),
             ("shaped", T, 2e-4 * np.column_stack([np.sin(5 * T)] * 3))], 2.3),
        "plot_estimation_error": plotting.plot_estimation_error(
            T, delta, 5 * delta, 1e-3 * delta, 0.5 * delta),
        "plot_accessibility_along": plotting.plot_accessibility_along(T, np.abs(delta)),
        "plot_identification": plotting.plot_identification(identify_modes(t_id, y)),
        "plot_calibration": plotting.plot_calibration(cal),
        "plot_joint_tracking": plotting.plot_joint_tracking(
            [("prescribed", T, run.q, run.q, run.tau),
             ("closed loop", T, run.q + 0.01 * run.q ** 2, run.q, run.tau)], [2.0, 2.3]),
    }


@pytest.fixture(scope="module")
def figures():
    figs = _figures()
    for fig in figs.values():
        FigureCanvasAgg(fig).draw()   # legends placed, layouts done
    return figs


def test_every_figure_function_is_covered(figures):
    drawn = {name for name in plotting.__all__ if name.startswith("plot_")}
    assert drawn - {"plot_accessibility"} == set(figures)


def _plotted_axes(fig):
    """The data axes of a figure (colour bars have no lines, patches or collections)."""
    return [ax for ax in fig.axes if ax.lines or ax.collections or ax.patches]


def test_every_axis_is_labelled_with_its_unit(figures):
    missing = []
    for name, fig in figures.items():
        for i, ax in enumerate(_plotted_axes(fig)):
            labels = {"y": ax.get_ylabel()}
            siblings = ax.get_shared_x_axes().get_siblings(ax)
            # panels stacked on one time axis carry its label once, under the bottom one
            if not any(s is not ax and s.get_xlabel() for s in siblings):
                labels["x"] = ax.get_xlabel()
            if hasattr(ax, "get_zlabel"):
                labels["z"] = ax.get_zlabel()
            missing += [f"{name} axes {i} {axis}: {text!r}" for axis, text in labels.items()
                        if not UNIT.search(text or "")]
    assert not missing


def _labelled_curves(ax):
    return [a.get_label() for a in [*ax.lines, *ax.collections]
            if not a.get_label().startswith("_")]


def test_a_legend_wherever_there_are_several_curves(figures):
    missing = []
    for name, fig in figures.items():
        keys = [{t.get_text() for t in ax.get_legend().get_texts()}
                for ax in fig.axes if ax.get_legend() is not None]
        for i, ax in enumerate(_plotted_axes(fig)):
            curves = _labelled_curves(ax)
            if len(ax.lines) + len(ax.collections) < 2 or ax.get_legend() is not None:
                continue
            # a panel may share the key drawn in another panel of the same figure
            if curves and any(set(curves) <= key for key in keys):
                continue
            missing.append(f"{name} axes {i}: {curves}")
    assert not missing


def _covered_points(ax):
    """Data points of the lines of ``ax`` that its legend box covers (display coords)."""
    legend = ax.get_legend()
    box = legend.get_window_extent()
    frame = ax.get_window_extent()
    covered = 0
    for line in ax.lines:
        xy = np.column_stack([line.get_xdata(), line.get_ydata()]).astype(float)
        if xy.size == 0:
            continue
        pts = line.get_transform().transform(xy)
        inside_axes = (frame.x0 <= pts[:, 0]) & (pts[:, 0] <= frame.x1) & \
            (frame.y0 <= pts[:, 1]) & (pts[:, 1] <= frame.y1)
        covered += int(np.sum(inside_axes & (box.x0 < pts[:, 0]) & (pts[:, 0] < box.x1)
                              & (box.y0 < pts[:, 1]) & (pts[:, 1] < box.y1)))
    return covered


@pytest.mark.parametrize("name", ["plot_frequencies_along", "plot_tip_deflection",
                                  "plot_prv", "plot_move_shaper", "plot_estimation_error",
                                  "plot_accessibility_along", "plot_sweep"])
def test_legends_do_not_cover_data(figures, name):
    covered = {i: _covered_points(ax) for i, ax in enumerate(figures[name].axes)
               if ax.get_legend() is not None and ax.lines}
    assert covered and not any(covered.values()), covered


# ---------------------------------------------------------------- design-report figures

def test_frequencies_cover_the_time_given_and_shade_each_design_range(figures):
    ax = figures["plot_frequencies_along"].axes[0]
    assert ax.get_xlim()[0] <= 0.0 and ax.get_xlim()[1] >= 3.0
    # axhspan's rectangle is in (axes x, data y) coordinates
    spans = sorted((p.get_y(), p.get_y() + p.get_height()) for p in ax.patches)
    assert np.allclose(spans, [(9.0, 12.0), (28.0, 33.0), (52.0, 60.0)])
    labels = {line.get_label() for line in ax.lines}
    assert {"end of the planned move (2 s)", "end of the shaped move (2.3 s)"} <= labels


def _zero_damping_vibration(shaper, w):
    """|Σ A_i exp(iωt_i)|: the residual vibration of an undamped mode (independent of
    casflex.shaping.residual_vibration)."""
    return np.abs(np.exp(1j * np.outer(w, shaper.times)) @ shaper.amplitudes)


def test_prv_curve_units_and_one_entry_per_range(figures):
    ax = figures["plot_prv"].axes[0]
    curve = ax.lines[0]
    w = np.asarray(curve.get_xdata())
    assert w[0] == 0.0 and ax.get_xlim()[0] == 0.0
    # sum of impulses without damping: percent of the unshaped vibration, to rounding
    np.testing.assert_allclose(curve.get_ydata(), 100.0 * _zero_damping_vibration(zv(9.0), w),
                               atol=1e-9)
    assert ax.get_xlabel() == "natural frequency [rad/s]"
    assert ax.get_ylabel() == "residual vibration [%]"
    texts = [t.get_text() for t in ax.get_legend().get_texts()]
    assert texts[1:] == ["range 1: 8–10 rad/s, Vtol 5 %", "range 2: 9.5–14 rad/s, Vtol 10 %"]
    hz = plotting.plot_prv(zv(9.0), TWO_RANGES, unit="Hz").axes[0]
    np.testing.assert_allclose(hz.lines[0].get_xdata(), w / (2.0 * np.pi))
    assert hz.get_xlabel() == "natural frequency [Hz]"


def test_overlapping_ranges_are_drawn_apart(figures):
    """The two ranges overlap in frequency (9.5–10 rad/s) but their strips do not, and
    the strips lie above the curve."""
    ax = figures["plot_prv"].axes[0]
    assert len(ax.collections) == 2
    boxes = [c.get_paths()[0].get_extents() for c in ax.collections]
    assert boxes[0].y1 <= boxes[1].y0 or boxes[1].y1 <= boxes[0].y0
    assert min(b.y0 for b in boxes) > max(ax.lines[0].get_ydata())
    np.testing.assert_allclose([(b.x0, b.x1) for b in boxes], [(8.0, 10.0), (9.5, 14.0)])
    assert not np.array_equal(ax.collections[0].get_facecolor(),
                              ax.collections[1].get_facecolor())


def test_move_shaper_draws_the_same_prv_panel_as_plot_prv(figures):
    top = figures["plot_move_shaper"].axes[0]
    prv = figures["plot_prv"].axes[0]
    np.testing.assert_array_equal(top.lines[0].get_ydata(), prv.lines[0].get_ydata())
    assert (top.get_xlabel(), top.get_ylabel()) == (prv.get_xlabel(), prv.get_ylabel())


def test_tip_deflection_says_which_tip_and_norm_and_labels_every_line(figures):
    ax = figures["plot_tip_deflection"].axes[0]
    assert "tip:" in ax.get_title() and "‖₂" in ax.get_ylabel()
    assert all(not line.get_label().startswith("_") for line in ax.lines)
    assert ax.lines[-1].get_linestyle() == ":" and "2.3 s" in ax.lines[-1].get_label()


def test_estimation_shows_every_mode_both_states_and_the_rms_ratio(figures):
    fig = figures["plot_estimation_error"]
    assert len(fig.axes) == 6
    titles = [ax.get_title() for ax in fig.axes]
    # row j: δj then δ̇j; errors 1e-3 δ (ratio 1000) and 0.5 δ on a state 5 δ (ratio 10)
    assert titles[0::2] == [f"δ{j}: RMS state / RMS error = 1e+03" for j in (1, 2, 3)]
    assert titles[1::2] == [f"δ̇{j}: RMS state / RMS error = 10" for j in (1, 2, 3)]
    ax = fig.axes[2]   # δ2: true, estimate, error on one axis
    true, estimate, error = (np.asarray(line.get_ydata()) for line in ax.lines)
    np.testing.assert_allclose(estimate - true, error, atol=1e-15)
