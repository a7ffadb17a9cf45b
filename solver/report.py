"""Results as plain data: the JSON documents of ``vertebra simulate`` and ``vertebra invert``
(every document carries ``"vertebra_version"``) and the frames as 4×4 transforms (CSV).

Pictures are drawn by :mod:`vertebra.solver.plots` (``plot_static`` and ``plot_inverse`` are
importable from here too), ParaView files written by :mod:`vertebra.solver.paraview`; both
import what they need when called, so ``import vertebra.solver`` stays light.
"""

from __future__ import annotations

import numpy as np

from vertebra import __version__
from vertebra.solver.bounds import bound_violations
from vertebra.solver.compliance import compliance_report
from vertebra.solver.friction import FrictionState, routes
from vertebra.solver.model import State, StaticResult, TrunkModel
from vertebra.solver.plots import plot_inverse, plot_static

__all__ = ["FRAME_COLUMNS", "frames_table", "inverse_report", "plot_inverse", "plot_static", "static_report",
           "write_frames"]


def _pose(position, quaternion) -> dict:
    return {"position": [float(v) for v in position], "quaternion": [float(v) for v in quaternion]}


def static_report(model: TrunkModel, result: StaticResult) -> dict:
    """The ``vertebra simulate --json`` document."""
    state = result.state
    actuation = result.actuation
    lengths = model.cable_lengths(state)
    volume = model.chamber_volume_growth(state, actuation[model.n_cables:])
    effectors = model.effector_positions(state)
    compliance = compliance_report(model, result)
    # a scene that declares contact shapes lists every candidate contact (docs/contact.md)
    contacts = ({"contacts": [c.as_dict() for c in result.contacts]} if model.trunk.contact is not None else {})
    return {
        "vertebra_version": __version__,
        "converged": bool(result.converged),
        "iterations": int(result.iterations),
        "residual": float(result.residual),
        "vertebrae": [_pose(state.positions[f], state.quaternions[f]) for f in model.vertebra_frames],
        "frames": [_pose(p, q) for p, q in zip(state.positions, state.quaternions)],
        "effectors": {name: {**({"direction": [float(v) for v in effectors[k]]} if model.effector_is_axis[k]
                                else {"position": [float(v) for v in effectors[k]]}),
                             "compliance": compliance.get(name)}
                      for k, name in enumerate(model.effector_names)},
        "cables": cables_report(model, state, actuation, lengths,
                                result.friction if isinstance(result.friction, FrictionState) else None),
        "chambers": {chamber.name: {"pressure": float(actuation[model.n_cables + k]),
                                    "volume_growth": float(volume[k]),
                                    "rest_volume": float(model.chamber_rest_volumes[k])}
                     for k, chamber in enumerate(model.scene.chambers)},
        **contacts,
        "timing": {key: float(value) for key, value in result.timings.items()},
        "diagnostics": {"load_stages": int(result.load_steps), "factorization": result.factorization,
                        "rounding_limited": bool(result.rounding_limited),
                        "frames": int(model.n_frames), "residual_history": [float(r) for r in result.residual_history],
                        "out_of_range": [excess.to_dict() for excess in result.out_of_range],
                        "bound_violations": [violation.to_dict() for violation in result.bound_violations]},
    }


