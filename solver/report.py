"""Results as plain data (the JSON documents of ``vertebra simulate`` and ``vertebra invert``)
and as pictures or VTK files. Every document carries ``"vertebra_version"``.

Matplotlib and meshio are imported lazily inside the functions that draw or write, so
``import vertebra.solver`` stays light.
"""

from __future__ import annotations

import numpy as np

from vertebra import __version__
from vertebra.solver.lie import qrotate
from vertebra.solver.model import State, StaticResult, TrunkModel


def _pose(position, quaternion) -> dict:
    return {"position": [float(v) for v in position], "quaternion": [float(v) for v in quaternion]}


def static_report(model: TrunkModel, result: StaticResult) -> dict:
    """The ``vertebra simulate --json`` document."""
    state = result.state
    actuation = result.actuation
    lengths = model.cable_lengths(state)
    volume = model.chamber_volume_growth(state, actuation[model.n_cables:])
    effectors = model.effector_positions(state)
    return {
        "vertebra_version": __version__,
        "converged": bool(result.converged),
        "iterations": int(result.iterations),
        "residual": float(result.residual),
        "vertebrae": [_pose(state.positions[f], state.quaternions[f]) for f in model.vertebra_frames],
        "frames": [_pose(p, q) for p, q in zip(state.positions, state.quaternions)],
        "effectors": {name: ({"direction": [float(v) for v in effectors[k]]} if model.effector_is_axis[k]
                             else {"position": [float(v) for v in effectors[k]]})
                      for k, name in enumerate(model.effector_names)},
        "cables": {cable.name: {"tension": float(actuation[k]), "length": float(lengths[k]),
                                "stroke": float(lengths[k] - model.rest_cable_lengths[k])}
                   for k, cable in enumerate(model.scene.cables)},
        "chambers": {chamber.name: {"pressure": float(actuation[model.n_cables + k]),
                                    "volume_growth": float(volume[k]),
                                    "rest_volume": float(model.chamber_rest_volumes[k])}
                     for k, chamber in enumerate(model.scene.chambers)},
        "timing": {key: float(value) for key, value in result.timings.items()},
        "diagnostics": {"load_stages": int(result.load_steps), "factorization": result.factorization,
                        "rounding_limited": bool(result.rounding_limited),
                        "frames": int(model.n_frames), "residual_history": [float(r) for r in result.residual_history]},
    }


def inverse_report(model: TrunkModel, steps: list, times, *, scene: str, mode: str, backend: str,
                   tolerance: float) -> dict:
    """The ``vertebra invert --json`` document of inverse ``steps`` (``solver.inverse.InverseStep``,
    reported at equilibrium where one was found) at ``times``: per step the actuator values and,
    per effector, target, position (or direction, for an axis effector) and error; the unreached
    effectors; the median and total step time."""
    unreached = [{"step": i, "t": float(t), "effector": name, "error": float(step.errors[k])}
                 for i, (t, step) in enumerate(zip(times, steps)) for k, name in enumerate(model.effector_names)
                 if not step.errors[k] <= tolerance]
    converged = all(step.equilibrium for step in steps)
    step_times = [step.timings["total_s"] for step in steps]
    return {
        "vertebra_version": __version__,
        "scene": scene,
        "mode": mode,
        "backend": backend,
        "tolerance": tolerance,
        "steps": [_inverse_step(model, t, step) for t, step in zip(times, steps)],
        "timing": {"median_step_s": float(np.median(step_times)), "total_s": float(np.sum(step_times))},
        "converged": bool(converged),
        "reached": bool(converged and not unreached),
        "unreached": unreached,
    }


def _inverse_step(model: TrunkModel, t, step) -> dict:
    nc, names = model.n_cables, model.actuator_names
    actuation, displacements = step.actuation, step.displacements
    active = step.qp.diagnostics() if step.qp is not None else None
    return {
        "t": float(t),
        "cables": {names[j]: {"tension": float(actuation[j]), "stroke": float(displacements[j])} for j in range(nc)},
        "chambers": {names[j]: {"pressure": float(actuation[j]), "volume_growth": float(displacements[j])}
                     for j in range(nc, len(names))},
        # an axis effector reports its world direction (unit vector) and a dimensionless error
        "effectors": {name: {"target": [float(v) for v in step.targets[k]],
                             ("direction" if model.effector_is_axis[k] else "position"):
                                 [float(v) for v in step.positions[k]],
                             "error": float(step.errors[k])} for k, name in enumerate(model.effector_names)},
        "reached": bool(step.reached and step.equilibrium),
        "equilibrium": bool(step.equilibrium),
        "status": step.status,
        "iterations": int(step.iterations),
        "qp": {"status": step.qp.status if step.qp else None,
               "iterations": int(step.qp.iterations) if step.qp else 0,
               "active_bounds": [] if active is None else
               [names[j] for j in range(len(names)) if active.active_lower[j] or active.active_upper[j]]},
        "timing": {key: float(value) for key, value in step.timings.items()},
    }


def cable_paths(model: TrunkModel, state: State) -> list[np.ndarray]:
    """World polyline of each cable through its holes."""
    return model.trunk.cables.paths(state.positions, state.quaternions)


def _vertebra_radius(model: TrunkModel) -> float:
    radii = [c.radius for c in model.scene.cables]
    return 1.3 * max(radii) if radii and max(radii) > 0 else 0.03 * model.length_scale


