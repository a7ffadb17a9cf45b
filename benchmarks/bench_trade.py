"""The speed–accuracy trade, measured: every knob's error against a reference and its cost.

References: the full nonlinear FE of the same trunk (``designer.nonlinear.fe_trunk.NonlinearTrunk``,
neo-Hookean, rigid vertebrae tying the segments' faces, on the entries' own meshes or on a finer
one) and closed forms (the planar elastica). Timings are CPU time of the calling thread
(``time.thread_time``, one BLAS thread), medians over rounds interleaved between the variants
compared (the machine is shared: only ratios within one run compare). Knobs (sections, each a
table in ``results/trade.md``, numbers in ``results/trade.json``, a panel in ``docs/trade-*.png``):

``mesh``       mesh size and element order (P1/P2) of a designed nonlinear rod entry: tip error of
               a two-segment soft rod trunk against the full nonlinear FE on a finer P2 mesh (and
               on the entry's own mesh), against the entry's design cost.
``fit``        fit degree and sampling density of ψ: read from ``results/nonlinear.json`` (written
               by ``bench_nonlinear.py``), not recomputed.
``links``      links per segment of analytic beams (a catalogue entry is one link by construction):
               tip error against the elastica and a fine discretisation, against solve time.
``entries``    linear vs nonlinear entries at increasing bending (planar and 3D rod trunks): tip
               error against the full nonlinear FE of the same meshes, against solve time.
``tolerance``  Newton tolerance: tip error against the tightest solve and the FE, against time.
``tick``       inverse in tick mode (one linearise–QP–step per target) vs converged mode along a
               circular trajectory of a pneumatic trunk: distance of the equilibrium reached from
               the target, against time per step.
``qp``         the inverse's QP tolerance and regularisation: target error against time per step.
``cbha``       four CBHA-like pneumatic slices (three chambers), 0–1.5 bar: forward (tip, bending
               angle, volume growth) and inverse (chamber pressures for a target tip position,
               then applied to the full nonlinear FE: the error a controller really gets), linear
               vs nonlinear entries.

Designed entries are kept in a catalogue and FE references in a JSON file, both under ``--cache``
(default ``tmp/cache`` of the repository) and keyed by content, so a rerun only re-times.

Run: ``make bench-trade`` or ``OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 .venv/bin/python
benchmarks/bench_trade.py [SECTION ...] [--quick] [--cache DIR]`` (``--quick``: fewer rounds and
cases, results into a temporary directory).
"""

from __future__ import annotations

import os

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import hashlib  # noqa: E402
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
from benchmarks.bench_runtime_nonlinear import linear_of  # noqa: E402
from benchmarks.common import DOCS, RESULTS, loadavg, log, timed  # noqa: E402
from vertebra import solver
from vertebra.core import lie  # noqa: E402
from vertebra.solver import analytic  # noqa: E402

HERE = Path(__file__).resolve().parent
CACHE = HERE.parent / "tmp" / "cache"
MATERIAL = "neo_hookean"
ROD = dict(radius=0.01, length=0.04, youngs_modulus=1e6, poisson_ratio=0.3)
CBHA = dict(outer_radius=0.04, chamber_radius=0.01, chamber_offset=0.0215, length=0.03, chambers=3,
            youngs_modulus=5e5, poisson_ratio=0.45)
CBHA_SAMPLING = {"degree": 6, "pressure": 1.5e5, "limit_fraction": 0.95}
BAR = 1e5


# ------------------------------------------------------------------ timing

def cpu_median(fn, repeats: int) -> float:
    """Median CPU time of the calling thread over ``repeats`` calls of ``fn``."""
    return timed(fn, repeats, warmup=0)[1]["thread_median_s"]


def interleaved(fns: dict, rounds: int, repeats: int) -> dict:
    """{name: median over ``rounds`` of the per-round median CPU time (s)}: the variants run in
    turn within each round, so a change of the machine's load hits all of them."""
    medians = {name: [] for name in fns}
    for _ in range(rounds):
        for name, fn in fns.items():
            medians[name].append(cpu_median(fn, repeats))
    return {name: float(np.median(values)) for name, values in medians.items()}


# ------------------------------------------------------------------ designed entries (cached)

@dataclasses.dataclass(frozen=True)
class Design:
    """One nonlinear catalogue entry to design: family, parameters, mesh and fit settings."""

    label: str
    family: str
    parameters: dict
    mesh_size: float
    order: int = 2
    sampling: dict | None = None

    def key(self) -> str:
        from vertebra import designer

        return designer.entry_key(self.family, self.parameters, mesh_size=self.mesh_size, order=self.order,
                                  material=MATERIAL, sampling=self.sampling)

    def solid(self):
        """The nonlinear FE segment on the entry's own mesh."""
        return fe_segment(self.family, self.parameters, self.mesh_size, self.order)


