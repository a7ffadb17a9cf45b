"""Contact friction (docs/contact.md, "Friction"): what a solve with Coulomb friction at its
obstacle contacts costs against the same robot's frictionless contact solve and its contact-free
solve.

    python -m benchmarks.bench_contact_friction [--rounds 9]

The 20-vertebra trunk of ``bench_contact`` (a capsule backbone along +z) sagging under gravity
until its outer part lies on a floor, the floor frictionless and with μ = 0.3 (its frames stick
or slip where they touched), and the trunk without the floor; solves from rest interleaved
(free, frictionless, frictional, free, …), medians and their ratios reported, with how many
contacts are pressed and how many of them stick. Writes benchmarks/results/contact_friction.json.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks.bench_contact import trunk
from benchmarks.common import RESULTS, loadavg, now, write_json
from vertebra.designer.threads import pin_blas_threads
from vertebra import __version__, solver

MU = 0.3


def models() -> dict:
    frictional = trunk(True)
    frictional["obstacle"][0]["friction"] = MU
    return {"free": solver.build_model(solver.parse_scene(trunk(False))),
            "frictionless": solver.build_model(solver.parse_scene(trunk(True))),
            "friction": solver.build_model(solver.parse_scene(frictional))}


def cost(rounds: int) -> dict:
    robots = models()
    first = {name: model.solve() for name, model in robots.items()}
    times = {name: [] for name in robots}
    for _ in range(rounds):
        for name, model in robots.items():
            start = time.perf_counter()
            result = model.solve()
            times[name].append(time.perf_counter() - start)
            assert result.converged
    medians = {name: float(np.median(t)) for name, t in times.items()}
    pressed = [c for c in first["friction"].contacts if c.force > 0.0]
    return {"mu": MU, "iterations": {name: r.iterations for name, r in first.items()},
            "load_stages": {name: r.load_steps for name, r in first.items()},
            "pressed_contacts": {"frictionless": sum(c.force > 0.0 for c in first["frictionless"].contacts),
                                 "friction": len(pressed)},
            "sticking": sum(c.sliding == "stick" for c in pressed),
            "slipping": sum(c.sliding == "slip" for c in pressed),
            "largest_friction_over_mu_normal": float(max(np.linalg.norm(c.friction) / (MU * c.force) for c in pressed)),
            "median_s": medians,
            "friction_over_frictionless": medians["friction"] / medians["frictionless"],
            "friction_over_free": medians["friction"] / medians["free"],
            "frictionless_over_free": medians["frictionless"] / medians["free"],
            "times_s": times}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=9)
    args = parser.parse_args(argv)
    pin_blas_threads()          # one BLAS thread: threaded BLAS on the small solves is 40x slower on a busy machine
    before = loadavg()
    c = cost(args.rounds)
    result = {"vertebra_version": __version__, "date": now(), "loadavg_before": before, "loadavg_after": loadavg(),
              "machine": "2 cores shared with other jobs: ratios are interleaved medians", "cost": c}
    print(f"friction μ = {c['mu']}: {c['pressed_contacts']['friction']} pressed ({c['sticking']} stick, "
          f"{c['slipping']} slip), {c['median_s']['friction'] * 1e3:.2f} ms; frictionless "
          f"{c['median_s']['frictionless'] * 1e3:.2f} ms; contact-free {c['median_s']['free'] * 1e3:.2f} ms; "
          f"friction/frictionless {c['friction_over_frictionless']:.2f}x, friction/free {c['friction_over_free']:.2f}x "
          f"(iterations {c['iterations']}, load average {result['loadavg_before']} → {result['loadavg_after']})")
    write_json(result, RESULTS / "contact_friction.json")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
