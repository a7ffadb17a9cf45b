"""``vertebra design FAMILY [--set NAME=VALUE ...] [--mesh-size H] [--order 1|2] [--material M] --catalogue FILE``

Mesh, solve and condense one segment into the catalogue. If the
content key is already in the catalogue the entry is reused, not recomputed.
``--material svk|neo_hookean`` also samples the segment's nonlinear response and fits its
energy (``--sampling NAME=VALUE`` settings; the FE solves run on ``--executor``, by default a
local process pool with one worker per core).
``vertebra design vertebra --set radius=.. --set thickness=.. --set density=..``
prints a rigid vertebra's mass properties as a scene snippet (no catalogue).
Progress and logs go to stderr; ``--json`` prints one JSON document on stdout.
"""

from __future__ import annotations

import math
import os
import sys
import time

from vertebra.cli.documents import print_document
from vertebra.cli.main import main as vertebra
from vertebra.cli.nonlinear_mesh import nonlinear_mesh_lines
from vertebra.cli.outputs import output_file
from vertebra.core import plausibility
from vertebra.core.errors import OptionError

MESH_SUFFIXES = (".vtu", ".vtk")


def add_arguments(parser) -> None:
    parser.add_argument("family", metavar="FAMILY",
                        help="rod | tube | bellows | pneumatic | tapered_pneumatic | vertebra")
    parser.add_argument("--set", dest="values", action="append", default=[], metavar="NAME=VALUE",
                        help="a design parameter (repeatable), e.g. --set radius=0.01")
    parser.add_argument("--mesh-size", type=float, default=None, metavar="H", help="target element size, m")
    parser.add_argument("--order", type=int, choices=(1, 2), default=2, help="element order (default 2)")
    parser.add_argument("--catalogue", metavar="FILE", help="HDF5 catalogue to add the entry to")
    parser.add_argument("--name", default=None, help="entry name (default FAMILY-<key prefix>)")
    parser.add_argument("--export-mesh", metavar="FILE.vtu", default=None, help="also write the mesh (.vtu or .vtk)")
    parser.add_argument("--json", action="store_true", help="print the entry as JSON on stdout")
    parser.add_argument("--no-accuracy", action="store_true",
                        help="skip the accuracy estimate (a coarser mesh; order 2 on the same mesh for order 1)")
    parser.add_argument("--linear-solver", choices=("auto", "direct", "amg"), default="auto")
    parser.add_argument("--max-elements", type=int, default=None, metavar="N",
                        help="refuse meshes estimated above N tetrahedra before meshing "
                             "(default 300,000: ~6.5 GB for second-order assembly)")
    parser.add_argument("--material", default="linear", metavar="linear|svk|neo_hookean",
                        help="constitutive model (default linear: the linear condensation alone)")
    parser.add_argument("--sampling", dest="sampling", action="append", default=[], metavar="NAME=VALUE",
                        help="a nonlinear sampling/fit setting (repeatable), e.g. --sampling degree=8")
    parser.add_argument("--pressurised", default=None, metavar="none|all|I,J,...",
                        help="cavities a nonlinear entry is sampled under pressure in (default all): 'none' skips "
                             "the inflation-limit search and fits ψ at zero pressure (sampling.cavities)")
    parser.add_argument("--nonlinear-mesh-size", type=float, default=None, metavar="H",
                        help="multi-fidelity: sample and fit the energy's nonlinear part on this coarser mesh "
                             "(m), keep this mesh's exact linear part and check the entry on it "
                             "(sampling.nonlinear_mesh_size; sampling.check_paths paths, default 2)")
    parser.add_argument("--executor", default="local", help="where nonlinear FE solves run: serial | local | dask")
    parser.add_argument("--workers", type=int, default=None, help="worker processes (default: one per core)")
    parser.add_argument("--scheduler", default=None, help="dask scheduler address (with --executor dask)")


def parse_values(values: list[str]) -> dict:
    """``NAME=VALUE`` strings to a dict of numbers (OptionError names the bad one)."""
    out = {}
    for item in values:
        name, sep, text = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise OptionError(f"expected NAME=VALUE, got {item!r}", field="--set")
        text = text.strip()
        try:
            value = int(text)
        except ValueError:
            try:
                value = float(text)
            except ValueError:
                raise OptionError(f"parameter {name!r}: not a number: {text!r}", field="--set") from None
        out[name] = value
    return out