def designed(design: Design, cache: Path):
    """The entry of ``design``: read from the cache catalogue, or designed (2 local workers) and
    added to it. The design's cost is the entry's own ``timings``."""
    from vertebra import designer
    from vertebra.store import catalogue

    path = cache / "trade-entries.h5"
    key = design.key()
    if catalogue.has_entry(path, key):
        with catalogue.open_catalogue(path) as cat:
            return dataclasses.replace(cat.load(key), name=design.label)
    log(f"designing {design.label} ({design.family}, P{design.order}, mesh {design.mesh_size} m)")
    entry = designer.design_segment(design.family, design.parameters, mesh_size=design.mesh_size, order=design.order,
                                    material=MATERIAL, sampling=design.sampling, estimate_accuracy=False,
                                    executor="local", workers=2, name=design.label)
    log(f"  {entry.timings['total_s']:.0f} s, {entry.mesh.get('dofs')} DoFs, {entry.energy.coefficients.size} terms")
    catalogue.add_entry(path, entry)
    return entry


def design_cost(entry) -> dict:
    """Wall seconds of the entry's design: total and the linear condensation's share."""
    t = entry.timings
    nonlinear = sum(float(t.get(k, 0.0)) for k in ("sampling_s", "fit_s"))
    total = float(t["total_s"])
    return {"total_s": total, "linear_s": max(total - nonlinear, 0.0), "sampling_s": float(t.get("sampling_s", 0.0))}


# ------------------------------------------------------------------ full nonlinear FE references (cached)

_SOLIDS: dict = {}


def fe_segment(family: str, parameters: dict, mesh_size: float, order: int):
    """The nonlinear FE of one segment (built once per process)."""
    from vertebra.designer.nonlinear_condensation import FamilySolid
    from vertebra.designer.families import canonical_parameters, family_of

    spec = FamilySolid(family, json.dumps(canonical_parameters(family_of(family), parameters), sort_keys=True),
                       mesh_size, order, MATERIAL)
    if spec.key() not in _SOLIDS:
        _SOLIDS[spec.key()] = (spec, spec.build())
    return _SOLIDS[spec.key()]


class References:
    """Full nonlinear FE solutions of trunks, cached in ``path`` by content (segment models and
    loads); a series of increasing loads continues from the last solved state."""

    def __init__(self, path: Path):
        self.path = path
        self.data = json.loads(path.read_text()) if path.exists() else {}

    def solve(self, solid, count: int, *, forces=None, pressures=None, initial=None):
        """(record, state): tip position, rotation and chamber volume growth (summed over the
        segments) of ``count`` copies of ``solid`` under dead ``forces`` {vertebra: force} and
        ``pressures`` (per-cavity, the same in every segment); state is None when cached or failed."""
        from vertebra.designer.nonlinear.fe_trunk import NonlinearTrunk, TrunkLoads

        spec, segment = solid
        forces = {int(k): np.asarray(f, dtype=float) for k, f in (forces or {}).items()}
        payload = json.dumps([spec.key(), count, sorted((k, f.tolist()) for k, f in forces.items()),
                              None if pressures is None else np.asarray(pressures, dtype=float).tolist()])
        key = hashlib.sha256(payload.encode()).hexdigest()[:24]
        if key in self.data:
            return self.data[key], None
        loads = TrunkLoads(forces=forces, pressures={} if pressures is None else
                           {i: np.asarray(pressures, dtype=float) for i in range(count)})
        start = time.perf_counter()
        try:
            response = NonlinearTrunk([segment] * count).solve(loads, initial=initial)
        except Exception as error:  # noqa: BLE001 - a failed reference is recorded and reported, not raised
            record = {"failed": f"{type(error).__name__}: {str(error)[:160]}"}
            log(f"    FE failed: {record['failed']}")
            return record, None
        record = {"tip": response.positions[-1].tolist(), "rotation": response.rotations[-1].tolist(),
                  "volume_growth": np.sum([np.asarray(v) for v in response.volume_growth], axis=0).tolist()
                  if pressures is not None else [],
                  "seconds": time.perf_counter() - start, "dofs": int(segment.n_dofs) * count
                  if hasattr(segment, "n_dofs") else None}
        self.data[key] = record
        self.path.write_text(json.dumps(self.data))
        return record, response.state


def angle_of(rotation) -> float:
    """Tip rotation angle (°) of a 3×3 rotation: its angle from the base axis."""
    return math.degrees(math.acos(float(np.clip(np.asarray(rotation)[2, 2], -1.0, 1.0))))


