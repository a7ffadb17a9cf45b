"""Nonlinear entries prepared for a scene: is the scene's range better served than the default one?

``pressure``: four CBHA-like slices (R 40 mm, three chambers r 10 mm at 21.5 mm, L 30 mm,
E 0.5 MPa, ν 0.45, neo-Hookean, the family's default mesh) as design segments of a scene whose
one chamber is bounded at 1 bar. ``vertebra prepare``'s path (``designer.prepare``) samples the
entry's pressures up to that bound; the default entry samples up to 90 % of the inflation limit
point. Both are compared with the full nonlinear FE trunk of the same meshes (rigid vertebrae,
follower pressure) at 0.25 / 0.5 / 1.0 bar — tip error in % of trunk length, tip angle and
chamber volume growth relative errors — and their held-out fit errors and costs are reported.
The chains are evaluated with ``tests/reference/energy_chain.py`` (the runtime's independent yardstick).

``twist``: the coarse twisted-rod scene of ``tests/test_prepare_ranges.py`` with the default
sampling density: the runtime with the prepared entry and with the default-range entry at the
actuation corners (out-of-range reports).

Results: benchmarks/results/prepare_ranges.json and .md (the machine is shared: load recorded).

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.bench_prepare_ranges [SECTION ...]
"""

from __future__ import annotations

import os

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from datetime import datetime, timezone  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks import render  # noqa: E402
from benchmarks.common import RESULTS, loadavg, log  # noqa: E402

CBHA = dict(outer_radius=0.04, chamber_radius=0.01, chamber_offset=0.0215, length=0.03, chambers=3,
            youngs_modulus=5e5, poisson_ratio=0.45)
SLICES = 4
BOUND = 1.0e5                     # Pa: the scene's chamber bound
LEVELS = (0.25e5, 0.5e5, 1.0e5)
WORKERS = 2



def pneumatic_scene(catalogue: str) -> dict:
    return {"name": "four CBHA-like slices", "catalogue": {"path": catalogue},
            "segment": [{"type": "design", "family": "pneumatic", "parameters": CBHA, "material": "neo_hookean",
                         "count": SLICES}],
            "chamber": [{"name": "a", "cavity": 0, "from": 1, "to": SLICES, "max_pressure": BOUND}],
            "effector": [{"name": "tip"}]}


def _trunk_errors(entry, references) -> list[dict]:
    from tests.reference.energy_chain import EntryEnergy, solve_chain

    rows = []
    length = SLICES * CBHA["length"]
    for p, ref in references:
        pressures = [np.array([p, 0.0, 0.0])] * SLICES
        chain = solve_chain([EntryEnergy(entry)] * SLICES, [], pressures=pressures, steps=4)
        angle = math.degrees(math.acos(np.clip(chain.tip_rotation[2, 2], -1, 1)))
        rows.append({"pressure": p, "tip": float(np.linalg.norm(chain.tip_position - ref["position"]) / length),
                     "angle": angle / ref["angle_deg"] - 1,
                     "volume": float(sum(v[0] for v in chain.volume_growth)) / ref["volume_growth"] - 1,
                     "left_range": bool(chain.left_range)})
    return rows


