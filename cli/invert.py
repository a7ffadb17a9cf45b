"""``vertebra invert SCENE [--trajectory FILE.csv] [--json] [--plot FILE.png] [--mode converged|tick]``

Actuation that brings the scene's effectors to their targets (or along a trajectory).
Exit codes (DESIGN.md §5): 0 every target reached within tolerance; 1 solved but some
target not reached (or an equilibrium failed) — the JSON says which; 2 bad input.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

# default effector tolerance (m) per mode: a converged static inverse is exact up to
# the solver tolerances; one linearise–QP step per tick lags a moving target.
DEFAULT_TOLERANCE = {"converged": 1e-6, "tick": 1e-3}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", help="scene file (TOML, DESIGN.md §4)")
    parser.add_argument("--trajectory", metavar="FILE.csv",
                        help="targets per step: columns <effector>.x,.y,.z (optional leading t)")
    parser.add_argument("--json", action="store_true", help="print one JSON document on stdout")
    parser.add_argument("--plot", metavar="FILE.png", help="targets vs achieved paths and actuation")
    parser.add_argument("--mode", choices=("converged", "tick"), default="converged",
                        help="converged static inverse (default) or one linearise–QP step per tick")
    parser.add_argument("--backend", default=None,
                        help="QP backend: daqp (default), gauss-seidel, qpsolvers:<solver>")
    parser.add_argument("--tolerance", type=float, default=None,
                        help="effector error counted as reached, m (default 1e-6 converged, 1e-3 tick)")
    parser.add_argument("--regularisation", type=float, default=None,
                        help="dimensionless actuation-energy weight ε (default 1e-8)")


def _log(message: str) -> None:
    print(message, file=sys.stderr)


def run(args) -> int:
    import numpy as np

    from vertebra import solver
    from vertebra.solver.inverse import DEFAULT_BACKEND, DEFAULT_REGULARISATION
    from vertebra.solver.inverse.controller import InverseController, InverseSettings
    from vertebra.solver.inverse.trajectory import Trajectory, read_trajectory
    from vertebra.store.errors import ConvergenceError, SceneError

    scene = solver.load_scene(args.scene)
    model = solver.build_model(scene)
    names = list(model.effector_names)
    if not names:
        raise SceneError("no [[effector]] to bring to a target", file=args.scene, field="effector")
    if not model.actuator_names:
        raise SceneError("no [[cable]] or [[chamber]] to invert for", file=args.scene, field="cable")
    tolerance = DEFAULT_TOLERANCE[args.mode] if args.tolerance is None else args.tolerance
    if not (tolerance > 0):
        raise SceneError(f"must be a positive length in m, got {tolerance}", field="--tolerance")
    if args.trajectory:
        trajectory = read_trajectory(args.trajectory, names, model.effector_targets)
    else:
        missing = [k for k, n in enumerate(names) if not np.isfinite(model.effector_targets[k]).all()]
        if missing:
            k = missing[0]
            raise SceneError(f"effector {names[k]!r} has no target (give one or --trajectory)",
                             file=args.scene, field=f"effector[{k}].target")
        trajectory = Trajectory(model.effector_targets[None].copy(), np.zeros(1))
    try:
        settings = InverseSettings(
            mode=args.mode, backend=args.backend or DEFAULT_BACKEND, tolerance=tolerance,
            regularisation=DEFAULT_REGULARISATION if args.regularisation is None else args.regularisation)
        from vertebra.solver.inverse.qp import get_backend

        get_backend(settings.backend)
    except ValueError as error:
        raise SceneError(str(error), field="--backend/--regularisation") from None
    controller = InverseController(model, settings, actuation=np.clip(
        model.default_actuation, *model.actuator_bounds))

    steps, step_times, equilibria = [], [], []
    unreached = []
    all_equilibrium = True
    for i, targets in enumerate(trajectory.targets):
        t0 = time.perf_counter()
        result = controller.step(targets)
        step_times.append(time.perf_counter() - t0)
        state, actuation = result.state, result.actuation
        equilibrium = result.equilibrium
        if not equilibrium:
            # tick mode: report where the robot really settles under the commanded
            # actuation (outside the timed control step)
            try:
                state = model.solve(actuation, initial=result.state).state
                equilibrium = True
            except ConvergenceError as error:
                _log(f"step {i}: no equilibrium under the commanded actuation: {error}")
        all_equilibrium &= equilibrium
        positions = model.effector_positions(state)
        errors = np.linalg.norm(positions - targets, axis=1)
        displacements = model.actuator_displacements(state, actuation)
        reached = bool(equilibrium and np.all(errors <= tolerance))
        for k, name in enumerate(names):
            if not errors[k] <= tolerance:
                unreached.append({"step": i, "effector": name, "error": float(errors[k])})
        steps.append(_step_json(model, trajectory.times[i], actuation, displacements, names,
                                targets, positions, errors, reached, equilibrium, result))
        equilibria.append(positions)
        if not args.json:
            worst = float(errors.max())
            _log(f"step {i}: error {worst:.3e} m ({result.status}, {result.iterations} iteration(s), "
                 f"{step_times[-1] * 1e3:.2f} ms)")

    reached_all = not unreached and all_equilibrium
    document = {
        "scene": scene.name or args.scene,
        "mode": args.mode,
        "backend": settings.backend,
        "tolerance": tolerance,
        "steps": steps,
        "timing": {"median_step_s": float(np.median(step_times)), "total_s": float(np.sum(step_times))},
        "converged": bool(all_equilibrium),
        "reached": bool(reached_all),
        "unreached": unreached,
    }
    if args.plot:
        _plot(args.plot, names, model.actuator_names, trajectory, np.array(equilibria),
              np.array([[*s["cables"].values(), *s["chambers"].values()] for s in steps], dtype=object),
              model=model, final_state=state)
    if args.json:
        print(json.dumps(document))
    else:
        last = steps[-1]
        for name, eff in last["effectors"].items():
            print(f"{name}: target {eff['target']} position {[round(v, 6) for v in eff['position']]} "
                  f"error {eff['error']:.3e} m")
        for name, c in last["cables"].items():
            print(f"cable {name}: tension {c['tension']:.6g} N, stroke {c['stroke']:.6g} m")
        for name, c in last["chambers"].items():
            print(f"chamber {name}: pressure {c['pressure']:.6g} Pa, volume growth {c['volume_growth']:.6g} m^3")
        print(f"{'reached' if reached_all else 'NOT reached'} within {tolerance:g} m; "
              f"median step {document['timing']['median_step_s'] * 1e3:.3f} ms")
    return 0 if reached_all else 1


def _step_json(model, t, actuation, displacements, names, targets, positions, errors, reached,
               equilibrium, result) -> dict:
    nc = model.n_cables
    act_names = model.actuator_names
    return {
        "t": float(t),
        "cables": {act_names[j]: {"tension": float(actuation[j]), "stroke": float(displacements[j])}
                   for j in range(nc)},
        "chambers": {act_names[j]: {"pressure": float(actuation[j]), "volume_growth": float(displacements[j])}
                     for j in range(nc, len(act_names))},
        # an axis effector reports its world direction (unit vector) and a dimensionless error
        "effectors": {name: {"target": [float(v) for v in targets[k]],
                             ("direction" if model.effector_is_axis[k] else "position"):
                                 [float(v) for v in positions[k]],
                             "error": float(errors[k])} for k, name in enumerate(names)},
        "reached": reached,
        "equilibrium": bool(equilibrium),
        "status": result.status,
        "iterations": int(result.iterations),
        "qp": {"status": result.qp.status if result.qp else None,
               "iterations": int(result.qp.iterations) if result.qp else 0,
               "active_bounds": [act_names[j] for j in range(len(act_names))
                                 if result.qp and (result.qp.active_lower[j] or result.qp.active_upper[j])]},
        "timing": {k: float(v) for k, v in result.timings.items()},
    }


def _plot(path, names, actuator_names, trajectory, achieved, actuation_rows, *, model=None, final_state=None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from vertebra.solver.report import draw_trunk, equal_axes

    fig = plt.figure(figsize=(11, 4.8))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    keep = np.ones(len(names), bool) if model is None else ~model.effector_is_axis
    points = [trajectory.targets[:, keep].reshape(-1, 3), achieved[:, keep].reshape(-1, 3)]
    if model is not None and final_state is not None:
        draw_trunk(ax, model, final_state, targets=False, legend_prefix="final ")
        points.append(final_state.positions)
    for k, name in enumerate(names):
        if model is not None and model.effector_is_axis[k]:
            continue                              # a direction target is not a place in space
        tgt = trajectory.targets[:, k]
        ach = achieved[:, k]
        ax.plot(tgt[:, 0], tgt[:, 1], tgt[:, 2], "x--", ms=5, label=f"{name} target")
        ax.plot(ach[:, 0], ach[:, 1], ach[:, 2], "o-", ms=2, label=f"{name} achieved")
    equal_axes(ax, np.vstack(points))
    ax.legend(fontsize=7)
    ax2 = fig.add_subplot(1, 2, 2)
    values = np.array([[list(v.values())[0] for v in row] for row in actuation_rows], dtype=float)
    if len(values) == 1:        # one target: the actuation as bars
        ax2.bar(range(len(actuator_names)), values[0], color=[f"C{j % 10}" for j in range(len(actuator_names))])
        ax2.set_xticks(range(len(actuator_names)), actuator_names, rotation=45, fontsize=7)
        ax2.set_ylabel("actuation (N or Pa)")
    else:
        for j, name in enumerate(actuator_names):
            ax2.plot(trajectory.times, values[:, j], label=name)
        ax2.set_xlabel("t")
        ax2.set_ylabel("actuation (N or Pa)")
        if len(actuator_names) <= 16:
            ax2.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
