"""Benchmark of the runtime with nonlinear catalogue entries (the ``nonlinear-entry`` link kind).

Sections (tables in ``results/runtime_nonlinear.md``, numbers in ``results/runtime_nonlinear.json``):

``speed``
    20-link forward solves of the same trunk under the same load with the nonlinear entries and
    with the same entries stripped of their energy (linear entries, quadratic links): CPU-time
    medians over interleaved rounds (nonlinear, linear, nonlinear, …; the machine may be shared),
    Newton iterations, time per iteration, and the links' part of one Newton evaluation. Entries:
    a neo-Hookean rod (degree 6 and 8) and a CBHA-like pneumatic slice (three chambers, degree 6,
    the default sampling), with a tip load and (pneumatic) one chamber pressurised along the trunk.
    Also the inverse's control tick (tick mode, one linearise–QP–step per target) on eight CBHA
    slices whose tip follows a small circle, nonlinear vs linear entries.
    The run-time cost of an entry is set by its fit (degree, symmetry, cavities), not by the mesh
    it was sampled on: the entries are designed on coarse meshes.
``accuracy``
    A spot check of the public path against the full nonlinear FE of the same trunk
    (``designer.nonlinear.fe_trunk.NonlinearTrunk``, same meshes and material, rigid vertebrae):
    ``build_model(scene)`` with the designed entries, rod trunks under dead loads (planar and
    3D) and four pneumatic slices with one chamber pressurised — tip error in % of the trunk
    length, tip angle and volume growth errors, for the nonlinear and the linear entries, and
    whether the solve reported leaving the fitted range. The full study (many trunks, fine
    meshes, CalculiX) is ``bench_nonlinear.py``'s and its successors'.

Run: ``OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.bench_runtime_nonlinear
[--quick] [--sections speed accuracy] [--entries DIR]`` (``--entries`` keeps the designed
entries in a catalogue there, reused by later runs; default: a temporary directory).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from datetime import datetime, timezone  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks import render  # noqa: E402
from benchmarks.common import RESULTS, loadavg, log, timed  # noqa: E402
from vertebra import solver
from vertebra.core import lie  # noqa: E402

ROD = dict(radius=0.01, length=0.04, youngs_modulus=1e6, poisson_ratio=0.3)
CBHA = dict(outer_radius=0.04, chamber_radius=0.01, chamber_offset=0.0215, length=0.03, chambers=3,
            youngs_modulus=5e5, poisson_ratio=0.45)
# (label, family, parameters, mesh size, sampling): coarse meshes, the default sampling of each degree
ENTRIES = {
    "rod-d6": ("rod", ROD, 0.008, {"degree": 6}),
    "rod-d8": ("rod", ROD, 0.008, {"degree": 8}),
    "cbha-d6": ("pneumatic", CBHA, 0.015, {"degree": 6, "pressure": 1.5e5, "limit_fraction": 0.95}),
}



def designed(label: str, directory: Path):
    """The nonlinear entry ``label`` (designed once, then read from the catalogue in ``directory``)."""
    from vertebra import designer
    from vertebra.store import catalogue

    family, parameters, mesh, sampling = ENTRIES[label]
    path = directory / "runtime-nonlinear.h5"
    key = designer.entry_key(family, parameters, mesh_size=mesh, material="neo_hookean", sampling=sampling)
    if catalogue.has_entry(path, key):
        with catalogue.open_catalogue(path) as cat:
            return cat.load(key)
    log(f"designing {label} ({family}, mesh {mesh} m, sampling {sampling})")
    start = time.perf_counter()
    entry = designer.design_segment(family, parameters, mesh_size=mesh, material="neo_hookean", sampling=sampling,
                                    estimate_accuracy=False, executor="local", workers=2, name=label)
    log(f"  {time.perf_counter() - start:.0f} s, {entry.energy.coefficients.size} terms")
    catalogue.add_entry(path, entry)
    return entry


def trunk(entry, count: int, *, forces=None, pressure: float = 0.0):
    """A trunk of ``count`` repetitions of ``entry`` with dead ``forces`` {vertebra: force} and
    (entries with cavities) chamber 0 at ``pressure`` along the whole trunk."""
    data = {"catalogue": {"path": "unused.h5"},
            "segment": [{"type": "entry", "entry": entry.name, "count": count}],
            "load": [{"vertebra": k, "force": list(map(float, f))} for k, f in (forces or {}).items()],
            "effector": [{"name": "tip", "vertebra": -1}]}
    if entry.n_cavities:
        data["chamber"] = [{"name": f"c{k}", "cavity": k, "from": 1, "to": count,
                            "pressure": pressure if k == 0 else 0.0, "max_pressure": 2e5}
                           for k in range(entry.n_cavities)]
    return solver.build_model(solver.parse_scene(data), {entry.name: entry})


def linear_of(entry):
    """The entry's linear part: its compliance, without the fitted energy and the record of the
    nonlinear design."""
    return dataclasses.replace(entry, energy=None,
                               provenance={k: v for k, v in entry.provenance.items() if k != "nonlinear"})


def tip_angle(state) -> float:
    return math.degrees(float(np.linalg.norm(lie.qlog(state.quaternions[-1]))))


# ------------------------------------------------------------------ speed

def cpu_median(model, repeats: int) -> float:
    """Median CPU time of ``repeats`` solves from rest."""
    return timed(model.solve, repeats, warmup=0)[1]["cpu_median_s"]


def evaluation_us(model, state, repeats: int) -> float:
    """CPU time of the links' part of one Newton evaluation at ``state``: the link energies'
    response and material tangent (what the energy class is asked per iteration)."""
    from vertebra.solver.potential import link_response
    from vertebra.solver.state import kinematics

    trunk_ = model.trunk
    load = model.loads(model.default_actuation, 1.0)
    xi = kinematics(state).xi
    energies = trunk_.links.energies

    def once():
        total, w, kept = link_response(trunk_, xi, load.link_loads)
        for energy, prepared, values in zip(energies, load.link_loads, kept):
            energy.material_tangent(xi[energy.links], prepared, values)

    once()
    start = time.process_time()
    for _ in range(repeats):
        once()
    return 1e6 * (time.process_time() - start) / repeats


SPEED_CASES = [
    # label, entry, tip force (N, x), chamber 0 pressure (Pa)
    ("rod, degree 6", "rod-d6", 0.3, 0.0),
    ("rod, degree 8", "rod-d8", 0.3, 0.0),
    ("CBHA slice, degree 6: tip load", "cbha-d6", 0.5, 0.0),
    ("CBHA slice, degree 6: chamber 0 at 0.5 bar", "cbha-d6", 0.0, 5e4),
    ("CBHA slice, degree 6: chamber 0 at 1 bar + tip load", "cbha-d6", 0.3, 1e5),
]


def section_speed(results: dict, entries: dict, quick: bool) -> None:
    rounds, repeats = (5, 5) if quick else (21, 15)
    rows = []
    for label, name, force, pressure in SPEED_CASES:
        entry = entries[name]
        forces = {-1: [force, 0.0, 0.0]} if force else {}
        models = {"nonlinear": trunk(entry, 20, forces=forces, pressure=pressure),
                  "linear": trunk(linear_of(entry), 20, forces=forces, pressure=pressure)}
        solved = {kind: model.solve() for kind, model in models.items()}
        medians = {kind: [] for kind in models}
        load = [loadavg()[0]]
        for _ in range(rounds):                       # interleaved: a load change hits both
            for kind, model in models.items():
                medians[kind].append(cpu_median(model, repeats))
        load.append(loadavg()[0])
        row = {"case": label, "entry": name, "terms": int(entry.energy.coefficients.size),
               "degree": int(entry.energy.degree), "links": 20, "tip_angle_deg": tip_angle(solved["nonlinear"].state),
               "out_of_range": len(solved["nonlinear"].out_of_range), "loadavg": load}
        for kind, model in models.items():
            t = float(np.median(medians[kind]))
            it = solved[kind].iterations
            row[kind] = {"solve_ms": 1e3 * t, "min_ms": 1e3 * float(np.min(medians[kind])), "iterations": it,
                         "per_iteration_us": 1e6 * t / max(it, 1),
                         "links_evaluation_us": evaluation_us(model, solved[kind].state, 200 if quick else 1000)}
        row["ratio"] = row["nonlinear"]["solve_ms"] / row["linear"]["solve_ms"]
        row["ratio_per_iteration"] = row["nonlinear"]["per_iteration_us"] / row["linear"]["per_iteration_us"]
        rows.append(row)
        log(f"  {label}: nonlinear {row['nonlinear']['solve_ms']:.3f} ms ({row['nonlinear']['iterations']} it), "
            f"linear {row['linear']['solve_ms']:.3f} ms ({row['linear']['iterations']} it): ×{row['ratio']:.2f}")
    results["speed"] = {"rows": rows, "rounds": rounds, "repeats": repeats}
    results["tick"] = tick_speed(entries["cbha-d6"], rounds, 30 if quick else 60)


def tick_speed(entry, rounds: int, ticks: int) -> dict:
    """CPU time per control tick (tick mode) of eight slices whose tip follows a 2 mm circle,
    nonlinear vs linear entries, interleaved rounds of ``ticks`` ticks from rest."""
    from vertebra.solver.inverse import InverseController, InverseSettings

    models = {"nonlinear": trunk(entry, 8), "linear": trunk(linear_of(entry), 8)}
    tip = models["linear"].effector_positions(models["linear"].rest_state)[0]
    angle = np.linspace(0.0, 2.0 * math.pi, ticks)
    targets = (tip + 0.002 * np.stack([np.sin(angle), 1.0 - np.cos(angle), 0.0 * angle], 1))[:, None, :]
    per_tick = {kind: [] for kind in models}
    errors = {}
    for _ in range(rounds):
        for kind, model in models.items():
            controller = InverseController(model, InverseSettings(mode="tick"), actuation=np.zeros(3))
            start = time.process_time()
            steps = controller.track(targets)
            per_tick[kind].append((time.process_time() - start) / ticks)
            errors[kind] = float(max(step.errors.max() for step in steps[ticks // 4:]))
    out = {kind: {"tick_ms": 1e3 * float(np.median(values)), "max_error_m": errors[kind]}
           for kind, values in per_tick.items()}
    out["ratio"] = out["nonlinear"]["tick_ms"] / out["linear"]["tick_ms"]
    log(f"  tick: nonlinear {out['nonlinear']['tick_ms']:.3f} ms, linear {out['linear']['tick_ms']:.3f} ms: "
        f"×{out['ratio']:.2f}")
    return out


# ------------------------------------------------------------------ accuracy

ROD_CASES = [
    # label, segments, forces {vertebra: force} at the full level, levels
    ("2 rods, planar", 2, {2: [1.0, 0.0, 0.0]}, (1.0, 2.0, 3.0)),
    ("2 rods, 3D", 2, {1: [0.0, 0.8, 0.0], 2: [1.0, 0.0, -0.3]}, (1.0, 2.0, 3.0)),
    ("4 rods, planar", 4, {4: [1.0, 0.0, 0.0]}, (0.5, 1.0, 1.5)),
    ("4 rods, 3D", 4, {3: [0.0, 0.8, 0.0], 4: [1.0, 0.0, -0.3]}, (0.5, 1.0, 1.5)),
]


def _segment(entry):
    from vertebra.designer.nonlinear_condensation import FamilySolid

    return FamilySolid(entry.family, json.dumps(entry.parameters, sort_keys=True), entry.mesh["mesh_size"], 2,
                       "neo_hookean").build()


def _runtime(entry, count, forces, pressure=0.0):
    out = {}
    for kind, e in (("nonlinear", entry), ("linear", linear_of(entry))):
        model = trunk(e, count, forces=forces, pressure=pressure)
        result = model.solve(raise_on_failure=False)
        out[kind] = (model, result)
    return out


def section_accuracy(results: dict, entries: dict, quick: bool) -> None:
    from vertebra.designer.nonlinear.fe_trunk import NonlinearTrunk, TrunkLoads

    rows = []
    rod = entries["rod-d6"]
    segment = _segment(rod)
    for label, count, forces, levels in (ROD_CASES[:2] if quick else ROD_CASES):
        fe, state = NonlinearTrunk([segment] * count), None
        length = count * ROD["length"]
        for level in levels:
            scaled = {k: level * np.array(f) for k, f in forces.items()}
            try:
                reference = fe.solve(TrunkLoads(forces=scaled), initial=state)
            except Exception as error:  # noqa: BLE001 - a failed reference ends the series, reported
                log(f"  {label} at ×{level}: FE failed ({type(error).__name__}: {str(error)[:100]})")
                break
            state = reference.state
            runs = _runtime(rod, count, scaled)
            row = {"case": label, "level": level, "fe_tip_angle_deg":
                   math.degrees(math.acos(np.clip(reference.rotations[-1][2, 2], -1, 1)))}
            for kind, (model, result) in runs.items():
                row[kind] = {"tip_error_pct": 100 * float(np.linalg.norm(result.state.positions[-1]
                                                                         - reference.positions[-1]) / length),
                             "converged": bool(result.converged), "out_of_range": len(result.out_of_range)}
            rows.append(row)
            log(f"  {label} ×{level} ({row['fe_tip_angle_deg']:.0f}°): nonlinear {row['nonlinear']['tip_error_pct']:.4f} %"
                f" (range {row['nonlinear']['out_of_range']}), linear {row['linear']['tip_error_pct']:.3f} %")
    results["accuracy_rods"] = rows

    cbha = entries["cbha-d6"]
    n = 4
    segment = _segment(cbha)
    fe, state = NonlinearTrunk([segment] * n), None
    length = n * CBHA["length"]
    rows = []
    for pressure in ((0.5e5, 1.0e5) if quick else (0.25e5, 0.5e5, 1.0e5, 1.5e5)):
        p = np.array([pressure, 0.0, 0.0])
        try:
            reference = fe.solve(TrunkLoads(pressures={i: p for i in range(n)}), initial=state)
        except Exception as error:  # noqa: BLE001
            log(f"  CBHA at {pressure:.3g} Pa: FE failed ({type(error).__name__}: {str(error)[:100]})")
            break
        state = reference.state
        angle = math.degrees(math.acos(np.clip(reference.rotations[-1][2, 2], -1, 1)))
        volume = float(sum(v[0] for v in reference.volume_growth))
        row = {"pressure": pressure, "fe_tip_angle_deg": angle, "fe_volume_growth": volume}
        for kind, (model, result) in _runtime(cbha, n, {}, pressure).items():
            growth = model.chamber_volume_growth(result.state, model.default_actuation[model.n_cables:])[0]
            row[kind] = {"tip_error_pct": 100 * float(np.linalg.norm(result.state.positions[-1]
                                                                     - reference.positions[-1]) / length),
                         "angle_error_pct": 100 * (tip_angle(result.state) / angle - 1),
                         "volume_error_pct": 100 * (growth / volume - 1), "converged": bool(result.converged),
                         "out_of_range": len(result.out_of_range)}
        rows.append(row)
        log(f"  CBHA {pressure:.3g} Pa ({angle:.1f}°): nonlinear tip {row['nonlinear']['tip_error_pct']:.3f} %, angle "
            f"{row['nonlinear']['angle_error_pct']:+.2f} %, volume {row['nonlinear']['volume_error_pct']:+.2f} %; "
            f"linear tip {row['linear']['tip_error_pct']:.2f} %")
    results["accuracy_cbha"] = rows
    results["entries"] = {name: {"dofs": int(e.mesh.get("dofs", 0)), "terms": int(e.energy.coefficients.size),
                                 "held_out": e.energy.fit_error.get("held_out", {})} for name, e in entries.items()}


# ------------------------------------------------------------------ output

def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer rounds and cases (a smoke run)")
    parser.add_argument("--sections", nargs="*", default=["speed", "accuracy"], choices=["speed", "accuracy"])
    parser.add_argument("--entries", type=Path, default=None, help="directory of the designed entries' catalogue")
    parser.add_argument("--out", type=Path, default=None, help="results directory (default benchmarks/results)")
    args = parser.parse_args(argv)
    directory = args.entries or Path(tempfile.mkdtemp(prefix="vertebra-runtime-nonlinear-"))
    directory.mkdir(parents=True, exist_ok=True)
    entries = {label: designed(label, directory) for label in ENTRIES}
    results = {"machine": {"host": platform.node(), "python": platform.python_version(),
                           "date": datetime.now(timezone.utc).replace(microsecond=0).isoformat()}}
    if "speed" in args.sections:
        log("speed")
        section_speed(results, entries, args.quick)
    if "accuracy" in args.sections:
        log("accuracy")
        section_accuracy(results, entries, args.quick)
    out = args.out or (Path(tempfile.gettempdir()) if args.quick else RESULTS)
    name = "runtime_nonlinear-quick" if args.quick else "runtime_nonlinear"
    render.write("runtime_nonlinear", results, out, stem=name)
    print(render.markdown("runtime_nonlinear", results))
    log(f"wrote {out / name}.md/.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