def rotation_angle(quaternion) -> float:
    return math.degrees(float(np.linalg.norm(lie.qlog(quaternion))))


# ------------------------------------------------------------------ runtime trunks

def trunk(entry, count: int, *, forces=None, chambers: dict | None = None, max_pressure: float = 1.5 * BAR,
          target=None, tolerance: float = 1e-9):
    """A trunk of ``count`` repetitions of ``entry``: dead ``forces`` {vertebra: force}, chambers
    c0…c(n-1) (one per cavity, over the whole trunk) at ``chambers`` {index: pressure}, a tip
    effector (with ``target``) and the Newton ``tolerance``."""
    data = {"catalogue": {"path": "unused.h5"}, "solver": {"tolerance": tolerance},
            "segment": [{"type": "entry", "entry": entry.name, "count": count}],
            "load": [{"vertebra": int(k), "force": list(map(float, f))} for k, f in (forces or {}).items()],
            "effector": [{"name": "tip", "vertebra": -1} | ({"target": list(map(float, target))} if target is not None
                                                            else {})]}
    if entry.n_cavities:
        data["chamber"] = [{"name": f"c{k}", "cavity": k, "from": 1, "to": count,
                            "pressure": float((chambers or {}).get(k, 0.0)), "min_pressure": 0.0,
                            "max_pressure": max_pressure} for k in range(entry.n_cavities)]
    return solver.build_model(solver.parse_scene(data), {entry.name: entry})


def both(entry) -> dict:
    return {"nonlinear": entry, "linear": linear_of(entry)}


# ------------------------------------------------------------------ (a) mesh size and element order

MESH_DESIGNS = [Design(f"rod-P{order}-h{1e3 * h:g}", "rod", ROD, h, order, {"degree": 6})
                for order, h in ((2, 0.012), (2, 0.008), (2, 0.005), (2, 0.0035), (1, 0.006), (1, 0.004), (1, 0.003))]
MESH_REFERENCE = (0.0025, 2)           # mesh size, order of the fine reference FE
MESH_FORCES = (1.0, 2.5, 5.0)          # N along x at the tip of two segments: ~22°, 45°, 65°


def section_mesh(results, cache, refs, quick):
    designs = MESH_DESIGNS[1:2] + MESH_DESIGNS[4:5] if quick else MESH_DESIGNS
    forces = MESH_FORCES[1:2] if quick else MESH_FORCES
    count, length = 2, 2 * ROD["length"]
    fine = fe_segment("rod", ROD, *MESH_REFERENCE) if not quick else fe_segment("rod", ROD, 0.008, 2)
    reference, state = [], None
    for f in forces:
        record, state = refs.solve(fine, count, forces={count: [f, 0, 0]}, initial=state)
        reference.append(record)
        log(f"  fine FE at {f} N: {angle_of(record['rotation']):.1f}°")
    rows = []
    for design in designs:
        entry = designed(design, cache)
        own, state = [], None
        for f in forces:
            record, state = refs.solve(design.solid(), count, forces={count: [f, 0, 0]}, initial=state)
            own.append(record)
        row = {"label": design.label, "order": design.order, "mesh_size": design.mesh_size,
               "dofs": int(entry.mesh.get("dofs", 0)), "cost": design_cost(entry),
               "held_out_load_max": float(entry.energy.fit_error.get("held_out", {}).get("load_max", math.nan)),
               "levels": []}
        for f, ref, mine in zip(forces, reference, own):
            level = {"force": f, "fe_angle_deg": angle_of(ref["rotation"]),
                     "same_mesh_fe_pct": 100 * float(np.linalg.norm(np.subtract(mine["tip"], ref["tip"]))) / length}
            for kind, e in both(entry).items():
                result = trunk(e, count, forces={count: [f, 0, 0]}).solve(raise_on_failure=False)
                tip = result.state.positions[-1]
                level[kind] = {"tip_error_pct": 100 * float(np.linalg.norm(tip - ref["tip"])) / length,
                               "same_mesh_pct": 100 * float(np.linalg.norm(tip - mine["tip"])) / length,
                               "converged": bool(result.converged), "out_of_range": len(result.out_of_range)}
            row["levels"].append(level)
        rows.append(row)
        log(f"  {design.label}: {row['dofs']} DoFs, {row['cost']['total_s']:.0f} s; tip error vs fine FE "
            + ", ".join(f"{lv['fe_angle_deg']:.0f}°: {lv['nonlinear']['tip_error_pct']:.3f} %"
                        for lv in row["levels"]))
    results["mesh"] = {"rows": rows, "reference": {"mesh_size": MESH_REFERENCE[0], "order": MESH_REFERENCE[1],
                                                   "seconds": [r.get("seconds") for r in reference],
                                                   "dofs": reference[0].get("dofs")},
                       "segments": count, "reference_error": reference_error(rows, MESH_REFERENCE[0])}


