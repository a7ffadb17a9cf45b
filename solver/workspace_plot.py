"""Pictures of a sampled workspace (matplotlib, imported when a picture is drawn).

``plot_workspace(workspace, path)`` draws, for every point effector, its cloud in 3D with
the convex hull as a translucent surface, and its projections on the x–y, x–z and y–z
planes with the outline of each projection's convex hull; samples beyond a bound of the scene
or an entry's fitted range are marked ×, unless dropped; in the paper style of
:mod:`vertebra.solver.plots`.
"""

from __future__ import annotations

import numpy as np

from vertebra.solver.hull import convex_hull
from vertebra.solver.plots import TEXT_WIDTH, equal_axes, few_ticks, paper_style
from vertebra.solver.workspace import Workspace, volume_text
from vertebra.core.errors import OptionError

PROJECTIONS = (("x", "y", 0, 1), ("x", "z", 0, 2), ("y", "z", 1, 2))


def _projected_outline(points: np.ndarray) -> np.ndarray | None:
    """Closed outline of the convex hull of 2D points (None when they span no area)."""
    from scipy.spatial import ConvexHull, QhullError

    if len(points) < 3:
        return None
    try:
        hull = ConvexHull(points)
    except QhullError:
        return None
    ring = points[hull.vertices]          # counter-clockwise in 2D
    return np.vstack([ring, ring[:1]])


def _marker(count: int) -> tuple[float, float]:
    """Marker size and opacity that keep a cloud of ``count`` points readable."""
    return float(np.clip(3000.0 / max(count, 1), 1.0, 12.0)), float(np.clip(600.0 / max(count, 1), 0.15, 0.8))


def plot_workspace(workspace: Workspace, path=None, *, title: str | None = None, fig=None, rest=None):
    """Draw the point effectors' clouds; returns the figure (written to ``path`` when given).

    One row per point effector, of the paper's text width; the hull's volume in the unit that
    reads best (mm³, cm³, …). ``rest`` (n_eff, 3) marks where the effectors sit at rest; ``fig``
    draws into an existing figure (cleared first)."""
    from matplotlib.figure import Figure
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    clouds = [c for c in workspace.clouds() if c.kind == "point"]
    if not clouds:
        raise OptionError("the scene has no point effector to draw", field="--plot")
    rows = len(clouds)
    with paper_style():
        if fig is None:
            fig = Figure(figsize=(TEXT_WIDTH, 1.95 * rows + 0.35), layout="constrained")
            fig.get_layout_engine().set(wspace=0.12)      # room for the 3D axis' z label
        else:
            fig.clear()
        for row, cloud in enumerate(clouds):
            colour = f"C{row}"
            points = cloud.points
            size, alpha = _marker(len(points))
            size *= 0.4                                          # the markers of a column-width figure
            ax = fig.add_subplot(rows, 4, 4 * row + 1, projection="3d")
            if len(points):
                ax.scatter(points[:, 0], points[:, 1], points[:, 2], s=size, alpha=alpha, color=colour, lw=0)
                hull = convex_hull(points)
                if hull.dimension == 3:
                    ax.add_collection3d(Poly3DCollection(points[hull.simplices], alpha=0.08, facecolor=colour,
                                                         edgecolor="none"))
                    caption = f"hull {volume_text(hull.volume)}"
                else:
                    caption = f"spans {hull.dimension} dimension(s)"
                equal_axes(ax, points)
            else:
                caption = "no converged sample"
                ax.set_xlabel("x [m]"), ax.set_ylabel("y [m]"), ax.set_zlabel("z [m]")
            # samples beyond a scene bound or a fitted range, marked over the cloud (unless dropped)
            flagged = np.zeros((0, 3)) if workspace.drop_outside else workspace.cloud(cloud.name, outside=True).points
            if len(flagged):
                ax.scatter(flagged[:, 0], flagged[:, 1], flagged[:, 2], s=size, marker="x", color="k", lw=0.4)
                caption += f", {len(flagged)} outside"
            elif workspace.drop_outside and np.any(workspace.outside):
                caption += f", {int(np.count_nonzero(workspace.outside))} outside dropped"
            ax.set_title(f"{cloud.name}: {len(points)} points,\n{caption}")
            k = workspace.effector_names.index(cloud.name)
            for column, (a_name, b_name, a, b) in enumerate(PROJECTIONS):
                side = fig.add_subplot(rows, 4, 4 * row + 2 + column)
                if len(points):
                    side.scatter(points[:, a], points[:, b], s=size, alpha=alpha, color=colour, lw=0,
                                 rasterized=True)
                    outline = _projected_outline(points[:, [a, b]])
                    if outline is not None:
                        side.plot(outline[:, 0], outline[:, 1], color="k", lw=0.8, label="hull")
                if len(flagged):
                    side.scatter(flagged[:, a], flagged[:, b], s=size, marker="x", color="k", lw=0.4,
                                 rasterized=True, label="beyond a bound or fitted range")
                if rest is not None:
                    side.plot(rest[k, a], rest[k, b], "x", color="tab:red", ms=5, mew=1.2, label="rest")
                side.set_aspect("equal", adjustable="datalim")
                few_ticks(side, 3)
                side.set_xlabel(f"{a_name} [m]"), side.set_ylabel(f"{b_name} [m]", labelpad=1)
                side.set_title(f"{a_name}–{b_name} projection")
                if row == 0 and column == 0:
                    side.legend(loc="best")
        converged = int(np.count_nonzero(workspace.converged))
        fig.suptitle(title or (f"Reachable workspace: {converged} of {workspace.n_samples} sampled actuations "
                               f"({workspace.settings.get('method', '')}) converged"))
        if path is not None:
            fig.savefig(path)
    return fig
