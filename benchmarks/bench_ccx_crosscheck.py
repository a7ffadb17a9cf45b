"""Cross-check of the project's full-trunk nonlinear FE reference against CalculiX (NLGEOM).

Both codes solve the same discrete trunks: the same gmsh meshes (P2 tetrahedra, CalculiX C3D10),
the same material law (neo-Hooke in the Abaqus/CalculiX form, or St Venant–Kirchhoff), rigid
vertebrae tying the segments' end faces, dead loads, gravity and follower chamber pressures
(decks: ``benchmarks/ccx``; cases: ``benchmarks/nonlinear_cases.py``).

1. Linear regime: CalculiX without NLGEOM against the project's linear full-FE chain
   (``tests/reference/fe_chain.py``: ``chain_fe_solve``), for a tip wrench and a chamber pressure, once with the
   project's own quadrature and once with CalculiX's (4-point volume, 3-point face rules) — the
   latter is the same discrete problem, so it must agree to the 7 digits CalculiX prints.
2. Large deformation: every case of ``nonlinear_cases.CASES`` at each load level, CalculiX against
   ``designer.nonlinear.NonlinearTrunk``: tip position difference in % of trunk length, tip
   rotation difference, chamber volume growth difference, base reaction balance of the CalculiX
   run, the inflation limit point where one is met, and the run times.

CalculiX is a benchmark dependency only (``apt-get install calculix-ccx``); without ``ccx`` on the
PATH the benchmark says so and exits 0. CalculiX results are cached in
``benchmarks/results/ccx/`` (keyed by a hash of the deck), so a re-run only solves what changed;
``--cached`` never runs CalculiX (re-reports from the cache, a missing deck is an error). Writes ``benchmarks/results/ccx_crosscheck.json`` and ``.md``.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python -m benchmarks.bench_ccx_crosscheck [--cases A B] [--threads 2]
"""

from __future__ import annotations

import argparse
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
from benchmarks.common import log  # noqa: E402

from benchmarks.ccx.deck import Material  # noqa: E402
from benchmarks.ccx.run import Loading, ccx_available, ccx_version, rotation_matrix, solve  # noqa: E402
from benchmarks.ccx.trunk import stack  # noqa: E402
from benchmarks.nonlinear_cases import CASES, case_meshes, n_cavities, project_trunk, scaled_loads, trunk_loads  # noqa: E402




# ---------------------------------------------------------------------------------------------
# 1. linear regime
# ---------------------------------------------------------------------------------------------

LINEAR_SEGMENTS = [("rod", dict(radius=0.01, length=0.02), 0.005),
                   ("tube", dict(outer_radius=0.01, inner_radius=0.006, length=0.015), 0.004),
                   ("pneumatic", dict(outer_radius=0.012, chamber_radius=0.003, chamber_offset=0.0065,
                                      length=0.015, chambers=3), 0.004)]
LINEAR_E, LINEAR_NU = 1.0e6, 0.4
LINEAR_LOADS = {"tip wrench": (np.array([1e-3, -2e-3, 3e-3, 2e-5, 1e-5, -3e-5]), None),
                "chamber pressure": (np.zeros(6), {2: np.array([100.0, 0.0, 0.0])})}


def _matched_quadrature(fes, faces: bool = True) -> None:
    """Re-assemble the linear FE models with CalculiX's C3D10 rules: 4 points per tetrahedron and
    (``faces``) 3 per face for the cavity wall loads."""
    from skfem import Basis, ElementTetP2
    from skfem.models.elasticity import lame_parameters

    from vertebra.designer.fem import assemble_elasticity
    for fe in fes:
        fe.K = assemble_elasticity(Basis(fe.mesh, ElementTetP2(), intorder=2), *lame_parameters(LINEAR_E, LINEAR_NU))
        if faces:
            fe.cavity_loads = [s.with_degree(2).load(fe.node_dofs, fe.n_dofs) for s in fe.cavity_surfaces]


def _deformed_volumes(trunk, fes, meshes, frames, pressures) -> np.ndarray:
    """Exact deformed cavity volumes of the project's linear solution (same integral as for CalculiX)."""
    from benchmarks.ccx.volume import cavity_volume

    from vertebra.designer.fem import displacement_field
    x = trunk.nodes.copy()
    for s, fe in enumerate(fes):
        q_bottom = np.zeros(6) if s == 0 else frames[s - 1]
        p = None if pressures is None or s not in pressures else pressures[s]
        u = displacement_field(fe, frames[s], p, q_bottom=q_bottom)
        a, b = trunk.segment_node_ranges[s]
        x[a:b] += u[fe.node_dofs]
    return np.array([cavity_volume(x, c) for c in trunk.cavities])


