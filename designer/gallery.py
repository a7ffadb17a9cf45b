"""Canonical designs reused by the example, the tests, the benchmarks and the demo (STYLE.md §8).

``cbha_catalogue(path)``: a CBHA-like pneumatic trunk (after Festo's Compact Bionic
Handling Assistant): two tapered sections of three chambers, eight vertebrae per
section. Each section tapers linearly; each of its eight intervertebral slices is a
``tapered_pneumatic`` entry with the radii of that slice (16 distinct entries). The
chambers of a section run through its vertebrae, so one scene ``[[chamber]]`` per
chamber spans the eight segments of its section (pressure 0–1.5 bar).
``cbha_design_scene()`` writes the trunk as a scene of design segments (the gallery scene
``gallery:cbha_design``); ``cbha_catalogue(path)`` prepares it into a catalogue.
"""

from __future__ import annotations

from vertebra.designer.accuracy import estimated_error
from vertebra.designer.preparation import Design, prepare_designs
from vertebra.designer.vertebra import vertebra_properties
from vertebra.core.errors import VertebraError
from vertebra.store.catalogue import open_catalogue

#: geometry of the two sections (bottom -> top), SI units
CBHA_SECTIONS = (
    {"length": 0.24, "outer_radius": (0.045, 0.036), "chamber_radius": (0.011, 0.009),
     "chamber_offset": (0.024, 0.019)},
    {"length": 0.20, "outer_radius": (0.036, 0.026), "chamber_radius": (0.009, 0.0065),
     "chamber_offset": (0.019, 0.0135)},
)
CBHA_MATERIAL = {"youngs_modulus": 0.5e6, "poisson_ratio": 0.45, "density": 1100.0}   # soft silicone
CBHA_VERTEBRAE_PER_SECTION = 8
CBHA_MAX_PRESSURE = 1.5e5          # 1.5 bar
CBHA_VERTEBRA = {"thickness": 0.003, "density": 1150.0}                               # rigid polyamide ring


def _lerp(pair, t):
    return pair[0] + (pair[1] - pair[0]) * t


def cbha_slices(coarse: bool = True) -> list[dict]:
    """Parameters, mesh size and name of the 16 tapered slices (bottom to top)."""
    out = []
    n = CBHA_VERTEBRAE_PER_SECTION
    for s, section in enumerate(CBHA_SECTIONS):
        length = section["length"] / n
        for k in range(n):
            t0, t1 = k / n, (k + 1) / n
            p = {"length": length, "chambers": 3, "chamber_angle_deg": 90.0, **CBHA_MATERIAL}
            for name in ("outer_radius", "chamber_radius", "chamber_offset"):
                p[f"bottom_{name}"] = round(_lerp(section[name], t0), 9)
                p[f"top_{name}"] = round(_lerp(section[name], t1), 9)
            r = min(p["bottom_chamber_radius"], p["top_chamber_radius"])
            # coarse: element size 1.2 chamber radii (P2 curved); fine: 0.8 (~3× the DoFs)
            mesh_size = round((1.2 if coarse else 0.8) * r, 6)
            out.append({"name": f"cbha-s{s + 1}-{k + 1}", "section": s, "slice": k,
                        "parameters": p, "mesh_size": mesh_size})
    return out


def cbha_vertebra(section: int, slice_index: int) -> dict:
    """A ring vertebra at the top of a slice: outer radius of the trunk there, holes = chambers."""
    sec = CBHA_SECTIONS[section]
    t = (slice_index + 1) / CBHA_VERTEBRAE_PER_SECTION
    return vertebra_properties({"radius": _lerp(sec["outer_radius"], t), **CBHA_VERTEBRA, "holes": 3,
                                "hole_radius": _lerp(sec["chamber_radius"], t),
                                "hole_offset": _lerp(sec["chamber_offset"], t), "hole_angle_deg": 90.0})


