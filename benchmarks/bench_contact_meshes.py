"""Contact with real triangle meshes (docs/contact.md, "Meshes"): fine convex meshes against the
analytic shapes they approximate, non-convex meshes touched near their concave and convex edges,
and a mesh read from an STL file.

    python -m benchmarks.bench_contact_meshes [--repeat 1]

* a tendon robot (8 vertebrae with 8 mm discs, one cable) bending onto an icosphere mesh of 1,280
  and of 5,120 triangles and onto the analytic sphere of the same radius (the equilibria should
  agree to the faceting error: the mesh lies inside the sphere by at most ``R(1 − cos θ)``);
* a cantilever with a capsule radius (5 mm) pushed onto the same spheres;
* a rod's 20 mm tip disc pushed onto an L-block (non-convex) near its concave edge and onto its
  convex edge, and into a U-channel's inner corner;
* the 5,120-triangle icosphere written as a binary STL file with meshio and read as ``path``.

Per case: time, iterations, converged, the fuzz's checks (benchmarks.bench_contact_fuzz.check_state),
the tip's position and, for meshes with an analytic twin, the distance between the equilibria.
Writes benchmarks/results/contact_meshes.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from vertebra import solver
from vertebra.designer.threads import pin_blas_threads

ROOT = Path(__file__).resolve().parent


sys.path.insert(0, str(ROOT.parent / "tests"))
from meshes import icosphere, l_block, mesh_obstacle, rod_scene, tendon_scene, u_channel  # noqa: E402


def cases(stl_dir: Path) -> list:
    """(name, scene, twin name or None) of every case."""
    out = []
    # tendon robot onto a sphere of radius 30 mm beside its bent shape
    R = 0.03
    centre = [0.045 + R, 0.01, 0.12]           # off the bending plane: no bifurcation
    sphere = {"type": "sphere", "center": centre, "radius": R}
    out.append(("tendon/sphere", tendon_scene(sphere), None))
    for s in (3, 4):
        v, t = icosphere(R, centre, s)
        out.append((f"tendon/icosphere-{t.shape[0]}", tendon_scene(mesh_obstacle(v, t)), "tendon/sphere"))
    # capsule cantilever onto a sphere at 0.6 of its length
    centre_c = [0.005 + 0.004 + R, 0.0, 0.18]
    out.append(("capsule/sphere", rod_scene({"type": "sphere", "center": centre_c, "radius": R},
                                            contact_radius=0.005), None))
    for s in (3, 4):
        v, t = icosphere(R, centre_c, s)
        out.append((f"capsule/icosphere-{t.shape[0]}", rod_scene(mesh_obstacle(v, t), contact_radius=0.005),
                    "capsule/sphere"))
    # the tip disc (20 mm) near an L-block's concave edge: the foot's top at z0 = 0.29 (1 cm below
    # the tip), the wall 4 mm beyond the rim
    v, t = l_block(x0=-0.05, z0=0.3 - 0.003, step=0.02 + 0.004 + 0.05, size=0.04, depth=0.08)
    out.append(("disc/L-concave", rod_scene(mesh_obstacle(v, t), disc=0.02), None))
    # … and onto its convex edge (the foot's corner 5 mm beyond the rim, at the tip's height)
    v, t = l_block(x0=0.025, z0=0.3 + 0.001, step=0.03, size=0.04, depth=0.08)
    out.append(("disc/L-convex", rod_scene(mesh_obstacle(v, t), disc=0.02), None))
    # into a U-channel round the disc (the floor 5 mm beyond the rim, the walls 2 mm above and below
    # its faces): the disc tilts as the rod bends, its rim into the inner corners
    v, t = u_channel(x0=0.025, z0=0.3, width=0.006, wall=0.01, size=0.06, depth=0.08)
    out.append(("disc/U-channel", rod_scene(mesh_obstacle(v, t), disc=0.02), None))
    # an STL file written with meshio (binary), read as ``path``
    import meshio

    v, t = icosphere(R, centre, 4)
    path = stl_dir / "icosphere.stl"
    meshio.write(str(path), meshio.Mesh(v, [("triangle", t)]), binary=True)
    out.append(("tendon/stl-5120", tendon_scene({"type": "mesh", "path": str(path)}), "tendon/sphere"))
    return out


def run(name, scene, base_dir) -> dict:
    from benchmarks.bench_contact_fuzz import check_state

    model = solver.build_model(solver.parse_scene(scene, base_dir=base_dir))
    start = time.perf_counter()
    result = model.solve(raise_on_failure=False)
    seconds = time.perf_counter() - start
    row = {"case": name, "seconds": seconds, "iterations": int(result.iterations), "converged": bool(result.converged),
           "tip": result.state.positions[-1].tolist(), "positions": result.state.positions.tolist(),
           "pressed": sum(c.force > 0 for c in result.contacts),
           "residuals": [float(r) for r in result.residual_history][-6:]}
    if result.converged:
        problems, balance = check_state(model, result, None)
        row.update(problems=problems, balance=balance)
    else:
        row["message"] = result.message[:300]
    return row


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(ROOT / "results" / "contact_meshes.json"))
    parser.add_argument("--only", default="")
    args = parser.parse_args(argv)
    pin_blas_threads()          # one BLAS thread: threaded BLAS on the small solves is 40x slower on a busy machine
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, scene, twin in cases(Path(tmp)):
            if args.only and args.only not in name:
                continue
            row = run(name, scene, tmp)
            if twin:
                other = next((r for r in rows if r["case"] == twin), None)
                if other is not None:
                    row["vs_" + twin] = float(np.abs(np.array(row["positions"]) - np.array(other["positions"])).max())
            rows.append(row)
            print(f"{name:24s} {row['seconds']:7.3f} s {row['iterations']:4d} it  converged={row['converged']}"
                  f"  pressed={row['pressed']}  problems={row.get('problems')}"
                  + (f"  vs twin {row['vs_' + twin]:.3g} m" if twin and 'vs_' + twin in row else "")
                  + f"  tip={np.round(row['tip'], 5).tolist()}", flush=True)
    for r in rows:
        r.pop("positions")
    Path(args.out).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