def linear_check(threads: int, cached_only: bool = False) -> dict:
    from vertebra.designer import FAMILIES, canonical_parameters
    from vertebra.designer.fem import build_fe
    from vertebra.designer.geometry import mesh_segment
    from tests.reference.fe_chain import chain_fe_solve

    meshes, lengths, ncav, params = [], [], [], []
    for family, p, h in LINEAR_SEGMENTS:
        fam = FAMILIES[family]
        p = canonical_parameters(fam, dict(p, youngs_modulus=LINEAR_E, poisson_ratio=LINEAR_NU))
        meshes.append(mesh_segment(fam, p, h, 2))
        lengths.append(fam.length(p))
        ncav.append(fam.n_cavities(p))
        params.append(p)
    trunk = stack(meshes, lengths, ncav)
    materials = [Material("svk", LINEAR_E, LINEAR_NU)] * len(meshes)
    rest = np.array([c.rest_volume for c in trunk.cavities])
    out = {"segments": [f"{f} {p} h={h}" for f, p, h in LINEAR_SEGMENTS], "dofs": trunk.dofs,
           "young": LINEAR_E, "poisson": LINEAR_NU, "rows": []}
    ccx = {}
    for name, (wrench, pressures) in LINEAR_LOADS.items():
        m = len(meshes)
        loading = Loading(forces={m: wrench[:3]}, moments={m: wrench[3:]},
                          pressures={} if pressures is None else {(s, k): float(v[k]) for s, v in pressures.items()
                                                                  for k in range(len(v))})
        result = solve(trunk, materials, [loading], nlgeom=False, threads=threads, cached_only=cached_only)
        step = result["steps"]["1"]
        ccx[name] = (np.hstack([np.array(step["translation"])[1:], np.array(step["rotation"])[1:]]),
                     np.array(step.get("volumes", rest)) - rest, result["wall_s"])
    for quadrature in ("project", "calculix volume", "calculix"):
        fes = [build_fe(mesh, LINEAR_E, LINEAR_NU, 0.0, k, L) for mesh, k, L in zip(meshes, ncav, lengths)]
        if quadrature != "project":
            _matched_quadrature(fes, faces=quadrature == "calculix")
        for name, (wrench, pressures) in LINEAR_LOADS.items():
            if quadrature == "calculix volume" and pressures is None:
                continue
            plist = None if pressures is None else [pressures.get(s, np.zeros(k)) for s, k in enumerate(ncav)]
            full = chain_fe_solve(fes, wrench, plist)
            frames = full["frames"]
            c_frames, c_growth, wall = ccx[name]
            row = {"load": name, "quadrature": quadrature, "ccx_s": wall,
                   "translation_rel": float(np.linalg.norm(c_frames[:, :3] - frames[:, :3]) / np.linalg.norm(frames[:, :3])),
                   "rotation_rel": float(np.linalg.norm(c_frames[:, 3:] - frames[:, 3:]) / np.linalg.norm(frames[:, 3:]))}
            if pressures is not None:
                growth = _deformed_volumes(trunk, fes, meshes, frames, pressures) - rest
                k = int(np.argmax(np.abs(c_growth)))
                row["volume_growth_rel"] = float(abs(c_growth[k] - growth[k]) / abs(growth[k]))
            out["rows"].append(row)
            log(f"  linear, {name}, {quadrature} quadrature: translations {row['translation_rel']:.2e}, "
                f"rotations {row['rotation_rel']:.2e}"
                + (f", volume growth {row['volume_growth_rel']:.2e}" if "volume_growth_rel" in row else "")
                + " (relative)")
    return out


# ---------------------------------------------------------------------------------------------
# 2. large deformation
# ---------------------------------------------------------------------------------------------

