"""Contact (docs/contact.md): what a solve with pressed contacts costs against the same robot's
contact-free solve, and do random tendon robots whose holes would meet converge once their
discs are declared?

    python -m benchmarks.bench_contact [--rounds 9] [--robots 100]

* cost: a 20-vertebra trunk (a capsule backbone) sagging under gravity until its outer part
  lies on a floor (five frames pressed), against the same trunk without the floor (no contact
  model); solves from rest, interleaved A, B, A, B … and medians reported.
* inverse: the two-tendon wall robot's targets only reachable by leaning (converged, 1e-6 m)
  and ticks on a path through the wall and along it (how deep a tick state enters the wall).
* robots: tests/robots.py's random tendon robots with their tensions tripled, without discs
  (how many are refused because cable holes meet) and with discs (1.2 × the widest hole, 20 %
  of the shortest spacing thick) on every vertebra and the base: how many converge, how many of
  those fold a disc past its neighbour's rim (turned by more than 90° against it: the rounded rims
  meet rim on rim), how many with non-adjacent discs touching (a trunk folded onto itself),
  whether any two discs overlap at the converged states (every pair's exact gap), and why the
  others stop.

Writes benchmarks/results/contact.json.
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np

from benchmarks.common import RESULTS, ROOT, loadavg, log, now, write_json
from vertebra.designer.threads import pin_blas_threads
from vertebra import __version__, solver
from vertebra.core.lie import qmatrix
from vertebra.solver import contact

VERTEBRAE, SPACING, RADIUS, E = 20, 0.01, 0.001, 2e9
FLOOR = 0.025          # m: the tip would sag 0.168 m; five frames come to lie on the floor
OVERLAP = 1e-9         # m: discs deeper into each other than this overlap (touching discs' gaps are rounding)


def trunk(floor: bool, gravity: float = 20.0) -> dict:
    """The 20-vertebra trunk along +z sagging under gravity along −x; with ``floor``, a plane
    ``FLOOR`` m below its axis that its outer part comes to lie on."""
    scene = {"segment": [{"type": "beam", "count": VERTEBRAE, "length": SPACING, "youngs_modulus": E,
                          "poisson_ratio": 0.3, "section": {"shape": "circle", "radius": RADIUS},
                          "vertebra": {"mass": 0.002}}],
             "gravity": {"vector": [-gravity, 0.0, 0.0]}}
    if floor:
        scene["segment"][0]["contact_radius"] = RADIUS
        scene["obstacle"] = [{"type": "plane", "point": [-FLOOR, 0.0, 0.0], "normal": [1.0, 0.0, 0.0]}]
    return scene


def cost(rounds: int) -> dict:
    with_stops = solver.build_model(solver.parse_scene(trunk(True)))
    without = solver.build_model(solver.parse_scene(trunk(False)))
    first = with_stops.solve()
    pressed = [c for c in first.contacts if c.force > 0.0]
    times = {"contact": [], "free": []}
    iterations = {"contact": first.iterations, "free": without.solve().iterations}
    for _ in range(rounds):
        for name, model in (("contact", with_stops), ("free", without)):
            start = time.perf_counter()
            result = model.solve()
            times[name].append(time.perf_counter() - start)
            assert result.converged
    medians = {name: float(np.median(t)) for name, t in times.items()}
    return {"vertebrae": VERTEBRAE, "links": with_stops.n_frames - 1, "pressed_contacts": len(pressed),
            "candidate_contacts": len(first.contacts), "iterations": iterations,
            "median_s": medians, "ratio": medians["contact"] / medians["free"],
            "times_s": times, "largest_penetration_m": float(max(0.0, -min(c.gap for c in first.contacts))),
            "largest_gap_times_force": float(max(abs(c.gap * c.force) for c in first.contacts))}


def robots(count: int) -> dict:
    sys.path.insert(0, str(ROOT / "tests"))
    from robots import tendon_robot

    rows = []
    for seed in range(count):
        scene = tendon_robot(np.random.default_rng(seed))
        for cable in scene["cable"]:
            cable["tension"] *= 3.0
            cable["max_tension"] = max(cable["max_tension"], cable["tension"])
        plain = solver.build_model(solver.parse_scene(scene)).solve(raise_on_failure=False)
        holes = max(c["radius"] for c in scene["cable"])
        spacing = min(s["length"] for s in scene["segment"])
        disc = {"disc_radius": 1.2 * holes, "disc_thickness": 0.2 * spacing}
        scene["segment"] = [dict(s, vertebra=dict(s.get("vertebra", {}), **disc)) for s in scene["segment"]]
        scene["base"] = dict(disc)
        model = solver.build_model(solver.parse_scene(scene))
        start = time.perf_counter()
        result = model.solve(raise_on_failure=False)
        elapsed = time.perf_counter() - start
        disc = model.trunk.contact
        axes = qmatrix(result.state.quaternions)[disc.disc_frame][:, :, 2]
        turned = float(np.degrees(np.arccos(np.clip(np.add.reduce(axes[1:] * axes[:-1], 1), -1.0, 1.0))).max())
        first, second = np.triu_indices(disc.disc_frame.size, 2)
        apart = (contact.disc_gaps(disc, result.state, first, second)
                 if first.size else np.zeros(0))
        folded = [c for c in result.contacts if c.force > 0.0 and c.bodies[1].endswith("disc")
                  and abs(int(c.bodies[0].split()[1]) - int(c.bodies[1].split()[1])) > 1]
        rows.append({"largest_adjacent_turn_deg": turned, "pressed_nonadjacent": len(folded),
                     "nonadjacent_min_gap_m": float(apart.min()) if apart.size else None, "seed": seed, "holes_meet_without_discs": "holes of the two vertebrae meet" in plain.message,
                     "converged_without_discs": bool(plain.converged), "converged": bool(result.converged),
                     "iterations": int(result.iterations), "load_stages": int(result.load_steps),
                     "pressed": sum(c.force > 0.0 for c in result.contacts),
                     "deepest_gap_m": float(min((c.gap for c in result.contacts), default=0.0)),
                     "solve_s": elapsed, "tip_m": result.state.positions[-1].tolist(), "message": result.message})
        log(f"robot {seed}: converged {result.converged} ({result.iterations} iterations, {elapsed:.2f} s)")
    return {"robots": count, "converged": sum(r["converged"] for r in rows),
            "converged_folded_past_a_rim": sum(r["converged"] and r["largest_adjacent_turn_deg"] > 90.0 for r in rows),
            "converged_with_nonadjacent_discs_touching": [r["seed"] for r in rows
                                                          if r["converged"] and r["pressed_nonadjacent"]],
            "converged_with_nonadjacent_discs_overlapping": [
                r["seed"] for r in rows if r["converged"] and r["nonadjacent_min_gap_m"] is not None
                and r["nonadjacent_min_gap_m"] < -OVERLAP],
            "failures": {r["seed"]: r["message"] for r in rows if not r["converged"]},
            "holes_meet_without_discs": sum(r["holes_meet_without_discs"] for r in rows),
            "converged_of_those": sum(r["converged"] for r in rows if r["holes_meet_without_discs"]),
            "median_iterations": float(np.median([r["iterations"] for r in rows if r["converged"]])),
            "largest_iterations": int(max(r["iterations"] for r in rows if r["converged"])),
            "single_load_stage": sum(r["converged"] and r["load_stages"] == 1 for r in rows), "rows": rows}


def inverse() -> dict:
    """The inverse with the contact forces in its QP (docs/contact.md): targets only reachable by
    leaning on a wall (tests/test_contact.py's two-tendon robot), and ticks through the wall and
    along it."""
    import dataclasses

    sys.path.insert(0, str(ROOT / "tests"))
    from test_contact import pressed, wall_path, wall_robot
    from vertebra.solver import contact
    from vertebra.solver.inverse import InverseController, InverseSettings

    base = wall_robot(0.02)
    cables = tuple(dataclasses.replace(c, max_tension=c.max_tension if k in (0, 4) else 0.0)
                   for k, c in enumerate(base.scene.cables))
    model = solver.build_model(dataclasses.replace(base.scene, cables=cables))
    rng = np.random.default_rng(3)
    rows = []
    for _ in range(10):
        a = np.zeros(16)
        a[[0, 4]] = rng.uniform(2.0, 15.0, 2)
        target = model.effector_positions(model.solve(a).state)[0]
        controller = InverseController(model, InverseSettings(mode="converged", tolerance=1e-6, time_budget=60.0))
        start = time.perf_counter()
        step = controller.step(target[None])
        result = model.solve(step.actuation, initial=step.state)
        rows.append({"reached": bool(step.reached), "error_m": float(step.errors.max()), "iterations": step.iterations,
                     "time_s": time.perf_counter() - start, "contact_force_N": max(c.force for c in result.contacts),
                     "deepest_gap_m": min(c.gap for c in result.contacts), "pressed": len(pressed(result))})
    wall = 0.02
    model = wall_robot(wall)
    controller = InverseController(model, InverseSettings(mode="tick", tolerance=1e-4))
    path = wall_path(model.effector_positions(controller.state)[0], wall)
    deepest, times = 0.0, []
    for target in path:
        start = time.perf_counter()
        step = controller.step(target[None])
        times.append(time.perf_counter() - start)
        deepest = min(deepest, float(contact.evaluate(model.trunk.contact, step.state).gap.min(initial=0.0)))
    return {"leaning_targets": {"reached": sum(r["reached"] for r in rows), "targets": len(rows), "rows": rows},
            "ticks_through_the_wall": {"ticks": len(path), "deepest_gap_m": deepest,
                                       "final_tip": step.positions[0].tolist(), "final_target": path[-1].tolist(),
                                       "median_tick_s": float(np.median(times))}}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=9)
    parser.add_argument("--robots", type=int, default=100)
    args = parser.parse_args(argv)
    pin_blas_threads()          # one BLAS thread: threaded BLAS on the small solves is 40x slower on a busy machine
    result = {"vertebra_version": __version__, "date": now(), "loadavg": loadavg(),
              "machine": "2 cores shared with other jobs: ratios are interleaved medians",
              "cost": cost(args.rounds), "random_robots": robots(args.robots), "inverse": inverse()}
    c, r = result["cost"], result["random_robots"]
    print(f"cost: {c['pressed_contacts']} pressed contacts, {c['median_s']['contact'] * 1e3:.2f} ms vs "
          f"{c['median_s']['free'] * 1e3:.2f} ms contact-free: {c['ratio']:.2f}x "
          f"({c['iterations']['contact']} vs {c['iterations']['free']} iterations)")
    print(f"random robots: {r['converged']}/{r['robots']} converge with discs (median {r['median_iterations']:.0f} "
          f"iterations, {r['single_load_stage']} in one load stage), {r['converged_folded_past_a_rim']} of them with a "
          f"disc folded past its neighbour's rim, non-adjacent discs touching in "
          f"{r['converged_with_nonadjacent_discs_touching']}; non-adjacent discs overlap in "
          f"{r['converged_with_nonadjacent_discs_overlapping']}; failures: {r['failures']}; "
          f"{r['holes_meet_without_discs']} were refused without discs (holes meet), {r['converged_of_those']} of them converge")
    i = result["inverse"]
    print(f"inverse: {i['leaning_targets']['reached']}/{i['leaning_targets']['targets']} targets only reachable by "
          f"leaning reached to 1e-6 m; ticks through the wall: deepest gap {i['ticks_through_the_wall']['deepest_gap_m']:.3g} m")
    write_json(result, RESULTS / "contact.json")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