def draw_trunk(ax, model: TrunkModel, state: State, *, rest: bool = True, targets: bool = True,
               legend_prefix: str = ""):
    """Draw backbone, vertebrae (discs), cables and effectors on a 3D matplotlib axis."""
    if rest:
        r = model.rest_state.positions
        ax.plot(r[:, 0], r[:, 1], r[:, 2], color="0.75", lw=1, ls="--", label="rest")
    x = state.positions
    ax.plot(x[:, 0], x[:, 1], x[:, 2], color="k", lw=2, label=f"{legend_prefix}backbone")
    radius = _vertebra_radius(model)
    angle = np.linspace(0, 2 * np.pi, 33)
    circle = np.stack([radius * np.cos(angle), radius * np.sin(angle), 0 * angle], -1)
    for f in model.vertebra_frames:
        ring = state.positions[f] + qrotate(state.quaternions[f][None], circle)
        ax.plot(ring[:, 0], ring[:, 1], ring[:, 2], color="tab:blue", lw=1)
    for k, path in enumerate(cable_paths(model, state)):
        ax.plot(path[:, 0], path[:, 1], path[:, 2], lw=1, color=f"C{(k % 8) + 1}")
    points = ~model.effector_is_axis            # directions are not drawn as points
    if np.any(points):
        e = model.effector_positions(state)[points]
        ax.scatter(e[:, 0], e[:, 1], e[:, 2], color="tab:red", s=25, label=f"{legend_prefix}effectors")
        t = model.effector_targets[points]
        if targets and np.all(np.isfinite(t)):
            ax.scatter(t[:, 0], t[:, 1], t[:, 2], marker="x", color="tab:green", s=40, label="targets")
    equal_axes(ax, np.vstack([x, model.rest_state.positions]))


def equal_axes(ax, points):
    """Equal scales on a 3D axis around ``points`` (matplotlib has no 'equal' for 3D data)."""
    centre = 0.5 * (points.max(0) + points.min(0))
    half = 0.55 * max(np.ptp(points, axis=0).max(), 1e-9)
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)
    ax.set_xlabel("x [m]"), ax.set_ylabel("y [m]"), ax.set_zlabel("z [m]")


def plot_static(model: TrunkModel, result: StaticResult, path: str, title: str | None = None):
    """Write a PNG of the equilibrium shape (3D view and x–z side view)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig = plt.figure(figsize=(11, 5.5))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    draw_trunk(ax, model, result.state)
    ax.legend(loc="upper left", fontsize=8)
    side = fig.add_subplot(1, 2, 2)
    r, x = model.rest_state.positions, result.state.positions
    side.plot(r[:, 0], r[:, 2], color="0.75", ls="--", label="rest")
    side.plot(x[:, 0], x[:, 2], color="k", lw=2, label="x–z")
    side.plot(x[:, 1], x[:, 2], color="tab:orange", lw=1, label="y–z")
    v = x[model.vertebra_frames]
    side.scatter(v[:, 0], v[:, 2], s=12, color="tab:blue", label="vertebrae")
    side.set_aspect("equal", adjustable="datalim")
    side.set_xlabel("x or y [m]"), side.set_ylabel("z [m]"), side.legend(fontsize=8)
    status = "converged" if result.converged else "NOT converged"
    fig.suptitle(title or f"{model.scene.name or 'scene'}: {status} in {result.iterations} iterations, "
                          f"residual {result.residual:.2g}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_inverse(model: TrunkModel, steps: list, times, path: str):
    """Write a PNG of inverse ``steps``: targets vs achieved effector paths with the last shape
    (3D), and the actuation per step (bars for a single step)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    targets = np.array([step.targets for step in steps])
    achieved = np.array([step.positions for step in steps])
    actuation = np.array([step.actuation for step in steps])
    final_state = steps[-1].state
    fig = plt.figure(figsize=(11, 4.8))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    points = ~model.effector_is_axis                # a direction target is not a place in space
    draw_trunk(ax, model, final_state, targets=False, legend_prefix="final ")
    for k, name in enumerate(model.effector_names):
        if points[k]:
            ax.plot(*targets[:, k].T, "x--", ms=5, label=f"{name} target")
            ax.plot(*achieved[:, k].T, "o-", ms=2, label=f"{name} achieved")
    equal_axes(ax, np.vstack([targets[:, points].reshape(-1, 3), achieved[:, points].reshape(-1, 3),
                              final_state.positions]))
    ax.legend(fontsize=7)
    ax2 = fig.add_subplot(1, 2, 2)
    names = model.actuator_names
    if len(steps) == 1:        # one target: the actuation as bars
        ax2.bar(range(len(names)), actuation[0], color=[f"C{j % 10}" for j in range(len(names))])
        ax2.set_xticks(range(len(names)), names, rotation=45, fontsize=7)
    else:
        for j, name in enumerate(names):
            ax2.plot(times, actuation[:, j], label=name)
        ax2.set_xlabel("t")
        if len(names) <= 16:
            ax2.legend(fontsize=6, ncol=2)
    ax2.set_ylabel("actuation (N or Pa)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_vtk(model: TrunkModel, state: State, path: str):
    """Backbone and cables as VTK line cells (``.vtu``, ``.vtk`` … by extension, via meshio)."""
    import meshio
    points = [state.positions]
    lines = [np.stack([np.arange(model.n_frames - 1), np.arange(1, model.n_frames)], -1)]
    kind = [np.zeros(model.n_frames - 1, int)]
    offset = model.n_frames
    for k, path_points in enumerate(cable_paths(model, state)):
        points.append(path_points)
        n = len(path_points)
        lines.append(offset + np.stack([np.arange(n - 1), np.arange(1, n)], -1))
        kind.append(np.full(n - 1, k + 1))
        offset += n
    is_vertebra = np.zeros(offset, int)
    is_vertebra[model.vertebra_frames] = 1
    mesh = meshio.Mesh(np.vstack(points), [("line", np.vstack(lines))],
                       point_data={"vertebra": is_vertebra},
                       cell_data={"kind": [np.concatenate(kind)]})
    mesh.write(path)
