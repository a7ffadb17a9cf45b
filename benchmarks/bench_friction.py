"""Tendon friction (docs/friction.md): the hysteresis loop of a pull and a release of one cable
over a planar 10-link section (tip position against the command) for μ = 0, 0.1, 0.2, 0.3, for a
tension-driven cable and a stroke-driven tendon; loop widths, the capstan ratio at the top of the
pull and the solve time per command.

    python -m benchmarks.bench_friction [--steps 12]

Writes benchmarks/results/friction.json and the picture docs/friction-hysteresis.png.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from benchmarks.common import RESULTS, ROOT, loadavg, log, now, write_json
from vertebra import __version__, solver
from vertebra.solver import friction

E, NU, R_ROD, LINK, N = 54e9, 0.3, 0.0007, 0.02, 10
MUS = (0.0, 0.1, 0.2, 0.3)
CASES = {
    "tension": ({"tension": 0.0}, 3.0, "base tension (N)"),
    "stroke": ({"stroke": 0.0, "stiffness": 2000.0, "pretension": 0.0}, 0.002, "servo stroke (m)"),
}


def section(mu: float, drive: dict):
    rod = {"type": "beam", "count": N, "length": LINK, "elements": 1, "youngs_modulus": E, "poisson_ratio": NU,
           "section": {"shape": "circle", "radius": R_ROD}}
    cable = {"name": "t", "radius": 0.01, "to": N, "friction": mu, **drive}
    return solver.build_model(solver.parse_scene({"segment": [rod], "cable": [cable],
                                                   "effector": [{"name": "tip", "vertebra": -1}]}))


def loop(mu: float, case: str, steps: int) -> dict:
    drive, top, _ = CASES[case]
    model = section(mu, drive)
    up = np.linspace(0.0, top, steps + 1)
    commands = np.r_[up[1:], up[::-1][1:]]
    start = time.perf_counter()
    results = model.solve_sequence([{"t": v} for v in commands])
    seconds = time.perf_counter() - start
    tip = np.r_[0.0, [r.state.positions[-1, 0] for r in results]]
    route = friction.routes(model.trunk.cables).pieces[0]
    peak = results[steps - 1]
    theta = float(friction.geometry(model.trunk, peak.state)[1][route].sum())
    pull, release = tip[:steps + 1], tip[steps:][::-1]
    return {"mu": mu, "commands": np.r_[0.0, commands].tolist(), "tip_x": tip.tolist(),
            "width_m": float(np.abs(release - pull).max()),
            "capstan_ratio_at_top": float(peak.friction.tension[route[-1]] / peak.friction.tension[route[0]]),
            "exp_minus_mu_theta": math.exp(-mu * theta), "turning_angle_rad": theta,
            "seconds_per_command": seconds / commands.size,
            "iterations_per_command": float(np.mean([r.iterations for r in results]))}


def picture(document: dict, path) -> None:
    """Top: tip deflection against the command, pull (solid) and release (dashed); bottom: the same
    less the frictionless curve, where the loops open."""
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(2, 2, figsize=(10, 7), sharex="col")
    for column, (case, rows) in enumerate(document["loops"].items()):
        scale = 1e3 if case == "stroke" else 1.0
        free = 1e3 * np.array(rows[0]["tip_x"])
        for row in rows:
            commands, tip = scale * np.array(row["commands"]), 1e3 * np.array(row["tip_x"])
            half = (commands.size - 1) // 2
            for axis, values in ((axes[0, column], tip), (axes[1, column], tip - free)):
                line, = axis.plot(commands[:half + 1], values[:half + 1], "-o", ms=3, label=f"μ = {row['mu']:g} pull")
                axis.plot(commands[half:], values[half:], "--s", ms=3, color=line.get_color(),
                          label=f"μ = {row['mu']:g} release")
        axes[0, column].set_title(f"{case}-driven cable, 10-link planar section")
        axes[0, column].set_ylabel("tip deflection x (mm)")
        axes[1, column].set_ylabel("tip x − frictionless tip x (mm)")
        axes[1, column].set_xlabel("base tension (N)" if case == "tension" else "servo stroke (mm)")
        for axis in axes[:, column]:
            axis.grid(alpha=0.3)
    axes[1, 0].legend(fontsize=7, ncol=2)
    figure.tight_layout()
    figure.savefig(path, dpi=110)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=12, help="commands per pull (and per release)")
    args = parser.parse_args(argv)
    document = {"benchmark": "friction", "vertebra_version": __version__, "date": now(), "loadavg": loadavg(),
                "steps": args.steps, "loops": {}}
    for case in CASES:
        document["loops"][case] = []
        for mu in MUS:
            row = loop(mu, case, args.steps)
            document["loops"][case].append(row)
            log(f"{case} μ={mu}: loop width {1e3 * row['width_m']:.4f} mm, distal/base at the top "
                f"{row['capstan_ratio_at_top']:.6f} (e^(−μΘ) {row['exp_minus_mu_theta']:.6f}), "
                f"{1e3 * row['seconds_per_command']:.1f} ms and {row['iterations_per_command']:.1f} Newton "
                "iterations per command")
    write_json(document, RESULTS / "friction.json")
    picture(document, ROOT / "docs" / "friction-hysteresis.png")
    log("wrote benchmarks/results/friction.json and docs/friction-hysteresis.png")


if __name__ == "__main__":
    main()
