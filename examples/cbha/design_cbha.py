"""CBHA-like pneumatic trunk: design its 16 segment entries into a catalogue and write a scene.

Two tapered sections of three chambers, eight vertebrae per section (after Festo's
Compact Bionic Handling Assistant). The reusable part is ``designer.gallery.cbha_catalogue``;
this script only chooses paths, prints what it did and optionally solves the scene.

    python examples/cbha/design_cbha.py [--out cbha-output] [--fine] [--no-accuracy] [--simulate]

Coarse defaults take well under two minutes on one core (16 entries, ~4–5k DoFs each,
each with a refined-mesh accuracy estimate). Entries already in the catalogue are reused.
Then ``vertebra simulate cbha-output/cbha.toml`` runs the trunk.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="cbha-output", help="output directory (catalogue.h5, cbha.toml)")
    parser.add_argument("--fine", action="store_true", help="2/3 of the coarse mesh size (~3× the DoFs, slower)")
    parser.add_argument("--no-accuracy", action="store_true", help="skip the refined-mesh accuracy estimates")
    parser.add_argument("--pressure", type=float, default=1.0e5,
                        help="pressure of chamber s1c0 and s2c1 in the scene, Pa (0–1.5e5)")
    parser.add_argument("--simulate", action="store_true", help="solve the scene and print the tip position")
    args = parser.parse_args(argv)

    from vertebra.designer.gallery import cbha_catalogue
    from vertebra.solver.scene import scene_toml
    from vertebra.designer.threads import pin_blas_threads

    pin_blas_threads(1)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    result = cbha_catalogue(out / "catalogue.h5", coarse=not args.fine, estimate_accuracy=not args.no_accuracy,
                            progress=True,
                            scene_catalogue="catalogue.h5",
                            pressures={"s1c0": args.pressure, "s2c1": args.pressure})
    elapsed = time.perf_counter() - start
    print(f"{'entry':12} {'key':20} {'DoFs':>6} {'accuracy':>9} {'time s':>7}")
    for row in result["entries"]:
        accuracy = row.get("accuracy")
        print(f"{row['name']:12} {row['key']:20} {row.get('dofs', '-'):>6} "
              f"{'reused' if row['reused'] else (f'{accuracy:.3g}' if accuracy is not None else '-'):>9} "
              f"{row['total_s']:7.2f}")
    scene_path = out / "cbha.toml"
    scene_path.write_text(scene_toml(result["scene"], "CBHA-like pneumatic trunk, written by "
                                        "examples/cbha/design_cbha.py (designer.gallery.cbha_catalogue)"))
    print(f"catalogue {out / 'catalogue.h5'}, scene {scene_path}; designed in {elapsed:.1f} s")
    if args.simulate:
        from vertebra import solver
        model = solver.build_model(solver.load_scene(scene_path))
        res = model.solve()
        print(f"converged {res.converged} in {res.iterations} iterations; tip at "
              f"{model.effector_positions(res.state)[0].round(4).tolist()} m")
    return 0


if __name__ == "__main__":
    sys.exit(main())