def reference_error(rows, h_ref: float) -> dict | None:
    """How far the fine reference itself is from the mesh-converged answer, estimated from the
    P2 meshes' own-mesh FE tip distances to it at the largest load: with e(h) = c (h^q − h_ref^q),
    the reference's own error is c h_ref^q (Richardson with a fitted order q)."""
    from scipy.optimize import curve_fit

    p2 = [r for r in rows if r["order"] == 2]
    if len(p2) < 3:
        return None
    x = np.array([r["mesh_size"] for r in p2]) / h_ref
    e = np.array([r["levels"][-1]["same_mesh_fe_pct"] for r in p2])
    (c, q), _ = curve_fit(lambda x, c, q: c * (x ** q - 1.0), x, e, p0=(e.min(), 2.0))
    fitted = c * (x ** q - 1.0)
    return {"order": float(q), "reference_error_pct": float(c), "angle_deg": rows[0]["levels"][-1]["fe_angle_deg"],
            "fit_residual_pct": float(np.abs(fitted - e).max())}


# ------------------------------------------------------------------ (b) fit degree and sampling density

def section_fit(results, cache, refs, quick):
    path = RESULTS / "nonlinear.json"
    if not path.exists():
        log("  results/nonlinear.json absent: run bench_nonlinear.py rod first")
        return
    data = json.loads(path.read_text())
    rod = data.get("rod", {})
    cost = rod.get("cost", {})
    per_solve = cost["sampling_s"] / max(cost["solves"], 1)
    kernel = {int(r["case"].split()[-1]): r["energy_us"] for r in data.get("kernel", {}).get("rows", [])
              if r["case"].startswith("rod degree")}
    rows = []
    for s in rod.get("study", []):
        in_range = [t["fit"] for series in s["trunks"].values() for t in series if not t["left_range"]]
        every = [t["fit"] for series in s["trunks"].values() for t in series]
        rows.append({"degree": s["degree"], "paths": s["paths"], "samples": s["training_samples"],
                     "unknowns": s["unknowns"], "held_out_load_max": s["held_out"]["load_max"],
                     "sampling_s_estimate": per_solve * s["training_samples"],
                     "kernel_us": kernel.get(s["degree"]),
                     "tip_max_in_range_pct": 100 * max(in_range) if in_range else None,
                     "tip_max_pct": 100 * max(every),
                     "max_angle_in_range": max((t["angle_deg"] for series in s["trunks"].values() for t in series
                                                if not t["left_range"]), default=None),
                     "linear_max_in_range_pct": 100 * max(t["linear"] for series in s["trunks"].values()
                                                          for t in series if not t["left_range"])})
    results["fit"] = {"rows": rows, "source": "benchmarks/results/nonlinear.json", "date": data["machine"]["date"],
                      "dofs": cost.get("dofs"), "per_solve_s": per_solve, "workers": cost.get("workers")}


# ------------------------------------------------------------------ (c) links per segment (analytic beams)

SLENDER = dict(radius=0.002, length=0.04, count=4, youngs_modulus=1e6, poisson_ratio=0.3)
LINKS = (1, 2, 4, 8, 16)
LINKS_FINE = 64
LOAD_PARAMETERS = (1.0, 5.0, 10.0)


def beam_trunk(elements: int, load_parameter: float):
    s = SLENDER
    length = s["count"] * s["length"]
    ei = s["youngs_modulus"] * math.pi * s["radius"] ** 4 / 4
    data = {"segment": [{"type": "beam", "count": s["count"], "length": s["length"], "elements": elements,
                         "youngs_modulus": s["youngs_modulus"], "poisson_ratio": s["poisson_ratio"],
                         "section": {"shape": "circle", "radius": s["radius"]}}],
            "load": [{"vertebra": -1, "force": [load_parameter * ei / length ** 2, 0.0, 0.0]}],
            "effector": [{"name": "tip", "vertebra": -1}]}
    return solver.build_model(solver.parse_scene(data))