def cables_report(model: TrunkModel, state, actuation: np.ndarray, lengths: np.ndarray | None = None,
                  friction: FrictionState | None = None) -> dict:
    """Every cable's tension (a stroke-driven tendon's from its elongation at ``state``; with
    friction the first span's), length and stroke ``L − L0`` (the change of its path through the
    holes), its ``route`` (the holes it runs through, proximal first), the ``tensions`` of its spans
    between them and ``stick`` (is it stuck at each interior hole: the ``friction`` state of a
    frictional solve; without one every span carries the cable's tension and nothing sticks); a
    stroke-driven tendon also its servo stroke (its command) and whether it is slack."""
    if lengths is None:
        lengths = model.cable_lengths(state)
    tensions = model.cable_tensions(state, actuation) if friction is None else None
    stroke_driven = model.trunk.actuators.stroke_driven
    paths = model.trunk.cables.paths(state.positions, state.quaternions)
    out = {}
    for k, cable in enumerate(model.scene.cables):
        run = routes(model.trunk.cables).pieces[k]
        spans = (np.full(run.size, tensions[k]) if friction is None else friction.tension[run])
        row = {"tension": float(spans[0]), "length": float(lengths[k]),
               "stroke": float(lengths[k] - model.rest_cable_lengths[k]),
               "route": [[float(v) for v in point] for point in paths[k]],
               "tensions": [float(v) for v in spans],
               "stick": ([False] * (run.size - 1) if friction is None else (friction.slip[run[1:]] == 0).tolist())}
        if stroke_driven[k]:
            row.update(servo_stroke=float(actuation[k]), slack=bool(not spans.any()))
        out[cable.name] = row
    return out


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
    predicted, miss = step.predicted_errors, step.prediction_miss
    # with friction (docs/friction.md) each cable also carries its span tensions and where it sticks
    friction = getattr(step, "friction", None)
    if not model.n_tendons:
        cables = {names[j]: {"tension": float(actuation[j]), "stroke": float(displacements[j])} for j in range(nc)}
        if friction is not None:
            for name, run in zip(names, routes(model.trunk.cables).pieces):
                cables[name].update(tensions=[float(v) for v in friction.tension[run]],
                                    stick=(friction.slip[run[1:]] == 0).tolist())
    else:
        dropped = ("length", "route") if friction is not None else ("length", "route", "tensions", "stick")
        cables = {name: {k: v for k, v in row.items() if k not in dropped}
                  for name, row in cables_report(model, step.state, actuation, friction=friction).items()}
    return {
        "t": float(t),
        "cables": cables,
        "chambers": {names[j]: {"pressure": float(actuation[j]), "volume_growth": float(displacements[j])}
                     for j in range(nc, len(names))},
        # an axis effector reports its world direction (unit vector) and a dimensionless error
        "effectors": {name: {"target": [float(v) for v in step.targets[k]],
                             ("direction" if model.effector_is_axis[k] else "position"):
                                 [float(v) for v in step.positions[k]],
                             "error": float(step.errors[k]),
                             **({} if predicted is None else {"predicted_error": float(predicted[k]),
                                                              "prediction_miss": float(miss[k])})}
                      for k, name in enumerate(model.effector_names)},
        "reached": bool(step.reached and step.equilibrium),
        "equilibrium": bool(step.equilibrium),
        "out_of_range": [excess.to_dict() for excess in step.out_of_range],
        "bound_violations": [violation.to_dict() for violation in bound_violations(model, step.state, actuation)],
        **({"stuck": step.stuck(model)} if friction is not None else {}),
        "status": step.status,
        "iterations": int(step.iterations),
        "fraction": float(step.fraction),
        **({"equilibrium_failure": step.equilibrium_failure} if step.equilibrium_failure else {}),
        "qp": {"status": step.qp.status if step.qp else None,
               "iterations": int(step.qp.iterations) if step.qp else 0,
               "active_bounds": [] if active is None else
               [names[j] for j in range(len(names)) if active.active_lower[j] or active.active_upper[j]]},
        "timing": {key: float(value) for key, value in step.timings.items()},
    }


FRAME_COLUMNS = tuple(f"T{row}{column}" for row in range(1, 5) for column in range(1, 5))


def frames_table(state: State) -> np.ndarray:
    """Every frame's pose as a row-major 4×4 transform flattened to 16 values: ``(n_frames, 16)``,
    columns :data:`FRAME_COLUMNS` (``T11 T12 T13 T14 T21 … T44``; translation in T14, T24, T34, m)."""
    return state.transforms().reshape(-1, 16)


def write_frames(path, state: State) -> None:
    """Write :func:`frames_table` as CSV: a header row, then one row per frame (base first),
    floats in shortest round-trip form."""
    with open(path, "w", newline="") as handle:
        handle.write(",".join(FRAME_COLUMNS) + "\n")
        for row in frames_table(state):
            handle.write(",".join(repr(float(v)) for v in row) + "\n")