def ccx_loadings(case) -> list:
    """CalculiX loads per level: the vertebra masses' weight is a dead force at each frame origin."""
    out = []
    for level in case.levels:
        L = scaled_loads(case, level)
        forces = {j: np.asarray(f, float) for j, f in L["forces"].items()}
        if L["gravity"] is not None and case.vertebra_mass:
            for j in range(1, case.n_segments + 1):
                forces[j] = forces.get(j, np.zeros(3)) + case.vertebra_mass * L["gravity"]
        pressures = {(s, k): float(p[k]) for s, p in L["pressures"].items() for k in range(len(p))}
        out.append(Loading(forces=forces, moments=L["moments"], pressures=pressures,
                           gravity=(0.0, 0.0, 0.0) if L["gravity"] is None else tuple(L["gravity"])))
    return out


def bend_angle(R: np.ndarray) -> float:
    """Angle between the vertebra's axis and the base axis, degrees."""
    return float(np.degrees(np.arccos(np.clip(R[2, 2], -1.0, 1.0))))


def rotation_angle(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(0.5 * (np.trace(R) - 1.0), -1.0, 1.0))))


def _volume_integrals(mesh, intorder: int) -> np.ndarray:
    """``∫ N_i dV`` for every node ``i`` of a P2 segment mesh (rest configuration), by the
    tetrahedron rule of degree ``intorder`` (2: CalculiX's 4-point C3D10 rule)."""
    from skfem import Basis, ElementTetP2, LinearForm, MeshTet2, asm
    basis = Basis(MeshTet2(np.ascontiguousarray(mesh.nodes.T), np.ascontiguousarray(mesh.tets.T)),
                  ElementTetP2(), intorder=intorder)
    per_dof = asm(LinearForm(lambda v, w: v), basis)
    out = np.zeros(mesh.nodes.shape[0])
    out[mesh.tets.T] = per_dof[basis.element_dofs]          # local order: corners, edges 01 12 02 03 13 23
    return out


def segment_masses(case) -> list:
    """Mass of each segment, kg: density times the exact volume of its curved P2 mesh (``det J``
    is cubic, integrated exactly)."""
    return [spec.p.get("density", 0.0) * float(_volume_integrals(mesh, 3).sum()) if spec.p.get("density") else 0.0
            for spec, mesh in zip(case.specs(), case_meshes(case))]


def base_mass_share(case) -> float:
    """Mass, kg, whose weight CalculiX's consistent body-force load puts on the nodes of the first
    segment's bottom face: nodes of the clamped base body, whose loads its reaction output leaves
    out. C3D10's 4-point rule on the rest mesh (gravity is a dead load)."""
    spec, mesh = case.specs()[0], case_meshes(case)[0]
    if not spec.p.get("density"):
        return 0.0
    return spec.p["density"] * float(_volume_integrals(mesh, 2)[np.unique(mesh.facets["bottom"])].sum())


def ccx_balance(case, trunk, loading, step) -> dict:
    """Base reactions of the CalculiX run against the loads on the free part of the trunk (relative
    to their size). CalculiX's reaction at the clamped base body leaves out the loads on that body's
    own nodes: the weight share of the first segment's bottom-face nodes is subtracted
    (:func:`base_mass_share`). Checked: the force balance always, the moment balance when no
    gravity acts (the weight's line of action would need the deformed mass distribution). Not
    checked when a chamber of the first segment is pressurised: the pressure on the base cap and
    the share of the wall pressure on the base rim's nodes land on the base body, and that share
    depends on the deformed walls, which the cached results do not keep."""
    if any(s == 0 and p != 0 for (s, _), p in loading.pressures.items()):
        return {"balance_kind": "not checked (pressurised chamber on the clamped base)"}
    positions = trunk.z[:, None] * np.array([0.0, 0.0, 1.0]) + np.array(step["translation"])
    applied = sum((np.asarray(f, float) for f in loading.forces.values()), np.zeros(3))
    moment = sum((np.cross(positions[j], np.asarray(f, float)) for j, f in loading.forces.items()), np.zeros(3))
    moment = moment + sum((np.asarray(M, float) for M in loading.moments.values()), np.zeros(3))
    g = np.asarray(loading.gravity, float)
    applied = applied + (sum(segment_masses(case)) - base_mass_share(case)) * g
    out = {"balance_kind": "relative"}
    for name, reaction, load in (("force", step["base_force"], applied), ("moment", step["base_rot_reaction"], moment)):
        if name == "moment" and np.any(g != 0):
            continue
        error, size = float(np.linalg.norm(np.asarray(reaction) + load)), float(np.linalg.norm(load))
        out[f"{name}_balance"] = error / size if size > 0 else error
        if size == 0:
            out[f"{name}_balance_kind"] = "absolute, N or N m (no net load)"
    return out


