"""Pictures: the helpers return figures, draw into given axes, label every axis with its unit,
distinguish many actuators, draw bounds and the tracking error, and show only what a run used."""

from __future__ import annotations

import matplotlib
import numpy as np
import pytest

from vertebra import solver
from vertebra.solver import gallery, plots
from vertebra.solver.inverse import InverseController, InverseSettings
from test_inverse_controller import pneumatic_entry


@pytest.fixture(scope="module")
def tendons16():
    return solver.build_model(gallery.load("paper_5v_16t"))


@pytest.fixture(scope="module")
def hybrid():
    """Three synthetic pneumatic segments with three chambers and two cables: both kinds."""
    entry = pneumatic_entry()
    scene = solver.parse_scene({
        "catalogue": {"path": "unused.h5"},
        "segment": [{"type": "entry", "entry": entry.name, "count": 3}],
        "chamber": [{"name": f"c{k}", "cavity": k, "to": 3, "max_pressure": 1.5e5} for k in range(3)],
        "cable": [{"name": f"t{k}", "radius": 0.008, "angle_deg": 90.0 * k, "to": 3, "max_tension": 5.0}
                  for k in range(2)],
        "effector": [{"name": "tip", "target": [0.0, 0.0, 0.1]}]})
    return solver.build_model(scene, entries={entry.name: entry})


def _texts(fig) -> str:
    return " | ".join(t.get_text() for ax in fig.axes for t in (ax.xaxis.label, ax.yaxis.label, ax.title)
                      ) + " | " + (fig._suptitle.get_text() if fig._suptitle else "")


def test_styles_are_distinct_for_forty_actuators():
    styles = plots.actuator_styles(40)
    assert len({(s["color"], s["linestyle"]) for s in styles}) == 40
    assert len({s["color"] for s in styles[:20]}) == 20          # 20 colours before any repeats