def section_links(results, cache, refs, quick):
    rounds, repeats = (3, 3) if quick else (9, 7)
    length = SLENDER["count"] * SLENDER["length"]
    rows = []
    for k in LOAD_PARAMETERS[:2] if quick else LOAD_PARAMETERS:
        exact = analytic.elastica_tip(k, length)
        fine = beam_trunk(LINKS_FINE, k).solve().state.positions[-1]
        models = {n: beam_trunk(n, k) for n in LINKS}
        times = interleaved({n: m.solve for n, m in models.items()}, rounds, repeats)
        for n, model in models.items():
            result = model.solve()
            tip = result.state.positions[-1]
            rows.append({"load_parameter": k, "links_per_segment": n, "links": n * SLENDER["count"],
                         "tip_angle_deg": rotation_angle(result.state.quaternions[-1]),
                         "elastica_pct": 100 * math.hypot(tip[0] - exact[0], tip[2] - exact[1]) / length,
                         "fine_pct": 100 * float(np.linalg.norm(tip - fine)) / length,
                         "solve_ms": 1e3 * times[n], "iterations": result.iterations})
        log(f"  PL²/EI = {k:g}: " + ", ".join(f"{r['links_per_segment']}: {r['fine_pct']:.2g} % "
                                              f"{r['solve_ms']:.2f} ms" for r in rows if r["load_parameter"] == k))
    results["links"] = {"rows": rows, "rod": SLENDER, "fine_links_per_segment": LINKS_FINE}


# ------------------------------------------------------------------ (d) linear vs nonlinear entries

ENTRY_DESIGN = MESH_DESIGNS[1]                    # P2, 8 mm: the rod entry of (d), (e)
BENDING = [
    # label, segments, forces at level 1 {vertebra: force}, levels
    ("4 rods, planar", 4, {4: [1.0, 0.0, 0.0]}, (0.12, 0.3, 0.6, 1.0, 1.6, 2.4, 3.6)),
    ("4 rods, 3D", 4, {3: [0.0, 0.8, 0.0], 4: [1.0, 0.0, -0.3]}, (0.12, 0.3, 0.6, 1.0, 1.5, 2.2)),
]


def section_entries(results, cache, refs, quick):
    rounds, repeats = (3, 3) if quick else (9, 5)
    entry = designed(ENTRY_DESIGN, cache)
    solid = ENTRY_DESIGN.solid()
    rows = []
    for label, count, forces, levels in (BENDING[:1] if quick else BENDING):
        length, state = count * ROD["length"], None
        for level in (levels[::2] if quick else levels):
            scaled = {k: level * np.asarray(f) for k, f in forces.items()}
            ref, state = refs.solve(solid, count, forces=scaled, initial=state)
            if "failed" in ref:
                break
            models = {kind: trunk(e, count, forces=scaled) for kind, e in both(entry).items()}
            times = interleaved({kind: m.solve for kind, m in models.items()}, rounds, repeats)
            row = {"case": label, "level": level, "fe_angle_deg": angle_of(ref["rotation"]),
                   "fe_seconds": ref.get("seconds")}
            for kind, model in models.items():
                result = model.solve(raise_on_failure=False)
                miss = float(np.linalg.norm(result.state.positions[-1] - ref["tip"]))
                row[kind] = {"tip_error_pct": 100 * miss / length,
                             "solve_ms": 1e3 * times[kind], "iterations": result.iterations,
                             "converged": bool(result.converged), "out_of_range": len(result.out_of_range)}
            rows.append(row)
            log(f"  {label} ×{level:g} ({row['fe_angle_deg']:.0f}°): "
                f"nonlinear {row['nonlinear']['tip_error_pct']:.4f} % "
                f"{row['nonlinear']['solve_ms']:.2f} ms, linear {row['linear']['tip_error_pct']:.3f} % "
                f"{row['linear']['solve_ms']:.2f} ms")
    results["entries"] = {"rows": rows, "entry": ENTRY_DESIGN.label, "dofs": int(entry.mesh.get("dofs", 0)),
                          "terms": int(entry.energy.coefficients.size)}


# ------------------------------------------------------------------ (e) Newton tolerance

TOLERANCES = (1e-2, 1e-3, 1e-4, 1e-6, 1e-8, 1e-10, 1e-12)


def section_tolerance(results, cache, refs, quick):
    rounds, repeats = (3, 3) if quick else (9, 5)
    entry = designed(ENTRY_DESIGN, cache)
    label, count, forces, levels = BENDING[1]
    level = levels[3]
    scaled = {k: level * np.asarray(f) for k, f in forces.items()}
    length = count * ROD["length"]
    ref, _ = refs.solve(ENTRY_DESIGN.solid(), count, forces=scaled)
    tightest = trunk(entry, count, forces=scaled, tolerance=1e-13).solve().state.positions[-1]
    models = {tol: trunk(entry, count, forces=scaled, tolerance=tol) for tol in TOLERANCES}
    times = interleaved({tol: m.solve for tol, m in models.items()}, rounds, repeats)
    rows = []
    for tol, model in models.items():
        result = model.solve(raise_on_failure=False)
        tip = result.state.positions[-1]
        rows.append({"tolerance": tol, "solve_ms": 1e3 * times[tol], "iterations": result.iterations,
                     "residual": float(result.residual), "converged": bool(result.converged),
                     "vs_tightest_pct": 100 * float(np.linalg.norm(tip - tightest)) / length,
                     "vs_fe_pct": 100 * float(np.linalg.norm(tip - ref["tip"])) / length})
        log(f"  tolerance {tol:g}: {rows[-1]['iterations']} it, {rows[-1]['solve_ms']:.2f} ms, "
            f"vs tightest {rows[-1]['vs_tightest_pct']:.2g} %, vs FE {rows[-1]['vs_fe_pct']:.3g} %")
    results["tolerance"] = {"rows": rows, "case": f"{label} ×{level:g}", "fe_angle_deg": angle_of(ref["rotation"])}