def section_pressure(results: dict) -> None:
    from vertebra import designer, solver
    from vertebra.designer.nonlinear.fe_trunk import NonlinearTrunk, TrunkLoads
    from vertebra.designer.nonlinear_condensation import FamilySolid

    out = {"loadavg": loadavg()[0], "slices": SLICES, "bound": BOUND}
    with tempfile.TemporaryDirectory() as tmp:
        scene = solver.parse_scene(pneumatic_scene(str(Path(tmp) / "cbha.h5")), base_dir=tmp)
        start = time.perf_counter()
        resolved, report = designer.prepare(scene, build_model=solver.build_model, executor="local",
                                            workers=WORKERS, estimate_accuracy=False, progress=True)
        out["prepared_s"] = time.perf_counter() - start
        assert report.exit_code == 0, report.summary()
        log(report.summary())
        out["prepared_settings"] = report.segments[0].sampling.to_json()
        from vertebra.store import catalogue
        with catalogue.open_catalogue(resolved.catalogue) as cat:
            prepared = cat.load(resolved.segments[0].entry)
    log("default-range entry (pressures up to 90 % of the inflation limit point)")
    start = time.perf_counter()
    default = designer.design_segment("pneumatic", CBHA, material="neo_hookean", estimate_accuracy=False,
                                      executor="local", workers=WORKERS, progress=lambda m: log(f"  {m}"))
    out["default_s"] = time.perf_counter() - start
    p = designer.canonical_parameters("pneumatic", CBHA)
    segment = FamilySolid("pneumatic", json.dumps(p, sort_keys=True), prepared.mesh["mesh_size"], 2,
                          "neo_hookean").build()
    trunk, state, references = NonlinearTrunk([segment] * SLICES), None, []
    start = time.perf_counter()
    for level in LEVELS:
        ref = trunk.solve(TrunkLoads(pressures={i: np.array([level, 0.0, 0.0]) for i in range(SLICES)}),
                          initial=state)
        state = ref.state
        references.append((level, {"position": ref.positions[-1],
                                   "angle_deg": math.degrees(math.acos(np.clip(ref.rotations[-1][2, 2], -1, 1))),
                                   "volume_growth": float(sum(v[0] for v in ref.volume_growth))}))
        log(f"  reference at {level:.3g} Pa: {references[-1][1]['angle_deg']:.2f}°")
    out["reference_s"] = time.perf_counter() - start
    out["dofs"] = prepared.mesh["dofs"]
    for name, entry in (("prepared", prepared), ("default", default)):
        energy = entry.energy
        out[name] = {"key": entry.key, "pressure_upper": energy.range.pressure_upper.tolist(),
                     "limit_pressure": energy.range.limit_pressure, "fold_pressure": energy.fold_pressure,
                     "held_out": energy.fit_error["held_out"], "solves": energy.sampling["solves"],
                     "sampling_s": entry.timings.get("sampling_s"), "rows": _trunk_errors(entry, references)}
        log(f"  {name}: {out[name]['rows']}")
    results["pressure"] = out


def section_twist(results: dict) -> None:
    from vertebra import designer, solver
    from vertebra.designer.scene_range import actuation_box, actuation_corners

    rod = {"radius": 0.01, "length": 0.04, "youngs_modulus": 1e6, "poisson_ratio": 0.3}
    segment = {"type": "design", "family": "rod", "parameters": rod, "mesh_size": 0.008, "material": "neo_hookean"}
    out = {"loadavg": loadavg()[0]}
    with tempfile.TemporaryDirectory() as tmp:
        data = {"name": "twisted rods", "catalogue": {"path": str(Path(tmp) / "rods.h5")},
                "segment": [segment, segment],
                "cable": [{"name": "pull", "radius": 0.008, "to": 2, "max_tension": 6.0}],
                "load": [{"vertebra": -1, "moment": [0.0, 0.0, 0.1]}], "effector": [{"name": "tip"}]}
        start = time.perf_counter()
        resolved, report = designer.prepare(solver.parse_scene(data, base_dir=tmp), build_model=solver.build_model,
                                            executor="serial", estimate_accuracy=False, progress=False)
        out["prepared_s"] = time.perf_counter() - start
        log(report.summary())
        out["settings"] = report.segments[0].sampling.to_json()
        start = time.perf_counter()
        default = designer.design_segment("rod", rod, mesh_size=0.008, material="neo_hookean", estimate_accuracy=False)
        out["default_s"] = time.perf_counter() - start
        models = {"prepared": solver.build_model(resolved),
                  "default": solver.build_model(resolved, {s.entry: default for s in resolved.segments})}
        lower, upper = actuation_box(models["prepared"])
        for name, model in models.items():
            rows = []
            for actuation in np.vstack([model.default_actuation[None], actuation_corners(lower, upper)]):
                result = model.solve(actuation)
                rows.append({"actuation": actuation.tolist(), "converged": bool(result.converged),
                             "out_of_range": sorted({f"{x.quantity} {x.value:.4g} > {x.upper:.4g}"
                                                     for x in result.out_of_range})})
            out[name] = rows
    results["twist"] = out


SECTIONS = {"twist": section_twist, "pressure": section_pressure}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sections", nargs="*", help=f"any of {', '.join(SECTIONS)} (default: all)")
    args = parser.parse_args(argv)
    unknown = sorted(set(args.sections) - set(SECTIONS))
    if unknown:
        parser.error(f"unknown section {unknown[0]!r} (known: {', '.join(SECTIONS)})")
    path = RESULTS / "prepare_ranges.json"
    results = json.loads(path.read_text()) if path.exists() else {}
    for name in args.sections or SECTIONS:
        log(f"== {name}")
        SECTIONS[name](results)
        results["machine"] = {"host": platform.node(), "python": platform.python_version(),
                              "date": datetime.now(timezone.utc).replace(microsecond=0).isoformat()}
        render.write("prepare_ranges", results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
