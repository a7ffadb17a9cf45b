"""Pictures of a sampled workspace (matplotlib, imported when a picture is drawn).

``plot_workspace(workspace, path)`` draws, for every point effector, its cloud in 3D with
the convex hull as a translucent surface, and its projections on the x–y, x–z and y–z
planes with the outline of each projection's convex hull.
"""

from __future__ import annotations

import numpy as np

from vertebra.solver.hull import convex_hull
from vertebra.solver.workspace import Workspace
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

    ``rest`` (n_eff, 3) marks where the effectors sit at rest; ``fig`` draws into an existing
    figure (cleared first)."""
    import matplotlib

    if path is not None and fig is None:
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    clouds = [c for c in workspace.clouds() if c.kind == "point"]
    if not clouds:
        raise OptionError("the scene has no point effector to draw", field="--plot")
    rows = len(clouds)
    if fig is None:
        fig = plt.figure(figsize=(15, 3.9 * rows + 0.6))
    else:
        fig.clear()
    for row, cloud in enumerate(clouds):
        colour = f"C{row}"
        points = cloud.points
        size, alpha = _marker(len(points))
        ax = fig.add_subplot(rows, 4, 4 * row + 1, projection="3d")
        if len(points):
            ax.scatter(points[:, 0], points[:, 1], points[:, 2], s=size, alpha=alpha, color=colour, lw=0)
            hull = convex_hull(points)
            if hull.dimension == 3:
                ax.add_collection3d(Poly3DCollection(points[hull.simplices], alpha=0.08, facecolor=colour,
                                                     edgecolor="none"))
                caption = f"hull {1e6 * hull.volume:.4g} cm³"
            else:
                caption = f"cloud spans {hull.dimension} dimension(s)"
            lower, upper = points.min(0), points.max(0)
            centre, half = 0.5 * (lower + upper), 0.55 * max(float(np.max(upper - lower)), 1e-12)
            ax.set_xlim(centre[0] - half, centre[0] + half)
            ax.set_ylim(centre[1] - half, centre[1] + half)
            ax.set_zlim(centre[2] - half, centre[2] + half)
        else:
            caption = "no converged sample"
        ax.set_xlabel("x [m]"), ax.set_ylabel("y [m]"), ax.set_zlabel("z [m]")
        ax.set_title(f"{cloud.name}: {len(points)} points, {caption}", fontsize=9)
        k = workspace.effector_names.index(cloud.name)
        for column, (a_name, b_name, a, b) in enumerate(PROJECTIONS):
            side = fig.add_subplot(rows, 4, 4 * row + 2 + column)
            if len(points):
                side.scatter(points[:, a], points[:, b], s=size, alpha=alpha, color=colour, lw=0, rasterized=True)
                outline = _projected_outline(points[:, [a, b]])
                if outline is not None:
                    side.plot(outline[:, 0], outline[:, 1], color="k", lw=1, label="hull of the projection")
            if rest is not None:
                side.plot(rest[k, a], rest[k, b], "x", color="tab:red", ms=8, mew=2, label="rest")
            side.set_aspect("equal", adjustable="datalim")
            side.set_xlabel(f"{a_name} [m]"), side.set_ylabel(f"{b_name} [m]")
            side.set_title(f"{cloud.name}: {a_name}–{b_name} projection", fontsize=9)
            if row == 0 and column == 0:
                side.legend(fontsize=7, loc="best")
    converged = int(np.count_nonzero(workspace.converged))
    fig.suptitle(title or (f"Reachable workspace: {converged} of {workspace.n_samples} sampled actuations "
                           f"({workspace.settings.get('method', '')}) converged"), fontsize=11)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=120)
        plt.close(fig)
    return fig