# ------------------------------------------------------------------ shared by (f), (g), (h): the CBHA entry

CBHA_DESIGN = Design("cbha-P2-h15", "pneumatic", CBHA, 0.015, 2, CBHA_SAMPLING)
TRACK_SLICES = 8
TRACK_CENTRE = {0: 0.6 * BAR, 1: 0.3 * BAR, 2: 0.3 * BAR}   # the pressures around whose tip the target circles
TRACK_RADIUS = 0.004


def circle(model, points: int):
    """(targets (points, 1, 3), state at the centre, actuation at the centre): a horizontal circle of
    TRACK_RADIUS starting at the tip reached under TRACK_CENTRE."""
    actuation = model.actuation({f"c{k}": p for k, p in TRACK_CENTRE.items()})
    result = model.solve(actuation)
    centre = model.effector_positions(result.state)[0]
    phase = np.linspace(0.0, 2.0 * math.pi, points + 1)[1:]
    targets = centre + TRACK_RADIUS * np.stack([1.0 - np.cos(phase), np.sin(phase), 0.0 * phase], 1)
    return targets[:, None, :], result.state, actuation


def run_inverse(model, settings, targets, state, actuation):
    """(CPU s per step, steps settled at their equilibrium): the timed run, then each step's
    commanded actuation solved to equilibrium (a tick's own state is a linear prediction)."""
    from vertebra.solver.inverse import InverseController

    controller = InverseController(model, settings, actuation=actuation.copy(), state=state)
    start = time.thread_time()
    steps = controller.track(targets)
    per_step = (time.thread_time() - start) / len(targets)
    return per_step, [controller.settled(step) for step in steps]


# ------------------------------------------------------------------ (f) tick vs converged

def section_tick(results, cache, refs, quick):
    from vertebra.solver.inverse import InverseSettings

    entry = designed(CBHA_DESIGN, cache)
    model = trunk(entry, TRACK_SLICES)
    rounds = 2 if quick else 5
    rows = []
    for points in ((25,) if quick else (25, 50, 100)):
        targets, state, actuation = circle(model, points)
        for mode in ("tick", "converged"):
            times, settled = [], None
            for _ in range(rounds):
                per_step, settled = run_inverse(model, InverseSettings(mode=mode), targets, state, actuation)
                times.append(per_step)
            errors = np.array([s.errors.max() for s in settled])
            failed = sum(bool(s.equilibrium_failure) for s in settled)
            rows.append({"mode": mode, "points_per_lap": points, "step_ms": 1e3 * float(np.median(times)),
                         "mean_error_mm": 1e3 * float(errors.mean()), "max_error_mm": 1e3 * float(errors.max()),
                         "target_step_mm": 1e3 * 2 * math.pi * TRACK_RADIUS / points, "unsettled": failed})
            log(f"  {mode}, {points} per lap: {rows[-1]['step_ms']:.2f} ms/step, error mean "
                f"{rows[-1]['mean_error_mm']:.4f} mm, max {rows[-1]['max_error_mm']:.4f} mm")
    results["tick"] = {"rows": rows, "slices": TRACK_SLICES, "radius_m": TRACK_RADIUS,
                       "centre_pressures": {f"c{k}": p for k, p in TRACK_CENTRE.items()}}


FLOOR_UM = 1e-6     # errors below this (µm) are drawn at it: log axes


def um(x_mm: float) -> float:
    return max(1e3 * x_mm, FLOOR_UM)


# ------------------------------------------------------------------ (g) QP tolerance and regularisation

REGULARISATIONS = (1e-10, 1e-8, 1e-6, 1e-4, 1e-2)          # with the exact backend (daqp)
QP_TOLERANCES = (1e-1, 1e-2, 1e-4, 1e-7, 1e-10)             # with the iterative backend (gauss-seidel)