def reached_level(levels, k: int, fraction: float) -> float:
    """The load level reached when step ``k`` (0-based) stopped at ``fraction`` of its way."""
    previous = 0.0 if k == 0 else levels[k - 1]
    return float(previous + fraction * (levels[k] - previous))


def run_ccx(case, threads: int, symmetric_xz: bool = False, cached_only: bool = False) -> dict:
    specs = case.specs()
    trunk = stack(case_meshes(case), [s.p["length"] for s in specs], [n_cavities(s) for s in specs])
    materials = [Material(case.material, s.p["youngs_modulus"], s.p["poisson_ratio"], s.p.get("density", 0.0))
                 for s in specs]
    loadings = ccx_loadings(case)
    result = solve(trunk, materials, loadings, threads=threads, symmetric_xz=symmetric_xz, cached_only=cached_only)
    levels = {}
    rest = np.array([c.rest_volume for c in trunk.cavities])
    for k, level in enumerate(case.levels):
        step = result["steps"].get(str(k + 1))
        if step is None:
            continue
        positions = trunk.z[:, None] * np.array([0.0, 0.0, 1.0]) + np.array(step["translation"])
        entry = {"positions": positions, "rotation_vectors": np.array(step["rotation"]),
                 "rotations": np.array([rotation_matrix(w) for w in step["rotation"]])}
        if "volumes" in step:
            entry["volumes"] = {(c.segment, c.index): v for c, v in zip(trunk.cavities, step["volumes"])}
            entry["rest_volumes"] = {(c.segment, c.index): v for c, v in zip(trunk.cavities, rest)}
        entry["balance"] = ccx_balance(case, trunk, loadings[k], step)
        entry["moment_residual"] = result["moment_residual"].get(str(k + 1))
        levels[level] = entry
    limit = None
    if not result["finished"]:
        k = len(levels)
        limit = {"message": result["message"], "last_time": result["last_time"],
                 "reached_level": reached_level(case.levels, k, result["last_time"] - k) if k < len(case.levels)
                 else case.levels[-1]}
    return {"levels": levels, "dofs": trunk.dofs, "wall_s": sum(p["wall_s"] for p in result["passes"]),
            "passes": result["passes"], "limit": limit, "ccx": result.get("ccx")}


def run_project(case, quadrature: str = "project") -> dict:
    from vertebra.core.errors import ConvergenceError
    start = time.perf_counter()
    trunk = project_trunk(case, quadrature)
    build_s = time.perf_counter() - start
    levels, state, limit = {}, None, None
    for k, level in enumerate(case.levels):
        start = time.perf_counter()
        try:
            out = trunk.solve(trunk_loads(case, level), initial=state)
        except ConvergenceError as error:
            fraction = 0.0
            if error.result is not None and error.result[1].history:
                fraction = error.result[1].history[-1][0]
            limit = {"message": str(error), "reached_level": reached_level(case.levels, k, fraction)}
            log(f"    project: level {level} failed: {str(error)[:160]}")
            break
        state = out.state
        levels[level] = {"positions": out.positions, "rotations": out.rotations,
                         "volumes": {(s, i): v for s, vs in enumerate(out.volumes) for i, v in enumerate(vs)},
                         "solve_s": time.perf_counter() - start, "iterations": out.iterations,
                         "load_steps": out.load_steps}
    dofs = int(sum(s.n_dofs for s in trunk.segments)) + 6 * case.n_segments
    return {"levels": levels, "build_s": build_s, "dofs": dofs, "limit": limit}


