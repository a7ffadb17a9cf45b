"""Designer angles are given in degrees, spelt ``…_deg`` as in scene files."""

import math

import pytest

from vertebra.designer.families import FAMILIES
from vertebra.designer.families.pneumatic import chamber_centres
from vertebra.designer.vertebra import vertebra_properties
from vertebra.core.errors import GeometryError

PNEUMATIC = {"outer_radius": 0.02, "length": 0.01, "chamber_radius": 0.004, "chamber_offset": 0.01,
             "youngs_modulus": 1e6, "poisson_ratio": 0.45}


@pytest.mark.parametrize("family", ["pneumatic", "tapered_pneumatic"])
def test_every_designer_angle_parameter_is_in_degrees(family):
    angles = [p for p in FAMILIES[family].parameters if "angle" in p.name]
    assert angles and all(p.name.endswith("_deg") and p.unit == "deg" for p in angles)


def test_radian_spelling_is_refused_naming_the_degree_parameter():
    with pytest.raises(GeometryError, match="'chamber_angle' is spelt 'chamber_angle_deg'"):
        FAMILIES["pneumatic"].canonical({**PNEUMATIC, "chamber_angle": 90})
    with pytest.raises(GeometryError, match="'hole_angle' is spelt 'hole_angle_deg'"):
        vertebra_properties({"radius": 0.02, "thickness": 0.003, "density": 1200, "hole_angle": 1.0})


def test_chamber_and_hole_angles_are_degrees():
    # 90° puts chamber 0 (and hole 0) on +y exactly where radians would put it at 90 rad ≈ 116.6°
    p = FAMILIES["pneumatic"].canonical({**PNEUMATIC, "chamber_angle_deg": 90})
    x, y = chamber_centres(p, p["chamber_offset"])[0]
    assert abs(x) < 1e-15 and math.isclose(y, 0.01, rel_tol=1e-15)
    holes = vertebra_properties({"radius": 0.02, "thickness": 0.003, "density": 1200, "holes": 3,
                                 "hole_radius": 0.002, "hole_offset": 0.01, "hole_angle_deg": 90})["holes"]
    assert [round(h["angle_deg"], 9) for h in holes] == [90.0, 210.0, 330.0]


def test_design_cli_refuses_radian_spelling_with_exit_2(capsys):
    from vertebra.cli.main import main

    argv = ["design", "pneumatic", "--catalogue", "unused.h5", "--set", "chamber_angle=90"]
    argv += [item for name, value in PNEUMATIC.items() for item in ("--set", f"{name}={value}")]
    assert main(argv) == 2
    assert "chamber_angle_deg" in capsys.readouterr().err