def qp_variants(quick: bool) -> dict:
    """{(backend, regularisation, QP tolerance): settings factory}: the regularisation swept with
    the exact QP (it ignores the QP tolerance), the QP tolerance with the iterative Gauss–Seidel
    QP at the default regularisation."""
    from vertebra.solver.inverse.space import DEFAULT_REGULARISATION

    exact = [("daqp", r, 1e-10) for r in ((1e-8, 1e-2) if quick else REGULARISATIONS)]
    iterative = [("gauss-seidel", DEFAULT_REGULARISATION, q) for q in ((1e-2, 1e-10) if quick else QP_TOLERANCES)]
    return {v: v for v in exact + iterative}


def section_qp(results, cache, refs, quick):
    from vertebra.solver.inverse import InverseSettings

    entry = designed(CBHA_DESIGN, cache)
    model = trunk(entry, TRACK_SLICES)
    targets, state, actuation = circle(model, 8 if quick else 24)
    rows = []
    for mode in ("converged", "tick"):
        settings = {v: InverseSettings(mode=mode, backend=v[0], regularisation=v[1], qp_tolerance=v[2])
                    for v in qp_variants(quick)}
        times = {k: [] for k in settings}
        settled = {}
        for _ in range(2 if quick else 3):                      # interleaved rounds
            for k, s in settings.items():
                per_step, settled[k] = run_inverse(model, s, targets, state, actuation)
                times[k].append(per_step)
        for (backend, r, q) in settings:
            errors = np.array([s.errors.max() for s in settled[(backend, r, q)]])
            rows.append({"mode": mode, "backend": backend, "regularisation": r, "qp_tolerance": q,
                         "step_ms": 1e3 * float(np.median(times[(backend, r, q)])),
                         "mean_error_mm": 1e3 * float(errors.mean()), "max_error_mm": 1e3 * float(errors.max())})
        log(f"  {mode}: " + ", ".join(f"{r['backend']} {r['regularisation']:g}/{r['qp_tolerance']:g}: "
                                      f"{1e3 * r['max_error_mm']:.3g} µm {r['step_ms']:.2f} ms"
                                      for r in rows if r["mode"] == mode))
    results["qp"] = {"rows": rows, "targets": len(targets), "slices": TRACK_SLICES}


# ------------------------------------------------------------------ (h) CBHA-like section, forward and inverse

CBHA_SLICES = 4
CBHA_PRESSURES = (0.25, 0.5, 0.75, 1.0, 1.25, 1.5)            # bar, chamber 0
# chamber pressures (bar) under which the full FE's tip is an inverse target (reachable by construction)
CBHA_TARGETS = ((0.5, 0.0, 0.0), (0.8, 0.3, 0.0), (1.0, 0.4, 0.0), (1.2, 0.5, 0.8))