def compare(case, ccx: dict, project: dict) -> list:
    rows = []
    L = case.length
    pressurised = {(s, k) for s, p in case.pressures.items() for k, v in enumerate(p) if v != 0}
    for level in case.levels:
        c, p = ccx["levels"].get(level), project["levels"].get(level)
        row = {"level": level}
        if c is not None:
            Rc = c["rotations"][-1]
            row.update(ccx_tip_bend_deg=bend_angle(Rc), ccx_tip_rotation_deg=rotation_angle(Rc),
                       ccx_tip_position_mm=(c["positions"][-1] * 1e3).tolist(), **c["balance"])
            if c["moment_residual"] is not None:
                row["ccx_moment_residual"] = c["moment_residual"]
        if c is not None and p is not None:
            dx = np.linalg.norm(c["positions"] - p["positions"], axis=1)
            Rp = p["rotations"][-1]
            row.update(tip_position_pct=100.0 * dx[-1] / L, max_vertebra_position_pct=100.0 * dx.max() / L,
                       tip_rotation_diff_deg=rotation_angle(Rc @ Rp.T),
                       tip_bend_diff_deg=bend_angle(Rc) - bend_angle(Rp),
                       project_solve_s=p["solve_s"], project_iterations=p["iterations"])
            if pressurised and "volumes" in c:
                diffs, growths = [], []
                for key in sorted(pressurised):
                    gc = c["volumes"][key] - c["rest_volumes"][key]
                    gp = p["volumes"][key] - c["rest_volumes"][key]
                    diffs.append(abs(gc - gp) / abs(gc))
                    growths.append(gc / c["rest_volumes"][key])
                row["volume_growth_rel_diff"] = float(max(diffs))
                row["ccx_volume_growth_of_rest"] = float(np.mean(growths))
        row["compared"] = c is not None and p is not None
        rows.append(row)
    return rows


MATCHED = ("rod4_planar_nh", "tube4_3d_nh", "cbha4_pneumatic_nh")


def run_case(case, threads: int, project: bool, matched: bool = False, cached_only: bool = False) -> dict:
    log(f"{case.name}: {case.description}")
    start = time.perf_counter()
    ccx = run_ccx(case, threads, cached_only=cached_only)
    log(f"  CalculiX: {ccx['dofs']} DoFs, {len(ccx['passes'])} pass(es), {ccx['wall_s']:.0f} s of ccx"
        + (f"; stopped at level {ccx['limit']['reached_level']:.4g}: {ccx['limit']['message'][:120]}"
           if ccx["limit"] else ""))
    proj = run_project(case) if project else {"levels": {}, "build_s": 0.0, "dofs": 0, "limit": None}
    rows = compare(case, ccx, proj)
    symmetric = None
    if case.symmetric_xz:
        sym = run_ccx(case, threads, symmetric_xz=True, cached_only=cached_only)
        log(f"  CalculiX on the symmetric path (vertebrae held in the xz-plane): {sym['wall_s']:.0f} s of ccx"
            + (f"; stopped at level {sym['limit']['reached_level']:.4g}: {sym['limit']['message'][:100]}"
               if sym["limit"] else ""))
        symmetric = {"rows": compare(case, sym, proj), "limit": sym["limit"], "wall_s": sym["wall_s"]}
        for row in symmetric["rows"]:
            if row["compared"]:
                log(f"    level {row['level']:g}: tip bend {row['ccx_tip_bend_deg']:.1f}°, tip Δ "
                    f"{row['tip_position_pct']:.4f} % L, rotation Δ {row['tip_rotation_diff_deg']:.4f}°"
                    + (f", volume growth Δ {100 * row['volume_growth_rel_diff']:.3f} %"
                       if "volume_growth_rel_diff" in row else ""))
    if project and matched:
        same = compare(case, ccx, run_project(case, "calculix"))
        for row, other in zip(rows, same):
            if other["compared"]:
                row["matched_tip_position_pct"] = other["tip_position_pct"]
                row["matched_tip_rotation_diff_deg"] = other["tip_rotation_diff_deg"]
    for row in rows:
        text = f"  level {row['level']:g}{case.level_unit and ' ' + case.level_unit}:"
        if "ccx_tip_bend_deg" in row:
            text += f" tip bend {row['ccx_tip_bend_deg']:.1f}°"
        if row["compared"]:
            text += (f", tip Δ {row['tip_position_pct']:.4f} % L, rotation Δ {row['tip_rotation_diff_deg']:.4f}°"
                     + (f", volume growth Δ {100 * row['volume_growth_rel_diff']:.3f} %"
                        if "volume_growth_rel_diff" in row else "")
                     + (f"; CalculiX's quadrature: tip Δ {row['matched_tip_position_pct']:.2e} % L, rotation Δ "
                        f"{row['matched_tip_rotation_diff_deg']:.1e}°" if "matched_tip_position_pct" in row else "")
                     + f" (project {row['project_solve_s']:.0f} s)")
        log(text)
    return {"name": case.name, "description": case.description, "material": case.material, "tags": list(case.tags),
            "segments": case.n_segments, "length_m": case.length, "level_unit": case.level_unit,
            "ccx": {"dofs": ccx["dofs"], "wall_s": ccx["wall_s"], "passes": ccx["passes"], "limit": ccx["limit"],
                    "version": ccx["ccx"]},
            "project": {"dofs": proj["dofs"], "build_s": proj["build_s"], "limit": proj["limit"],
                        "solve_s": sum(v["solve_s"] for v in proj["levels"].values())},
            "rows": rows, "symmetric": symmetric, "wall_s": time.perf_counter() - start,
            "ccx_levels": {str(k): {"positions": v["positions"].tolist(), "rotation_vectors": v["rotation_vectors"].tolist(),
                                    **({"volumes": [[list(key), val] for key, val in v["volumes"].items()]}
                                       if "volumes" in v else {})}
                           for k, v in ccx["levels"].items()}}