def _cbha_trunk(segments: list[dict], catalogue: str | None, pressures) -> dict:
    """The trunk around its 16 segment tables: chambers, gravity, tip effector."""
    n = CBHA_VERTEBRAE_PER_SECTION
    pressures = pressures or {}
    chambers = []
    for s in range(len(CBHA_SECTIONS)):
        for c in range(3):
            label = f"s{s + 1}c{c}"
            chambers.append({"name": label, "cavity": c, "from": s * n + 1, "to": (s + 1) * n,
                             "pressure": float(pressures.get(label, 0.0)), "min_pressure": 0.0,
                             "max_pressure": CBHA_MAX_PRESSURE})
    length = sum(sec["length"] for sec in CBHA_SECTIONS)
    scene = {"name": "CBHA-like pneumatic trunk", "solver": {"tolerance": 1e-9, "max_iterations": 100},
             "gravity": {"vector": [0.0, 0.0, -9.81]}}
    if catalogue is not None:
        scene["catalogue"] = {"path": catalogue}
    return scene | {"segment": segments, "chamber": chambers,
                    "effector": [{"name": "tip", "vertebra": -1, "offset": [0.0, 0.0, 0.0],
                                  "target": [0.05, 0.0, 0.9 * length], "weight": 1.0}]}


def _vertebra_table(index: int) -> dict:
    v = cbha_vertebra(index // CBHA_VERTEBRAE_PER_SECTION, index % CBHA_VERTEBRAE_PER_SECTION)
    return {"mass": v["mass"], "center_of_mass": v["center_of_mass"]}


def cbha_scene(names: list[str], catalogue: str, pressures=None) -> dict:
    """Scene dictionary (docs/scenes.md) for the 16 entries ``names`` (bottom to top)."""
    segments = [{"type": "entry", "entry": name, "count": 1, "vertebra": _vertebra_table(i)}
                for i, name in enumerate(names)]
    return _cbha_trunk(segments, catalogue, pressures)


def cbha_design_scene(coarse: bool = True, catalogue: str | None = None, pressures=None) -> dict:
    """Scene dictionary of the trunk with its 16 slices as ``type = "design"`` segments (the
    gallery scene ``gallery:cbha_design`` is this, coarse, without a catalogue);
    ``vertebra prepare`` designs them."""
    segments = [{"type": "design", "family": "tapered_pneumatic", "parameters": item["parameters"],
                 "mesh_size": item["mesh_size"], "order": 2, "count": 1, "vertebra": _vertebra_table(i)}
                for i, item in enumerate(cbha_slices(coarse))]
    return _cbha_trunk(segments, catalogue, pressures)


def cbha_catalogue(path, *, coarse: bool = True, estimate_accuracy: bool = True, progress: bool = False,
                   scene_catalogue: str | None = None, pressures=None, executor: str = "serial",
                   workers: int | None = None) -> dict:
    """Design the 16 CBHA slices into the catalogue at ``path`` (``designer.prepare`` of
    :func:`cbha_design_scene`: entries already there, by content key, are reused) and return
    ``{"entries": [{name, key, section, slice, reused, total_s, dofs, accuracy}], "scene": scene
    dict naming the entries by key}``. ``scene_catalogue`` is the catalogue path written in the
    scene (default: ``path`` as given); ``pressures`` maps chamber names (``s1c0`` …) to Pa;
    ``progress`` shows the progress bar on stderr."""
    designs = [Design(i, s["family"], s["parameters"], {"mesh_size": s["mesh_size"], "order": s["order"]})
               for i, s in enumerate(cbha_design_scene(coarse)["segment"])]
    report = prepare_designs(designs, path, source="designer.gallery.cbha_design_scene", label="prepare CBHA slices",
                             executor=executor, workers=workers, estimate_accuracy=estimate_accuracy,
                             progress=progress)
    if report.exit_code:
        raise VertebraError("designing the CBHA slices failed:\n" + report.summary())
    seconds = {outcome.key: outcome.seconds for outcome in report.run.completed}
    rows = []
    with open_catalogue(path) as cat:
        for item, prepared in zip(cbha_slices(coarse), report.segments):
            entry = cat.load(prepared.key)
            rows.append({k: item[k] for k in ("name", "section", "slice")}
                        | {"key": prepared.key, "reused": prepared.status == "reused",
                           "total_s": seconds.get(prepared.key, 0.0), "dofs": entry.mesh["dofs"],
                           "accuracy": estimated_error(entry.accuracy)})
    scene = cbha_scene([r["key"] for r in rows], str(path) if scene_catalogue is None else scene_catalogue,
                       pressures)
    return {"entries": rows, "scene": scene}