def parse_pressurised(text: str) -> list | None:
    """``--pressurised``: ``all`` (None), ``none`` ([]) or comma-separated cavity indices."""
    lowered = text.strip().lower()
    if lowered == "all":
        return None
    if lowered == "none":
        return []
    try:
        cavities = [int(part) for part in lowered.split(",")]
    except ValueError:
        raise OptionError(f"expected none, all or cavity indices like 0,2; got {text!r}", field="--pressurised") from None
    if any(c < 0 for c in cavities):
        raise OptionError(f"cavity indices are ≥ 0; got {text!r}", field="--pressurised")
    return cavities


def parse_sampling(values: list[str]) -> dict:
    """``--sampling NAME=VALUE`` strings to settings (numbers, true/false, none)."""
    out = {}
    for item in values:
        name, sep, text = item.partition("=")
        name, text = name.strip(), text.strip()
        if not sep or not name:
            raise OptionError(f"{item!r}: expected NAME=VALUE", field="--sampling")
        lowered = text.lower()
        if lowered in ("true", "false"):
            out[name] = lowered == "true"
        elif lowered == "none":
            out[name] = None
        else:
            try:
                out[name] = int(text)
            except ValueError:
                try:
                    out[name] = float(text)
                except ValueError:
                    raise OptionError(f"{name}: not a number: {text!r}", field="--sampling") from None
    return out


def entry_document(entry) -> dict:
    """The JSON document (docs/json.md) of ``vertebra design --json`` (with ``material``, and for a
    nonlinear entry an ``energy`` summary: degree, terms, fit error, range, sampling, timings)."""
    document = {"key": entry.key, "name": entry.name, "compliance": entry.compliance.tolist(),
                "cavity_volumes": entry.cavity_volumes.tolist(), "mass": entry.mass,
                "dofs": int(entry.mesh.get("dofs", 0)), "accuracy": dict(entry.accuracy),
                "material": "linear" if entry.energy is None else entry.energy.material.get("model"),
                "timing": {k: float(entry.timings.get(k, 0.0)) for k in ("mesh_s", "assemble_s", "solve_s", "total_s")}}
    if entry.energy is not None:
        energy = entry.energy
        document["energy"] = {"degree": energy.degree, "terms": int(energy.coefficients.size),
                              "fit_error": energy.fit_error, "range": energy.range.to_dict(),
                              "fold_pressure": energy.fold_pressure, "material": energy.material,
                              "sampling": {k: energy.sampling[k] for k in ("samples", "solves", "paths",
                                                                           "held_out_paths", "nonlinear_mesh",
                                                                           "entry_mesh_check", "nonlinear_mesh_fallback")
                                           if k in energy.sampling},
                              "sampled": sampled_range(energy)}
        document["timing"].update({k: float(entry.timings[k]) for k in ("sampling_s", "fit_s", "nonlinear_mesh_s",
                                                                         "check_s", "ramp_s", "fallback_s")
                                  if k in entry.timings})
        warning = fit_warning(energy)
        if warning:
            document["energy"]["warnings"] = [warning]
    return document


#: held-out load error (a fraction of the load range) above which ``design`` says the fit does
#: not follow the material within its box: the designer's ``energy_fit.FIT_LIMIT``, above which
#: ``vertebra prepare`` refuses the entry where a scene needs it (not imported: the parser loads
#: every command's module, the designer only for the command that runs)
FIT_WARNING = 0.05


def fit_warning(energy) -> str | None:
    """What to say when a nonlinear entry's energy fit misses its held-out samples by more than
    :data:`FIT_WARNING` of the load range (None otherwise)."""
    held = energy.fit_error.get("held_out", {}) if isinstance(energy.fit_error, dict) else {}
    error = held.get("load_max")
    if error is None or not error > FIT_WARNING:
        return None
    model = energy.material.get("model") if isinstance(energy.material, dict) else None
    why = (" St Venant–Kirchhoff softens towards a compressive limit point inside this box, which the "
           "polynomial does not follow;" if model == "svk" else "")
    return (f"the energy fit misses its held-out samples by up to {error:.3g} of the load range (rms "
            f"{held.get('load_rms', float('nan')):.3g}): states inside the range carry errors of that order;{why} "
            f"narrow the sampled box (--sampling strain=…, bending=…), raise the degree, or choose another "
            f"material model (neo_hookean); `vertebra prepare` refuses this entry for a scene that goes where "
            f"the error exceeds {FIT_WARNING:g} (--max-fit-error overrides)")