# ---------------------------------------------------------------------------------------------
# report
# ---------------------------------------------------------------------------------------------

def summarise(cases: list) -> list:
    rows = [r for c in cases for r in c["rows"] if r["compared"]]
    if not rows:
        return []
    out = [f"largest tip position difference {max(r['tip_position_pct'] for r in rows):.4f} % of trunk length "
           f"(any vertebra {max(r['max_vertebra_position_pct'] for r in rows):.4f} %), largest tip rotation "
           f"difference {max(r['tip_rotation_diff_deg'] for r in rows):.4f}° over {len(rows)} compared levels "
           f"(tip bends {min(r['ccx_tip_bend_deg'] for r in rows):.0f}–{max(r['ccx_tip_bend_deg'] for r in rows):.0f}°)"]
    vol = [r["volume_growth_rel_diff"] for r in rows if "volume_growth_rel_diff" in r]
    if vol:
        out.append(f"largest chamber volume growth difference {100 * max(vol):.3f} %")
    for c in cases:
        if c.get("symmetric") and c["symmetric"]["limit"]:
            out.append(f"{c['name']}: CalculiX on the symmetric path stopped at level "
                       f"{c['symmetric']['limit']['reached_level']:.4g}{(' ' + c['level_unit']) if c['level_unit'] else ''}")
        for who, name in (("ccx", "CalculiX"), ("project", "project")):
            if c[who]["limit"]:
                out.append(f"{c['name']}: {name} stopped at level {c[who]['limit']['reached_level']:.4g}"
                           f"{(' ' + c['level_unit']) if c['level_unit'] else ''}")
    return out


def _jsonable(value):
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="*", default=list(CASES), help="case names (default: all)")
    parser.add_argument("--threads", type=int, default=1, help="CalculiX threads (default 1)")
    parser.add_argument("--no-linear", action="store_true", help="skip the linear-regime check")
    parser.add_argument("--ccx-only", action="store_true", help="only run (or read cached) CalculiX results")
    parser.add_argument("--matched", nargs="*", default=list(MATCHED),
                        help="cases also solved by the project with CalculiX's volume quadrature")
    parser.add_argument("--cached", action="store_true",
                        help="CalculiX results from the cache only (a deck not in the cache is an error, CalculiX "
                             "never runs): re-reports the comparison after a change to the project or the report")
    args = parser.parse_args(argv)
    if not ccx_available():
        log("bench_ccx_crosscheck: skipped — CalculiX (`ccx`) is not on the PATH "
            "(install it with `apt-get install calculix-ccx`); nothing written.")
        return 0
    unknown = sorted(set(args.cases) - set(CASES))
    if unknown:
        parser.error(f"unknown case(s) {unknown}; known: {sorted(CASES)}")
    start = time.perf_counter()
    result = {"meta": {"date": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"), "host": socket.gethostname(),
                       "cpus": os.cpu_count(), "load_average": round(os.getloadavg()[0], 1),
                       "python": platform.python_version(), "ccx": ccx_version(), "threads": args.threads}}
    if not args.no_linear:
        log("linear regime")
        result["linear"] = linear_check(args.threads, args.cached)
    result["cases"] = [run_case(CASES[name], args.threads, not args.ccx_only, name in args.matched, args.cached)
                       for name in args.cases]
    result["summary"] = summarise(result["cases"])
    result["meta"]["total_s"] = time.perf_counter() - start
    for line in result["summary"]:
        log(line)
    log(f"total {result['meta']['total_s']:.0f} s")
    render.write("ccx_crosscheck", _jsonable(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
