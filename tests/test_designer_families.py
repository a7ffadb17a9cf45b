"""Design parameters, impossible geometry, content keys and vertebra mass properties.

No meshing here: GeometryError must come BEFORE gmsh is touched, and keys are
computed without meshing — so this file is fast.
"""

from __future__ import annotations

import math
import sys

import numpy as np
import pytest

from vertebra import designer
from vertebra.core.errors import GeometryError

MATERIAL = dict(youngs_modulus=1e6, poisson_ratio=0.45)
VALID = {
    "rod": dict(radius=0.01, length=0.04, **MATERIAL),
    "tube": dict(outer_radius=0.01, inner_radius=0.006, length=0.04, **MATERIAL),
    "bellows": dict(inner_radius=0.008, outer_radius=0.014, wall_thickness=0.0015, length=0.02, **MATERIAL),
    "pneumatic": dict(outer_radius=0.02, chamber_radius=0.005, chamber_offset=0.011, length=0.02, **MATERIAL),
    "tapered_pneumatic": dict(bottom_outer_radius=0.02, top_outer_radius=0.016, bottom_chamber_radius=0.005,
                              top_chamber_radius=0.004, bottom_chamber_offset=0.011, top_chamber_offset=0.009,
                              length=0.02, **MATERIAL),
}


def test_registry_has_the_families_of_issue_3():
    assert set(designer.FAMILIES) >= set(VALID)


@pytest.mark.parametrize("family", sorted(VALID))
def test_canonical_parameters_fill_defaults_and_normalise(family):
    p = designer.canonical_parameters(family, VALID[family])
    assert p["density"] == 0.0                                   # default filled
    assert all(isinstance(v, (int, float)) for v in p.values())
    again = designer.canonical_parameters(family, {k: str(v) for k, v in p.items()})
    assert again == p                                            # strings from the CLI parse to the same


# (family, override, parameter named in the message, condition words in the message)
IMPOSSIBLE = [
    ("rod", {"radius": 0.0}, "radius", "> 0"),
    ("rod", {"poisson_ratio": 0.5}, "poisson_ratio", "< 0.5"),
    ("rod", {"youngs_modulus": -1.0}, "youngs_modulus", "> 0"),
    ("tube", {"inner_radius": 0.012}, "outer_radius", "wall thickness"),
    ("bellows", {"wall_thickness": 0.0}, "wall_thickness", "> 0"),
    ("bellows", {"wall_thickness": 0.007}, "outer_radius", "corrugation"),
    ("pneumatic", {"chamber_offset": 0.016}, "chamber_offset", "pierce the outer wall"),
    ("pneumatic", {"chamber_offset": 0.008, "chamber_radius": 0.0075}, "chamber_radius", "intersect"),
    ("pneumatic", {"inner_radius": 0.007}, "inner_radius", "central bore"),
    ("pneumatic", {"chambers": 0}, "chambers", ">= 1"),
    ("tapered_pneumatic", {"top_chamber_offset": 0.0125}, "top_chamber_offset", "pierce the outer wall"),
    ("tapered_pneumatic", {"bottom_chamber_offset": 0.008, "bottom_chamber_radius": 0.0075}, "bottom_chamber_radius",
     "intersect"),
]


@pytest.mark.parametrize("family,override,parameter,words", IMPOSSIBLE)
def test_impossible_geometry_raises_before_meshing(family, override, parameter, words):
    gmsh_loaded = "gmsh" in sys.modules
    with pytest.raises(GeometryError) as info:
        designer.design_segment(family, {**VALID[family], **override}, estimate_accuracy=False)
    message = str(info.value)
    assert repr(parameter) in message and words in message
    assert ("gmsh" in sys.modules) == gmsh_loaded                # nothing was meshed: gmsh not even imported