def sampled_range(energy) -> dict:
    """The range a nonlinear entry was sampled on, in physical terms (per segment: bending and
    twist in degrees, lateral and axial displacement of the strain chart in mm; the loads it
    carried in N and N·m; pressures in bar), what bounded the bending, and how to widen it."""
    rng = energy.range
    degrees, mm = 180.0 / math.pi, 1e3
    settings = energy.sampling.get("settings", {})
    caps = energy.sampling.get("pose_caps")
    out = {"bending_deg": degrees * float(rng.pose_upper[2]),
           "twist_deg": [degrees * float(rng.pose_lower[3]), degrees * float(rng.pose_upper[3])],
           "lateral_mm": mm * float(rng.pose_upper[0]),
           "axial_mm": [mm * float(rng.pose_lower[1]), mm * float(rng.pose_upper[1])],
           "lateral_force_N": float(rng.load_upper[0]), "axial_force_N": [float(rng.load_lower[1]),
                                                                         float(rng.load_upper[1])],
           "bending_moment_Nm": float(rng.load_upper[2]),
           "twist_moment_Nm": [float(rng.load_lower[3]), float(rng.load_upper[3])],
           "pressure_bar": [1e-5 * float(p) for p in rng.pressure_upper]}
    bending = settings.get("bending")
    if caps is not None and bending is not None:
        by_strain = float(caps[2]) < float(bending) * (1.0 - 1e-9)
        out["bending_bounded_by"] = "strain" if by_strain else "bending"
        widen = ("the outer-fibre strain bounds the bending (strain = "
                 f"{settings.get('strain')}, bending ≤ strain·L/r): raise --sampling strain=…" if by_strain else
                 f"the bending setting bounds it (bending = {bending} rad): raise --sampling bending=… (rad, < π)")
        out["widen"] = (f"{widen} (and --sampling twist=… for twist), or let `vertebra prepare` size the range from "
                        "a scene's loads; beyond the range the entry continues on its linear stiffness with the "
                        "fitted correction's boundary force, and a solve reports the states outside it")
    return out


def _log(message: str) -> None:
    print(f"vertebra design: {message}", file=sys.stderr, flush=True)


def _print_json(document) -> None:
    print_document(document)


def _run_vertebra(args, values) -> int:
    # lazy: the parser imports every subcommand module; the libraries load for the command that runs
    from vertebra.designer.vertebra import vertebra_properties, vertebra_snippet

    props = vertebra_properties(values)
    if args.json:
        _print_json({k: props[k] for k in ("mass", "center_of_mass", "inertia", "thickness", "holes", "parameters")})
    else:
        print(vertebra_snippet(props))
    return 0