def section_cbha(results, cache, refs, quick):
    from vertebra.solver.inverse import InverseSettings, invert

    rounds, repeats = (3, 3) if quick else (9, 5)
    entry = designed(CBHA_DESIGN, cache)
    solid = CBHA_DESIGN.solid()
    n, length = CBHA_SLICES, CBHA_SLICES * CBHA["length"]
    forward, state = [], None
    for bar in (CBHA_PRESSURES[1::2] if quick else CBHA_PRESSURES):
        p = np.array([bar * BAR, 0.0, 0.0])
        ref, state = refs.solve(solid, n, pressures=p, initial=state)
        if "failed" in ref:
            forward.append({"pressure_bar": bar, "failed": ref["failed"]})
            break
        angle, volume = angle_of(ref["rotation"]), float(ref["volume_growth"][0])
        models = {kind: trunk(e, n, chambers={0: p[0]}) for kind, e in both(entry).items()}
        times = interleaved({kind: m.solve for kind, m in models.items()}, rounds, repeats)
        row = {"pressure_bar": bar, "fe_angle_deg": angle, "fe_volume_growth": volume, "fe_seconds": ref.get("seconds")}
        for kind, model in models.items():
            result = model.solve(raise_on_failure=False)
            growth = model.chamber_volume_growth(result.state, model.default_actuation[model.n_cables:])[0]
            row[kind] = {"tip_error_pct": 100 * float(np.linalg.norm(result.state.positions[-1] - ref["tip"])) / length,
                         "angle_error_pct": 100 * (rotation_angle(result.state.quaternions[-1]) / angle - 1),
                         "volume_error_pct": 100 * (growth / volume - 1), "solve_ms": 1e3 * times[kind],
                         "iterations": result.iterations, "converged": bool(result.converged),
                         "out_of_range": len(result.out_of_range)}
        forward.append(row)
        log(f"  {bar:g} bar ({angle:.1f}°): nonlinear tip {row['nonlinear']['tip_error_pct']:.3f} %, linear "
            f"{row['linear']['tip_error_pct']:.2f} %")
    inverse = []
    for pressures in (CBHA_TARGETS[:2] if quick else CBHA_TARGETS):
        p_true = BAR * np.asarray(pressures)
        target_ref, _ = refs.solve(solid, n, pressures=p_true)
        if "failed" in target_ref:
            inverse.append({"pressures_bar": list(pressures), "failed": target_ref["failed"]})
            continue
        target = np.asarray(target_ref["tip"])
        row = {"pressures_bar": list(pressures), "target": target.tolist(),
               "target_offset_pct": 100 * float(np.linalg.norm(target - [0.0, 0.0, length])) / length}
        for kind, e in both(entry).items():
            model = trunk(e, n, target=target)
            settings = InverseSettings(mode="converged", tolerance=1e-7)
            step = invert(model, **dataclasses.asdict(settings))
            times = [cpu_median(lambda: invert(model, **dataclasses.asdict(settings)), 1) for _ in range(repeats)]
            p = np.asarray(step.actuation[model.n_cables:], dtype=float)
            applied, _ = refs.solve(solid, n, pressures=p)
            achieved = ("failed" not in applied)
            row[kind] = {"pressures_bar": (p / BAR).tolist(),
                         "model_error_pct": 100 * float(step.errors.max()) / length,
                         "reached": bool(step.reached), "invert_ms": 1e3 * float(np.median(times)),
                         "out_of_range": len(step.out_of_range),
                         "fe_error_pct": 100 * float(np.linalg.norm(np.asarray(applied["tip"]) - target)) / length
                         if achieved else None, "fe_failed": None if achieved else applied["failed"]}
        inverse.append(row)
        log(f"  target from {pressures} bar: nonlinear → {np.round(row['nonlinear']['pressures_bar'], 3)} bar, FE "
            f"{row['nonlinear']['fe_error_pct']} %; linear → {np.round(row['linear']['pressures_bar'], 3)} bar, FE "
            f"{row['linear']['fe_error_pct']} %")
    results["cbha"] = {"forward": forward, "inverse": inverse, "slices": n, "entry": CBHA_DESIGN.label,
                       "dofs": int(entry.mesh.get("dofs", 0)), "terms": int(entry.energy.coefficients.size)}


# ------------------------------------------------------------------ output

SECTIONS = {
    "mesh": section_mesh,
    "fit": section_fit,
    "links": section_links,
    "entries": section_entries,
    "tolerance": section_tolerance,
    "tick": section_tick,
    "qp": section_qp,
    "cbha": section_cbha,
}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("sections", nargs="*", default=list(SECTIONS), help=f"any of {', '.join(SECTIONS)}")
    parser.add_argument("--quick", action="store_true", help="fewer cases and rounds (a smoke run)")
    parser.add_argument("--cache", type=Path, default=CACHE, help="designed entries and FE references (reused)")
    parser.add_argument("--out", type=Path, default=None, help="results directory (default benchmarks/results)")
    parser.add_argument("--docs", type=Path, default=None, help="pictures directory (default docs/)")
    args = parser.parse_args(argv)
    unknown = set(args.sections) - set(SECTIONS)
    if unknown:
        parser.error(f"unknown sections {sorted(unknown)}; choose from {', '.join(SECTIONS)}")
    from vertebra.designer.threads import pin_blas_threads

    pin_blas_threads(1)
    args.cache.mkdir(parents=True, exist_ok=True)
    refs = References(args.cache / ("trade-fe-quick.json" if args.quick else "trade-fe.json"))
    out = args.out or (Path(tempfile.mkdtemp(prefix="vertebra-trade-")) if args.quick else RESULTS)
    docs = args.docs or (out if args.quick else DOCS)
    name = "trade-quick" if args.quick else "trade"
    path = out / f"{name}.json"
    # sections run separately accumulate into one results file
    results = json.loads(path.read_text()) if path.exists() else {}
    load = [loadavg()[0]]
    for section in args.sections:
        log(section)
        start = time.perf_counter()
        SECTIONS[section](results, args.cache, refs, args.quick)
        if results.get(section) is not None:
            results[section]["wall_s"] = time.perf_counter() - start
        log(f"  {section}: {time.perf_counter() - start:.0f} s")
    load.append(loadavg()[0])
    results["machine"] = {"host": platform.node(), "python": platform.python_version(), "loadavg": load,
                          "date": datetime.now(timezone.utc).replace(microsecond=0).isoformat()}
    written = render.write("trade", results, out, stem=name, pictures_to=docs)
    log(f"wrote {', '.join(str(p) for p in written)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
