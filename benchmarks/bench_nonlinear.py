"""Nonlinear condensation benchmark: what a fitted energy ψ(s, p) costs and how close it gets.

Sections (all by default; name some to run only those):

``kernel``
    Runtime cost of a link's share of a Newton iteration for 20 links: the quadratic links'
    force and tangent against ``core.energy.EnergyModel.evaluate`` plus the same tangent
    algebra (rod degree 4/6/8, CBHA-like slice with 3 chambers), in interleaved rounds
    (median of ratios; the machine is shared).
``rod``
    One neo-Hookean rod entry (R 10 mm, L 40 mm, E 1 MPa, ν 0.3) at ~10k DoFs with the default
    sampling on the local pool of 2 workers: cost per entry. Then the fit study on its samples:
    degree 4/6/8 × number of loading paths, each fit's held-out error and the tip error of
    trunks of 2 and 4 segments (planar and 3D loads, up to ~90°) against the full nonlinear FE
    of the same trunk (designer.nonlinear.fe_trunk.NonlinearTrunk, same mesh), linear entries
    for comparison.
``family``
    A squat neo-Hookean rod (length/radius 1, four segments), an ``svk`` rod (length/radius 4)
    and a neo-Hookean tube (ν 0.45), default sampling and mesh: held-out errors and trunk tip
    errors (fit vs linear) with tip forces up to 0.9 of the range's bending bound at the base.
``pneumatic``
    Four CBHA-like slices (R 40 mm, 3 chambers r 10 mm at 21.5 mm, L 30 mm, E 0.5 MPa,
    ν 0.45), one chamber pressurised 0.25–1.5 bar: tip position (% of length), tip angle and
    chamber volume growth (relative) of the fitted and the linear entries against the full
    nonlinear trunk.

Writes benchmarks/results/nonlinear.json and .md and docs/nonlinear-fit-error-vs-cost.png.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python -m benchmarks.bench_nonlinear [SECTION ...] [--quick]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import platform
import socket
import sys
import time
from datetime import datetime, timezone

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np  # noqa: E402

from benchmarks import render  # noqa: E402
from benchmarks.common import RESULTS, log  # noqa: E402

ROD = dict(radius=0.01, length=0.04, youngs_modulus=1e6, poisson_ratio=0.3)
CBHA = dict(outer_radius=0.04, chamber_radius=0.01, chamber_offset=0.0215, length=0.03, chambers=3,
            youngs_modulus=5e5, poisson_ratio=0.45)



def _load_results() -> dict:
    path = RESULTS / "nonlinear.json"
    return json.loads(path.read_text()) if path.exists() else {}


def _save(results: dict) -> None:
    results["machine"] = {"host": socket.gethostname(), "python": platform.python_version(),
                          "date": datetime.now(timezone.utc).replace(microsecond=0).isoformat()}
    render.write("nonlinear", results, draw=False)


# ------------------------------------------------------------------ building blocks

def condensed(family, parameters, material, *, mesh_size=None, sampling=None, workers=2):
    """A linear entry and its condensed energy (with the samples, for the fit study)."""
    from vertebra import designer
    from vertebra.designer.energy_sampling import SamplingSettings
    from vertebra.designer.nonlinear_condensation import FamilySolid, condense_energy, material_constants

    fam = designer.FAMILIES[family]
    p = fam.canonical(parameters)
    start = time.perf_counter()
    entry = designer.design_segment(family, p, mesh_size=mesh_size, estimate_accuracy=False)
    linear_s = time.perf_counter() - start
    spec = FamilySolid(family, json.dumps(p, sort_keys=True), entry.mesh["mesh_size"], 2, material)
    result = condense_energy(entry, spec, radius=fam.outer_radius(p), youngs_modulus=p["youngs_modulus"],
                             symmetry=fam.symmetry(p), material=material_constants(material, p),
                             settings=SamplingSettings.from_dict(sampling), executor="local", workers=workers,
                             progress=lambda m: log(f"  {m}"))
    return dataclasses.replace(entry, energy=result.energy), result, spec, linear_s


def refit(entry, result, symmetry, *, degree, paths=None, pressure_degree=None, hessian_weight=0.3):
    """The entry with its energy refitted from a subset of the samples (the first ``paths``
    Halton paths and every box axis; the held-out paths stay held out)."""
    from vertebra.designer.energy_fit import fit_energy, fit_errors, symmetry_group
    from vertebra.core.energy import EnergyFit, linear_terms

    samples, held = result.samples, result.held_out
    n_axes = 5 + (2 if entry.n_cavities > 1 else entry.n_cavities)
    if paths is not None:
        keep = (samples.path < n_axes + paths) | held
        samples, held = samples.take(keep), held[keep]
    linear = linear_terms(entry.compliance, entry.rest_translation)
    energy = result.energy
    m = entry.n_cavities
    start = time.perf_counter()
    fit = fit_energy(samples, linear, degree=degree, pressure_degree=(pressure_degree or degree) if m else 0,
                     group=symmetry_group(symmetry, degree), scales=energy.scales, held_out=held,
                     hessian_weight=hessian_weight, fold=energy.fold_pressure)
    fit_s = time.perf_counter() - start
    volume_scale = float(np.abs(samples.pressure_gradient).max()) if m else None
    errors = fit_errors(fit, linear, samples.take(held), energy.range.load_upper, volume_scale)
    new = EnergyFit(exponents=fit.exponents, coefficients=fit.coefficients, scales=fit.scales, range=energy.range,
                    fit_error={"held_out": errors}, material=energy.material, sampling=energy.sampling,
                    fold_pressure=energy.fold_pressure)
    return dataclasses.replace(entry, energy=new), errors, fit_s, int(samples.size - held.sum()), fit.unknowns


LOAD_KINDS = {
    # planar: a dead tip force across the axis; 3d: forces on the last two vertebrae in perpendicular
    # directions (bending out of any one plane, twisting the trunk) with an axial component
    "planar": lambda n: {n: np.array([1.0, 0.0, 0.0])},
    "3d": lambda n: {n - 1: np.array([0.0, 0.8, 0.0]), n: np.array([1.0, 0.0, -0.3])},
}


def trunk_cases(segment, entry, n, kind, levels, *, reference_cache):
    """Full nonlinear FE trunk solutions of ``n`` segments at increasing load levels (continuation)."""
    from vertebra.designer.nonlinear.fe_trunk import NonlinearTrunk, TrunkLoads

    key = (n, kind)
    if key in reference_cache:
        return reference_cache[key]
    trunk = NonlinearTrunk([segment] * n)
    state, out = None, []
    for level in levels:
        forces = {k: level * f for k, f in LOAD_KINDS[kind](n).items()}
        start = time.perf_counter()
        try:
            response = trunk.solve(TrunkLoads(forces=forces), initial=state)
        except Exception as error:  # noqa: BLE001 - a failed reference ends the series, reported
            log(f"    trunk {n}×{kind} at {level:.3g} N: {type(error).__name__}: {str(error)[:120]}")
            break
        state = response.state
        out.append({"level": level, "forces": forces, "tip": response.positions[-1],
                    "angle": math.degrees(math.acos(np.clip(response.rotations[-1][2, 2], -1, 1))),
                    "seconds": time.perf_counter() - start})
    reference_cache[key] = out
    return out


def chain_errors(entry, cases, n):
    """Tip errors (fraction of the trunk length) of the fitted and the linear entry on ``cases``."""
    from tests.reference.energy_chain import EntryEnergy, PointLoad, solve_chain

    length = n * float(entry.rest_translation[2])
    rows = []
    for case in cases:
        loads = [PointLoad(k, tuple(f)) for k, f in case["forces"].items()]
        row = {"angle_deg": case["angle"], "level": case["level"]}
        for name, linear_only in (("fit", False), ("linear", True)):
            try:
                chain = solve_chain([EntryEnergy(entry, linear_only=linear_only)] * n, loads, steps=4)
                row[name] = float(np.linalg.norm(chain.tip_position - case["tip"]) / length)
                if not linear_only:
                    row["left_range"] = bool(chain.left_range)
            except Exception as error:  # noqa: BLE001
                row[name] = None
                log(f"    chain ({name}) failed: {error}")
        rows.append(row)
    return rows


# ------------------------------------------------------------------ sections

def section_kernel(results, quick):
    from vertebra.designer.energy_fit import invariant_basis, symmetry_group
    from vertebra.designer.families import AXISYMMETRIC, FAMILIES
    from vertebra.core.lie import qexp
    from vertebra.solver.links import Links, link_tangent
    from vertebra.core.energy import EnergyFit, EnergyModel, EnergyRange

    rng = np.random.default_rng(0)
    n = 20
    K = np.diag([2e3, 2e3, 8e3, 0.2, 0.2, 0.15])
    qa, qb = qexp(rng.normal(size=(n, 3)) * 0.1), qexp(rng.normal(size=(n, 3)) * 0.1)
    xa = rng.normal(size=(n, 3))
    links = Links.of(qa, xa, qb, xa + [0, 0, 0.04])
    stiffness = np.repeat(K[None], n, 0)
    rest = np.tile([0, 0, 0.04, 0, 0, 0.0], (n, 1))

    def linear():                       # a quadratic link's share of a Newton iteration
        w = ((links.xi - rest)[:, None, :] @ stiffness)[:, 0]
        link_tangent(links, w, stiffness, links.gradient(w))

    cases = []
    for label, symmetry, m, degree in (("rod degree 4", AXISYMMETRIC, 0, 4), ("rod degree 6", AXISYMMETRIC, 0, 6),
                                       ("rod degree 8", AXISYMMETRIC, 0, 8),
                                       ("3 chambers degree 6, pressure 4", None, 3, (6, 4)),
                                       ("3 chambers degree 6, pressure 6", None, 3, (6, 6))):
        if symmetry is None:
            symmetry = FAMILIES["pneumatic"].symmetry(FAMILIES["pneumatic"].canonical(CBHA))
        d, dp = degree if isinstance(degree, tuple) else (degree, degree)
        scales = np.array([0.004, 0.004, 0.002, 0.8, 0.8, 0.4] + [1.5e5] * m)
        exponents, basis = invariant_basis(6 + m, m, d, dp, symmetry_group(symmetry, d), scales)
        coefficients = basis @ rng.normal(size=basis.shape[1])
        wide, low = np.full(4, 1e300), np.array([0.0, -1e300, 0.0, -1e300])
        fit = EnergyFit(exponents, coefficients, scales, EnergyRange(low, wide, low, wide, np.zeros(m),
                                                                     np.full(m, 1.5e5)))
        model = EnergyModel(fit, K, np.full((6, m), 1e-8), np.eye(m) * 1e-11)
        p = np.abs(rng.normal(size=(n, m))) * 5e4
        def nonlinear():                # the same with ψ: the kernel, then the same frame algebra
            values = model.evaluate(links.xi - rest, p)
            link_tangent(links, values.gradient, values.hessian, links.gradient(values.gradient))

        ratios, times = [], []
        for _ in range(5 if quick else 15):
            t0 = time.perf_counter()
            for _ in range(50):
                linear()
            t1 = time.perf_counter()
            for _ in range(50):
                nonlinear()
            t2 = time.perf_counter()
            ratios.append((t2 - t1) / (t1 - t0))
            times.append(((t1 - t0) / 50 * 1e6, (t2 - t1) / 50 * 1e6))
        lin_us, nl_us = np.median(np.array(times), axis=0)
        cases.append({"case": label, "terms": int(exponents.shape[0]), "unknowns": int(basis.shape[1]),
                      "monomials": int(model.n_monomials), "linear_us": float(lin_us), "energy_us": float(nl_us),
                      "ratio": float(np.median(ratios))})
        log(f"kernel {label}: {nl_us:.0f} µs vs quadratic links {lin_us:.0f} µs (×{np.median(ratios):.2f})")
    results["kernel"] = {"links": n, "rows": cases}


def section_rod(results, quick):
    from vertebra.designer.families import AXISYMMETRIC

    mesh = 0.0035 if not quick else 0.006
    log(f"rod: neo-Hookean entry, mesh {mesh}")
    start = time.perf_counter()
    entry, result, spec, linear_s = condensed("rod", ROD, "neo_hookean", mesh_size=mesh)
    total = time.perf_counter() - start
    cost = {"dofs": entry.mesh["dofs"], "linear_entry_s": linear_s, "sampling_s": result.timings["sampling_s"],
            "fit_s": result.timings["fit_s"], "total_s": total, "solves": entry.energy.sampling["solves"],
            "samples": entry.energy.sampling["samples"], "workers": 2,
            "held_out": entry.energy.fit_error["held_out"]}
    log(f"rod cost: {cost}")
    segment = spec.build()
    cache: dict = {}
    levels = {2: [1.0, 2.5, 5.0, 9.0], 4: [0.5, 1.2, 2.5, 4.5]}
    study = []
    for degree in (4, 6, 8):
        for paths in ((6, 12, 18) if not quick else (18,)):
            fitted, errors, fit_s, training, unknowns = refit(entry, result, AXISYMMETRIC, degree=degree, paths=paths)
            row = {"degree": degree, "paths": paths, "training_samples": training, "unknowns": unknowns,
                   "fit_s": fit_s, "held_out": errors, "trunks": {}}
            for n in (2, 4):
                for kind in ("planar", "3d"):
                    cases = trunk_cases(segment, entry, n, kind, levels[n], reference_cache=cache)
                    row["trunks"][f"{n}x{kind}"] = chain_errors(fitted, cases, n)
            study.append(row)
            worst = max((r["fit"] or 1) for t in row["trunks"].values() for r in t)
            log(f"rod degree {degree}, {paths} paths: held-out load {errors['load_max']:.3g}, worst tip {worst:.2e}")
    results["rod"] = {"cost": cost, "study": study,
                      "references": {f"{n}x{k}": [{"angle_deg": c["angle"], "seconds": c["seconds"]} for c in v]
                                     for (n, k), v in cache.items()}}


def section_family(results, quick):
    from vertebra import designer

    cases = [("rod", dict(ROD, length=0.01), "neo_hookean"), ("rod", ROD, "svk"),
             ("tube", dict(outer_radius=0.01, inner_radius=0.005, length=0.02, youngs_modulus=1e6,
                           poisson_ratio=0.45), "neo_hookean")]
    if quick:
        cases = cases[:1]
    rows = []
    for family, parameters, material in cases:
        log(f"family: {family} {parameters} {material}")
        entry, result, spec, _ = condensed(family, parameters, material)
        segment = spec.build()
        length = parameters["length"]
        radius = designer.FAMILIES[family].outer_radius(designer.FAMILIES[family].canonical(parameters))
        n = 4 if length / radius < 2 else 2
        # force scale: a tip force whose moment at the base segment is the fitted range's bending bound
        force = float(entry.energy.range.load_upper[2]) / (n * length)
        cache: dict = {}
        row = {"family": family, "parameters": parameters, "material": material, "dofs": entry.mesh["dofs"],
               "segments": n, "held_out": entry.energy.fit_error["held_out"],
               "sampling_s": result.timings["sampling_s"], "trunks": {}}
        for kind in ("planar", "3d"):
            refs = trunk_cases(segment, entry, n, kind, [force * f for f in (0.3, 0.6, 0.9)],
                               reference_cache=cache)
            row["trunks"][kind] = chain_errors(entry, refs, n)
        rows.append(row)
        log(f"  {json.dumps(row['trunks'])[:400]}")
    results["family"] = rows


def section_pneumatic(results, quick):
    from tests.reference.energy_chain import EntryEnergy, solve_chain
    from vertebra.designer.nonlinear.fe_trunk import NonlinearTrunk, TrunkLoads

    log("pneumatic: CBHA-like slice")
    entry, result, spec, linear_s = condensed("pneumatic", CBHA, "neo_hookean",
                                              sampling={"pressure": 1.5e5, "limit_fraction": 0.95})
    segment = spec.build()
    n = 4
    trunk = NonlinearTrunk([segment] * n)
    state, rows = None, []
    length = n * CBHA["length"]
    for p in (0.25e5, 0.5e5, 1.0e5, 1.5e5):
        pressures = [np.array([p, 0.0, 0.0])] * n
        try:
            ref = trunk.solve(TrunkLoads(pressures={i: pressures[i] for i in range(n)}), initial=state)
        except Exception as error:  # noqa: BLE001
            log(f"  trunk at {p:.3g} Pa: {error}")
            break
        state = ref.state
        angle = math.degrees(math.acos(np.clip(ref.rotations[-1][2, 2], -1, 1)))
        volume = float(sum(v[0] for v in ref.volume_growth))
        row = {"pressure": p, "angle_deg": angle, "volume_growth": volume}
        for name, linear_only in (("fit", False), ("linear", True)):
            chain = solve_chain([EntryEnergy(entry, linear_only=linear_only)] * n, [], pressures=pressures, steps=4)
            chain_angle = math.degrees(math.acos(np.clip(chain.tip_rotation[2, 2], -1, 1)))
            row[name] = {"tip": float(np.linalg.norm(chain.tip_position - ref.positions[-1]) / length),
                         "angle": chain_angle / angle - 1,
                         "volume": float(sum(v[0] for v in chain.volume_growth)) / volume - 1}
            if not linear_only:
                row[name]["left_range"] = bool(chain.left_range)
        rows.append(row)
        log(f"  {p:.3g} Pa: {row}")
    energy = entry.energy
    results["pneumatic"] = {"dofs": entry.mesh["dofs"], "held_out": energy.fit_error["held_out"],
                            "unknowns": energy.fit_error["unknowns"], "terms": int(energy.coefficients.size),
                            "sampling_s": result.timings["sampling_s"], "solves": energy.sampling["solves"],
                            "limit_pressure": energy.range.limit_pressure, "fold_pressure": energy.fold_pressure,
                            "pressure_upper": energy.range.pressure_upper.tolist(), "rows": rows}


# ------------------------------------------------------------------ report

SECTIONS = {"kernel": section_kernel, "rod": section_rod, "family": section_family, "pneumatic": section_pneumatic}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("sections", nargs="*", metavar="SECTION", help=f"any of {', '.join(SECTIONS)} (default all)")
    parser.add_argument("--quick", action="store_true", help="coarse meshes and fewer cases")
    args = parser.parse_args(argv)
    unknown = [name for name in args.sections if name not in SECTIONS]
    if unknown:
        parser.error(f"unknown section {unknown[0]!r} (known: {', '.join(SECTIONS)})")
    from vertebra.designer.threads import pin_blas_threads
    pin_blas_threads(1)
    results = _load_results()
    for name in args.sections or list(SECTIONS):
        start = time.perf_counter()
        SECTIONS[name](results, args.quick)
        log(f"section {name}: {time.perf_counter() - start:.0f} s")
        _save(results)
    render.pictures("nonlinear", results)
    print(render.markdown("nonlinear", results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