def test_unknown_and_missing_parameters_are_named():
    with pytest.raises(GeometryError, match="'radius' is required"):
        designer.canonical_parameters("rod", {"length": 0.04, **MATERIAL})
    with pytest.raises(GeometryError, match="unknown parameter 'raduis'"):
        designer.canonical_parameters("rod", {**VALID["rod"], "raduis": 0.01})
    with pytest.raises(GeometryError, match="unknown family 'spring'"):
        designer.canonical_parameters("spring", {})
    with pytest.raises(GeometryError, match="'chambers': must be an integer"):
        designer.canonical_parameters("pneumatic", {**VALID["pneumatic"], "chambers": 2.5})


def test_entry_key_is_content_addressed_without_meshing():
    p = VALID["pneumatic"]
    key = designer.entry_key("pneumatic", p)
    # same content spelled differently (defaults explicit, key order) -> same key
    spelled = dict(reversed(list({**p, "density": 0.0, "chambers": 3}.items())))
    assert designer.entry_key("pneumatic", spelled) == key
    # every result-changing setting changes it
    others = {designer.entry_key("pneumatic", {**p, "poisson_ratio": 0.3}),
              designer.entry_key("pneumatic", p, order=1),
              designer.entry_key("pneumatic", p, mesh_size=0.003),
              designer.entry_key("tapered_pneumatic", VALID["tapered_pneumatic"])}
    assert key not in others and len(others) == 4
    # the default mesh size is resolved into the key: explicit default = implicit
    h = designer.resolve_mesh_size("pneumatic", p)
    assert designer.entry_key("pneumatic", p, mesh_size=h) == key


def test_vertebra_solid_disc_matches_closed_form():
    R, t, rho = 0.02, 0.004, 1200.0
    props = designer.vertebra_properties(dict(radius=R, thickness=t, density=rho))
    m = rho * math.pi * R ** 2 * t
    # closed form of a solid cylinder about its centre; exact arithmetic up to round-off
    assert props["mass"] == pytest.approx(m, rel=1e-12)
    np.testing.assert_allclose(props["inertia"], np.diag([m * (3 * R ** 2 + t ** 2) / 12] * 2 + [m * R ** 2 / 2]),
                               rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(props["center_of_mass"], 0.0, atol=1e-15)


def test_vertebra_holes_mass_centre_and_snippet():
    R, t, rho, r, d = 0.02, 0.003, 1000.0, 0.002, 0.014
    sym = designer.vertebra_properties(dict(radius=R, thickness=t, density=rho, holes=4, hole_radius=r,
                                            hole_offset=d))
    assert sym["mass"] == pytest.approx(rho * t * math.pi * (R ** 2 - 4 * r ** 2), rel=1e-12)
    np.testing.assert_allclose(sym["center_of_mass"], 0.0, atol=1e-15)      # symmetric holes
    assert [round(h["angle_deg"]) for h in sym["holes"]] == [0, 90, 180, 270]
    one = designer.vertebra_properties(dict(radius=R, thickness=t, density=rho, holes=1, hole_radius=r,
                                            hole_offset=d))
    # one hole at +x: centre of mass moves to −x by m_hole d / m (lever rule, exact)
    m_hole = rho * t * math.pi * r ** 2
    assert one["center_of_mass"][0] == pytest.approx(-m_hole * d / one["mass"], rel=1e-12)
    assert np.allclose(np.array(one["inertia"]), np.array(one["inertia"]).T)
    snippet = designer.vertebra_snippet(sym)
    assert snippet.startswith("vertebra = { mass = ") and "center_of_mass = [" in snippet
    import tomllib
    parsed = tomllib.loads(snippet)["vertebra"]
    assert parsed["mass"] == pytest.approx(sym["mass"], rel=1e-5)


def test_vertebra_impossible_holes():
    with pytest.raises(GeometryError, match="'hole_offset'.*rim"):
        designer.vertebra_properties(dict(radius=0.02, thickness=0.003, density=1000, holes=3, hole_radius=0.002,
                                          hole_offset=0.019))
    with pytest.raises(GeometryError, match="'hole_radius'.*intersect"):
        designer.vertebra_properties(dict(radius=0.02, thickness=0.003, density=1000, holes=12, hole_radius=0.002,
                                          hole_offset=0.007))