def run(args) -> int:
    # lazy: the parser imports every subcommand module; the libraries load for the command that runs
    from vertebra import designer
    from vertebra.designer.geometry import export_mesh

    values = parse_values(args.values)
    if args.family == "vertebra":
        return _run_vertebra(args, values)
    if args.catalogue is None:
        raise OptionError("required to design a segment", field="--catalogue")
    output_file(args.catalogue, "--catalogue", None)           # refused before meshing, not after
    output_file(args.export_mesh, "--export-mesh", MESH_SUFFIXES)
    family = designer.FAMILIES.get(args.family)
    if family is None:
        raise OptionError(f"unknown family {args.family!r} (known: {', '.join(sorted(designer.FAMILIES))}, vertebra)",
                          field="FAMILY")
    parameters = designer.canonical_parameters(family, values)          # GeometryError before meshing
    plausibility.design(parameters, args.mesh_size, parameters_field="", mesh_field="--mesh-size")
    sampling = parse_sampling(args.sampling) if args.material != "linear" else None
    if args.pressurised is not None and sampling is not None:
        sampling["cavities"] = parse_pressurised(args.pressurised)
    if args.nonlinear_mesh_size is not None:
        if sampling is None:
            raise OptionError("a linear entry has no nonlinear part: choose a hyperelastic --material",
                              field="--nonlinear-mesh-size")
        sampling["nonlinear_mesh_size"] = args.nonlinear_mesh_size
    key = designer.entry_key(family, parameters, mesh_size=args.mesh_size, order=args.order, material=args.material,
                             sampling=sampling)

    # lazy: the parser imports every subcommand module; the libraries load for the command that runs
    from vertebra.store import catalogue

    start = time.perf_counter()
    if catalogue.has_entry(args.catalogue, key):
        with catalogue.open_catalogue(args.catalogue) as cat:
            entry = cat.load(key)
        _log(f"key {key} is already in {args.catalogue} (entry {entry.name!r}): reusing it, nothing recomputed")
    else:
        entry = designer.design_segment(family, parameters, mesh_size=args.mesh_size, order=args.order,
                                        name=args.name, linear_solver=args.linear_solver,
                                        estimate_accuracy=not args.no_accuracy, progress=_log,
                                        max_elements=args.max_elements, material=args.material, sampling=sampling,
                                        executor=args.executor, workers=args.workers, scheduler=args.scheduler,
                                        estimate_alongside=(os.cpu_count() or 1) > 1)
        stored = catalogue.add_entry(args.catalogue, entry)
        _log(f"added {entry.name!r} (key {stored}) to {args.catalogue} in {time.perf_counter() - start:.2f} s"
             + ("" if stored.merge_deferred is None else
                f"; stored, merge deferred ({stored.merge_deferred}): the next merge picks it up"))
    if args.export_mesh:
        legend = export_mesh(family, parameters, args.export_mesh, mesh_size=args.mesh_size, order=args.order,
                             max_elements=args.max_elements)
        _log(f"mesh written to {args.export_mesh} (cell data 'group': "
             + ", ".join(f"{k}={v}" for k, v in legend.items()) + ")")
    document = entry_document(entry)
    if args.json:
        _print_json(document)
        return 0
    t = document["timing"]
    acc = entry.accuracy
    print(f"key       {entry.key}\nname      {entry.name}\nfamily    {entry.family}\n"
          f"dofs      {document['dofs']} (order {entry.mesh.get('order')}, h = {entry.mesh.get('mesh_size')})")
    names = ["x", "y", "z", "θx", "θy", "θz"] + [f"V{k}" for k in range(entry.n_cavities)]
    print("compliance diagonal  " + "  ".join(f"{n}={v:.4g}" for n, v in zip(names, entry.compliance.diagonal())))
    if entry.n_cavities:
        print("cavity volumes       " + "  ".join(f"{v:.4g}" for v in entry.cavity_volumes) + " m^3")
    print(f"mass      {entry.mass:.6g} kg, centre of mass {list(map(float, entry.center_of_mass))}")
    if "relative_error" in acc:
        print(f"accuracy  estimated relative compliance error {acc['relative_error']:.3g} ({acc['basis']}; "
              "the better compliance is in the entry)")
    elif acc.get("method") == "unavailable":
        print(f"accuracy  not estimated: {acc['reason']}")
    for warning in acc.get("warnings", []):
        print(f"warning   {warning}")
    if entry.energy is not None:
        energy = document["energy"]
        held = energy["fit_error"].get("held_out", {})
        print(f"energy    {energy['material']['model']}: degree {energy['degree']}, {energy['terms']} terms, "
              f"{energy['sampling']['samples']} samples; held-out load error {held.get('load_max', float('nan')):.3g} "
              f"of the range (linear entry {held.get('linear_load_max', float('nan')):.3g})"
              + (f", volume {held['volume_max']:.3g}" if "volume_max" in held else ""))
        for line in nonlinear_mesh_lines(entry.energy):
            print(line)
        rng, box = energy["range"], energy["sampled"]
        print(f"range     per segment: bending ≤ {box['bending_deg']:.3g}°, twist {box['twist_deg'][0]:.3g}…"
              f"{box['twist_deg'][1]:.3g}°, lateral ≤ {box['lateral_mm']:.3g} mm, axial {box['axial_mm'][0]:.3g}…"
              f"{box['axial_mm'][1]:.3g} mm" + (f", pressure ≤ {max(box['pressure_bar']):.4g} bar"
                                                if box["pressure_bar"] else "")
              + (f" (inflation limit point ≈ {1e-5 * rng['limit_pressure']:.4g} bar)"
                 if rng["limit_pressure"] else ""))
        force = box["axial_force_N"]
        print(f"loads     lateral force ≤ {box['lateral_force_N']:.3g} N, "
              f"axial force {force[0]:.3g}…{force[1]:.3g} N, "
              f"bending moment ≤ {box['bending_moment_Nm']:.3g} N·m, twisting moment "
              f"{box['twist_moment_Nm'][0]:.3g}…{box['twist_moment_Nm'][1]:.3g} N·m")
        if "widen" in box:
            print(f"widen     {box['widen']}")
        for warning in energy.get("warnings", []):
            print(f"warning   {warning}")
    print(f"timing    mesh {t['mesh_s']:.2f} s, assemble {t['assemble_s']:.2f} s, solve {t['solve_s']:.2f} s, "
          f"total {t['total_s']:.2f} s")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry (``python -m cli.design``): ``vertebra design`` with the same exit codes."""
    return vertebra(["design", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())