def test_static_plot_returns_the_figure_with_units_and_no_targets(tendons16, tmp_path):
    result = tendons16.solve({"t1": 3.0, "t16": 1.0})
    fig = plots.plot_static(tendons16, result, tmp_path / "s.png")
    assert isinstance(fig, matplotlib.figure.Figure)
    assert (tmp_path / "s.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = _texts(fig)
    assert "tension [N]" in text and "z [m]" in text and "paper_5v_16t: equilibrium" in text
    assert "iteration" not in text and "residual" not in text          # solver diagnostics are in the JSON
    assert fig.get_size_inches()[0] == pytest.approx(plots.TEXT_WIDTH)  # a paper's text width
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    # only the pulled cables are labelled, with their tension; the scene's targets are not drawn
    assert "t1 3 N" in labels and "t16 1 N" in labels and not any(l.startswith("t2 ") for l in labels)
    assert "targets" not in labels
    # the bounds (0 and 20 N) are drawn on the tension axis
    levels = {line.get_ydata()[0] for line in fig.axes[2].get_lines()}
    assert {0.0, 20.0} <= levels


def test_static_plot_draws_into_given_axes(tendons16):
    from matplotlib.figure import Figure

    fig = Figure()
    axes = [fig.add_subplot(1, 3, 1, projection="3d"), fig.add_subplot(1, 3, 2), fig.add_subplot(1, 3, 3)]
    assert plots.static_panels(tendons16) == 3
    assert plots.plot_static(tendons16, tendons16.solve(), axes=axes) is fig
    assert all(ax.has_data() for ax in axes)


def test_inverse_plot_has_an_axis_per_kind_time_in_seconds_and_the_error(hybrid, tmp_path):
    rest_tip = hybrid.effector_positions(hybrid.rest_state)[0]
    targets = np.array([[rest_tip + [0.002 * k, 0.0, 0.001 * k]] for k in range(4)])
    controller = InverseController(hybrid, InverseSettings())
    steps = controller.track(targets, settle=True)
    times = np.array([0.0, 0.5, 1.0, 1.5])
    fig = plots.plot_inverse(hybrid, steps, times, tmp_path / "i.png", tolerance=1e-6)
    assert plots.inverse_panels(hybrid) == 4 and len(fig.axes) == 4
    tension, pressure, error = fig.axes[1:]
    assert tension.get_ylabel() == "tension [N]" and pressure.get_ylabel() == "pressure [kPa]"
    assert error.get_ylabel() == "tracking error [mm]" and error.get_xlabel() == "time [s]"
    # pressures are drawn in kPa: the lines are the actuation / 1000
    chamber = np.array([step.actuation[2:] for step in steps])
    drawn = np.array([line.get_ydata() for line in pressure.get_lines()[:3]]).T
    assert np.allclose(drawn, chamber / 1e3, rtol=1e-12)
    assert np.array_equal(pressure.get_lines()[0].get_xdata(), times)
    # bounds: 0–150 kPa and 0–5 N; the error panel in mm with the tolerance
    assert {0.0, 150.0} <= {line.get_ydata()[0] for line in pressure.get_lines()[3:]}
    assert {0.0, 5.0} <= {line.get_ydata()[0] for line in tension.get_lines()[2:]}
    errors_mm = np.array([step.errors[0] for step in steps]) * 1e3
    assert np.allclose(error.get_lines()[0].get_ydata(), errors_mm)
    assert error.get_lines()[1].get_ydata()[0] == pytest.approx(1e-3)
    assert "inverse, 4 steps over 1.5 s" in _texts(fig) and "error" not in fig._suptitle.get_text()


def test_inverse_plot_without_times_counts_steps(tendons16):
    controller = InverseController(tendons16, InverseSettings(mode="tick"))
    tip = tendons16.effector_positions(tendons16.rest_state)
    steps = controller.track(np.array([tip + [0.001 * k, 0.0, 0.0] for k in range(3)]), settle=True)
    fig = plots.plot_inverse(tendons16, steps)
    assert fig.axes[-1].get_xlabel() == "step" and "3 steps" in fig._suptitle.get_text()
    # sixteen tendons: sixteen distinct colour/style pairs in the tension panel's legend
    handles = fig.axes[1].get_legend().legend_handles
    assert len({(h.get_color(), h.get_linestyle()) for h in handles}) == 16


def _steps(errors, reached):
    """Stand-ins for inverse steps of the two tip effectors: only what the error panel reads."""
    from types import SimpleNamespace

    return [SimpleNamespace(errors=np.array([e, 0.5 * e]), reached=r) for e, r in zip(errors, reached)]


def test_error_axes_are_logarithmic_when_errors_span_decades_and_mark_what_was_not_reached(tendons16):
    """One rule for every error axis: log when the errors and the tolerance span more than a
    decade (a 2.8e-7 mm error under a 1e-3 mm tolerance is a visible bar, not a zero), linear
    from 0 otherwise; the steps not reached are ringed and counted in the title."""
    from matplotlib.figure import Figure

    ax = Figure().add_subplot()
    plots.draw_tracking_error(ax, tendons16, _steps([2.8e-10], [True]), tolerance=1e-6)
    assert ax.get_yscale() == "log" and ax.get_ylim()[0] < 2.8e-7
    ax = Figure().add_subplot()
    plots.draw_tracking_error(ax, tendons16, _steps([4e-7, 6e-7, 2e-3], [True, True, False]), tolerance=1e-6)
    assert ax.get_yscale() == "log" and "1 of 3 not reached" in ax.get_title()
    [ring] = [line for line in ax.get_lines() if line.get_label() == "not reached"]
    assert np.allclose(ring.get_ydata(), [2.0])                                   # mm, at the missed step
    ax = Figure().add_subplot()
    plots.draw_tracking_error(ax, tendons16, _steps([4e-7, 6e-7], [True, True]), tolerance=1e-6)
    assert ax.get_yscale() == "linear" and ax.get_ylim()[0] == 0.0 and "not reached" not in ax.get_title()
    ax = Figure().add_subplot()
    plots.draw_tracking_error(ax, tendons16, _steps([3e-3], [False]), tolerance=1e-6)
    assert "not reached" in " ".join(t.get_text() for t in ax.texts)


def test_paper_style_sizes_the_text(tendons16):
    fig = plots.plot_static(tendons16, tendons16.solve())
    sizes = {t.get_fontsize() for ax in fig.axes for t in (ax.xaxis.label, ax.yaxis.label)}
    assert sizes == {plots.PAPER_STYLE["axes.labelsize"]}
    assert max(t.get_fontsize() for t in fig.axes[2].get_xticklabels()) <= 7


def test_volumes_and_areas_read_in_sensible_units():
    from vertebra.solver.workspace import area_text, volume_text

    assert volume_text(2.589e-6) == "2.59 cm³" and volume_text(3.2e-8) == "32 mm³"
    assert volume_text(0.0042) == "4.2 dm³" and volume_text(2.5) == "2.5 m³"
    assert area_text(3e-5) == "30 mm²" and area_text(0.5) == "0.5 m²"
