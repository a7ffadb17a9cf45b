"""Pictures of forward and inverse results (matplotlib, imported when a picture is drawn).

Every function draws into axes the caller may give and returns the matplotlib figure; a figure
it makes itself is a plain :class:`matplotlib.figure.Figure` (no pyplot state, no backend
switch), written to ``path`` when one is given.

* :func:`plot_static` — the equilibrium in 3D, its side views, and the actuation it was under;
* :func:`plot_inverse` — targets against achieved effector paths, each actuator kind on its own
  axis with its unit and bounds, and the tracking error, over time (s) or steps;
* building blocks: :func:`draw_trunk`, :func:`draw_actuation`, :func:`draw_tracking_error`,
  :func:`actuator_styles`.
"""

from __future__ import annotations

import numpy as np

from vertebra.solver import display

# actuator kinds: (slice of the actuation vector, what it is, unit shown, scale from SI to it)
TENSION = ("tension", "N", 1.0)
PRESSURE = ("pressure", "kPa", 1e-3)
LINE_STYLES = ("-", "--", "-.", ":")
MM = 1e3


def actuator_styles(count: int) -> list[dict]:
    """Distinct ``color``/``linestyle`` for ``count`` actuators: the ten dark colours of tab20,
    then its ten light ones, with the line style changing every ten (40 distinct pairs)."""
    import matplotlib

    palette = matplotlib.colormaps["tab20"].colors
    ordered = palette[0::2] + palette[1::2]                    # dark ten, then light ten
    return [{"color": ordered[k % 20], "linestyle": LINE_STYLES[(k // 10) % len(LINE_STYLES)]}
            for k in range(count)]


def _kinds(model) -> list[tuple[slice, tuple]]:
    """The actuator kinds the model has: (indices in the actuation vector, kind)."""
    nc, n = model.n_cables, len(model.actuator_names)
    return [(index, kind) for index, kind in ((slice(0, nc), TENSION), (slice(nc, n), PRESSURE))
            if index.stop > index.start]


# Figures are sized for a two-column paper (inches): the full text width, or one column; text
# is set in the sizes a journal prints at that width (8 pt labels, 7 pt ticks and legends).
TEXT_WIDTH = 7.16
COLUMN_WIDTH = 3.5
PAPER_STYLE = {"font.size": 8, "axes.titlesize": 8, "axes.labelsize": 8, "xtick.labelsize": 7,
               "ytick.labelsize": 7, "legend.fontsize": 6.5, "legend.title_fontsize": 7, "figure.titlesize": 9,
               "lines.linewidth": 1.2, "axes.linewidth": 0.6, "savefig.dpi": 200}
DECADES = 10.0            # errors spanning more than this ratio (with the tolerance) get a log axis


def paper_style():
    """A matplotlib ``rc_context`` with :data:`PAPER_STYLE` (text is sized when it is drawn)."""
    import matplotlib

    return matplotlib.rc_context(PAPER_STYLE)


def _figure(size):
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, layout="constrained")
    fig.get_layout_engine().set(wspace=0.12)      # room for a 3D axis' z label beside its neighbour
    return fig


def _finish(fig, path):
    if path is not None:
        fig.savefig(path)
    return fig


def few_ticks(ax, n: int = 4) -> None:
    """At most ``n`` ticks on each axis of ``ax`` (2D or 3D): tick labels that do not collide."""
    from matplotlib.ticker import MaxNLocator

    for axis in (ax.xaxis, ax.yaxis) + ((ax.zaxis,) if hasattr(ax, "zaxis") else ()):
        axis.set_major_locator(MaxNLocator(n))


def error_scale(ax, values, tolerance: float | None) -> None:
    """Log scale on ``ax``'s y axis when the positive ``values`` and the ``tolerance`` span more
    than :data:`DECADES` (the one rule of every error axis); otherwise a linear axis from 0 with
    room above the largest for its label."""
    values = np.asarray(values, dtype=float).ravel()
    shown = np.concatenate([values[np.isfinite(values) & (values > 0)],
                            [tolerance] if tolerance is not None and tolerance > 0 else []])
    if shown.size and shown.max() > DECADES * shown.min():
        ax.set_yscale("log")
        ax.set_ylim(shown.min() / 3.0, shown.max() * 3.0)
    else:
        ax.set_ylim(0.0, 1.25 * shown.max(initial=0.0) or 1.0)


# ----------------------------------------------------------------------------- building blocks

def equal_axes(ax, points):
    """Equal scales on a 3D axis around ``points`` (matplotlib has no 'equal' for 3D data)."""
    centre = 0.5 * (points.max(0) + points.min(0))
    half = 0.55 * max(np.ptp(points, axis=0).max(), 1e-9)
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)
    ax.set_box_aspect((1, 1, 1))
    few_ticks(ax, 3)
    ax.tick_params(pad=0)
    ax.set_xlabel("x [m]", labelpad=-2), ax.set_ylabel("y [m]", labelpad=-2), ax.set_zlabel("z [m]", labelpad=-2)


ROUNDING = 1e-9           # actuator values below this share of the largest are rounding of zero


def draw_trunk(ax, model, state, actuation=None, *, rest: bool = True, targets=None, label: str = "",
               cable_labels: bool = True):
    """Draw the backbone, vertebra discs, cables (coloured by :func:`actuator_styles`; with
    ``cable_labels``, the pulled ones labelled with their tension under ``actuation``), point
    effectors and, when given, their ``targets`` ((n_eff, 3), NaN where none) on a 3D axis.
    Returns the axis."""
    x = state.positions
    if rest:
        r = model.rest_state.positions
        ax.plot(r[:, 0], r[:, 1], r[:, 2], color="0.7", lw=1, ls="--", label="rest")
    ax.plot(x[:, 0], x[:, 1], x[:, 2], color="k", lw=2.2, label=f"{label}backbone")
    for rim in display.disc_rims(model, state):
        ring = np.vstack([rim, rim[:1]])
        ax.plot(ring[:, 0], ring[:, 1], ring[:, 2], color="0.35", lw=0.8)
    values = model.actuation(actuation)
    pulled = np.abs(values) > ROUNDING * np.abs(values).max(initial=0.0)
    styles = actuator_styles(len(model.actuator_names))
    for k, path in enumerate(display.cable_paths(model, state)):
        name = model.actuator_names[k]
        ax.plot(path[:, 0], path[:, 1], path[:, 2], lw=1.2, **styles[k],
                label=f"{name} {values[k]:.3g} N" if cable_labels and pulled[k] else None)
    points = ~np.asarray(model.effector_is_axis)            # directions are not drawn as points
    if np.any(points):
        e = model.effector_positions(state)[points]
        ax.scatter(e[:, 0], e[:, 1], e[:, 2], color="tab:red", s=28, depthshade=False, label=f"{label}effectors")
        if targets is not None:
            t = np.asarray(targets, dtype=float)[points]
            t = t[np.all(np.isfinite(t), axis=1)]
            if len(t):
                ax.scatter(t[:, 0], t[:, 1], t[:, 2], marker="x", color="tab:green", s=50, depthshade=False,
                           label="targets")
    equal_axes(ax, np.vstack([x, model.rest_state.positions]))
    return ax


def draw_actuation(ax, model, kind_index: slice, kind: tuple, actuation: np.ndarray, times=None):
    """One actuator kind on ``ax``: lines over ``times`` (s; None: step index) for a series
    ``(n_steps, n_act)``, bars for one step; finite bounds drawn dashed (one line per distinct
    bound, labelled). ``kind`` is :data:`TENSION` or :data:`PRESSURE`. Returns the axis."""
    quantity, unit, scale = kind
    names = model.actuator_names[kind_index]
    values = np.atleast_2d(actuation)[:, kind_index] * scale
    styles = actuator_styles(len(model.actuator_names))[kind_index]
    lower, upper = (np.asarray(b)[kind_index] * scale for b in model.actuator_bounds)
    if len(values) == 1:
        ax.bar(range(len(names)), values[0], color=[s["color"] for s in styles], edgecolor="0.2", lw=0.5)
        ax.set_xticks(range(len(names)), names, rotation=90 if len(names) > 6 else 0)
        ax.set_xlim(-0.6, len(names) - 0.4)
    else:
        x = np.arange(len(values)) if times is None else np.asarray(times, dtype=float)
        for j, name in enumerate(names):
            ax.plot(x, values[:, j], lw=1.4, label=name, **styles[j])
        ax.set_xlabel("time [s]" if times is not None else "step")
        ax.legend(ncol=max(1, (len(names) + 7) // 8), loc="upper left", bbox_to_anchor=(1.01, 1.0),
                  borderaxespad=0.0, title=quantity)
    for bounds, which, below in ((lower, "min", False), (upper, "max", True)):
        for value in np.unique(bounds[np.isfinite(bounds)]):
            _level(ax, value, f"{which} {value:g} {unit}", "0.3", below)
    ax.set_ylabel(f"{quantity} [{unit}]")
    ax.set_title(f"{'cable tensions' if quantity == 'tension' else 'chamber pressures'}")
    ax.grid(alpha=0.3)
    return ax


def draw_tracking_error(ax, model, steps, times=None, tolerance: float | None = None):
    """Each point effector's distance to its target (mm) over ``times`` (s; None: step index),
    bars for one step, with the ``tolerance`` as a dashed line; the steps whose targets were
    not reached are ringed (and named "not reached"). The axis is logarithmic when the errors
    and the tolerance span more than a decade (:func:`error_scale`). Returns the axis."""
    points = np.flatnonzero(~np.asarray(model.effector_is_axis))
    errors = np.array([step.errors for step in steps])[:, points] * MM
    missed = ~np.array([bool(step.reached) for step in steps])
    names = [model.effector_names[k] for k in points]
    if len(steps) == 1:
        bars = ax.bar(range(len(names)), errors[0], color=[f"C{k}" for k in range(len(names))], width=0.5)
        ax.bar_label(bars, [f"{e:.3g} mm" + (", not reached" if missed[0] else "") for e in errors[0]], fontsize=6.5)
        ax.set_xticks(range(len(names)), names)
    else:
        x = np.arange(len(steps)) if times is None else np.asarray(times, dtype=float)
        for k, name in enumerate(names):
            ax.plot(x, errors[:, k], marker="o", ms=2.0, lw=1.0, color=f"C{k}", label=name)
        if missed.any():
            worst = errors[missed].max(axis=1)
            ax.plot(x[missed], worst, "o", ms=6, mfc="none", mec="tab:red", mew=0.9, ls="none", label="not reached")
        ax.set_xlabel("time [s]" if times is not None else "step")
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, title="effector")
    if tolerance is not None:
        _level(ax, tolerance * MM, f"tolerance {tolerance * MM:g} mm", "tab:red", False)
    error_scale(ax, errors, None if tolerance is None else tolerance * MM)
    ax.set_ylabel("tracking error [mm]")
    ax.set_title("distance to target" + (f" ({int(missed.sum())} of {len(steps)} not reached)" if missed.any()
                                          and len(steps) > 1 else ""))
    ax.grid(alpha=0.3)
    return ax


def _level(ax, value: float, text: str, colour, below: bool) -> None:
    """A dashed horizontal line at ``value`` with ``text`` at its right end (under it when
    ``below``, over it otherwise)."""
    ax.axhline(value, color=colour, lw=0.9, ls=(0, (4, 3)))
    ax.annotate(text, (1.0, value), xycoords=("axes fraction", "data"), xytext=(-3, -2 if below else 2),
                textcoords="offset points", ha="right", va="top" if below else "bottom", fontsize=6,
                color=colour)


# ----------------------------------------------------------------------------- whole pictures

def static_panels(model) -> int:
    """How many axes :func:`plot_static` draws: 3D, side view, then one per actuator kind."""
    return 2 + len(_kinds(model))


def plot_static(model, result, path=None, *, title: str | None = None, axes=None):
    """The equilibrium of ``result`` (a :class:`~vertebra.solver.newton.StaticResult`): 3D view
    (cables labelled with their tensions), side views (x–z and y–z projections) and the
    actuation per kind with its unit and bounds. Only what the solve used is drawn (no targets);
    the title names the scene (and says so when the solve did not converge), the solver's
    iterations and residual are in the JSON report, not in the picture.

    ``axes``: :func:`static_panels` axes to draw into (the first one 3D); default: a new figure
    of the paper's text width. Returns the figure (written to ``path`` when given)."""
    with paper_style():
        kinds = _kinds(model)
        if axes is None:
            panels = static_panels(model)
            fig = _figure((TEXT_WIDTH, 2.9))
            axes = [fig.add_subplot(1, panels, 1, projection="3d")]
            axes += [fig.add_subplot(1, panels, k) for k in range(2, panels + 1)]
        fig = axes[0].figure
        state, actuation = result.state, result.actuation
        draw_trunk(axes[0], model, state, actuation)
        axes[0].legend(loc="upper left", ncol=1 + len(model.actuator_names) // 12, handlelength=1.5,
                       bbox_to_anchor=(-0.05, 0.97), borderaxespad=0.0)
        axes[0].set_title("equilibrium")
        side = axes[1]
        r, x = model.rest_state.positions, state.positions
        side.plot(r[:, 0], r[:, 2], color="0.7", ls="--", lw=1, label="rest")
        side.plot(x[:, 0], x[:, 2], color="k", lw=1.6, label="x–z")
        side.plot(x[:, 1], x[:, 2], color="tab:orange", lw=1.2, label="y–z")
        v = x[model.vertebra_frames]
        side.scatter(v[:, 0], v[:, 2], s=6, color="0.35", zorder=3, label="vertebrae")
        side.set_aspect("equal", adjustable="datalim")
        few_ticks(side)
        side.set_xlabel("x or y [m]"), side.set_ylabel("z [m]")
        side.legend(), side.grid(alpha=0.3)
        side.set_title("side views")
        for ax, (index, kind) in zip(axes[2:], kinds):
            draw_actuation(ax, model, index, kind, actuation)
        name = model.scene.name or "scene"
        fig.suptitle(title or (f"{name}: equilibrium" if result.converged else f"{name}: NOT an equilibrium "
                                                                                "(the solve did not converge)"))
        return _finish(fig, path)


def inverse_panels(model) -> int:
    """How many axes :func:`plot_inverse` draws: 3D, one per actuator kind, tracking error."""
    return 2 + len(_kinds(model))


def plot_inverse(model, steps, times=None, path=None, *, tolerance: float | None = None,
                 title: str | None = None, axes=None):
    """Inverse ``steps`` (``solver.inverse.InverseStep``): targets against achieved effector
    paths with the last shape (3D); each actuator kind on its own axis with its unit (N, kPa)
    and bounds; the tracking error (mm) with ``tolerance``, the steps not reached ringed. The x
    axis is ``times`` in seconds, or the step index when ``times`` is None. One step draws bars.

    ``axes``: :func:`inverse_panels` axes to draw into (the first one 3D); default: a new figure
    of the paper's text width (3D on the left, the other panels stacked on the right). Returns
    the figure (written to ``path`` when given)."""
    with paper_style():
        kinds = _kinds(model)
        if axes is None:
            rows = inverse_panels(model) - 1
            fig = _figure((TEXT_WIDTH, max(3.0, 1.6 * rows + 0.3)))
            grid = fig.add_gridspec(rows, 2, width_ratios=(1.0, 1.35))
            axes = [fig.add_subplot(grid[:, 0], projection="3d")]
            for k in range(rows):
                axes.append(fig.add_subplot(grid[k, 1], sharex=axes[1] if k and len(steps) > 1 else None))
        fig = axes[0].figure
        targets = np.array([step.targets for step in steps])
        achieved = np.array([step.positions for step in steps])
        actuation = np.array([step.actuation for step in steps])
        final = steps[-1]
        ax = axes[0]
        draw_trunk(ax, model, final.state, final.actuation, label="final ", cable_labels=False)
        points = ~np.asarray(model.effector_is_axis)               # a direction target is not a place in space
        for colour, k in enumerate(np.flatnonzero(points)):       # the colours of the error panel
            name = model.effector_names[k]
            ax.plot(*targets[:, k].T, "x--", color=f"C{colour}", ms=4, lw=0.8, label=f"{name} targets")
            ax.plot(*achieved[:, k].T, "o-", color=f"C{colour}", ms=2, lw=1.1, alpha=0.8, label=f"{name} achieved")
        equal_axes(ax, np.vstack([targets[:, points].reshape(-1, 3), achieved[:, points].reshape(-1, 3),
                                  final.state.positions, model.rest_state.positions]))
        ax.legend(loc="upper left", bbox_to_anchor=(-0.05, 0.97), borderaxespad=0.0, handlelength=1.5)
        ax.set_title("targets and achieved positions")
        for panel, (index, kind) in zip(axes[1:], kinds):
            draw_actuation(panel, model, index, kind, actuation, times)
        draw_tracking_error(axes[1 + len(kinds)], model, steps, times, tolerance)
        if len(steps) > 1:
            for panel in axes[1:len(kinds) + 1]:
                panel.set_xlabel("")
                panel.tick_params(labelbottom=False)
        span = (f"{len(steps)} steps over {times[-1] - times[0]:g} s" if times is not None and len(steps) > 1
                else f"{len(steps)} step{'s' * (len(steps) > 1)}")
        fig.suptitle(title or f"{model.scene.name or 'scene'}: inverse, {span}")
        return _finish(fig, path)
